"""SAM segmenter: segment-anything's automatic mask generator from a local checkpoint (optional extra).

Built by ``SamSegmenterConfig.setup()``; the protocol, the mask type and the shared mask operations are in
:mod:`.segment`.
"""

from __future__ import annotations

from typing import ClassVar
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..advanced import Advanced
from .segment import (
    LEVELS,
    SAM_INSTALL_HINT,
    Mask,
    assign_levels_by_containment,
    check_image,
    deduplicate,
    sort_masks,
)

# ---------------------------------------------------------------------------------------------------------
# SAM (optional extra)
# ---------------------------------------------------------------------------------------------------------


@dataclass
class SamSegmenterConfig:
    """segment-anything automatic mask generation from a local checkpoint."""

    name: ClassVar[str] = "sam"

    checkpoint: Path | None = None
    """The SAM checkpoint file (.pth), required."""
    model_type: str = "vit_h"
    """The checkpoint's model type: vit_h, vit_l or vit_b."""
    device: str = "auto"
    """Where SAM runs: auto (CUDA when available), cpu or cuda."""
    points_per_side: Advanced[int] = 32
    min_predicted_iou: Advanced[float] = 0.86
    """Drop masks with SAM predicted IoU below this (SAM's pred_iou_thresh)."""
    min_stability: Advanced[float] = 0.92
    """Drop masks with SAM stability score below this (SAM's stability_score_thresh)."""
    dedup_iou: Advanced[float] = 0.85
    min_area_frac: Advanced[float] = 0.002
    min_area_px: Advanced[int] = 64
    containment: Advanced[float] = 0.9
    """A mask is inside another when at least this fraction of it is covered (level assignment)."""
    max_masks_per_level: Advanced[tuple[int, int, int]] = (4, 16, 24)
    levels: Advanced[tuple[str, ...]] = LEVELS
    generator_kwargs: Advanced[dict] = field(default_factory=dict)
    """Extra keyword arguments for SamAutomaticMaskGenerator (e.g. crop_n_layers)."""

    def setup(self) -> SamSegmenter:
        """The segmenter of this config; loads the checkpoint now, so a missing package or file fails before
        any work (with the install / checkpoint hint)."""
        seg = SamSegmenter(self)
        seg._load()
        return seg


class SamSegmenter:
    """segment-anything's automatic mask generator, three levels by containment (see module docstring)."""

    name = "sam"

    def __init__(self, config: SamSegmenterConfig | None = None):
        self.config = config or SamSegmenterConfig()
        self._generator = None

    def fingerprint(self) -> str:
        cfg = self.config
        ckpt = Path(cfg.checkpoint).name if cfg.checkpoint else None
        return (
            f"sam:{ckpt}:{cfg.model_type}:{cfg.points_per_side}:{cfg.min_predicted_iou}:{cfg.min_stability}:"
            f"{cfg.dedup_iou}:{cfg.min_area_frac}:{cfg.min_area_px}:{cfg.containment}:{cfg.max_masks_per_level}:"
            f"{cfg.levels}:{sorted(cfg.generator_kwargs.items())}"
        )

    def _load(self):
        if self._generator is not None:
            return self._generator
        cfg = self.config
        try:
            import segment_anything  # noqa: F401
            from segment_anything import SamAutomaticMaskGenerator, sam_model_registry
        except ImportError as err:
            raise ImportError(SAM_INSTALL_HINT) from err
        if cfg.checkpoint is None:
            raise FileNotFoundError("no SAM checkpoint given. " + SAM_INSTALL_HINT)
        ckpt = Path(cfg.checkpoint).expanduser()
        if not ckpt.is_file():
            raise FileNotFoundError(f"SAM checkpoint not found: {ckpt}. " + SAM_INSTALL_HINT)
        if cfg.model_type not in sam_model_registry:
            raise ValueError(
                f"unknown SAM model type {cfg.model_type!r}; choose from {sorted(sam_model_registry)}"
            )
        device = cfg.device
        if device == "auto":
            import torch

            device = "cuda" if torch.cuda.is_available() else "cpu"
        model = sam_model_registry[cfg.model_type](checkpoint=str(ckpt))
        model.to(device=device)
        self._generator = SamAutomaticMaskGenerator(
            model,
            points_per_side=cfg.points_per_side,
            pred_iou_thresh=cfg.min_predicted_iou,
            stability_score_thresh=cfg.min_stability,
            output_mode="binary_mask",
            **cfg.generator_kwargs,
        )
        return self._generator

    def segment(self, image: np.ndarray) -> list[Mask]:
        cfg = self.config
        image = check_image(image)
        h, w = image.shape[:2]
        records = self._load().generate(image)
        min_area = max(cfg.min_area_px, int(cfg.min_area_frac * h * w))
        kept = []
        for r in records:
            seg = np.asarray(r["segmentation"], dtype=bool)
            area = int(seg.sum())
            piou = float(r.get("predicted_iou", 0.0))
            stab = float(r.get("stability_score", 0.0))
            if area < min_area or piou < cfg.min_predicted_iou or stab < cfg.min_stability:
                continue
            kept.append(Mask(seg, area, min(max(piou, 0.0), 1.0), min(max(stab, 0.0), 1.0), "part"))
        # dedup first so near-duplicates do not create spurious hierarchy levels
        kept = deduplicate(kept, cfg.dedup_iou)
        if not kept:
            return []
        levels = assign_levels_by_containment(np.stack([m.segmentation for m in kept]), cfg.containment)
        out: list[Mask] = []
        for li, level in enumerate(LEVELS):
            if level not in cfg.levels:
                continue
            ms = [
                Mask(m.segmentation, m.area, m.predicted_iou, m.stability, level)
                for m, lv in zip(kept, levels)
                if lv == level
            ]
            ms.sort(key=lambda m: -m.score * m.area)
            out.extend(ms[: cfg.max_masks_per_level[li]])
        return sort_masks(out)
