"""Load a trained run for export: its property field's tensors from the checkpoint and its cameras from the
dataset, without nerfstudio's datamanager and without building the model.

nerfstudio's ``eval_setup`` builds the whole training pipeline to evaluate a run: it imports every registered
method, sets up the datamanager (datasets, samplers), reads the seed point cloud and seeds the Gaussians from
it (a k-nearest-neighbour search over all seed points), and only then replaces them by the checkpoint's. An
export needs none of that: this loader parses the dataset's cameras and material legend (transforms.json,
materials.json: no image is opened), builds the model with a one-Gaussian placeholder (no
nearest-neighbour seeding, ``placeholder_gaussians``), and loads the model's part
of the checkpoint through a memory map (the optimizers' moments, twice the model's size, are never read).
The model is the one ``eval_setup`` would build (same class, config, legend, camera count and state dict).

An export does not even build the model (:func:`load_run_state`): the field is a function of the checkpoint's
model tensors, the legend and two numbers of the model's config (:meth:`physgs_nerfstudio.export.field.PropertyField.from_state`), so
the config is read as a tree of names (:func:`physgs_nerfstudio.safe_yaml.load_config_tree`) and the training
cameras are read without nerfstudio (:func:`.train_split.read_train_split`, the same values as its dataparser;
where that reader cannot reproduce it, only the dataparser's config is built and nerfstudio's dataparser runs).
splatfacto, the viewer and nerfstudio's trainer are never imported; that import was most of an export's fixed
cost. :func:`load_run_model` (the model itself) stays for callers that need it.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

logger = logging.getLogger(__name__)

__all__ = ["RunModel", "RunState", "load_run_model", "load_run_state"]


@dataclass
class RunModel:
    config: Any
    """the run's TrainerConfig"""
    model: Any
    """the trained model, on the CPU, in eval mode"""
    dataparser_outputs: Any
    """the training split's DataparserOutputs (cameras in the scene frame, image and map paths, legend)"""
    checkpoint: Path
    step: int


MODEL_DEFAULTS = {"dirichlet_alpha0": None, "dirichlet_lambda": None, "material_weights": "dominant"}
"""PhysGSModelConfig's defaults of the fields an export reads, for configs written before a field existed (a test
holds them equal to the class's; importing it would import splatfacto)"""


@dataclass
class RunState:
    model_config: Any
    """the run's model config, a :class:`~physgs_nerfstudio.safe_yaml.ConfigObject` (fields by name)"""
    state: dict[str, torch.Tensor]
    """the model's tensors of the checkpoint (memory-mapped)"""
    dataparser_outputs: Any
    """the training split's DataparserOutputs (cameras in the scene frame, image and map paths, legend)"""
    checkpoint: Path
    step: int

    def material_weights(self) -> str:
        """The model config's ``material_weights`` (PhysGSModelConfig's default when an older config lacks it)."""
        return getattr(self.model_config, "material_weights", MODEL_DEFAULTS["material_weights"])

    def prior(self) -> tuple[float, float]:
        """The model's Dirichlet prior alpha0 and evidence strength lambda: its config's, else the legend's, else
        1 (PhysGSModel.populate_modules)."""
        legend = self.dataparser_outputs.metadata["material_legend"]
        out = []
        for name, fallback in (("dirichlet_alpha0", legend.alpha0), ("dirichlet_lambda", legend.lam)):
            value = getattr(self.model_config, name, MODEL_DEFAULTS[name])
            value = fallback if value is None else value
            out.append(1.0 if value is None else float(value))
        return out[0], out[1]


def _checked_dataparser(dp_config: Any) -> Any:
    """The run's dataparser config, built only after :func:`.check.check_dataparser` passed it."""
    from .check import check_dataparser

    check_dataparser(dp_config)
    return dp_config.build() if hasattr(dp_config, "build") else dp_config


