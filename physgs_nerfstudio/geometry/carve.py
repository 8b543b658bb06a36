"""Space carving: the object's volume from many views' masks and rendered depth, with a robust vote (each
view's votes, its mask and depth looked up at the voxel centres: :mod:`.carve_views`).

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
trainings, whose soft surfaces let the expected depth carve compact solids thin) and with the expected depth on
gsplat, where the 512 px trainings' surfaces are sharp, so the expected depth is the first surface and the
median would only cost time (:func:`resolve_depth_render`; docs/architecture.md, "Mass geometry").

The Gaussians' depth. A rasterizer gives every pixel that a Gaussian covers the depth of the Gaussian's *centre*,
and a trained splat's surface Gaussians have their centres behind the surface they draw: their footprints, not
their centres, reach the object's outline in the views that see a face edge-on. So the expected depth lies about one
Gaussian thickness behind each face, and the depth votes carved that layer off both faces of every plate (on the
GPU a 25 mm oak top can keep half of its volume, both faces losing 4-5 mm whatever the voxel). ``front_extent`` moves the depth that carves towards the
camera by k times the pixel's blended *along-ray extent* (:func:`.gaussians.ray_extent`: each Gaussian's standard
deviation along the ray through it, ``1 / sqrt(d^T Sigma^-1 d)``, rendered as a colour channel): a flat Gaussian
lying in a face adds its thickness across the face, not its in-plane size, and a face of thin Gaussians is not moved.
k = 2 with the expected depth (the default, gsplat's depth), 0 with the median depth (the CPU's reference
rasterizer), which already lies in front of a layer's centres; the mass interval samples k - 1 and k + 1 as
geometry variants, since where the surface lies within a Gaussian's extent is known only to about one extent.
Why two: at one extent a GPU training's solids still come out a median 5-17% under their enclosed volumes (metal
plates' faces render 0.3-0.7 voxel behind them).

Depth consensus. The vote's fraction is low (15% of the views that frame a voxel) because most views cannot see
a given empty voxel at all: it is hidden behind the object in them. But then a surface voxel is carved as soon as
15% of the views render the surface behind it, so the carved surface follows the *most* biased views, not the
typical one: a surface rendered a little too deep in a few views shaves a layer off a flat face (the GPU suite's
compact solids came out 0.72-0.9x of their volume). So a voxel that the silhouette votes alone do not carve is
carved only when its depth votes are also at least ``depth_consensus`` (0.5: a majority) of the views that see it
near their rendered surface (no more than ``near_band_voxels`` behind it) or in front of it: the views that have
evidence about it. A cup's inside passes (the views that look into it see past it; the views that have it hidden
behind the wall have no say); a face that most views render where it is keeps its layer. A view has a say ("near") only
where it could have voted: the voxel projects at least ``near_inset_px`` inside its mask (not onto the silhouette's
edge pixels, whose depth is the edge's) and the lookup's slack there is within the band. Without that, an exact
box (tests/test_geometry.py) keeps a rim of voxels along its edges (1.104x; with it 1.099x, as the vote alone).

The centre test makes the recovered volume unbiased to first order in the voxel size (a boundary voxel is
counted when its centre is inside). The solid's small disconnected specks (below ``min_component`` of the
largest component's volume) are dropped, and cavities that the solid encloses completely are filled: a view
can only see past a voxel along a ray of empty space, so an enclosed empty pocket was carved by wrong
evidence (a depth rendered too deep through a semi-transparent wall), never seen.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from .capture import CaptureView
from .carve_config import EXPECTED_DEPTH_EXTENT, CarveConfig
from .carve_views import (
    _add_views,
    _corners,  # noqa: F401  (re-exported, as _sample: the tests' oracles import them from here)
    _Rule,
    _sample,  # noqa: F401
    _ViewBatch,
    carve_depth,
    default_batch_points,
    depth_slack,
    mask_view_votes,
    resolve_depth_render,
    signed_mask_distance,
    signed_mask_distances,
)
from .gaussians import ViewRender
from .grid import VoxelGrid

__all__ = [
    "EXPECTED_DEPTH_EXTENT",
    "CarveConfig",
    "CarveVotes",
    "VoteKey",
    "carve_depth",
    "carve_votes",
    "carve_votes_many",
    "default_batch_points",
    "depth_slack",
    "hull_from_votes",
    "mask_view_votes",
    "resolve_depth_render",
    "signed_mask_distance",
    "signed_mask_distances",
    "solid_from_votes",
    "vote_key",
]

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
    """:func:`carve_votes` under several settings, the same votes as a call each: every voxel centre, or each of
    ``points`` [M, 3], is looked up once per view (``batch_points`` pairs at a time: :func:`default_batch_points`)."""
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
