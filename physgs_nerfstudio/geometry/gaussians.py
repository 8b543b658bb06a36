"""What geometry needs from a splat: per-view depth and alpha, and per-Gaussian evidence lifted from masks.

Works on any object with ``means``, ``quats``, ``scales`` (activated), ``opacities`` (activated) tensors, e.g.
:class:`physgs_nerfstudio.export.field.PropertyField`. Rendering goes through :func:`physgs_nerfstudio.render.rasterize`
(gsplat on CUDA, the pure-torch reference rasterizer on CPU).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Literal, TypeVar

import torch
from jaxtyping import Float
from torch import Tensor

from ..lifting import group_views, lift_views
from ..render import rasterize, reference_median_depth
from ..render.backend import resolve_backend
from ..render.projection import quat_to_rotmat
from .capture import CaptureView

__all__ = ["ViewRender", "depth_spread", "lift_masks", "lift_masks_and_labels", "ray_extent", "render_depth",
           "surface_excess", "surface_views"]

logger = logging.getLogger(__name__)
_T = TypeVar("_T")


@dataclass
class ViewRender:
    depth: Float[Tensor, "H W"]
    """expected depth (camera z) where alpha > 0, else +inf"""
    alpha: Float[Tensor, "H W"]
    spread: Float[Tensor, "H W"] | None = None
    """the depth spread that a plane does not explain (:func:`depth_spread`), camera-z units; None = not rendered"""
    median: Float[Tensor, "H W"] | None = None
    """median depth (the transmittance crosses 1/2) where alpha >= 1/2, the expected depth elsewhere; None = not
    rendered"""
    extent: Float[Tensor, "H W"] | None = None
    """the blending-weighted mean of the contributing Gaussians' extents along their rays (:func:`ray_extent`),
    camera-z units, 0 where nothing is rendered; None = not rendered"""


def depth_spread(m: Tensor) -> Tensor:
    """float [H, W] from the blending-weighted moments ``m`` [H, W, 9] of the contributing Gaussians' centres
    (z, u, v, z^2, u^2, v^2, zu, zv, uv; z camera depth, u, v pixel coordinates, each normalised by alpha): the
    standard deviation of their depths about the least-squares plane z = a + b u + c v through them.

    A pixel's expected depth mixes every Gaussian that its ray meets, weighted by blending weight. On one plane,
    however oblique, the centres' depths differ only by the plane's slope across their image footprint, which the
    fit removes: the spread is 0. It is large where the weights mix surfaces at different depths (the front and
    the back of a thin part whose front is not opaque) or a curved surface across the pixel's footprint (a
    sphere, a handle): there the expected depth lies *behind* the first surface. By Cantelli's inequality at most
    1 / (1 + k^2) of the pixel's weight lies more than k spreads in front of the plane (k = 1: at most half, so
    ``depth - spread`` is not behind the weighted median of the depths)."""
    m = m.double()
    mz, mu, mv = m[..., 0], m[..., 1], m[..., 2]
    vzz = m[..., 3] - mz * mz
    vuu = m[..., 4] - mu * mu
    vvv = m[..., 5] - mv * mv
    czu = m[..., 6] - mz * mu
    czv = m[..., 7] - mz * mv
    cuv = m[..., 8] - mu * mv
    eps = 1e-6  # px^2: a pixel whose Gaussians share one centre explains nothing by the plane
    a, b, d = vuu.clamp_min(0) + eps, cuv, vvv.clamp_min(0) + eps
    det = (a * d - b * b).clamp_min(eps * eps)
    explained = (d * czu * czu - 2 * b * czu * czv + a * czv * czv) / det
    return (vzz - explained).clamp_min(0).sqrt().float()


def ray_extent(means: Float[Tensor, "N 3"], quats: Float[Tensor, "N 4"], scales: Float[Tensor, "N 3"],
               viewmat: Float[Tensor, "4 4"]) -> Float[Tensor, " N"]:  # fmt: skip
    """float [N]: each Gaussian's extent along the ray from the camera ``viewmat`` through its centre, in camera-z
    units: the standard deviation ``1 / sqrt(d^T Sigma^-1 d)`` of its density along the ray's unit direction ``d``
    (the Gaussian restricted to the line), times ``d``'s camera-z component.

    A rasterizer gives every pixel that a Gaussian covers the depth of its *centre*. A Gaussian that draws part of a
    surface extends in front of its centre along the ray by about this much; for a flat Gaussian lying in a face
    seen at an angle ``theta`` to its normal it is ``sigma_normal / cos(theta)`` along the ray: the face's thickness
    as the ray crosses it, not the Gaussian's in-plane size."""
    return _ray_extent(means, _axes_over_scales(quats, scales), viewmat)


