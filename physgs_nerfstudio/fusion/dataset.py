"""Fusion orchestration for a nerfstudio dataset: stored observations -> materials.json (per-material NIG
posteriors), one material / confidence map per frame (per-pixel Dirichlet over the frame's masks) and their
transforms.json entries. Perception calls it at the end of a run; it knows nothing of how the masks were
made: ``view_masks`` hands it each frame's image and masks.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..materials import MaterialLibrary, PriorConfig
from .maps import MapFusionConfig, fuse_view
from .properties import fuse_properties, legend_names
from .transaction import DatasetTransaction
from .writer import (
    frame_names,
    legend_colors,
    materials_document,
    update_transforms,
    write_legend,
    write_materials_json,
    write_view_maps,
)

ViewMasks = Callable[[str], "tuple[np.ndarray, np.ndarray, list[str]] | None"]
"""view -> (uint8 image [H, W, 3], bool masks [M, H, W], level of each mask), or None (never segmented)."""


@dataclass
class DatasetOutputs:
    materials: list[str]
    materials_json: Path
    label_paths: dict[str, str] = field(default_factory=dict)
    confidence_paths: dict[str, str] = field(default_factory=dict)


def _view_records(observations: Sequence[dict], index: dict[str, int]) -> dict[str, list[dict]]:
    """Per view, the usable records (a legend material, confidence in (0, 1])."""
    by_view: dict[str, list[dict]] = {}
    for o in observations:
        if o["material"] in index and 0 < float(o["confidence"]) <= 1:
            by_view.setdefault(o["view"], []).append(o)
    return by_view


def write_dataset_outputs(
    root: Path,
    views: Sequence[str],
    observations: Sequence[dict],
    library: MaterialLibrary,
    view_masks: ViewMasks,
    *,
    legend: str,
    fusion: MapFusionConfig,
    prior: PriorConfig,
    source: dict,
    simulated: bool,
) -> DatasetOutputs:
    """Fuse ``observations`` into materials.json and per-frame maps of ``views``; update transforms.json.
    Every file is staged first and the dataset changes in one step (transaction.py): an error, a full disk
    included, leaves it as it was."""
    names = legend_names(observations, library, legend)
    post = fuse_properties(observations, library, names, prior)
    colors = [library[n].color for n in names]
    palette = legend_colors(colors)
    index = {n: i for i, n in enumerate(names)}
    by_view = _view_records(observations, index)
    out_names = frame_names(list(views))
    paths: dict[str, tuple[str, str]] = {}
    with DatasetTransaction(root) as txn:  # all of it or none of it (transaction.py)
        for view in views:
            got = view_masks(view)
            if got is None:
                continue  # never segmented (e.g. the run stopped before this frame) or unreadable
            image, stack, levels = got
            recs = by_view.get(view, [])
            maps = fuse_view(
                stack,
                levels,
                [int(r["mask_id"]) for r in recs],
                [index[r["material"]] for r in recs],
                [float(r["confidence"]) for r in recs],
                len(names),
                fusion,
            )
            paths[view] = write_view_maps(root, out_names[view], maps, palette, image, txn)
        simulated = simulated or any(o.get("simulated") for o in observations)
        doc = materials_document(post, library, simulated, fusion, {**source, "observations": len(observations)})
        materials_json = write_materials_json(root, doc, txn)
        write_legend(root, names, colors, txn)
        if paths:
            update_transforms(root, paths, txn=txn)
    return DatasetOutputs(
        names,
        materials_json,
        {v: p[0] for v, p in paths.items()},
        {v: p[1] for v, p in paths.items()},
    )
