"""`materials.json` (written by `physgs perceive`, see docs/architecture.md) as typed tensors.

The legend is the scene's material vocabulary: K materials with ids 1..K (label 0 = unknown / background),
their display colours and their per-property Normal-Inverse-Gamma posteriors. It is read once by the
dataparser and handed to the model through the dataparser metadata.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from jaxtyping import Float
from torch import Tensor

from ..errors import PhysGSError

MATERIALS_FILENAME = "materials.json"
PERCEIVE_HINT = (
    "Run `physgs perceive --data <dataset>` first: it writes materials.json and a per-frame material map "
    "(`material_path`, `material_confidence_path` in transforms.json)."
)
NIG_FIELDS = ("tau", "kappa", "a", "b")

# Viewer / output names of the contract's property keys (docs/architecture.md, "Units and property keys").
VIEWER_NAMES: dict[str, str] = {
    "density": "density",
    "kinetic_friction": "friction",
    "shore_hardness": "hardness",
    "youngs_modulus": "stiffness",
}


class MaterialsFileError(PhysGSError, ValueError):
    """materials.json is missing or malformed."""


@dataclass
class MaterialLegend:
    """The contents of `materials.json` that training and rendering need."""

    names: list[str]
    """material names, index i <-> label id i + 1"""
    colors: Float[Tensor, "k 3"]
    """legend colours in [0, 1]"""
    property_keys: tuple[str, ...]
    """order of the property axis P"""
    log_space: tuple[bool, ...]
    """per property: the NIG lives in natural-log units"""
    nig: dict[str, Float[Tensor, "k p"]]
    """posterior NIG fields tau, kappa, a, b, each [K, P]"""
    alpha0: float | None = None
    lam: float | None = None
    simulated: bool = False
    path: Path | None = None

    @property
    def num_materials(self) -> int:
        return len(self.names)


def _fail(path: Path, what: str) -> MaterialsFileError:
    return MaterialsFileError(f"{path}: {what}. {PERCEIVE_HINT}")


def load_legend(path: Path) -> MaterialLegend:
    """Reads and validates `materials.json` (ids 1..K in order, one NIG per property and material)."""
    path = Path(path)
    if not path.exists():
        raise _fail(path, "not found")
    try:
        meta: dict[str, Any] = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise _fail(path, f"is not valid JSON ({err})") from None
    except RecursionError:
        raise _fail(path, "is nested too deeply to read") from None
    except UnicodeDecodeError:
        raise _fail(path, "is not UTF-8 text") from None
    mats = meta.get("materials")
    if not isinstance(mats, list) or len(mats) == 0:
        raise _fail(path, "has no `materials` list")
    keys = meta.get("property_keys")
    if not isinstance(keys, list) or not keys:
        raise _fail(path, "has no `property_keys` list")
    ids = [m.get("id") for m in mats]
    if ids != list(range(1, len(mats) + 1)):
        raise _fail(path, f"material ids must run 1..K in order, got {ids}")
    log_space_map = meta.get("log_space", {})
    names: list[str] = []
    colors: list[list[float]] = []
    fields: dict[str, list[list[float]]] = {f: [] for f in NIG_FIELDS}
    for m in mats:
        name = m.get("name")
        if not isinstance(name, str):
            raise _fail(path, f"material id {m.get('id')} has no name")
        color = m.get("color")
        if not (isinstance(color, (list, tuple)) and len(color) == 3):
            raise _fail(path, f"material {name!r} needs a colour [r, g, b] (0..255)")
        names.append(name)
        colors.append([float(c) / 255.0 for c in color])
        post = m.get("posterior")
        if not isinstance(post, dict):
            raise _fail(path, f"material {name!r} has no `posterior`")
        for f in NIG_FIELDS:
            row = []
            for k in keys:
                if k not in post or f not in post[k]:
                    raise _fail(path, f"material {name!r}: posterior of {k!r} lacks {f!r}")
                row.append(float(post[k][f]))
            fields[f].append(row)
    return MaterialLegend(
        names=names,
        colors=torch.tensor(colors, dtype=torch.float32),
        property_keys=tuple(keys),
        log_space=tuple(bool(log_space_map.get(k, False)) for k in keys),
        nig={f: torch.tensor(v, dtype=torch.float64) for f, v in fields.items()},
        alpha0=float(meta["alpha0"]) if meta.get("alpha0") is not None else None,
        lam=float(meta["lambda"]) if meta.get("lambda") is not None else None,
        simulated=bool(meta.get("simulated", False)),
        path=path,
    )


def check_material_paths(frames: Sequence[dict], data_dir: Path) -> None:
    """MaterialsFileError unless some frame of transforms.json has a ``material_path`` (perception ran)."""
    if not any("material_path" in f for f in frames):
        raise MaterialsFileError(f"{data_dir}: no frame of transforms.json has a `material_path`. {PERCEIVE_HINT}")


def frame_material_maps(
    frames_by_image: Mapping[Path, dict], image_filenames: Sequence[Path], data_dir: Path
) -> tuple[list[Path | None], list[Path | None]]:
    """Per image of a split, its frame's material map and confidence map (``material_path``,
    ``material_confidence_path`` of transforms.json, relative to ``data_dir``; None where the frame has none, a
    confidence map only with a material map). ``frames_by_image``: the frames by their image filename as the
    split names it. MaterialsFileError when a listed map does not exist."""
    material_files: list[Path | None] = []
    confidence_files: list[Path | None] = []
    for image_filename in image_filenames:
        frame = frames_by_image[image_filename]
        mat = frame.get("material_path")
        conf = frame.get("material_confidence_path")
        material_files.append(data_dir / mat if mat else None)
        confidence_files.append(data_dir / conf if (mat and conf) else None)
    for p in [*material_files, *confidence_files]:
        if p is not None and not p.exists():
            raise MaterialsFileError(f"material map {p} listed in transforms.json does not exist. {PERCEIVE_HINT}")
    return material_files, confidence_files
