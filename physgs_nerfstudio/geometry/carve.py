"""Space carving: the object's volume from many views' masks and rendered depth, with a robust vote.

For every voxel centre ``x`` and every view ``v`` in whose image it projects (in front of the camera):

* **seen outside**: ``x`` projects outside the view's object mask, by more than ``mask_margin_px`` pixels
  (signed distance to the mask boundary; a negative margin erodes the mask, a positive one dilates it);
* **seen in front**: ``x`` projects inside the mask, the splat is opaque there (alpha >= ``min_alpha``), and
  ``x`` lies in front of the rendered surface by more than ``depth_margin_voxels`` voxels plus
  ``depth_margin_rel`` of the depth: the camera sees *past* ``x`` onto a surface behind it, so ``x`` is empty
  (this carves concavities that silhouettes cannot, such as a cup's inside).

Either is an *empty vote*. A view *sees* ``x`` when ``x`` projects into its image; it sees ``x`` *directly*
when, besides, the splat is opaque there and ``x`` is not hidden behind the rendered surface (``x`` lies in
front of it or within the depth margin of it). A voxel is carved (empty) when its empty votes reach
``min_votes`` and either

* ``min_vote_fraction`` of the views that see it (the rule for silhouettes), or
* (off by default, see :class:`CarveConfig`) ``min_direct_fraction`` of the views that see it directly,
  counting only the depth votes among them (the rule for space that few views can see: under an object shot
  from above, only the few low views see that space at all, every higher view has it hidden behind the object;
  the low views that see past it are then all the direct evidence there is).

A voxel that fewer than ``min_seen_fraction`` of the views have in their image at all is empty (an object-centric
capture frames its object in every view). Otherwise it is solid, so space that no view sees past (the inside of
a closed object) stays solid. The direct rule never lets silhouette votes alone carve (a thick part's inside is
seen directly by no view, so two bad masks stay 2 votes out of every view that sees it). Why a vote rather than
the classic visual hull's "any one view":

* one bad mask (a part the segmenter missed in one view) casts one wrong empty vote: with ``min_votes`` = 2 it
  cannot delete the part;
* a floater in front of a surface only *lowers* the rendered depth in the views that see it, which withholds
  depth votes; it never adds volume, because the masks of the other views still carve around the object;
* the fraction keeps the rule meaningful when the capture has many views (60 views: 9 must agree at 0.15).

First surface. A depth vote is right only if the rendered depth is the *first* surface along the pixel's ray.
The expected depth (the blending-weighted mean of the Gaussians' depths) is that surface only when the surface is
opaque: where the first surface lets part of the ray through (trained Gaussians on a sphere, a handle, a shoe are
not opaque at 96 px), the mean is pulled towards the back surface, the voxels between lie "in front of the surface",
and every view carves its front of the object away (a solid sphere of Gaussians with opacity 0.5 kept 0.60 of its
volume with exact masks: tests/test_geometry.py). On a thin slab the front and the back surfaces are within a voxel
and the mean is right. ``depth_render="median"`` carves with the depth at which the ray's transmittance falls to
1/2 (the *median depth* of 3-D Gaussian surface reconstruction,
:func:`physgs_nerfstudio.render.reference_median_depth`): a surface that stops half of the ray keeps it, whatever
lies behind; on one thin layer of Gaussians it is that layer's depth, as the mean is, but on a layer that is
spread in depth it lies in front of the layer's mean (the weights fall off behind the first Gaussians), which
thickens thin walls. Two rules from the moments of the
contributing Gaussians' depths (:func:`.gaussians.depth_spread`, the spread about a plane through them:
``front_spread``, carve only in front of depth - k x spread; ``max_spread_voxels``, no depth vote where the spread
is large) are kept as options: the variance is dominated by a few per cent of weight on the far surface (the
spread of an opaque box's faces was 2-9 cm on a 40 cm box), so they withhold carving that was right. The default,
"auto", carves with the median where the reference rasterizer renders the depth (the CPU's short, low-resolution
trainings, where it raised the compact solids' volume: hammer 0.62x -> 0.74x, dumbbell 0.80x -> 0.96x at seed 101,
and lowered the held-out suite's median APE) and with the expected depth on gsplat, where the 512 px trainings'
surfaces are sharp and the median gained nothing (:func:`resolve_depth_render`; docs/architecture.md, "Mass
geometry"; benchmarks/README.md, rounds 5 and 7).

The Gaussians' depth. A rasterizer gives every pixel that a Gaussian covers the depth of the Gaussian's *centre*,
and a trained splat's surface Gaussians have their centres behind the surface they draw: their footprints, not
their centres, reach the object's outline in the views that see a face edge-on. So the expected depth lies about one
Gaussian thickness behind each face, and the depth votes carved that layer off both faces of every plate (on the
GPU the table's oak top kept 0.53 of its volume and the dumbbell's plates 0.71-0.75, both faces losing 4-5 mm
whatever the voxel: benchmarks/README.md, session 16). ``front_extent`` moves the depth that carves towards the
camera by k times the pixel's blended *along-ray extent* (:func:`.gaussians.ray_extent`: each Gaussian's standard
deviation along the ray through it, ``1 / sqrt(d^T Sigma^-1 d)``, rendered as a colour channel): a flat Gaussian
lying in a face adds its thickness across the face, not its in-plane size, and a face of thin Gaussians is not moved.
k = 2 with the expected depth (the default, gsplat's depth), 0 with the median depth (the CPU's reference
rasterizer), which already lies in front of a layer's centres; the mass interval samples k - 1 and k + 1 as
geometry variants, since where the surface lies within a Gaussian's extent is known only to about one extent.
Session 17 set k = 1 (GPU seed 5252: median APE 0.146 -> 0.099, median volume error 0.148 -> 0.074). With k =
1 the GPU suite's solids still came out a median 5-17% under their enclosed volumes at five later seeds (the
metal plates' faces rendered 0.3-0.7 voxel behind them, session 22), and k = 2 came closer at four of them; at
the two fresh seeds exported both ways the median APE went 0.070 -> 0.047 and 0.059 -> 0.045
(benchmarks/README.md, session 31).

Depth consensus. The vote's fraction is low (15% of the views that frame a voxel) because most views cannot see
a given empty voxel at all: it is hidden behind the object in them. But then a surface voxel is carved as soon as
15% of the views render the surface behind it, so the carved surface follows the *most* biased views, not the
typical one: a surface rendered a little too deep in a few views shaves a layer off a flat face (the GPU suite's
compact solids came out 0.72-0.9x of their volume). So a voxel that the silhouette votes alone do not carve is
carved only when its depth votes are also at least ``depth_consensus`` (0.5: a majority) of the views that see it
near their rendered surface (no more than ``near_band_voxels`` behind it) or in front of it: the views that have
evidence about it. A cup's inside passes (the views that look into it see past it; the views that have it hidden
behind the wall have no say); a face that most views render where it is keeps its layer. Measured at fresh
seeds on the same trained runs (benchmarks/README.md, round 9) with 0.5: GPU median volume error 0.139 -> 0.096
and median APE 0.158 -> 0.118; CPU demo settings 0.151 -> 0.134 and 0.106 -> 0.098. A view has a say ("near") only
where it could have voted: the voxel projects at least ``near_inset_px`` inside its mask (not onto the silhouette's
edge pixels, whose depth is the edge's) and the lookup's slack there is within the band. Without that, an exact
box (tests/test_geometry.py) kept a rim of voxels along its edges (1.104x; with it 1.099x, as the vote alone). The
default since round 10 (benchmarks/README.md): GPU seed 2727 median APE 0.119 against 0.118 without, volume 0.129
against 0.136; CPU seed 2828 0.125 and 10 of 12 covered against 0.147 and 9 of 12.

The centre test makes the recovered volume unbiased to first order in the voxel size (a boundary voxel is
counted when its centre is inside). The solid's small disconnected specks (below ``min_component`` of the
largest component's volume) are dropped, and cavities that the solid encloses completely are filled: a view
can only see past a voxel along a ray of empty space, so an enclosed empty pocket was carved by wrong
evidence (a depth rendered too deep through a semi-transparent wall), never seen.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor

from .capture import CaptureView
from .gaussians import ViewRender
from .grid import VoxelGrid

__all__ = [
    "EXPECTED_DEPTH_EXTENT",
    "CarveConfig",
    "CarveVotes",
    "VoteKey",
    "carve_votes",
    "carve_votes_many",
    "hull_from_votes",
    "resolve_depth_render",
    "signed_mask_distance",
    "signed_mask_distances",
    "solid_from_votes",
    "vote_key",
]

EXPECTED_DEPTH_EXTENT = 2.0
"""the default ``front_extent`` where the expected depth carves (gsplat): the module doc's k"""