def _axes_over_scales(quats: Tensor, scales: Tensor) -> Tensor:
    """float [N, 3, 3]: each Gaussian's axes (rotation columns) divided by its scales: ``d^T Sigma^-1 d`` is the
    squared norm of ``d`` times it (view-independent, so computed once for every view)."""
    return quat_to_rotmat(quats) / scales.clamp_min(1e-12)[:, None, :]


def _ray_extent(means: Tensor, axes: Tensor, viewmat: Tensor) -> Tensor:
    """:func:`ray_extent` from :func:`_axes_over_scales`."""
    pc = means @ viewmat[:3, :3].T + viewmat[:3, 3]
    d = pc / pc.norm(dim=-1, keepdim=True).clamp_min(1e-12)  # the ray's direction, camera frame
    q = ((d @ viewmat[:3, :3]).unsqueeze(1) @ axes).squeeze(1).square().sum(-1)  # |R^T d / s|^2
    return d[:, 2] / q.sqrt().clamp_min(1e-12)


@torch.no_grad()
def render_depth(g: Any, views: Sequence[CaptureView], *, backend: str = "auto", spread: bool = False,
                 depth: Literal["expected", "median", "both"] = "expected", extent: bool = False
                 ) -> list[ViewRender]:  # fmt: skip
    """Expected depth and alpha of the Gaussians ``g`` in every view; with ``spread`` also the depth spread
    about a plane (:func:`depth_spread`, from the weighted moments of the Gaussians' centres rendered as colours);
    with ``extent`` the blended extent of the Gaussians along the rays (:func:`ray_extent`, a colour channel).
    ``depth="median"``: the depth where the transmittance crosses 1/2
    (:func:`physgs_nerfstudio.render.reference_median_depth`, on any device) where alpha reaches 1/2, the
    expected depth elsewhere; "both": the expected depth in ``depth`` and the median in ``median``."""
    if depth not in ("expected", "median", "both"):
        raise ValueError(f"render_depth: depth must be 'expected', 'median' or 'both', got {depth!r}")
    out = []
    # each attribute read once (on a subset view of a field, every read gathers its rows again)
    means, quats, scales, opacities = g.means, g.quats, g.scales, g.opacities
    dev = means.device
    axes = _axes_over_scales(quats, scales) if extent else None

    def render(group: list[CaptureView]) -> list[ViewRender]:
        vm = torch.stack([v.viewmat.to(dev) for v in group])
        K = torch.stack([v.K.to(dev) for v in group])
        channels = [[] for _ in group]  # per view: [N, C] colour blocks
        for i, ch in enumerate(channels):
            if spread:
                ch.append(_centre_moments(means, vm[i], K[i]))
            if extent:
                ch.append(_ray_extent(means, axes, vm[i])[:, None])
        if channels[0]:
            colors = torch.stack([torch.cat(ch, -1) for ch in channels])
            colors = colors[0] if len(group) == 1 else colors
        else:
            colors = torch.zeros(means.shape[0], 1, device=dev)
        rgbd, alpha, _ = rasterize(means, quats, scales, opacities, colors, vm, K, group[0].width, group[0].height,
                                   render_mode="RGB+ED", packed=False, backend=backend)  # fmt: skip
        rendered = []
        for i, v in enumerate(group):
            a = alpha[i, ..., 0]
            d = rgbd[i, ..., -1]
            sp = ext = None
            if spread:
                m = rgbd[i, ..., :9] / a[..., None].clamp_min(1e-10)
                sp = torch.where(a > 1e-3, depth_spread(m), torch.zeros_like(d))
            if extent:
                e = rgbd[i, ..., -2] / a.clamp_min(1e-10)
                ext = torch.where(a > 1e-3, e, torch.zeros_like(d))
            med = None
            if depth != "expected":
                med = reference_median_depth(means, quats, scales, opacities, vm[i], K[i], v.width, v.height)
                med = torch.where(a > 1e-3, torch.where(torch.isfinite(med), med.to(d.dtype), d), float("inf"))
                if depth == "median":
                    d, med = med, None
            rendered.append(ViewRender(torch.where(a > 1e-3, d, torch.full_like(d, float("inf"))), a, sp, med, ext))
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


