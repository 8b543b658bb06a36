"""Load a trained run for export: the model from its config and checkpoint, without nerfstudio's datamanager.

nerfstudio's ``eval_setup`` builds the whole training pipeline to evaluate a run: it imports every registered
method, sets up the datamanager (datasets, samplers), reads the seed point cloud and seeds the Gaussians from
it (a k-nearest-neighbour search over all seed points), and only then replaces them by the checkpoint's. An
export needs none of that: this loader parses the dataset's cameras and material legend (transforms.json,
materials.json: no image is opened), builds the model with a one-Gaussian placeholder (no
nearest-neighbour seeding, ``placeholder_gaussians``), and loads the model's part
of the checkpoint through a memory map (the optimizers' moments, twice the model's size, are never read).
The model is the one ``eval_setup`` would build (same class, config, legend, camera count and state dict).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

logger = logging.getLogger(__name__)

__all__ = ["RunModel", "load_run_model"]


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


def _model_state(checkpoint: Path) -> tuple[dict[str, torch.Tensor], int]:
    """The model's tensors of a nerfstudio checkpoint (``pipeline`` entries under ``_model.``, DDP's
    ``module.`` prefixes removed), read through a memory map."""
    try:
        loaded = torch.load(checkpoint, map_location="cpu", mmap=True, weights_only=True)
    except RuntimeError:  # a checkpoint not in the zip format cannot be memory-mapped
        loaded = torch.load(checkpoint, map_location="cpu", weights_only=True)
    state = {}
    for key, value in loaded["pipeline"].items():
        key = key.removeprefix("module.")
        if key.startswith("_model."):
            key = key[len("_model."):]
            state[key.removeprefix("module.")] = value
    return state, int(loaded.get("step", 0))


def load_run_model(config: Any, checkpoint: Path) -> RunModel:
    """The trained model and the training split's dataparser outputs of a run: its ``config`` (the TrainerConfig
    that :func:`.runcheck.check_run` read safely) and the ``checkpoint`` it chose (module doc)."""
    dm = config.pipeline.datamanager
    dp_config = dm.dataparser
    if getattr(dm, "data", None) is not None:  # as the datamanager does
        dp_config.data = Path(dm.data)
    else:
        dm.data = dp_config.data
    if hasattr(dp_config, "load_3D_points"):
        dp_config.load_3D_points = False  # seed points are replaced by the checkpoint's Gaussians
    dataparser = dp_config.setup()
    dataparser.downscale_factor = 1  # as eval_setup(test_mode="inference"): never open an image
    dpo = dataparser.get_dataparser_outputs(split="train")
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
