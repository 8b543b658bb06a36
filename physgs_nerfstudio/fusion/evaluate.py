"""Agreement of written material maps with a generated scene's ground-truth material maps."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass
class MapAccuracy:
    foreground_accuracy: float
    """Fraction of ground-truth foreground pixels (material != 0) whose label names the true material."""
    coverage: float
    """Fraction of ground-truth foreground pixels with a known (non-zero) label."""
    background_labelled: float
    """Fraction of ground-truth background pixels that received a material label."""
    pixels: int
    views: int


def material_map_accuracy(root: Path) -> MapAccuracy:
    """Compare ``material_path`` maps of transforms.json with ``ground_truth.json`` maps, per pixel."""
    from ..image_files import read_array

    root = Path(root)
    gt = json.loads((root / "ground_truth.json").read_text(encoding="utf-8"))
    mats = json.loads((root / "materials.json").read_text(encoding="utf-8"))
    tf = json.loads((root / "transforms.json").read_text(encoding="utf-8"))
    gt_names = [m["name"] if isinstance(m, dict) else str(m) for m in gt["materials"]]
    ids = {m["name"]: int(m["id"]) for m in mats["materials"]}
    lut = np.array([0] + [ids.get(n, -1) for n in gt_names])
    gt_by_view = {}
    for i, fr in enumerate(gt.get("frames", [])):
        view = fr.get("file_path") or tf["frames"][i]["file_path"]
        gt_by_view[view] = fr.get("material_path") or fr.get("material")
    correct = covered = fg_total = bg_lab = bg_total = views = 0
    for fr in tf["frames"]:
        if "material_path" not in fr or fr["file_path"] not in gt_by_view:
            continue
        pred = read_array(root / fr["material_path"]).astype(np.int64)
        truth = read_array(root / gt_by_view[fr["file_path"]]).astype(np.int64)
        fg = truth > 0
        correct += int((pred[fg] == lut[truth[fg]]).sum())
        covered += int((pred[fg] > 0).sum())
        fg_total += int(fg.sum())
        bg_lab += int((pred[~fg] > 0).sum())
        bg_total += int((~fg).sum())
        views += 1
    return MapAccuracy(
        correct / max(fg_total, 1), covered / max(fg_total, 1), bg_lab / max(bg_total, 1), fg_total, views
    )
