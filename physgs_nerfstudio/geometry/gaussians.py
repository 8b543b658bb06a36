"""What geometry needs from a splat: per-view depth and alpha, and per-Gaussian evidence lifted from masks.

Works on any object with ``means``, ``quats``, ``scales`` (activated), ``opacities`` (activated) tensors, e.g.
:class:`physgs_nerfstudio.export.field.PropertyField`. Rendering goes through :func:`physgs_nerfstudio.render.rasterize`
(gsplat on CUDA, the pure-torch reference rasterizer on CPU).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch
from jaxtyping import Float
from torch import Tensor

from ..lifting import lift_evidence
from ..render import rasterize
from .capture import CaptureView

__all__ = ["ViewRender", "lift_masks", "render_depth"]


@dataclass
class ViewRender:
    depth: Float[Tensor, "H W"]
    """expected depth (camera z) where alpha > 0, else +inf"""
    alpha: Float[Tensor, "H W"]


@torch.no_grad()
def render_depth(g: Any, views: Sequence[CaptureView], *, backend: str = "auto") -> list[ViewRender]:
    """Expected depth and alpha of the Gaussians ``g`` in every view."""
    out = []
    dev = g.means.device
    colors = torch.zeros(g.means.shape[0], 1, device=dev)
    for v in views:
        rgbd, alpha, _ = rasterize(g.means, g.quats, g.scales, g.opacities, colors, v.viewmat[None].to(dev),
                                   v.K[None].to(dev), v.width, v.height, render_mode="RGB+ED", packed=False,
                                   backend=backend)  # fmt: skip
        a = alpha[0, ..., 0]
        d = rgbd[0, ..., -1]
        out.append(ViewRender(torch.where(a > 1e-3, d, torch.full_like(d, float("inf"))), a))
    return out


@torch.no_grad()
def lift_masks(g: Any, views: Sequence[CaptureView], *, backend: str = "auto",
               min_view_weight: float = 1e-3) -> tuple[Tensor, Tensor]:  # fmt: skip
    """Per Gaussian (inside, outside) evidence: over the views that see it, the share of its blending weight
    on foreground-mask pixels, summed, so each view that sees a Gaussian is one observation (docs/architecture.md,
    "evidence per view"). Returns two float [N] tensors."""
    dev = g.means.device
    n = g.means.shape[0]
    inside = torch.zeros(n, dtype=torch.float64, device=dev)
    outside = torch.zeros_like(inside)
    for v in views:
        m = v.mask.to(dev).float()[None, ..., None]
        res = lift_evidence(g.means, g.quats, g.scales, g.opacities, v.viewmat[None].to(dev), v.K[None].to(dev),
                            v.width, v.height, m, backend=backend)  # fmt: skip
        w = res.visibility.double()
        seen = w > min_view_weight
        frac = torch.where(seen, res.evidence[:, 0].double() / w.clamp_min(1e-12), torch.zeros_like(w)).clamp(0, 1)
        inside += torch.where(seen, frac, torch.zeros_like(frac))
        outside += torch.where(seen, 1 - frac, torch.zeros_like(frac))
    return inside, outside
