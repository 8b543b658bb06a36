"""Space carving: the object's volume from many views' free space, with a robust vote, and the object masks' visual
hull (each view's surface depth and mask looked up at the voxel centres: :mod:`.carve_views`).

Two rules, each a vote of the views over the voxel centres ``x``; a view *sees* ``x`` when ``x`` projects into its
image, in front of the camera.

* **The free-space vote** (:func:`carve_votes_many`, :func:`solid_from_votes`): a view *sees through* ``x`` when
  ``x`` lies in front of the view's surface depth there by more than ``depth_margin_voxels`` voxels (plus the
  lookup's slack, below): the camera sees past ``x`` onto a surface behind it, or along a ray that meets no surface
  (:mod:`.free_space`: the whole splat's depth, the object masks do not carve). A voxel is carved (empty) when the
  views that see through it reach ``min_votes`` and ``min_vote_fraction`` of the views that see it, and pass the
  depth consensus below.
* **The silhouette vote** (:func:`mask_hull`): a view votes ``x`` empty when ``x`` projects outside its object mask
  (the mask's signed distance there is positive). The voxels that the same counts leave are the masks' *visual
  hull*; its empty voxels outside the solid are the object's concavities, which only depth carves (a cup's inside):
  :func:`.walls.part_areas` does not count the walls that face them twice.

In both, a voxel that fewer than ``min_seen_fraction`` of the views have in their image at all is empty (an
object-centric capture frames its object in every view). Otherwise it is solid, so space that no view sees through
(the inside of a closed object) stays solid. Why a vote rather than the classic visual hull's "any one view":

* one bad view (a depth rendered too deep, a part one mask missed) casts one wrong empty vote: with ``min_votes`` = 2
  it cannot delete the part;
* a floater in front of a surface only *lowers* the rendered depth in the views that see it, which withholds free
  votes; it never adds volume, because the other views still see through the space around the object;
* the fraction keeps the rule meaningful when the capture has many views (60 views: 9 must agree at 0.15).

The surface depth. A free vote is right only if the rendered depth lies at or in front of the object's surface along
the pixel's ray: every centre in front of it is carved. A trained splat draws a surface as a soft layer of
semi-transparent Gaussians, and a rasterizer gives every pixel a Gaussian covers the depth of the Gaussian's
*centre*, so a depth read from inside the layer carves a shell off every face it is seen from. The depth that
carves is where the ray's transmittance first crosses :data:`.gaussians.SURFACE_TRANSMITTANCE` (0.8: the ray has
lost a fifth of its light; :func:`.gaussians.render_depth`, the reference compositor on every backend), the
front of the layer; a surface that stops that much of the ray keeps it whatever lies behind. The expected depth
(the blending-weighted mean) is pulled towards the back surface wherever the front one is not opaque, and the
median depth (transmittance 1/2) lies halfway into the layer; both carved the path-traced development families'
walls (docs/architecture.md, "Mass geometry", gives the comparison). A ray that never loses that much light has no
surface and sees through every point on it (:data:`.free_space.SEES_THROUGH`). The depth is read bilinearly between
the four pixels around a centre's projection, and the margin grows by ``depth_slope_margin`` times that lookup's
error bound (:func:`.carve_views.depth_slack`: 0 on a plane, so a slab is not thickened).

Depth consensus. The vote's fraction is low (15% of the views that frame a voxel) because most views cannot see
through a given empty voxel at all: it is hidden behind the object in them. But then a surface voxel is carved as
soon as 15% of the views render the surface behind it, so the carved surface follows the *most* biased views, not
the typical one: a surface rendered a little too deep in a few views shaves a layer off a flat face (the GPU suite's
compact solids came out 0.72-0.9x of their volume). So a voxel is carved only when its free votes are also at least
``depth_consensus`` (0.5: a majority) of the views that see it near their surface (no more than
``near_band_voxels`` behind it, where the lookup's slack is within the band) or in front of it: the views that have
evidence about it. A cup's inside passes (the views that look into it see through it; the views that have it hidden
behind the wall have no say); a face that most views render where it is keeps its layer.

The centre test makes the recovered volume unbiased to first order in the voxel size (a boundary voxel is
counted when its centre is inside). The solid's small disconnected specks (below ``min_component`` of the
largest component's volume) are dropped, and cavities that the solid encloses completely are filled: a view
can only see through a voxel along a ray of empty space, so an enclosed empty pocket was carved by wrong
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
    _bilinear,
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
from .grid import VoxelGrid

__all__ = [
    "CarveConfig",
    "CarveVotes",
    "carve_votes_many",
    "carved_by_votes",
    "default_batch_points",
    "depth_slack",
    "mask_hull",
    "mask_view_votes",
    "signed_mask_distance",
    "signed_mask_distances",
    "solid_from_votes",
]


@dataclass
class CarveVotes:
    free: Tensor
    """int [M]: views that see through each voxel"""
    seen: Tensor
    """int [M]: views in whose image each voxel projects"""
    near: Tensor
    """int [M]: views that see each voxel in front of or within ``near_band_voxels`` behind their surface"""
    num_views: int
    """views voted"""


def _centres(grid: VoxelGrid, s0: int, n: int, device: torch.device | str) -> Tensor:
    """float32 [n, 3]: the centres of voxels ``s0 .. s0 + n - 1`` of ``grid`` (flattened C order)."""
    shape = torch.as_tensor(grid.shape, device=device)
    flat = torch.arange(s0, s0 + n, device=device)
    ijk = torch.stack([flat // (shape[1] * shape[2]), (flat // shape[2]) % shape[1], flat % shape[2]], -1)
    return grid.centres(ijk)


@torch.no_grad()
def carve_votes_many(
    grid: VoxelGrid,
    views: Sequence[CaptureView],
    depths: Sequence[Tensor],
    cfgs: Sequence[CarveConfig],
    *,
    chunk: int = 1 << 20,
    batch_points: int | None = None,
    device: torch.device | str = "cpu",
    points: Tensor | None = None,
) -> list[CarveVotes]:
    """The free-space votes (module doc) of every voxel centre of ``grid`` (flattened C order), or of each of
    ``points`` [M, 3], under each of ``cfgs``: ``views`` give the cameras, ``depths`` [H, W] their surface depths
    (finite: :func:`.free_space.free_space_depths`). Every point is looked up once per view (``batch_points`` pairs
    at a time: :func:`default_batch_points`), and settings that vote alike (the same margin, slope and band) share
    one count."""
    if batch_points is None:
        batch_points = default_batch_points(device)
    keys = [(c.depth_margin_voxels, c.depth_slope_margin, c.near_band_voxels) for c in cfgs]
    unique = list(dict.fromkeys(keys))
    rule = _Rule([cfgs[keys.index(k)] for k in unique], grid.voxel_size)
    M = grid.num_voxels if points is None else len(points)
    free, near = (torch.zeros(len(unique), M, dtype=torch.int32, device=device) for _ in range(2))
    seen = torch.zeros(M, dtype=torch.int32, device=device)
    depths = [d.to(device) for d in depths]
    batches = _ViewBatch.group(views, [{"depth": d} for d in depths], [{"slack": depth_slack(d)} for d in depths])
    for s0 in range(0, M, chunk):  # voxel centres once per chunk, then every view
        n = min(M - s0, chunk)
        x = (_centres(grid, s0, n, device) if points is None
             else points[s0 : s0 + n].to(device=device, dtype=torch.float32))  # fmt: skip
        sl = slice(s0, s0 + n)
        for part in _ViewBatch.parts(batches, n, batch_points):  # [B, n] per quantity
            ok, z, at, px = part.lookup(x)
            vals, weights = at["depth"]
            d = sum(dk * cw for dk, cw in zip(vals, weights)) / sum(weights)
            through, by = rule.votes(ok, z, d, px["slack"])
            _add_views(free[:, sl], through)
            _add_views(near[:, sl], by)
            _add_views(seen[sl], ok)
    return [CarveVotes(free[unique.index(k)], seen, near[unique.index(k)], len(views)) for k in keys]


def carved_by_votes(votes: CarveVotes, cfg: CarveConfig) -> Tensor:
    """bool [M]: the points that the free-space vote carves (module doc), point by point (no specks dropped, no
    cavity filled: :func:`solid_from_votes` does that on the grid)."""
    carved = _outvoted(votes.free, votes.seen, cfg)
    if cfg.depth_consensus > 0:
        carved &= votes.free.float() >= cfg.depth_consensus * votes.near.float()
    return carved | _unframed(votes.seen, votes.num_views, cfg)


def _unframed(seen: Tensor, num_views: int, cfg: CarveConfig) -> Tensor:
    """bool [M]: the points fewer than ``min_seen_fraction`` of the views have in their image (module doc)."""
    return seen.float() < cfg.min_seen_fraction * num_views


def _outvoted(empty: Tensor, seen: Tensor, cfg: CarveConfig) -> Tensor:
    """bool [M]: the points whose empty votes reach ``min_votes`` and ``min_vote_fraction`` of the views that see
    them: the count both votes share (each also empties the points too few views frame, :func:`_unframed`)."""
    e = empty.float()
    return (e >= cfg.min_votes) & (e >= cfg.min_vote_fraction * seen.float())


@torch.no_grad()
def mask_hull(grid: VoxelGrid, views: Sequence[CaptureView], cfg: CarveConfig, *, chunk: int = 1 << 20,
              batch_points: int | None = None, device: torch.device | str = "cpu") -> np.ndarray:  # fmt: skip
    """bool [X, Y, Z]: the object masks' visual hull, the voxels that the silhouette vote (module doc) under
    ``cfg``'s counts leaves."""
    sdf = [t.to(device) for t in signed_mask_distances([v.mask for v in views])]
    batches = _ViewBatch.group(views, [{"sdf": s} for s in sdf])
    outside, seen = (torch.zeros(grid.num_voxels, dtype=torch.int32, device=device) for _ in range(2))
    for s0 in range(0, grid.num_voxels, chunk):
        n = min(grid.num_voxels - s0, chunk)
        x = _centres(grid, s0, n, device)
        for part in _ViewBatch.parts(batches, n, batch_points or default_batch_points(device)):
            ok, _, at, _ = part.lookup(x)
            _add_views(outside[s0 : s0 + n], ok & (_bilinear(at["sdf"]) > 0))
            _add_views(seen[s0 : s0 + n], ok)
    return (~(_outvoted(outside, seen, cfg) | _unframed(seen, len(views), cfg))).reshape(grid.shape).cpu().numpy()


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