def _dataparser_outputs(config: Any, run_dir: Path | None = None) -> Any:
    """The training split's DataparserOutputs of a run config (a built one or a ConfigObject tree), as
    ``eval_setup(test_mode="inference")`` makes them: no image opened, no seed points read. With the tree and
    ``run_dir`` (the folder of its dataparser_transforms.json), :func:`.train_split.read_train_split` reads the
    same without importing nerfstudio where it can (a debug line says why not)."""
    from ..safe_yaml import ConfigObject

    dm = config.pipeline.datamanager
    if run_dir is not None and isinstance(config, ConfigObject):
        from .train_split import Unsupported, read_train_split

        try:
            dpo = read_train_split(dm.dataparser, getattr(dm, "data", None), Path(run_dir))
            if getattr(dm, "data", None) is None:  # as below
                dm.data = dm.dataparser.data
            return dpo
        except Unsupported as why:
            logger.debug("reading the training cameras through nerfstudio's dataparser: %s", why)
    dp_config = _checked_dataparser(dm.dataparser)
    if getattr(dm, "data", None) is not None:  # as the datamanager does
        dp_config.data = Path(dm.data)
    else:
        dm.data = dp_config.data
    if hasattr(dp_config, "load_3D_points"):
        dp_config.load_3D_points = False  # seed points are replaced by the checkpoint's Gaussians
    dataparser = dp_config.setup()
    dataparser.downscale_factor = 1  # as eval_setup(test_mode="inference"): never open an image
    return dataparser.get_dataparser_outputs(split="train")


def load_run_state(config: Any, checkpoint: Path, run_dir: Path | None = None) -> RunState:
    """The model's checkpoint tensors and the training split's dataparser outputs of a run (module doc): its
    ``config`` as :func:`.check.check_run` read it, the ``checkpoint`` it chose and its ``run_dir`` (where
    dataparser_transforms.json is; without it the cameras are read through nerfstudio's dataparser)."""
    dpo = _dataparser_outputs(config, run_dir)
    if run_dir is not None:
        check_run_manifest(Path(run_dir), getattr(config.pipeline.datamanager, "data", None), dpo.metadata)
    check_poses(dpo)
    state, step = _model_state(Path(checkpoint))
    legend = dpo.metadata.get("material_legend")
    check_state(state, Path(checkpoint), legend.num_materials if legend is not None else None)
    return RunState(config.pipeline.model, state, dpo, Path(checkpoint), step)


def check_run_manifest(run_dir: Path, data: Path | str | None, metadata: Any) -> None:
    """:func:`physgs_nerfstudio.runfiles.manifest.check_manifest` (the run was trained with this dataset's legend,
    posteriors and maps); one line on stderr for a run without a manifest."""
    import sys

    from .manifest import MANIFEST, check_manifest, dataset_dir

    data_dir = dataset_dir(data)
    if data_dir is None or metadata is None or "material_legend" not in metadata:
        return
    if not check_manifest(Path(run_dir), data_dir, metadata):
        print(f"physgs: {Path(run_dir) / MANIFEST} not found (a run trained before runs recorded one): the legend and "
              "maps it was trained with are not checked.", file=sys.stderr)  # fmt: skip


STATE_KEYS = ("means", "scales", "quats", "opacities", "dirichlet_evidence")
"""the model tensors (``gauss_params.*``) an export reads, each checked to be there and finite"""
_NIG_KEYS = ("nig_tau", "nig_kappa", "nig_a", "nig_b")


def check_state(state: dict[str, torch.Tensor], checkpoint: Path, num_materials: int | None = None) -> None:
    """:class:`~.check.RunFilesError` naming the checkpoint unless it holds a PhysGS model's tensors
    (:data:`STATE_KEYS` and the NIG posteriors), all finite, with one evidence column per material of the legend
    (``num_materials``; None: not checked)."""
    from .check import RunFilesError

    missing = [k for k in (*(f"gauss_params.{k}" for k in STATE_KEYS), *_NIG_KEYS) if k not in state]
    if missing:
        raise RunFilesError(f"{checkpoint}: not a PhysGS checkpoint (no {missing[0]}: a splatfacto run, or another "
                            "model's); export a run of `ns-train physgs` or `physgs-lite`.")  # fmt: skip
    for key in (*(f"gauss_params.{k}" for k in STATE_KEYS), *_NIG_KEYS):
        value = state[key]
        if not isinstance(value, torch.Tensor):
            raise RunFilesError(f"{checkpoint}: {key} is not a tensor; the checkpoint is damaged: retrain.")
        bad = int((~torch.isfinite(value.float())).sum()) if value.is_floating_point() else 0
        if bad:
            raise RunFilesError(f"{checkpoint}: {key} holds {bad} NaN or infinite values of {value.numel()}: training "
                                "diverged; retrain (a lower learning rate, or an earlier checkpoint with "
                                "--load-step).")  # fmt: skip
    k = state["gauss_params.dirichlet_evidence"].shape[-1]
    if num_materials is not None and k != num_materials:
        raise RunFilesError(f"{checkpoint}: the model was trained with {k} materials, the dataset's materials.json "
                            f"lists {num_materials} (perception was rerun after training); restore the materials.json "
                            "it was trained with, or retrain.")  # fmt: skip