@dataclass
class CarveConfig:
    """The carving rule (module doc). The defaults are the nominal geometry; :mod:`.variants` perturbs them."""

    min_votes: int = 2
    """a voxel is empty when at least this many views see past it ..."""
    min_vote_fraction: float = 0.15
    """... and at least this fraction of the views that see it"""
    mask_margin_px: float = 0.0
    """+: dilate the object masks by this many pixels before carving; -: erode"""
    depth_margin_voxels: float = 0.0
    depth_margin_rel: float = 0.0
    """a voxel is in front of the surface when nearer than depth - (margin_voxels * voxel + margin_rel * depth)"""
    depth_lookup: Literal["bilinear", "nearest"] = "bilinear"
    """how the rendered depth is read at a voxel's projection: interpolated between the opaque pixels around it,
    or the depth of the pixel that holds it"""
    depth_slope_margin: float = 1.0
    """... plus this times the lookup's error bound at that pixel (:func:`depth_slack`: 0 on a plane with the
    bilinear lookup; half a pixel's depth change with the nearest); 0 = off"""
    min_alpha: float = 0.5
    """pixels less opaque than this do not carve by depth"""
    depth_render: Literal["auto", "expected", "median", "first"] = "auto"
    """the rendered depth that carves (module doc, "First surface"): "expected", the blending-weighted mean of the
    Gaussians' depths; "median", the depth where the transmittance crosses 1/2; "first", the expected depth
    except where it lies more than ``mixed_depth_voxels`` behind the median (the pixel mixes surfaces), the
    median there; "auto" (:func:`resolve_depth_render`): the median where the depth is rendered by the reference
    rasterizer (CPU), the expected depth with gsplat (CUDA)"""
    mixed_depth_voxels: float = 1.0
    """"first": a pixel mixes surfaces when its expected depth lies this many voxels behind its median depth"""
    front_spread: float = 0.0
    """carve by depth only in front of depth - this times the pixel's depth spread about a plane
    (:func:`.gaussians.depth_spread`): a front-surface estimate where a pixel mixes surfaces (module doc,
    "First surface"); 0 = the expected depth"""
    max_spread_voxels: float = float("inf")
    """pixels whose depth spread exceeds this many voxels do not carve by depth (their depth is no surface)"""
    front_extent: float | None = None
    """carve with the rendered depth moved this many of its pixel's blended along-ray extents
    (:func:`.gaussians.ray_extent`) towards the camera (module doc, "The Gaussians' depth"); 0 = the depth as
    rendered; None (default): :data:`EXPECTED_DEPTH_EXTENT` (2) with the expected depth, 0 with the median and
    "first" depths, which already lie in front of the centres (:meth:`extent_multiple`)"""
    min_direct_fraction: float = 2.0
    """... or at least this fraction of the views that see it directly see past it by depth (module doc);
    > 1 (the default) switches the direct rule off: over the generated suite at seed 101 it carved the space
    under objects but also thin bottoms that only a few poorly reconstructed low views see (median APE 0.307
    with 0.5 against 0.273 without; benchmarks/README.md). 0.5 is the setting to try for a capture with views
    from below"""
    depth_consensus: float = 0.5
    """a voxel that the silhouette votes alone do not carve is carved only when its depth votes are at least this
    fraction of the views that see it near or in front of their rendered surface (within ``near_band_voxels``
    behind it: module doc, "Depth consensus"); 0 = off (the vote alone decides); documented range 0.35-0.65"""
    near_band_voxels: float = 1.0
    """... a view sees a voxel *near* its surface when the voxel lies at most this many voxels (plus the depth
    margin) behind the rendered depth, where that depth is sharp (the lookup's slack, :func:`depth_slack`, no wider
    than the band) ..."""
    near_inset_px: float = 1.0
    """... and the voxel projects at least this many pixels inside the view's mask: a view that has the voxel on its
    silhouette's edge pixels, whose depth is the edge's, has no say"""
    use_depth: bool = True
    min_seen_fraction: float = 0.5
    """a voxel that fewer than this fraction of the views have in their image is empty: an object-centric capture
    frames its object in every view, so space out of frame in most views is not the object (left solid, as unseen
    space inside the object is, it filled a domain that outliers of the selection had stretched); lower it for a
    capture whose views each show only part of the object"""
    min_component: float = 0.02
    """drop solid components smaller than this fraction of the largest one"""
    fill_cavities: bool = True
    """fill empty pockets that the solid encloses completely (module doc)"""

    def __post_init__(self) -> None:
        if self.min_votes < 1:
            raise ValueError(f"CarveConfig.min_votes must be >= 1, got {self.min_votes}.")
        if not 0 <= self.min_vote_fraction <= 1:
            raise ValueError(f"CarveConfig.min_vote_fraction must be in [0, 1], got {self.min_vote_fraction}.")
        if self.front_extent is not None and not self.front_extent >= 0:
            raise ValueError(f"CarveConfig.front_extent must be >= 0 (or None: by the depth), got {self.front_extent}.")
        if self.depth_margin_voxels < -1 or self.depth_margin_rel < 0:
            raise ValueError(f"CarveConfig: depth_margin_voxels must be >= -1 and depth_margin_rel >= 0, got "
                             f"{self.depth_margin_voxels} and {self.depth_margin_rel}.")

    def extent_multiple(self) -> float:
        """``front_extent`` resolved: as set, or (None) :data:`EXPECTED_DEPTH_EXTENT` where the depth that
        carves is the expected depth, else 0 (an unresolved ``depth_render="auto"`` carves with the median
        where the render has one)."""
        if self.front_extent is not None:
            return float(self.front_extent)
        return EXPECTED_DEPTH_EXTENT if self.depth_render == "expected" else 0.0