def _centre_moments(means: Tensor, vm: Tensor, K: Tensor) -> Tensor:
    """float [N, 9]: the colours whose blend gives a pixel's moments of the Gaussians' centres (:func:`depth_spread`)
    in the view ``vm``, ``K``: centred (depth about the Gaussians' median, pixels about the principal point) so
    float32 keeps the variances: the spread is a small difference of second moments."""
    pc = means @ vm[:3, :3].T + vm[:3, 3]
    z = pc[:, 2]
    zc = z.clamp_min(1e-6)
    dz = z - z.median()
    du, dv = K[0, 0] * pc[:, 0] / zc, K[1, 1] * pc[:, 1] / zc
    return torch.stack([dz, du, dv, dz * dz, du * du, dv * dv, dz * du, dz * dv, du * dv], -1)


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
    inside, outside, _ = lift_masks_and_labels(g, views, backend=backend, min_view_weight=min_view_weight,
                                               views_per_call=views_per_call)  # fmt: skip
    return inside, outside


@torch.no_grad()
def lift_masks_and_labels(g: Any, views: Sequence[CaptureView], labels: Sequence[Tensor | None] | None = None,
                          num_labels: int = 0, *, backend: str = "auto", min_view_weight: float = 1e-3,
                          views_per_call: int | None = None) -> tuple[Tensor, Tensor, Tensor]:  # fmt: skip
    """:func:`lift_masks`, and in the same rasterizer calls the share of each Gaussian's blending weight on the
    pixels of each of ``num_labels`` labels, summed over the views that see it: float64 [N, num_labels].
    ``labels[i]``: long [H, W] at ``views[i]``'s size, the label of each pixel (-1: none; None: no labels in that
    view)."""
    means, quats, scales, opacities = g.means, g.quats, g.scales, g.opacities
    dev = means.device
    n = means.shape[0]
    per_call = views_per_call if views_per_call is not None else _views_per_call(backend, dev, n)
    inside = torch.zeros(n, dtype=torch.float64, device=dev)
    outside = torch.zeros_like(inside)
    counts = torch.zeros(n, num_labels, dtype=torch.float64, device=dev)
    index = {id(v): i for i, v in enumerate(views)}

    def maps(v: CaptureView) -> Tensor:
        m = v.mask.to(dev).float()[..., None]
        if not num_labels:
            return m
        lab = labels[index[id(v)]] if labels is not None else None
        if lab is None:
            return torch.cat([m, m.new_zeros((*m.shape[:2], num_labels))], -1)
        lab = lab.to(dev)
        return torch.cat([m, torch.nn.functional.one_hot(lab.clamp_min(0), num_labels).float()
                          * (lab >= 0)[..., None].float()], -1)  # fmt: skip

    def lift(group: list[CaptureView]) -> list[tuple[Tensor, Tensor]]:
        size = (group[0].width, group[0].height)
        stacked = torch.stack([maps(v) for v in group])
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
            evd = ev.double()
            share = torch.where(seen[:, None], evd / w.clamp_min(1e-12)[:, None], torch.zeros_like(evd))
            frac = share[:, 0].clamp(0, 1)
            inside += torch.where(seen, frac, torch.zeros_like(frac))
            outside += torch.where(seen, 1 - frac, torch.zeros_like(frac))
            if num_labels:
                counts += share[:, 1:].clamp(0, 1)
    return inside, outside, counts


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
