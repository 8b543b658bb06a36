"""The training split of a run's dataset (cameras, image and material-map filenames, legend) without nerfstudio.

What nerfstudio's ``Nerfstudio`` dataparser (and ``PhysGSDataParser`` on top of it) returns for
``get_dataparser_outputs(split="train")`` as ``eval_setup(test_mode="inference")`` sets it up (downscale factor 1:
no image opened), read from the dataset's ``transforms.json`` and the run's ``dataparser_transforms.json``
instead: importing nerfstudio's ``Cameras`` (``camera_utils`` scripts functions with ``torch.jit`` at import,
``torch.broadcast_shapes`` imports sympy) was most of what an export still spent before its own work.

The same frames in the same order (sorted by image filename as :class:`pathlib.Path` objects compare), the same
split (``eval_mode`` fraction, filename, interval, all, or transforms.json's ``{train,val,test}_filenames``
lists), the same poses: the dataparser orients, centres and scales the poses of *all* frames (``transform``,
3x4, and ``scale``, which training saved in ``dataparser_transforms.json``), then keeps the split's. Here the
saved transform is applied to all frames with the same float32 operations, so every value is bit-equal to
nerfstudio's (``tests/test_export_train_split.py`` holds them equal for every split mode).

:func:`read_train_split` raises :class:`Unsupported` (the caller falls back to nerfstudio's dataparser) where
the saved transform is not the one the poses got or the dataset uses what this reader does not read: no
``dataparser_transforms.json``; another dataparser class; ``pca`` orientation (nerfstudio flips poses, not only
the transform, there); an ``applied_scale`` or an ``applied_transform`` that is not a signed axis permutation
(COLMAP's is one); a camera model other than a pinhole one (PINHOLE, SIMPLE_PINHOLE, OPENCV, ...); mask or
depth paths; frames sharing an image; and anything nerfstudio itself would refuse (a missing intrinsic, an
unknown split mode, a bad split list): nerfstudio then says what is wrong in its own words.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from jaxtyping import Float, Int
from torch import Tensor

from .legend import MaterialsFileError, check_material_paths, frame_material_maps, load_legend

__all__ = ["TrainCameras", "TrainSplit", "Unsupported", "read_train_split"]

DATAPARSER_CONFIG = "physgs_nerfstudio.nerfstudio.dataparser.PhysGSDataParserConfig"
DATAPARSER = "physgs_nerfstudio.nerfstudio.dataparser.PhysGSDataParser"
PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
"""camera models nerfstudio maps to its PERSPECTIVE camera (any distortion is kept, as there)"""
_DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
"""nerfstudio's order of the distortion parameters"""
_COLMAP_APPLIED = [[0.0, 1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0]]
"""the applied transform nerfstudio assumes for a dataset with a colmap/sparse/0 folder and none listed"""
_CONFIG_FIELDS = ("data", "eval_mode", "train_split_fraction", "eval_interval", "orientation_method",
                  "materials_file", "depth_unit_scale_factor", "mask_color")  # fmt: skip


class Unsupported(Exception):
    """The fast reader does not reproduce nerfstudio's dataparser for this run (the message says why)."""


@dataclass
class TrainCameras:
    """The attributes of nerfstudio's ``Cameras`` that the export reads, same shapes and dtypes."""

    camera_to_worlds: Float[Tensor, "n 3 4"]
    """scene frame, OpenGL camera axes"""
    fx: Float[Tensor, "n 1"]
    fy: Float[Tensor, "n 1"]
    cx: Float[Tensor, "n 1"]
    cy: Float[Tensor, "n 1"]
    width: Int[Tensor, "n 1"]
    height: Int[Tensor, "n 1"]
    distortion_params: Float[Tensor, "n 6"]
    """k1, k2, k3, k4, p1, p2 (the export renders undistorted pinhole views, as with nerfstudio's cameras)"""

    def __len__(self) -> int:
        return int(self.camera_to_worlds.shape[0])


@dataclass
class TrainSplit:
    """The fields of nerfstudio's ``DataparserOutputs`` that the export reads (module doc)."""

    cameras: TrainCameras
    image_filenames: list[Path]
    metadata: dict[str, Any] = field(default_factory=dict)
    """``material_filenames``, ``material_confidence_filenames``, ``material_legend`` and nerfstudio's
    ``depth_filenames`` (None), ``depth_unit_scale_factor``, ``mask_color``"""


