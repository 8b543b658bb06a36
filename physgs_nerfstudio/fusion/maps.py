"""Per-view material maps: a per-pixel Dirichlet over materials from the masks that cover each pixel.

For a view with masks m (bool [M, H, W]) and observations o (mask(o), class c_o, confidence p_o):

    evidence[pixel, k] = sum_o  level_weight[level(mask(o))] * p_o * [pixel in mask(o)] * [c_o = k]
    alpha = alpha0 + lambda * evidence;   pi = alpha / sum(alpha)           (bayes.dirichlet)
    label = argmax_k pi + 1 where sum_k evidence > 0, else 0 (unknown);  confidence = max_k pi (0 if unknown)

computed as one matrix product ``masks^T [HW, M] @ mask_evidence [M, K]``. Finer levels weigh more by
default (whole 0.5, part 1.0, subpart 1.5): a whole-object mask often spans several materials (a mug's
ceramic body and metal handle), so its answer is the least specific evidence for any one pixel inside it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from ..bayes import dirichlet_posterior, evidence_from_observations, predictive


@dataclass
class MapFusionConfig:
    level_weights: dict[str, float] = field(
        default_factory=lambda: {"whole": 0.5, "part": 1.0, "subpart": 1.5}
    )
    """Evidence weight of an observation by the level of its mask."""
    alpha0: float = 1.0
    """Dirichlet prior concentration per material (written to materials.json)."""
    lam: float = 4.0
    """Evidence strength lambda: one observation with confidence 1 at weight 1 counts as this many
    pseudo-counts (written to materials.json as "lambda")."""


@dataclass
class ViewMaps:
    labels: np.ndarray
    """uint8/int [H, W], 0 = unknown, k = names[k - 1]."""
    confidence: np.ndarray
    """float32 [H, W] in [0, 1]."""
    evidence: np.ndarray
    """float32 [H, W, K]."""


def fuse_view(
    masks: np.ndarray,
    levels: Sequence[str],
    obs_mask: Sequence[int],
    obs_class: Sequence[int],
    obs_conf: Sequence[float],
    num_classes: int,
    config: MapFusionConfig | None = None,
) -> ViewMaps:
    """masks: bool [M, H, W]; levels: per mask; obs_*: per observation (mask index, class index in
    [0, K), confidence)."""
    cfg = config or MapFusionConfig()
    masks = np.asarray(masks, dtype=bool)
    if masks.ndim != 3:
        raise ValueError(f"masks must be [M, H, W], got shape {masks.shape}")
    M, H, W = masks.shape
    K = int(num_classes)
    if K > 255:
        raise ValueError(f"{K} materials do not fit an 8-bit label map (at most 255)")
    if len(levels) != M:
        raise ValueError(f"{len(levels)} levels for {M} masks")
    unknown_levels = sorted(set(levels) - set(cfg.level_weights))
    if unknown_levels:
        raise ValueError(f"no level weight for levels {unknown_levels}; set MapFusionConfig.level_weights")
    om = torch.as_tensor(np.asarray(obs_mask, dtype=np.int64))
    if len(om) and (om.min() < 0 or om.max() >= M):
        raise ValueError(
            f"observation mask ids must lie in [0, {M}); got {om.min().item()}..{om.max().item()}"
        )
    lw = torch.tensor([cfg.level_weights[lv] for lv in levels], dtype=torch.float32)
    if K == 0 or M == 0 or len(om) == 0:
        return ViewMaps(
            np.zeros((H, W), np.uint8), np.zeros((H, W), np.float32), np.zeros((H, W, K), np.float32)
        )
    # weights[e, o] = level weight of mask e if observation o is about mask e
    weights = torch.zeros(M, len(om), dtype=torch.float32)
    weights[om, torch.arange(len(om))] = lw[om]
    conf = torch.as_tensor(np.asarray(obs_conf, dtype=np.float32))
    mask_evidence = evidence_from_observations(
        torch.as_tensor(np.asarray(obs_class, dtype=np.int64)), conf, K, weights
    )
    flat = torch.from_numpy(masks.reshape(M, H * W)).to(torch.float32)
    evidence = flat.T @ mask_evidence  # [HW, K]
    alpha = dirichlet_posterior(evidence, cfg.alpha0, cfg.lam)
    pi = predictive(alpha)
    conf_px, arg = pi.max(dim=-1)
    has = evidence.sum(-1) > 0
    labels = torch.where(has, arg + 1, torch.zeros_like(arg)).to(torch.uint8)
    confidence = torch.where(has, conf_px, torch.zeros_like(conf_px))
    return ViewMaps(
        labels.reshape(H, W).numpy(),
        confidence.reshape(H, W).numpy().astype(np.float32),
        evidence.reshape(H, W, K).numpy(),
    )


def view_observations(
    records: Sequence[dict], view: str, names: Sequence[str]
) -> tuple[list[int], list[int], list[float]]:
    """(mask ids, class indices, confidences) of the records of one view whose material is in names."""
    index = {n: i for i, n in enumerate(names)}
    om, oc, op = [], [], []
    for r in records:
        if r.get("view") != view:
            continue
        k = index.get(r.get("material"))
        try:
            p = float(r.get("confidence"))
        except (TypeError, ValueError):
            continue
        if k is None or not (0 < p <= 1):
            continue
        om.append(int(r["mask_id"]))
        oc.append(k)
        op.append(p)
    return om, oc, op