def signed_mask_distance(mask: np.ndarray | Tensor) -> Float[Tensor, "H W"]:
    """Signed distance in pixels at pixel centres, > 0 outside and < 0 inside, offset by half a pixel so that
    its bilinear interpolation (:func:`_sample`) crosses 0 on the pixel edges between inside and outside.

    Exact Euclidean distances (OpenCV's ``DIST_MASK_PRECISE``, the same values as SciPy's
    ``distance_transform_edt``, tested against it; about 5x faster at 512 px, and it releases the GIL, so
    :func:`signed_mask_distances` computes many views at once)."""
    import cv2

    m = np.asarray(mask.cpu() if isinstance(mask, Tensor) else mask, dtype=bool)
    if not m.any():
        return torch.full(m.shape, 1e6)
    if m.all():
        return torch.full(m.shape, -1e6)
    u8 = np.ascontiguousarray(m).view(np.uint8)
    out = cv2.distanceTransform(1 - u8, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    inside = cv2.distanceTransform(u8, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return torch.from_numpy(np.where(m, 0.5 - inside, out - 0.5).astype(np.float32))


def signed_mask_distances(masks: Sequence[np.ndarray | Tensor], workers: int | None = None) -> list[Tensor]:
    """:func:`signed_mask_distance` of every mask, on a thread pool (OpenCV releases the GIL)."""
    from concurrent.futures import ThreadPoolExecutor

    masks = list(masks)
    if len(masks) < 4:
        return [signed_mask_distance(m) for m in masks]
    with ThreadPoolExecutor(max_workers=workers or min(16, os.cpu_count() or 1)) as pool:
        return list(pool.map(signed_mask_distance, masks))


def _shift(t: Tensor, dim: int, step: int, fill: float | bool) -> Tensor:
    """``t`` moved by ``step`` pixels along ``dim`` (out[i] = t[i - step]), ``fill`` where nothing moved in."""
    n = t.shape[dim]
    body = t.narrow(dim, 0, n - step) if step > 0 else t.narrow(dim, -step, n + step)
    pad = torch.full_like(t.narrow(dim, 0, abs(step)), fill)
    return torch.cat([pad, body] if step > 0 else [body, pad], dim)


def depth_slack(depth: Tensor, alpha: Tensor, min_alpha: float = 0.5, lookup: str = "bilinear") -> Tensor:
    """float [H, W]: a bound on the error of the depth looked up at a point inside each pixel, from the depth's
    differences to opaque neighbours (alpha >= ``min_alpha``), summed over the two image axes:

    * ``lookup="nearest"`` (the pixel's own depth): half a pixel's first difference, the larger one-sided one;
    * ``lookup="bilinear"``: where both neighbours along an axis are opaque, linear interpolation's error bound
      |second difference| / 8, zero on a plane however obliquely it is seen; next to a transparent neighbour
      (the interpolation falls back to the opaque side) half the one-sided first difference.
    """
    op = alpha >= min_alpha
    d = torch.where(op, depth, torch.zeros_like(depth))
    out = torch.zeros_like(d)
    for dim in (0, 1):
        prev, nxt = _shift(d, dim, 1, 0.0), _shift(d, dim, -1, 0.0)
        p_ok, n_ok = _shift(op, dim, 1, False) & op, _shift(op, dim, -1, False) & op
        first = 0.5 * torch.maximum(torch.where(p_ok, (d - prev).abs(), 0.0), torch.where(n_ok, (nxt - d).abs(), 0.0))
        if lookup == "bilinear":
            first = torch.where(p_ok & n_ok, (prev - 2 * d + nxt).abs() / 8, first)
        out += first
    return out


def _corners(shape: tuple[int, ...], u: Tensor, v: Tensor) -> list[tuple[Tensor, Tensor, Tensor]]:
    """(row, column, bilinear weight) of the four pixels around continuous pixel coordinates (pixel i covers
    [i, i+1)), clamped to the image."""
    H, W = shape
    x = (u - 0.5).clamp(0, W - 1)
    y = (v - 0.5).clamp(0, H - 1)
    x0 = x.floor().long().clamp(0, W - 1)
    y0 = y.floor().long().clamp(0, H - 1)
    x1, y1 = (x0 + 1).clamp(max=W - 1), (y0 + 1).clamp(max=H - 1)
    fx, fy = x - x0, y - y0
    return [(y0, x0, (1 - fx) * (1 - fy)), (y0, x1, fx * (1 - fy)), (y1, x0, (1 - fx) * fy), (y1, x1, fx * fy)]


def _sample(img: Tensor, u: Tensor, v: Tensor) -> Tensor:
    """Bilinear sample of ``img`` [H, W] at continuous pixel coordinates (pixel i covers [i, i+1))."""
    return sum(img[yy, xx] * w for yy, xx, w in _corners(img.shape, u, v))


def resolve_depth_render(kind: str, backend: str) -> str:
    """``depth_render`` with "auto" resolved for the rasterizer ``backend`` ("gsplat" or "reference") that renders
    the depth. Why it depends on it (benchmarks/README.md, round 7): the demo's and CI's short CPU trainings
    (16 views at 96 px, reference rasterizer) leave semi-transparent surface layers whose expected depth lies
    behind the first surface, so carving by it erodes compact solids, and the median fixed that at every CPU seed
    measured (suite median APE 0.297 -> 0.254 at seeds 1111/1212, 0.250 -> 0.236 at 1717/1818); the GPU runs (60
    views at 512 px, 7,000 steps) have sharp surfaces, gained nothing from it (4 objects at seed 1919), and the median
    depth has no gsplat kernel (the reference compositor on CUDA costs about 2.6 s more per export at 1M
    Gaussians)."""
    if kind != "auto":
        return kind
    return "median" if backend == "reference" else "expected"


def carve_depth(render: ViewRender, kind: str, mixed: float = 0.0) -> Tensor:
    """float [H, W]: the depth image that carves (:class:`CarveConfig` ``depth_render``; ``mixed``: the
    "first" rule's threshold in depth units). "median" and "first" need a render with its median depth, unless
    the render's ``depth`` already is the median; "auto" (not resolved by :func:`resolve_depth_render`): the
    render's median where it has one, else its depth. (``front_extent`` moves it by the looked-up extent, per
    setting, in the vote.)"""
    if kind == "auto":
        kind = "median"
    if kind == "expected" or (kind == "median" and render.median is None):
        return render.depth
    if render.median is None:
        raise ValueError("carve_depth: depth_render 'first' needs renders with their median depth "
                         "(render_depth(..., depth='both')).")  # fmt: skip
    if kind == "median":
        return render.median
    if kind != "first":
        raise ValueError(f"carve_depth: unknown depth_render {kind!r}")
    return torch.where(render.depth - render.median > mixed, render.median, render.depth)


@dataclass
class CarveVotes:
    empty: Tensor
    """int [M]: views that see past each voxel"""
    seen: Tensor
    """int [M]: views in whose image each voxel projects"""
    depth_empty: Tensor | None = None
    """int [M]: the empty votes cast by depth (a subset of ``empty``)"""
    direct: Tensor | None = None
    """int [M]: views that see each voxel directly (opaque there, not hidden behind the rendered surface)"""
    num_views: int = 0
    """views voted"""
    near: Tensor | None = None
    """int [M]: views that see each voxel directly or within ``near_band_voxels`` behind their surface (None: not
    counted, when no setting asks for the depth consensus)"""


@torch.no_grad()
def carve_votes(
    grid: VoxelGrid,
    views: Sequence[CaptureView],
    renders: Sequence[ViewRender] | None,
    cfg: CarveConfig,
    *,
    sdf: Sequence[Tensor] | None = None,
    chunk: int = 1 << 20,
    device: torch.device | str = "cpu",
) -> CarveVotes:
    """Empty and seen votes for every voxel of ``grid`` (flattened C order)."""
    return carve_votes_many(grid, views, renders, [cfg], sdf=sdf, chunk=chunk, device=device)[0]


VoteKey = tuple[float, float, float, float]


def vote_key(cfg: CarveConfig) -> VoteKey:
    """The settings that the geometry variants and the partial-volume surface change and that the votes depend on
    (mask margin, depth margin, absolute and relative, and the depth's move in front): settings whose keys are
    equal, and whose other vote settings agree, share one voting pass."""
    return cfg.mask_margin_px, cfg.depth_margin_voxels, cfg.depth_margin_rel, cfg.extent_multiple()


@torch.no_grad()
def carve_votes_many(
    grid: VoxelGrid,
    views: Sequence[CaptureView],
    renders: Sequence[ViewRender] | None,
    cfgs: Sequence[CarveConfig],
    *,
    sdf: Sequence[Tensor] | None = None,
    chunk: int = 1 << 20,
    batch_points: int | None = None,
    device: torch.device | str = "cpu",
    points: Tensor | None = None,
) -> list[CarveVotes]:
    """:func:`carve_votes` under several settings in one pass: each voxel centre is projected into each view,
    and its mask distance and rendered depth are looked up, once; then it is voted on under every setting
    (per setting the same arithmetic as a call of its own, so the votes are identical). Views of one image size
    are voted on together, ``batch_points`` (voxel, view) pairs at a time (default: 2^23 on a GPU, where it saves
    kernel launches; one view at a time on the CPU): the same operations on every pair, so the same votes.
    ``points`` [M, 3] (scene units): vote at these points instead of the grid's voxel centres (``grid`` then
    gives only the voxel size, the margins' unit: :func:`boundary_fill`'s sub-voxel points)."""
    if batch_points is None:
        batch_points = default_batch_points(device)
    M = grid.num_voxels if points is None else len(points)
    G = len(cfgs)
    empty, depth_empty, direct = ([torch.zeros(M, dtype=torch.int32, device=device) for _ in cfgs] for _ in range(3))
    counts_near = renders is not None and any(c.depth_consensus > 0 and c.use_depth for c in cfgs)
    near = [torch.zeros(M, dtype=torch.int32, device=device) if c.depth_consensus > 0 else None for c in cfgs]
    seen = torch.zeros(M, dtype=torch.int32, device=device)
    sdf = [t.to(device) for t in (sdf if sdf is not None else signed_mask_distances([v.mask for v in views]))]
    cams = [(v.viewmat[:3, :3].to(device), v.viewmat[:3, 3].to(device), v.K.to(device)) for v in views]
    any_depth = renders is not None and any(c.use_depth for c in cfgs)
    slope = any(c.depth_slope_margin > 0 for c in cfgs)
    lookup = cfgs[0].depth_lookup
    if any(c.depth_lookup != lookup for c in cfgs):
        raise ValueError("carve_votes_many: every setting must use the same depth_lookup.")
    kind = cfgs[0].depth_render
    if any((c.depth_render, c.mixed_depth_voxels) != (kind, cfgs[0].mixed_depth_voxels) for c in cfgs):
        raise ValueError("carve_votes_many: every setting must use the same depth_render and mixed_depth_voxels.")
    images = ([carve_depth(r, kind, cfgs[0].mixed_depth_voxels * grid.voxel_size).to(device) for r in renders]
              if any_depth else [None] * len(views))  # fmt: skip
    depth = ([(d, r.alpha.to(device), depth_slack(d, r.alpha.to(device), lookup=lookup) if slope else None)
              for d, r in zip(images, renders)] if any_depth else [None] * len(views))  # fmt: skip
    use_spread = any_depth and any(c.front_spread > 0 or c.max_spread_voxels < float("inf") for c in cfgs)
    if use_spread and any(r.spread is None for r in renders):
        raise ValueError("carve_votes_many: front_spread / max_spread_voxels need renders with a depth spread "
                         "(render_depth(..., spread=True)).")  # fmt: skip
    spreads = [r.spread.to(device) for r in renders] if use_spread else [None] * len(views)
    use_extent = any_depth and any(c.extent_multiple() > 0 for c in cfgs)
    if use_extent and any(r.extent is None for r in renders):
        raise ValueError("carve_votes_many: front_extent needs renders with their along-ray extent "
                         "(render_depth(..., extent=True)).")  # fmt: skip
    extents = [r.extent.to(device) for r in renders] if use_extent else [None] * len(views)
    shape = torch.as_tensor(grid.shape, device=device)
    rule = _Rule(cfgs, grid.voxel_size)
    batches = _ViewBatch.group(views, cams, sdf, depth, spreads, lookup == "bilinear", extents)
    for s0 in range(0, M, chunk):  # voxel centres once per chunk, then every view
        flat = torch.arange(s0, min(M, s0 + chunk), device=device)
        if points is None:
            ijk = torch.stack([flat // (shape[1] * shape[2]), (flat // shape[2]) % shape[1], flat % shape[2]], -1)
            x = grid.centres(ijk)
        else:
            x = points[s0 : s0 + chunk].to(device=device, dtype=torch.float32)
        n_seen = torch.zeros(len(flat), dtype=torch.int32, device=device)
        # [G, n]: one row per setting
        n_empty, n_depth, n_direct = (torch.zeros(G, len(flat), dtype=torch.int32, device=device) for _ in range(3))
        n_near = torch.zeros(G, len(flat), dtype=torch.int32, device=device) if counts_near else None
        for part in _ViewBatch.parts(batches, len(flat), batch_points):  # [B, n] per quantity
            ok, z, dist, d, a, sl, sp, ex = part.lookup(x)
            if d is None:
                vote = rule.silhouette(ok, dist)
            else:
                vote, dvote, seen_directly, seen_near = rule.votes(ok, dist, z, d, a, sl, sp, ex)
                _add_views(n_depth, dvote)
                _add_views(n_direct, seen_directly)
                if seen_near is not None and n_near is not None:
                    _add_views(n_near, seen_near)
            _add_views(n_empty, vote)
            _add_views(n_seen, ok)
        sl = slice(s0, s0 + len(flat))
        seen[sl] = n_seen
        for g in range(G):
            empty[g][sl], depth_empty[g][sl], direct[g][sl] = n_empty[g], n_depth[g], n_direct[g]
            if n_near is not None and near[g] is not None:
                near[g][sl] = n_near[g]
    return [CarveVotes(empty[g], seen, depth_empty[g], direct[g], len(views), near[g] if any_depth else None)
            for g in range(G)]


def _add_views(total: Tensor, votes: Tensor) -> None:
    """``total`` [..., n] += the votes [..., B, n] summed over their B views."""
    if votes.shape[-2] == 1:
        total += votes.squeeze(-2)
    else:
        total += votes.sum(-2, dtype=total.dtype)


class _ViewBatch:
    """Views whose images share their sizes and types, voted on together: their images stacked (per size and type,
    so that one gather reads all of them at a pixel) and their cameras' numbers as [B, 1] columns. Every operation
    is, pair for pair, the one that a view on its own gets (:func:`carve_votes_many`)."""

    def __init__(self, views: list[CaptureView], cams: list[tuple[Tensor, Tensor, Tensor]],
                 around: dict[str, list[Tensor]], held: dict[str, list[Tensor]], bilinear: bool,
                 index: list[int] | None = None) -> None:  # fmt: skip
        self.views, self.cams, self.bilinear = views, cams, bilinear
        self.index = index if index is not None else list(range(len(views)))
        """each view's position in the views the batches were grouped from (:meth:`group`)"""
        self._around, self._held = around, held
        self._stacked: tuple[list, list] | None = None  # stacked when first looked up
        self._parts: dict[tuple[int, int], _ViewBatch] = {}
        dev = cams[0][0].device
        K = torch.stack([c[2] for c in cams])
        self.fx, self.cx, self.fy, self.cy = (K[:, i, j][:, None] for i, j in ((0, 0), (0, 2), (1, 1), (1, 2)))
        self.width = torch.tensor([v.width for v in views], device=dev)[:, None]
        self.height = torch.tensor([v.height for v in views], device=dev)[:, None]

    def __len__(self) -> int:
        return len(self.views)

    @classmethod
    def group(cls, views: Sequence[CaptureView], cams: list[tuple[Tensor, Tensor, Tensor]], sdf: list[Tensor],
              depth: list, spreads: list, bilinear: bool, extents: list | None = None) -> list[_ViewBatch]:  # fmt: skip
        """The views grouped by the sizes and types of their images (in their order)."""
        groups: dict[tuple, list[int]] = {}
        per_view = []
        extents = extents if extents is not None else [None] * len(views)
        for i, (sd, dz, spr, ext) in enumerate(zip(sdf, depth, spreads, extents)):
            around = {"sdf": sd}
            held: dict[str, Tensor] = {}
            if dz is not None:
                held = {"depth": dz[0], "alpha": dz[1]}
                if dz[2] is not None:
                    held["slack"] = dz[2]
                if spr is not None:
                    held["spread"] = spr
                if ext is not None:
                    held["extent"] = ext
                if bilinear:
                    around.update({k: v for k, v in held.items() if k != "slack"})
            per_view.append((around, held))
            key = tuple((k, tuple(v.shape), v.dtype) for d in (around, held) for k, v in d.items())
            key += (cams[i][0].dtype, cams[i][2].dtype)
            groups.setdefault(key, []).append(i)
        out = []
        for idx in groups.values():
            around = {k: [per_view[i][0][k] for i in idx] for k in per_view[idx[0]][0]}
            held = {k: [per_view[i][1][k] for i in idx] for k in per_view[idx[0]][1]}
            out.append(cls([views[i] for i in idx], [cams[i] for i in idx], around, held, bilinear, idx))
        return out

    @staticmethod
    def parts(batches: list[_ViewBatch], n: int, batch_points: int) -> Iterator[_ViewBatch]:
        """The batches cut to at most ``batch_points`` (point, view) pairs for ``n`` points (one view at least)."""
        per = max(1, batch_points // max(n, 1))
        for batch in batches:
            for b0 in range(0, len(batch), per):
                yield batch.part(b0, b0 + per)

    def part(self, b0: int, b1: int) -> _ViewBatch:
        if b0 == 0 and b1 >= len(self):
            return self
        if (b0, b1) in self._parts:  # (the next chunk of voxels)
            return self._parts[(b0, b1)]
        sub = lambda d: {k: v[b0:b1] for k, v in d.items()}
        part = _ViewBatch(self.views[b0:b1], self.cams[b0:b1], sub(self._around), sub(self._held), self.bilinear,
                          self.index[b0:b1])  # fmt: skip
        self._parts[(b0, b1)] = part
        return part

    @property
    def around(self) -> list[tuple[Tensor, tuple[int, ...], list[str]]]:
        """The stacks of the images read at the four pixels around a point."""
        if self._stacked is None:
            self._stacked = (self._stacks(self._around), self._stacks(self._held))
        return self._stacked[0]

    @property
    def held(self) -> list[tuple[Tensor, tuple[int, ...], list[str]]]:
        """The stacks of the images read at the pixel that holds a point."""
        self.around  # noqa: B018  (stacks both)
        return self._stacked[1]  # type: ignore[index]

    @staticmethod
    def _stacks(images: dict[str, list[Tensor]]) -> list[tuple[Tensor, tuple[int, ...], list[str]]]:
        """[B * H * W, C] per size and type of image (a pixel's C values side by side), with the names of its C
        images."""
        groups: dict[tuple, list[str]] = {}
        for name, ims in images.items():
            groups.setdefault((tuple(ims[0].shape), ims[0].dtype), []).append(name)
        return [(torch.stack([torch.stack(images[n]).reshape(-1) for n in names], -1), key[0], names)
                for key, names in groups.items()]  # fmt: skip

    def _gather(self, stack: Tensor, shape: tuple[int, ...], rows: Tensor, cols: Tensor) -> Tensor:
        """[C, B, n]: the C images of each view at pixels (``rows``, ``cols``) [B, n] (one gather)."""
        if stack.shape[1] == 1 and len(self) == 1:  # one image: indexed as such (no flat index to compute)
            return stack.view(shape)[rows, cols][None]
        flat = rows * shape[1] + cols
        if len(self) > 1:  # view b's images start at b * H * W
            flat = flat + torch.arange(len(self), device=flat.device)[:, None] * (shape[0] * shape[1])
        return stack.index_select(0, flat.reshape(-1)).T.reshape(stack.shape[1], *rows.shape)

    def lookup(self, x: Tensor) -> tuple[Tensor, ...]:
        """[B, n] each, for voxel centres ``x`` [n, 3]: whether the view frames the centre, its camera depth, the mask
        distance there (:func:`_sample`), and the depth, alpha, slack, spread and along-ray extent that the vote reads
        (None where not rendered): the depth, the spread and the extent bilinear from the opaque pixels (alpha >= 0.5)
        among the four around the point, their bilinear weights renormalised (the depth +inf and the others 0 where
        none is opaque), or else
        the pixel's own; the alpha and the slack the pixel's own."""
        pc = (torch.stack([x @ R.T + t for R, t, _ in self.cams]) if len(self) > 1
              else (x @ self.cams[0][0].T + self.cams[0][1])[None])  # [B, n, 3], each view's as on its own
        z = pc[..., 2]
        u = self.fx * pc[..., 0] / z.clamp_min(1e-9) + self.cx
        v = self.fy * pc[..., 1] / z.clamp_min(1e-9) + self.cy
        if len(self) == 1:  # the view's numbers as such (one clamp where a column takes two)
            W, H = self.views[0].width, self.views[0].height
            ok = (z > 1e-6) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
            uc, vc = u.clamp(0, W), v.clamp(0, H)
        else:
            W, H = self.width.to(u.dtype), self.height.to(u.dtype)
            ok = (z > 1e-6) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
            uc, vc = u.clamp_min(0).minimum(W), v.clamp_min(0).minimum(H)
        at: dict[str, tuple[list[Tensor], list[Tensor]]] = {}  # name: (values at the four corners, their weights)
        for stack, shape, names in self.around:
            corners = _corners(shape, uc, vc)  # type: ignore[arg-type]
            got = [self._gather(stack, shape, yy, xx) for yy, xx, _ in corners]
            for i, n in enumerate(names):
                at[n] = ([g[i] for g in got], [cw for _, _, cw in corners])
        vals, weights = at["sdf"]
        dist = sum(s * cw for s, cw in zip(vals, weights))
        if not self.held:
            return ok, z, dist, None, None, None, None, None  # type: ignore[return-value]
        if len(self) == 1:
            ui = u.floor().long().clamp(0, self.views[0].width - 1)
            vi = v.floor().long().clamp(0, self.views[0].height - 1)
        else:
            ui = u.floor().long().clamp_min(0).minimum(self.width - 1)
            vi = v.floor().long().clamp_min(0).minimum(self.height - 1)
        px: dict[str, Tensor] = {}
        for stack, shape, names in self.held:
            px.update(zip(names, self._gather(stack, shape, vi, ui)))
        d, a, sl = px["depth"], px["alpha"], px.get("slack")
        extra = {n: px[n] for n in ("spread", "extent") if n in px}
        if self.bilinear:
            depth, weights = at["depth"]
            alpha = at["alpha"][0]
            num = torch.zeros_like(u)
            den = torch.zeros_like(u)
            nums = {n: torch.zeros_like(u) for n in extra}
            for k, cw in enumerate(weights):
                good = alpha[k] >= 0.5
                cw = torch.where(good, cw, 0.0)
                num += cw * torch.where(good, depth[k], 0.0)
                for n, acc in nums.items():
                    acc += cw * torch.where(good, at[n][0][k], 0.0)
                den += cw
            has = den > 0
            d = torch.where(has, num / den.clamp_min(1e-12), torch.full_like(num, float("inf")))
            extra = {n: torch.where(has, acc / den.clamp_min(1e-12), torch.zeros_like(acc)) for n, acc in nums.items()}
        return ok, z, dist, d, a, sl, extra.get("spread"), extra.get("extent")

class _Rule:
    """The carving rule of several settings at once, as [G, n] comparisons against [G, 1] columns of the settings'
    thresholds: row g is, value for value, what the rule of setting g alone computes (the same operations, the
    thresholds rounded to the compared tensor's type as a Python number would be)."""

    def __init__(self, cfgs: Sequence[CarveConfig], voxel_size: float) -> None:
        self.values: dict[str, list] = {
            "mask_margin": [c.mask_margin_px for c in cfgs],
            "margin_abs": [c.depth_margin_voxels * voxel_size for c in cfgs],
            "margin_rel": [c.depth_margin_rel for c in cfgs],
            "slope": [c.depth_slope_margin for c in cfgs],
            "min_alpha": [c.min_alpha for c in cfgs],
            "front_spread": [c.front_spread for c in cfgs],
            "front_extent": [c.extent_multiple() for c in cfgs],
            "max_spread": [c.max_spread_voxels * voxel_size for c in cfgs],
            "use_depth": [c.use_depth for c in cfgs],
            "has_slope": [c.depth_slope_margin > 0 for c in cfgs],
            "has_max_spread": [c.max_spread_voxels < float("inf") for c in cfgs],
            "near_band": [c.near_band_voxels * voxel_size for c in cfgs],
            "consensus": [c.depth_consensus > 0 for c in cfgs],
            "near_inset": [c.near_inset_px for c in cfgs],
        }
        self._cols: dict[tuple, Tensor] = {}

    def col(self, name: str, like: Tensor, dtype: torch.dtype | None = None) -> Tensor:
        """[G, 1, ...]: the settings' values of ``name``, in ``like``'s type (or ``dtype``), to broadcast against
        ``like``; [1, 1, ...] when every setting has the same value (the operation then runs once, not G times)."""
        dtype = dtype or like.dtype
        key = (name, dtype, like.dim(), like.device)
        if key not in self._cols:
            vals = self.values[name]
            vals = vals[:1] if all(v == vals[0] for v in vals) else vals
            self._cols[key] = torch.tensor(vals, dtype=dtype, device=like.device).reshape(-1, *([1] * like.dim()))
        return self._cols[key]

    def every(self, name: str) -> bool | None:
        """True (False) when the flag ``name`` is set (unset) for every setting, None when it differs."""
        vals = self.values[name]
        return bool(vals[0]) if all(v == vals[0] for v in vals) else None

    def silhouette(self, ok: Tensor, dist: Tensor) -> Tensor:
        """bool [G, n]: the mask votes."""
        return ok & (dist > self.col("mask_margin", dist))

    def votes(self, ok: Tensor, dist: Tensor, z: Tensor, d: Tensor, a: Tensor, sl: Tensor | None,
              sp: Tensor | None, ex: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor, Tensor | None]:  # fmt: skip
        """bool [G, n] each (or [1, n] where every setting gives the same): the empty votes, the depth votes among
        them, whether the view sees the voxel directly, and whether near its surface (None when no setting asks
        for the depth consensus)."""
        like = d  # [B, n]: the columns' shape ([G, 1, 1]) whatever the depth's below
        if ex is not None:  # the surface in front of the Gaussians' centres (module doc, "The Gaussians' depth")
            d = d - self.col("front_extent", ex) * ex
        margin = self.col("margin_abs", like) + self.col("margin_rel", like) * d
        slope = self.every("has_slope")
        if sl is not None and slope is not False:
            sloped = margin + self.col("slope", sl) * sl
            margin = sloped if slope else torch.where(self.col("has_slope", sl, torch.bool), sloped, margin)
        inside = ok & (dist <= self.col("mask_margin", dist)) & (a >= self.col("min_alpha", a))
        if not self.every("use_depth"):
            inside = inside & self.col("use_depth", ok, torch.bool)
        front = d
        if sp is not None:
            front = d - self.col("front_spread", sp) * sp
            capped = self.every("has_max_spread")
            if capped:
                inside = inside & (sp <= self.col("max_spread", sp))
            elif capped is None:
                inside = inside & ((sp <= self.col("max_spread", sp)) | ~self.col("has_max_spread", sp, torch.bool))
        dvote = inside & (z < front - margin)
        near = None
        if self.every("consensus") is not False:
            # a view has a say about the voxel only where it could have voted: the voxel falls clearly inside its
            # mask (not on the silhouette's edge pixels, whose depth is the edge's) and its depth is sharp there
            # (the lookup's slack no wider than the band)
            band = self.col("near_band", like)
            deep = dist <= self.col("mask_margin", dist) - self.col("near_inset", dist)
            near = inside & deep & (z <= d + margin + band) & (margin <= band)
        return self.silhouette(ok, dist) | dvote, dvote, inside & (z <= d + margin), near


def default_batch_points(device: torch.device | str) -> int:
    """(point, view) pairs looked up at once: many on a GPU (fewer kernel launches), one view at a time on the CPU
    (no faster batched there)."""
    return 1 << 23 if torch.device(device).type == "cuda" else 1


def mask_view_votes(x: Tensor, views: Sequence[CaptureView], sdf: Sequence[Tensor], margin_px: float,
                    batch_points: int | None = None) -> tuple[Tensor, Tensor]:  # fmt: skip
    """bool [V, n] each, for points ``x`` [n, 3] (float32, on the views' device), in the order of ``views``: whether
    each view frames each point (in front of the camera, inside the image), and whether it frames it and the point
    lies outside its mask by more than ``margin_px`` (``sdf``: the masks' signed distances,
    :func:`signed_mask_distances`, on that device); the carving's projection and mask lookup
    (:func:`carve_votes_many`), views of one image size together."""
    dev = x.device
    cams = [(v.viewmat[:3, :3].to(dev), v.viewmat[:3, 3].to(dev), v.K.to(dev)) for v in views]
    none = [None] * len(views)
    batches = _ViewBatch.group(views, cams, list(sdf), none, none, False)
    framed = torch.zeros(len(views), len(x), dtype=torch.bool, device=dev)
    outside = torch.zeros_like(framed)
    points = batch_points if batch_points is not None else default_batch_points(dev)
    for part in _ViewBatch.parts(batches, len(x), points):
        ok, _, dist, *_ = part.lookup(x)
        rows = torch.tensor(part.index, device=dev)
        framed[rows] = ok
        outside[rows] = ok & (dist > margin_px)
    return framed, outside


def carved_by_votes(votes: CarveVotes, cfg: CarveConfig) -> Tensor:
    """bool [M]: the points that the vote carves (module doc), point by point (no specks dropped, no cavity
    filled: :func:`solid_from_votes` does that on the grid)."""
    e = votes.empty.float()
    carved = (e >= cfg.min_votes) & (e >= cfg.min_vote_fraction * votes.seen.float())
    if cfg.depth_consensus > 0 and votes.near is not None and votes.depth_empty is not None:
        de = votes.depth_empty.float()
        m = e - de  # the silhouette votes
        by_masks = (m >= cfg.min_votes) & (m >= cfg.min_vote_fraction * votes.seen.float())
        carved &= by_masks | (de >= cfg.depth_consensus * votes.near.float())
    carved |= votes.seen.float() < cfg.min_seen_fraction * votes.num_views
    if votes.direct is not None and votes.depth_empty is not None and cfg.min_direct_fraction <= 1:
        d = votes.direct.float()
        carved |= (e >= cfg.min_votes) & (d > 0) & (votes.depth_empty.float() >= cfg.min_direct_fraction * d)
    return carved


def solid_from_votes(votes: CarveVotes, grid: VoxelGrid, cfg: CarveConfig) -> np.ndarray:
    """bool [X, Y, Z]: voxels not carved by the vote (module doc), without specks."""
    from scipy import ndimage  # lazily: a PLY-only export needs no SciPy
    full = (~carved_by_votes(votes, cfg)).reshape(grid.shape).cpu().numpy()
    if not full.any():
        return full
    # on the solid's bounding box with one empty voxel around it (the same components, and the same cavities: a
    # pocket open to the grid's outside is open to the box's border layer)
    lo, hi = bounding_box(full)
    crop = tuple(slice(max(a - 1, 0), b + 1) for a, b in zip(lo, hi))
    solid = full[crop]
    labels, n = ndimage.label(solid, structure=np.ones((3, 3, 3), bool))
    if n > 1:
        sizes = np.bincount(labels.ravel())
        sizes[0] = 0
        solid = (sizes >= cfg.min_component * sizes.max())[labels] & (labels > 0)
    if cfg.fill_cavities:
        solid = fill_holes(solid)
    out = np.zeros_like(full)
    out[crop] = solid
    return out


def hull_from_votes(votes: CarveVotes, grid: VoxelGrid, cfg: CarveConfig) -> np.ndarray:
    """bool [X, Y, Z]: the *visual hull* of the vote, the voxels that the silhouette votes alone leave (the depth
    votes withheld). Its empty voxels outside the solid are the object's concavities, which only depth carves (a
    cup's inside): :func:`physgs_nerfstudio.geometry.parts.part_areas` does not count the walls that face them
    twice."""
    e = votes.empty if votes.depth_empty is None else votes.empty - votes.depth_empty
    e = e.float()
    carved = (e >= cfg.min_votes) & (e >= cfg.min_vote_fraction * votes.seen.float())
    carved |= votes.seen.float() < cfg.min_seen_fraction * votes.num_views
    return (~carved).reshape(grid.shape).cpu().numpy()


def fill_holes(solid: np.ndarray) -> np.ndarray:
    """``scipy.ndimage.binary_fill_holes(solid)``: the empty voxels that no face-connected path of empty voxels joins
    to the array's border become solid. One labelling of the empty voxels (6-connected, the fill's flood), instead of
    the fill's dilation repeated until nothing changes (a few times faster on a carved solid)."""
    from scipy import ndimage

    labels, n = ndimage.label(~solid)
    if n == 0:
        return solid.copy()
    outside = np.zeros(n + 1, bool)
    for axis in range(solid.ndim):
        for end in (0, -1):
            outside[np.take(labels, end, axis=axis)] = True
    outside[0] = False  # the solid itself
    return ~outside[labels]


def bounding_box(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index bounds [lo, hi) of the True voxels of a non-empty ``mask`` (``argwhere``'s min and max + 1, from the
    mask's projections on its axes)."""
    lo, hi = [], []
    for axis in range(mask.ndim):
        hit = np.flatnonzero(mask.any(axis=tuple(a for a in range(mask.ndim) if a != axis)))
        lo.append(hit[0])
        hi.append(hit[-1] + 1)
    return np.asarray(lo), np.asarray(hi)
