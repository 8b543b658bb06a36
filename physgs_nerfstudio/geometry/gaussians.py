"""What geometry needs from a splat: per-view depth and alpha, and per-Gaussian evidence lifted from masks.

Works on any object with ``means``, ``quats``, ``scales`` (activated), ``opacities`` (activated) tensors, e.g.
:class:`physgs_nerfstudio.export.field.PropertyField`. Rendering goes through :func:`physgs_nerfstudio.render.rasterize`
(gsplat on CUDA, the pure-torch reference rasterizer on CPU).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor

from ..lifting import group_views, lift_views
from ..render import rasterize, reference_surface_depth
from ..render.backend import resolve_backend
from ..render.projection import quat_to_rotmat
from .capture import CaptureView
from .grid import VoxelGrid

__all__ = [
    "SURFACE_TRANSMITTANCE",
    "Subset",
    "ViewRender",
    "lift_masks",
    "render_depth",
    "support_directions",
    "support_excess",
    "surface_excess",
    "surface_views",
    "within_support",
]

logger = logging.getLogger(__name__)
_T = TypeVar("_T")


@dataclass
class Subset:
    """The Gaussians ``g`` at rows ``idx``: every attribute of ``g`` (``means``, ``scales``, ...) indexed by them."""

    g: Any
    idx: Tensor

    def __getattr__(self, name: str) -> Any:
        return getattr(self.g, name)[self.idx]


SURFACE_TRANSMITTANCE = 0.8
"""The transmittance at which a pixel's ray reaches the object's surface: the depth that carves
(:func:`render_depth`) is the first Gaussian's along the ray at which the light that passes drops to this share
(the ray has lost a fifth of its light), and a pixel whose alpha never reaches ``1 - SURFACE_TRANSMITTANCE`` has
no surface depth (+inf; the carving sees through it, :data:`.free_space.SEES_THROUGH`).