def _config_fields(dp_config: Any) -> dict[str, Any]:
    class_name = getattr(dp_config, "class_name", None)
    if class_name != DATAPARSER_CONFIG:
        raise Unsupported(f"dataparser config {class_name or type(dp_config).__name__}, not {DATAPARSER_CONFIG}")
    target = getattr(getattr(dp_config, "fields", {}).get("_target"), "name", None)
    if target != DATAPARSER:
        raise Unsupported(f"dataparser class {target}, not {DATAPARSER}")
    missing = [name for name in _CONFIG_FIELDS if name not in dp_config.fields]
    if missing:
        raise Unsupported(f"the dataparser config lacks {', '.join(missing)}")
    return {name: dp_config.fields[name] for name in _CONFIG_FIELDS}


def _saved_transform(run_dir: Path, meta: dict, data: Path) -> tuple[Tensor, float]:
    """The transform and scale the dataparser applied to the poses (its ``transform_matrix`` and
    ``scale_factor``), from dataparser_transforms.json, which holds them composed with the dataset's
    ``applied_transform`` and ``applied_scale``."""
    path = Path(run_dir) / "dataparser_transforms.json"
    if not path.is_file():
        raise Unsupported(f"{path} not found")
    saved = json.loads(path.read_text())
    transform = torch.tensor(saved["transform"], dtype=torch.float32)
    scale = float(saved["scale"])
    if transform.shape != (3, 4) or not math.isfinite(scale):
        raise Unsupported(f"{path}: transform {tuple(transform.shape)} or scale {scale} unusable")
    if float(meta.get("applied_scale", 1.0)) != 1.0:
        raise Unsupported("transforms.json has an applied_scale (the saved scale includes it)")
    applied = meta.get("applied_transform")
    if applied is None and (data / "colmap/sparse/0").exists():
        applied = _COLMAP_APPLIED
    if applied is not None:
        a = torch.tensor(applied, dtype=torch.float32)
        rot = a[:, :3]
        if a.shape != (3, 4) or a[:, 3].any() or not (rot.abs().sum(0) == 1).all() or not (rot.abs().sum(1) == 1).all():
            raise Unsupported("transforms.json's applied_transform is not a signed axis permutation")
        # saved = transform @ [applied; 0 0 0 1]; a signed permutation's inverse is its transpose, and every
        # product here has one nonzero term, so this recovers the transform exactly
        a4 = torch.cat([a, torch.tensor([[0.0, 0.0, 0.0, 1.0]])], 0)
        transform = transform @ a4.T
    return transform, scale


def _intrinsic(meta: dict, frames: list[dict], key: str, cast: type) -> list:
    """Per frame ``key`` (top level of transforms.json when there, else each frame's), as nerfstudio reads it."""
    if key in meta:
        return [cast(meta[key])] * len(frames)
    return [cast(f[key]) for f in frames]


def _distortion(source: dict) -> list[float]:
    if "distortion_params" in source:
        return [float(v) for v in source["distortion_params"]]
    return [float(source.get(k, 0.0)) for k in _DISTORTION_KEYS]


def _split_indices(cfg: dict[str, Any], meta: dict, image_filenames: list[Path], data_dir: Path) -> list[int]:
    """The training frames' indices into the sorted frames, as nerfstudio's dataparser chooses them."""
    n = len(image_filenames)
    if "train_filenames" in meta:
        wanted = {data_dir / Path(x) for x in meta["train_filenames"]}
        if wanted - set(image_filenames):
            raise Unsupported("train_filenames lists images that are not frames")
        return [i for i, name in enumerate(image_filenames) if name in wanted]
    if "val_filenames" in meta or "test_filenames" in meta:
        raise Unsupported("transforms.json lists val or test filenames but no train_filenames")
    mode = cfg["eval_mode"]
    if mode == "fraction":
        fraction = float(cfg["train_split_fraction"])
        num_train = math.ceil(n * fraction)
        if not 1 <= num_train <= n:
            raise Unsupported(f"train_split_fraction {fraction} of {n} frames")
        return [int(i) for i in np.linspace(0, n - 1, num_train, dtype=int)]  # evenly spaced, first and last
    if mode == "filename":
        names = [os.path.basename(str(p)) for p in image_filenames]
        if any("train" not in b and "eval" not in b for b in names):
            raise Unsupported("eval_mode filename with a frame named neither train nor eval")
        return [i for i, b in enumerate(names) if "train" in b]
    if mode == "interval":
        interval = cfg["eval_interval"]
        return [i for i in range(n) if i % interval != 0]
    if mode == "all":
        return list(range(n))
    raise Unsupported(f"eval_mode {mode!r}")