def check_poses(dpo: Any) -> None:
    """:class:`~.check.RunFilesError` naming the frame when a training camera's pose is not finite or its
    rotation is degenerate (an all-zero transform_matrix)."""
    from .check import RunFilesError

    c2w = torch.as_tensor(dpo.cameras.camera_to_worlds).float()
    finite = torch.isfinite(c2w).flatten(1).all(1)
    det = torch.where(finite, torch.linalg.det(torch.nan_to_num(c2w[:, :3, :3])), torch.zeros(()))
    bad = torch.nonzero(~finite | (det.abs() < 1e-6)).flatten()
    if len(bad):
        i = int(bad[0])
        name = dpo.image_filenames[i] if i < len(dpo.image_filenames) else f"camera {i}"
        why = "not finite (NaN or infinite values)" if not bool(finite[i]) else "degenerate (an all-zero rotation)"
        raise RunFilesError(f"transforms.json: the pose of frame {name} is {why} ({len(bad)} such frame(s)); fix its "
                            "transform_matrix (or remove the frame) and retrain.")  # fmt: skip


def _model_state(checkpoint: Path) -> tuple[dict[str, torch.Tensor], int]:
    """The model's tensors of a nerfstudio checkpoint (``pipeline`` entries under ``_model.``, DDP's
    ``module.`` prefixes removed), read through a memory map."""
    import pickle

    from .check import RunFilesError

    try:
        try:
            loaded = torch.load(checkpoint, map_location="cpu", mmap=True, weights_only=True)
        except RuntimeError:  # a checkpoint not in the zip format cannot be memory-mapped
            loaded = torch.load(checkpoint, map_location="cpu", weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError, ValueError, AttributeError) as err:
        why = " ".join(str(err).split())[:160]
        raise RunFilesError(f"{checkpoint}: not a checkpoint of tensors ({type(err).__name__}: {why}); it was not "
                            "run. Use the checkpoint ns-train wrote, or retrain.") from None  # fmt: skip
    pipeline = loaded.get("pipeline") if isinstance(loaded, dict) else None
    if not isinstance(pipeline, dict):
        raise RunFilesError(f"{checkpoint}: no \"pipeline\" state in the checkpoint; use the checkpoint ns-train "
                            "wrote, or retrain.")  # fmt: skip
    state = {}
    for key, value in pipeline.items():
        key = key.removeprefix("module.")
        if key.startswith("_model."):
            key = key[len("_model."):]
            state[key.removeprefix("module.")] = value
    return state, int(loaded.get("step", 0))


def load_run_model(config: Any, checkpoint: Path) -> RunModel:
    """The trained model and the training split's dataparser outputs of a run: its ``config`` (the TrainerConfig
    that :func:`.check.check_run` read safely) and the ``checkpoint`` it chose (module doc)."""
    if hasattr(config, "build"):  # a ConfigObject tree (check_run's): the real TrainerConfig
        config = config.build()
    dpo = _dataparser_outputs(config)
    state, step = _model_state(Path(checkpoint))
    model = config.pipeline.model.setup(scene_box=dpo.scene_box, num_train_data=len(dpo.image_filenames),
                                        metadata=dpo.metadata, device="cpu", grad_scaler=None, seed_points=None,
                                        placeholder_gaussians=True)  # fmt: skip
    model.update_to_step(step)
    try:
        model.load_state_dict(state, strict=True)
    except RuntimeError as err:  # as nerfstudio's Pipeline.load_state_dict: retry without strict key matching
        logger.warning("checkpoint %s does not match the model exactly (%s); loading the matching entries",
                       checkpoint, str(err).splitlines()[0][:160])  # fmt: skip
        model.load_state_dict(state, strict=False)
    model.eval()
    return RunModel(config, model, dpo, Path(checkpoint), step)