Physically: a trained splat draws a surface not as one opaque sheet but as a soft layer of semi-transparent
Gaussians, a few millimetres to a centimetre deep, whose centres lie on both sides of the true surface. Every
point of space that a view renders in front of its depth is carved, so the depth must lie at or in front of the
true surface in every view, or each view carves a shell off the object. The *expected* depth (the blending-weighted
mean) lies inside the layer and is pulled towards any surface behind it; the *median* depth (transmittance 1/2)
lies halfway into the layer (on path-traced renders of the development families, about a wall's thickness behind
the true surface at the demo's settings); a depth where the ray has lost only a little light lies at the layer's
front. Too high a transmittance (0.9 and above) reads the depth off the first faint Gaussians (floaters, the
layer's fringe) and carves too little, so thin gaps and concavities fill. Why 0.8: docs/architecture.md, "Which
depth carves", gives the comparison over the development families that chose it."""


@dataclass
class ViewRender:
    depth: Float[Tensor, "H W"]
    """the surface depth (camera z): where the ray's transmittance first crosses :data:`SURFACE_TRANSMITTANCE`;
    +inf where alpha never reaches ``1 - SURFACE_TRANSMITTANCE`` (from :func:`render_depth` with ``surface=False``:
    the expected depth where alpha > 0)"""
    alpha: Float[Tensor, "H W"]


@torch.no_grad()
def render_depth(g: Any, views: Sequence[CaptureView], *, backend: str = "auto", surface: bool = True
                 ) -> list[ViewRender]:  # fmt: skip
    """The surface depth and the alpha of the Gaussians ``g`` in every view. The alpha is the rasterizer's
    (``backend``: gsplat on CUDA, the reference rasterizer on CPU); the depth is where the ray's transmittance crosses
    :data:`SURFACE_TRANSMITTANCE`, from the reference compositor
    (:func:`physgs_nerfstudio.render.reference_surface_depth`, on the Gaussians' device: gsplat has no such mode).
    ``surface=False``: the rasterizer's expected depth instead (no compositor pass), for callers that use the alpha
    only (masks) or order whole renders by depth."""
    out = []
    # each attribute read once (on a subset view of a field, every read gathers its rows again)
    means, quats, scales, opacities = g.means, g.quats, g.scales, g.opacities
    dev = means.device

    def render(group: list[CaptureView]) -> list[ViewRender]:
        vm = torch.stack([v.viewmat.to(dev) for v in group])
        K = torch.stack([v.K.to(dev) for v in group])
        colors = torch.zeros(means.shape[0], 1, device=dev)
        rgbd, alpha, _ = rasterize(means, quats, scales, opacities, colors, vm, K, group[0].width, group[0].height,
                                   render_mode="RGB+ED", packed=False, backend=backend)  # fmt: skip
        rendered = []
        for i, v in enumerate(group):
            a = alpha[i, ..., 0]
            d = rgbd[i, ..., -1]
            if surface:
                d = reference_surface_depth(means, quats, scales, opacities, vm[i], K[i], v.width, v.height,
                                            transmittance=SURFACE_TRANSMITTANCE).to(d.dtype)  # fmt: skip
            rendered.append(ViewRender(torch.where(a > 1e-3, d, torch.full_like(d, float("inf"))), a))
        return rendered

    for group in _view_groups(views, _views_per_call(backend, dev, means.shape[0])):
        out += _grouped(render, group)
    return out


def _view_depth_excess(x: Tensor, v: CaptureView, r: ViewRender, min_alpha: float) -> Tensor:
    """float [N]: each point's camera depth behind ``r``'s rendered depth at its nearest pixel, +inf where it projects
    outside the image, behind the camera or on a pixel less than ``min_alpha`` opaque."""
    vm = v.viewmat.to(x)
    K = v.K.to(x)
    c = x @ vm[:3, :3].T + vm[:3, 3]
    z = c[:, 2]
    zs = z.clamp_min(1e-9)
    u = K[0, 0] * c[:, 0] / zs + K[0, 2]
    w = K[1, 1] * c[:, 1] / zs + K[1, 2]
    H, W = r.alpha.shape
    ok = (z > 0) & (u >= 0) & (u < W) & (w >= 0) & (w < H)
    ui = u.floor().long().clamp(0, W - 1)
    vi = w.floor().long().clamp(0, H - 1)
    ok &= r.alpha.to(x.device)[vi, ui] >= min_alpha
    excess = z - r.depth.to(x.device)[vi, ui].float()
    return torch.where(ok, excess, torch.full_like(excess, float("inf")))


@torch.no_grad()
def surface_views(means: Float[Tensor, "N 3"], views: Sequence[CaptureView], renders: Sequence[ViewRender],
                  band: float | Float[Tensor, " N"], min_alpha: float = 0.5
                  ) -> Float[Tensor, " N"]:  # fmt: skip
    """For each Gaussian, how many of ``views`` see its centre on their rendered surface: it projects into the image
    on a pixel at least ``min_alpha`` opaque (nearest pixel), in front of the camera, and its camera depth lies at most
    ``band`` (scene units; one for all or one per point) behind that pixel's rendered depth. A Gaussian
    under the surface that every view sees (inside a solid, under a shell) scores 0, however its lifted labels
    came to it (a sliver of blending weight through the surface in front of it counts a view in the lifting,
    :mod:`physgs_nerfstudio.nerfstudio.pipeline`). Whether any view sees it, at several bands:
    :func:`surface_excess`."""
    out = torch.zeros(len(means), dtype=torch.float32, device=means.device)
    if not len(means):
        return out
    x = means.float()
    if isinstance(band, Tensor):
        band = band.to(x)
    for v, r in zip(views, renders):
        out += (_view_depth_excess(x, v, r, min_alpha) <= band).float()
    return out


@torch.no_grad()
def surface_excess(means: Float[Tensor, "N 3"], views: Sequence[CaptureView], renders: Sequence[ViewRender],
                   min_alpha: float = 0.5) -> Float[Tensor, " N"]:  # fmt: skip
    """For each Gaussian, the smallest depth (scene units) by which its centre lies behind a view's rendered surface,
    over the views that see it on a pixel at least ``min_alpha`` opaque (negative: in front of it; +inf: no such
    view). ``surface_excess(...) <= band`` is ``surface_views(..., band) > 0``, for every band from one pass."""
    out = torch.full((len(means),), float("inf"), dtype=torch.float32, device=means.device)
    x = means.float()
    for v, r in zip(views, renders):
        out = torch.minimum(out, _view_depth_excess(x, v, r, min_alpha))
    return out


_GAUSSIAN_VIEWS_PER_CALL = 8_000_000
"""Gaussians x views in one rasterizer call on a GPU (:func:`lift_masks`, :func:`render_depth`): 8 views at a million
Gaussians"""


def _views_per_call(backend: str, device: torch.device, n: int) -> int:
    """Views per rasterizer call: up to 8 with gsplat, fewer above a million Gaussians; 1 with the reference
    rasterizer, which loops over cameras anyway."""
    if resolve_backend(backend, device) != "gsplat":  # type: ignore[arg-type]
        return 1
    return max(1, min(8, _GAUSSIAN_VIEWS_PER_CALL // max(n, 1)))


def _view_groups(views: Sequence[CaptureView], per_call: int) -> list[list[CaptureView]]:
    """Consecutive runs of at most ``per_call`` views of one size, in order (:func:`..lifting.group_views`)."""
    return [[views[i] for i in g] for g in group_views([(v.width, v.height) for v in views], per_call)]


@torch.no_grad()
def lift_masks(g: Any, views: Sequence[CaptureView], *, backend: str = "auto",
               min_view_weight: float = 1e-3, views_per_call: int | None = None) -> tuple[Tensor, Tensor]:  # fmt: skip
    """Per Gaussian (inside, outside) evidence: over the views that see it, the share of its blending weight
    on foreground-mask pixels, summed, so each view that sees a Gaussian is one observation (docs/architecture.md,
    "evidence per view"). Returns two float [N] tensors. ``views_per_call``: views of one size rendered in one
    rasterizer call (:func:`physgs_nerfstudio.lifting.lift_views`; None: :func:`_views_per_call`); the views'
    evidence is added in their order either way."""
    means, quats, scales, opacities = g.means, g.quats, g.scales, g.opacities
    dev = means.device
    n = means.shape[0]
    per_call = views_per_call if views_per_call is not None else _views_per_call(backend, dev, n)
    inside = torch.zeros(n, dtype=torch.float64, device=dev)
    outside = torch.zeros_like(inside)

    def lift(group: list[CaptureView]) -> list[tuple[Tensor, Tensor]]:
        size = (group[0].width, group[0].height)
        stacked = torch.stack([v.mask.to(dev).float()[..., None] for v in group])
        viewmats = torch.stack([v.viewmat.to(dev) for v in group])
        Ks = torch.stack([v.K.to(dev) for v in group])
        return [(ev[k], vis[k])
                for _, ev, vis in lift_views(means, quats, scales, opacities, viewmats, Ks, size[0], size[1], stacked,
                                             backend=backend, views_per_call=len(group))  # type: ignore[arg-type]
                for k in range(vis.shape[0])]  # fmt: skip

    for group in _view_groups(views, per_call):
        for ev, vis in _grouped(lift, group):  # view by view, in order
            w = vis.double()
            seen = w > min_view_weight
            frac = torch.where(seen, ev[:, 0].double() / w.clamp_min(1e-12), torch.zeros_like(w)).clamp(0, 1)
            inside += frac  # 0 where the view does not see the Gaussian
            outside += seen.double() - frac
    return inside, outside


def _grouped(fn: Callable[[list[CaptureView]], list[_T]], group: list[CaptureView]) -> list[_T]:
    """``fn(group)``, one result per view; when the group runs out of GPU memory, its views one at a time (the same
    results: a grouped call only saves per-call work)."""
    try:
        return fn(group)
    except torch.cuda.OutOfMemoryError:
        if len(group) == 1:
            raise
        torch.cuda.empty_cache()
        logger.warning("out of GPU memory with %d views in one rasterizer call: rendering them one at a time",
                       len(group))  # fmt: skip
        return [r for v in group for r in fn([v])]


# The object's extent: a voxel beyond every Gaussian of the object is not the object. Carving keeps space no view
# sees past, under an object shot from above a slab of the domain's padding; the Gaussians are the splat's only
# evidence of surface, so the solid is cut to their *support polytope*: a voxel centre ``x`` is kept when
# ``u . x <= max_i u . mu_i + pad`` for each direction ``u`` (26 lattice directions and a Fibonacci set; the
# lattice ones cut an upright object's flat bottom exactly). Concavities are left to the views. Only Gaussians that
# some view sees on its rendered surface count (:func:`surface_excess`): unseen ones under an unseen underside would
# leave a layer of false solid. The outlier count is the whole selection's, so that polytope is never the wider one.


def support_directions(n_fibonacci: int = 100) -> Float[Tensor, "D 3"]:
    """Unit directions: the 26 of the 3x3x3 lattice (faces, edges, corners) and ``n_fibonacci`` spread evenly over
    the sphere (a Fibonacci lattice)."""
    lat = torch.tensor([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1) if (i, j, k) != (0, 0, 0)],
                       dtype=torch.float64)  # fmt: skip
    i = torch.arange(n_fibonacci, dtype=torch.float64) + 0.5
    z = 1 - 2 * i / n_fibonacci
    phi = i * math.pi * (3 - math.sqrt(5))
    r = torch.sqrt(1 - z * z)
    fib = torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], 1)
    d = torch.cat([lat, fib])
    return d / d.norm(dim=1, keepdim=True)


def support_heights(means: Float[Tensor, "N 3"], d: Float[Tensor, "D 3"], scales: Tensor | None = None,
                    quats: Tensor | None = None, chunk: int = 1 << 16, skip: int = 0) -> Float[Tensor, " D"]:  # fmt: skip
    """h(u) = max_i u . mu_i (+ sigma_i(u), the Gaussian's standard deviation along u, when ``scales`` [N, 3] and
    ``quats`` [N, 4] are given: the support function of the Gaussians' one-sigma ellipsoids), float64. ``skip``: the
    (skip + 1)-th largest instead of the largest (the ``skip`` outermost Gaussians along u do not count; all but one
    when there are no more), so that a few strays beyond the surface do not set the object's extent."""
    d = d.double()
    k = max(0, int(skip)) + 1
    top = torch.full((0, len(d)), -torch.inf, dtype=torch.float64, device=means.device)
    for i in range(0, len(means), chunk):
        hi = means[i:i + chunk].double() @ d.T
        if scales is not None and quats is not None:
            R = quat_to_rotmat(quats[i:i + chunk].double())  # columns: the Gaussian's axes
            along = torch.einsum("nji,dj->nid", R, d)  # [n, 3, D]: u on each axis
            hi = hi + (along * scales[i:i + chunk].double()[:, :, None]).norm(dim=1)
        both = torch.cat([top, hi])
        top = both.topk(min(k, len(both)), dim=0).values if k > 1 else both.amax(0, keepdim=True)
    if not len(top):
        return torch.full((len(d),), -torch.inf, dtype=torch.float64, device=means.device)
    return top[-1]


@torch.no_grad()
def support_excess(grid: VoxelGrid, means: Float[Tensor, "N 3"], candidates: np.ndarray, n_fibonacci: int = 100,
                   scales: Tensor | None = None, quats: Tensor | None = None, skip: int = 0) -> np.ndarray:  # fmt: skip
    """float64 [C]: for each of the ``candidates`` voxels (``np.argwhere`` order), how far its centre lies beyond
    the support polytope of ``means`` (of the Gaussians' one-sigma ellipsoids with ``scales`` and ``quats``), in
    voxels: ``max_u (u . x - h(u)) / voxel`` (<= 0 inside). A voxel lies within the polytope grown by ``pad``
    voxels when its excess is at most ``pad``, so one call answers every pad. Computed on the means' device.
    ``skip``: the polytope of all but the ``skip`` outermost Gaussians along each direction (:func:`support_heights`)."""
    idx = np.argwhere(candidates)
    d = support_directions(n_fibonacci).to(means.device)
    h = support_heights(means, d, scales, quats, skip=skip)
    out = []
    for c in torch.from_numpy(idx).to(means.device).split(1 << 18):
        x = grid.centres(c).double().to(means.device)
        out.append(((x @ d.T) - h).amax(1))
    return (torch.cat(out) / grid.voxel_size).cpu().numpy() if out else np.zeros(0)


def within_support(grid: VoxelGrid, means: Float[Tensor, "N 3"], candidates: np.ndarray, pad_voxels: float = 1.0,
                   n_fibonacci: int = 100, scales: Tensor | None = None, quats: Tensor | None = None,
                   skip: int = 0) -> np.ndarray:  # fmt: skip
    """bool [X, Y, Z]: the ``candidates`` voxels whose centres lie inside the support polytope of ``means`` (of the
    Gaussians' one-sigma ellipsoids with ``scales`` and ``quats``) grown by ``pad_voxels`` voxels (module doc);
    ``candidates`` itself when there are no means; ``skip``: as in :func:`support_heights`."""
    if len(means) == 0 or not candidates.any():
        return candidates.copy()
    out = np.zeros_like(candidates)
    idx = np.argwhere(candidates)
    k = support_excess(grid, means, candidates, n_fibonacci, scales, quats, skip) <= pad_voxels
    out[tuple(idx[k].T)] = True
    return out
