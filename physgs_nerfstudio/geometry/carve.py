"""Space carving: the object's volume from many views' masks and rendered depth, with a robust vote (each
view's votes, its mask and depth looked up at the voxel centres: :mod:`.carve_views`).

For every voxel centre ``x`` and every view ``v`` in whose image it projects (in front of the camera):

* **seen outside**: ``x`` projects outside the view's object mask, by more than ``mask_margin_px`` pixels
  (signed distance to the mask boundary; a negative margin erodes the mask, a positive one dilates it);
* **seen in front**: ``x`` projects inside the mask, the splat is opaque there (alpha >= ``min_alpha``), and
  ``x`` lies in front of the rendered surface by more than ``depth_margin_voxels`` voxels plus
  ``depth_margin_rel`` of the depth: the camera sees *past* ``x`` onto a surface behind it, so ``x`` is empty
  (this carves concavities that silhouettes cannot, such as a cup's inside).

Either is an *empty vote*. The object's carving (:mod:`.free_space`) gives every view a mask that holds every pixel and
the whole splat's surface depth, so that only the views' free space carves; the silhouette votes alone make the
object masks' visual hull (:func:`hull_from_votes`). A view *sees* ``x`` when ``x`` projects into its image. A voxel is carved (empty)
when its empty votes reach ``min_votes`` and ``min_vote_fraction`` of the views that see it (and, for depth
votes, the depth consensus below).

A voxel that fewer than ``min_seen_fraction`` of the views have in their image at all is empty (an object-centric
capture frames its object in every view). Otherwise it is solid, so space that no view sees past (the inside of
a closed object) stays solid. Why a vote rather than the classic visual hull's "any one view":

* one bad mask (a part the segmenter missed in one view) casts one wrong empty vote: with ``min_votes`` = 2 it
  cannot delete the part;
* a floater in front of a surface only *lowers* the rendered depth in the views that see it, which withholds
  depth votes; it never adds volume, because the masks of the other views still carve around the object;
* the fraction keeps the rule meaningful when the capture has many views (60 views: 9 must agree at 0.15).

The surface depth. A depth vote is right only if the rendered depth lies at or in front of the object's surface
along the pixel's ray: every centre in front of it is carved. A trained splat draws a surface as a soft layer of
semi-transparent Gaussians, and a rasterizer gives every pixel a Gaussian covers the depth of the Gaussian's
*centre*, so a depth read from inside the layer carves a shell off every face it is seen from. The depth that
carves is where the ray's transmittance first crosses :data:`.gaussians.SURFACE_TRANSMITTANCE` (0.8: the ray has
lost a fifth of its light; :func:`.gaussians.render_depth`, the reference compositor on every backend), the
front of the layer; a surface that stops that much of the ray keeps it whatever lies behind. The expected depth
(the blending-weighted mean) is pulled towards the back surface wherever the front one is not opaque, and the
median depth (transmittance 1/2) lies halfway into the layer; both carved the path-traced development families'
walls (docs/architecture.md, "Mass geometry", gives the comparison). A pixel whose alpha never reaches
``1 - SURFACE_TRANSMITTANCE`` has no surface depth and does not carve by depth (``min_alpha`` is at least that).

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
from .carve_config import CarveConfig
from .carve_views import (
    _add_views,
    _corners,  # noqa: F401  (re-exported, as _sample: the tests' oracles import them from here)
    _Rule,
    _sample,  # noqa: F401
    _ViewBatch,
    default_batch_points,
    depth_slack,
    mask_view_votes,
    signed_mask_distance,
    signed_mask_distances,
)
from .gaussians import ViewRender
from .grid import VoxelGrid

__all__ = [
    "CarveConfig",
    "CarveVotes",
    "VoteKey",
    "carve_votes",
    "carve_votes_many",
    "default_batch_points",
    "depth_slack",
    "hull_from_votes",
    "mask_view_votes",
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
    num_views: int = 0
    """views voted"""
    near: Tensor | None = None
    """int [M]: views that see each voxel in front of or within ``near_band_voxels`` behind their surface (None: not
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


VoteKey = tuple[float, float, float]


def vote_key(cfg: CarveConfig) -> VoteKey:
    """The settings that the geometry variants and the partial-volume surface change and that the votes depend on
    (mask margin, depth margin, absolute and relative): settings whose keys are equal, and whose other vote
    settings agree, share one voting pass."""
    return cfg.mask_margin_px, cfg.depth_margin_voxels, cfg.depth_margin_rel


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
    empty, depth_empty = ([torch.zeros(M, dtype=torch.int32, device=device) for _ in cfgs] for _ in range(2))
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
    images = [r.depth.to(device) for r in renders] if any_depth else [None] * len(views)
    depth = ([(d, r.alpha.to(device), depth_slack(d, r.alpha.to(device), lookup=lookup) if slope else None)
              for d, r in zip(images, renders)] if any_depth else [None] * len(views))  # fmt: skip
    shape = torch.as_tensor(grid.shape, device=device)
    rule = _Rule(cfgs, grid.voxel_size)
    batches = _ViewBatch.group(views, cams, sdf, depth, lookup == "bilinear")
    for s0 in range(0, M, chunk):  # voxel centres once per chunk, then every view
        flat = torch.arange(s0, min(M, s0 + chunk), device=device)
        if points is None:
            ijk = torch.stack([flat // (shape[1] * shape[2]), (flat // shape[2]) % shape[1], flat % shape[2]], -1)
            x = grid.centres(ijk)
        else:
            x = points[s0 : s0 + chunk].to(device=device, dtype=torch.float32)
        n_seen = torch.zeros(len(flat), dtype=torch.int32, device=device)
        # [G, n]: one row per setting
        n_empty, n_depth = (torch.zeros(G, len(flat), dtype=torch.int32, device=device) for _ in range(2))
        n_near = torch.zeros(G, len(flat), dtype=torch.int32, device=device) if counts_near else None
        for part in _ViewBatch.parts(batches, len(flat), batch_points):  # [B, n] per quantity
            ok, z, dist, d, a, sl = part.lookup(x)
            if d is None:
                vote = rule.silhouette(ok, dist)
            else:
                vote, dvote, seen_near = rule.votes(ok, dist, z, d, a, sl)
                _add_views(n_depth, dvote)
                if seen_near is not None and n_near is not None:
                    _add_views(n_near, seen_near)
            _add_views(n_empty, vote)
            _add_views(n_seen, ok)
        sl = slice(s0, s0 + len(flat))
        seen[sl] = n_seen
        for g in range(G):
            empty[g][sl], depth_empty[g][sl] = n_empty[g], n_depth[g]
            if n_near is not None and near[g] is not None:
                near[g][sl] = n_near[g]
    return [CarveVotes(empty[g], seen, depth_empty[g], len(views), near[g] if any_depth else None)
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
