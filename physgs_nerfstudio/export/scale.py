"""Metric scale of a nerfstudio scene: how many metres one scene (model) unit is.

nerfstudio's dataparser maps dataset coordinates ``p_d`` to scene coordinates
``p_s = scale * (R p_d + t)`` (``transform`` = [R | t], a rigid 3x4, and ``scale``, both saved in the run
folder's ``dataparser_transforms.json``). Hence, with ``u`` metres per dataset unit,

    metres_per_unit (scene) = u / scale.

Three ways to know ``u`` (first match wins):

1. ``known_length``: two points in dataset coordinates and their true distance in metres
   (``u = distance / |p1 - p2|``, so ``metres_per_unit = distance / (scale |p1 - p2|)``);
2. ``scale``: the user's metres per dataset unit (e.g. 0.01 for a dataset in centimetres);
3. the dataset is metric (``u = 1``): true for generated scenes (`physgs synth`), Polycam, Record3D and
   ARKit captures, not for COLMAP reconstructions (arbitrary scale): the caller is warned.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

logger = logging.getLogger(__name__)

DATAPARSER_TRANSFORMS = "dataparser_transforms.json"

KnownLength = tuple[float, float, float, float, float, float, float]
"""(x1, y1, z1, x2, y2, z2, distance_m): two points in dataset coordinates and their distance in metres."""


@dataclass(frozen=True)
class SceneScale:
    """Resolved metric scale with its provenance (reported next to every mass)."""

    metres_per_unit: float
    source: str
    """"known_length" | "user_scale" | "metric_dataset" | "given"."""
    dataparser_scale: float = 1.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.metres_per_unit) and self.metres_per_unit > 0):
            raise ValueError(f"metres_per_unit must be a finite number > 0, got {self.metres_per_unit}.")


def read_dataparser_scale(run_dir: Path) -> float:
    """``scale`` from ``<run_dir>/dataparser_transforms.json`` (ValueError with a hint if absent)."""
    path = Path(run_dir) / DATAPARSER_TRANSFORMS
    if not path.exists():
        raise FileNotFoundError(
            f"{path} not found: nerfstudio writes it into the run folder at the start of training. Pass the "
            "config.yml of a finished run, or give the scale explicitly (--scale / --known-length)."
        )
    meta = json.loads(path.read_text())
    scale = float(meta.get("scale", float("nan")))
    if not (math.isfinite(scale) and scale > 0):
        raise ValueError(f"{path}: 'scale' must be a number > 0, got {meta.get('scale')!r}.")
    return scale


def resolve_scale(
    dataparser_scale: float = 1.0,
    *,
    scale: float | None = None,
    known_length: Sequence[float] | None = None,
    warn_if_assumed: bool = True,
) -> SceneScale:
    """Metres per scene unit from the dataparser scale and the user's options (module doc)."""
    if not (math.isfinite(dataparser_scale) and dataparser_scale > 0):
        raise ValueError(f"dataparser scale must be > 0, got {dataparser_scale}.")
    if known_length is not None:
        if len(known_length) != 7:
            raise ValueError(
                "known_length takes 7 numbers: x1 y1 z1 x2 y2 z2 distance_m (two points in dataset "
                f"coordinates and their true distance in metres); got {len(known_length)}."
            )
        x1, y1, z1, x2, y2, z2, dist = (float(v) for v in known_length)
        gap = math.dist((x1, y1, z1), (x2, y2, z2))
        if gap <= 0 or not math.isfinite(gap):
            raise ValueError("known_length: the two points coincide; pick two distinct points.")
        if not (math.isfinite(dist) and dist > 0):
            raise ValueError(f"known_length: the distance must be > 0 metres, got {dist}.")
        return SceneScale(dist / (gap * dataparser_scale), "known_length", dataparser_scale)
    if scale is not None:
        if not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"scale (metres per dataset unit) must be > 0, got {scale}.")
        return SceneScale(scale / dataparser_scale, "user_scale", dataparser_scale)
    if warn_if_assumed:
        logger.warning(
            "Assuming the dataset is in metres (true for `physgs synth`, Polycam, Record3D, ARKit). For a COLMAP "
            "reconstruction the scale is arbitrary: pass --scale (metres per dataset unit) or --known-length."
        )
    return SceneScale(1.0 / dataparser_scale, "metric_dataset", dataparser_scale)