def _check_frames(meta: dict, frames: list[dict]) -> None:
    model = meta.get("camera_model", "PINHOLE")
    if model not in PINHOLE_MODELS:
        raise Unsupported(f"camera model {model}")
    if "orientation_override" in meta:
        raise Unsupported("transforms.json overrides the orientation method")
    for key in ("mask_path", "depth_file_path"):
        if any(key in f for f in frames):
            raise Unsupported(f"frames with a {key}")
    if any(np.asarray(f["transform_matrix"]).shape != (4, 4) for f in frames):
        raise Unsupported("a frame's transform_matrix is not 4x4")


def _cameras(meta: dict, frames: list[dict], order: list[int], train: list[int], transform: Tensor,
             scale: float) -> TrainCameras:  # fmt: skip
    """The training cameras: every frame's pose transformed (as the dataparser, on all frames in sorted order),
    then the training frames' poses and intrinsics."""
    sorted_frames = [frames[i] for i in order]
    poses = torch.from_numpy(np.array([f["transform_matrix"] for f in sorted_frames]).astype(np.float32))
    poses = transform @ poses
    poses[:, :3, 3] *= scale
    pick = torch.tensor(train, dtype=torch.long)
    train_frames = [sorted_frames[i] for i in train]

    def column(key: str, cast: type, dtype: torch.dtype) -> Tensor:
        return torch.tensor(_intrinsic(meta, train_frames, key, cast), dtype=dtype).reshape(-1, 1)

    fixed = any(k in meta for k in (*_DISTORTION_KEYS[:3], "p1", "p2", "distortion_params"))
    distortion = [_distortion(meta)] * len(train_frames) if fixed else [_distortion(f) for f in train_frames]
    # nerfstudio's rescale_output_resolution(1.0): the sizes go through float32 and back to int64
    size = {k: (column(k, int, torch.int64) * torch.tensor([1.0])).to(torch.int64) for k in ("w", "h")}
    return TrainCameras(poses[pick][:, :3, :4], column("fl_x", float, torch.float32),
                        column("fl_y", float, torch.float32), column("cx", float, torch.float32),
                        column("cy", float, torch.float32), size["w"], size["h"],
                        torch.tensor(distortion, dtype=torch.float32).reshape(len(train_frames), -1))  # fmt: skip


def read_train_split(dp_config: Any, data: Path | None, run_dir: Path) -> TrainSplit:
    """The training split of a run (module doc): ``dp_config`` its dataparser config as
    :func:`~physgs_nerfstudio.safe_yaml.load_config_tree` read it, ``data`` the datamanager's dataset path (None:
    the dataparser's), ``run_dir`` the folder of its dataparser_transforms.json. :class:`Unsupported` where
    nerfstudio's dataparser has to read it; MaterialsFileError as PhysGSDataParser."""
    cfg = _config_fields(dp_config)
    if cfg["orientation_method"] == "pca":
        raise Unsupported("orientation method pca")
    data = Path(data if data is not None else cfg["data"])
    transforms = data if data.suffix == ".json" else data / "transforms.json"
    data_dir = transforms.parent
    try:
        meta = json.loads(transforms.read_text())
        frames = list(meta["frames"])
        _check_frames(meta, frames)
        names = [data_dir / Path(f["file_path"]) for f in frames]
        if len(set(names)) != len(names):
            raise Unsupported("frames sharing an image file")
        order = [int(i) for i in np.argsort(np.array(names, dtype=object))]
        image_filenames = [names[i] for i in order]
        train = _split_indices(cfg, meta, image_filenames, data_dir)
        transform, scale = _saved_transform(run_dir, meta, data)
        cameras = _cameras(meta, frames, order, train, transform, scale)
    except (OSError, KeyError, TypeError, ValueError, IndexError, ArithmeticError, RuntimeError) as err:
        if isinstance(err, MaterialsFileError):
            raise
        raise Unsupported(f"{transforms} not read as nerfstudio reads it ({type(err).__name__}: {err})") from err
    check_material_paths(frames, data_dir)
    legend = load_legend(data_dir / Path(cfg["materials_file"]))
    image_filenames = [image_filenames[i] for i in train]
    by_image = dict(zip(names, frames))
    material_files, confidence_files = frame_material_maps(by_image, image_filenames, data_dir)
    metadata = {"depth_filenames": None, "depth_unit_scale_factor": cfg["depth_unit_scale_factor"],
                "mask_color": cfg["mask_color"], "material_filenames": material_files,
                "material_confidence_filenames": confidence_files, "material_legend": legend}  # fmt: skip
    return TrainSplit(cameras, image_filenames, metadata)
