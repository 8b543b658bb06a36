"""Partial volume: how much of each boundary voxel the carving's surface keeps.

The carving (:mod:`.carve`) decides each voxel by its centre, so a voxel on the solid's boundary counts whole or
not at all. Where the rule's surface is the object's that is unbiased, but the free-space vote carves a voxel only
when it lies in front of the rendered surface by more than ``depth_margin_voxels``: a tolerance against noisy depth that,
counted by centres, would become a layer of volume on every face that only the depth places (on the demo's renders
the depth places most of a chair's faces, and the +1 voxel margin variant added about a quarter of its volume).

So every voxel that the surface may cut counts the share of its ``n x n x n`` sub-points (:data:`BOUNDARY_SUBSAMPLES`
per axis) that the same vote keeps with the depth margin no wider than 0 (:func:`surface_config`: the rendered
surface itself; a negative margin says the surface lies deeper and stays). The voxels that the surface may cut:

* the solid's voxels with a face onto space outside it and, under a positive depth margin, as many layers deeper as
  the margin has voxels, rounded up (one kept by the margin alone, wholly in front of the surface, counts 0);
* the voxels just outside the solid that the vote itself carved (part of them may lie behind the surface; counting
  only the kept voxels would lose an eighth of a voxel layer on every face). Their share goes to the part of a solid
  neighbour (:func:`part_volumes`).

The margin still decides which voxels the carving keeps; the rendered surface decides how much of the space around
it is solid. Faces that other rules end (the support plane, the Gaussians' polytope, hidden open space) are
unchanged: the vote keeps every sub-point of their voxels, and the space those rules removed counts 0.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor

from .capture import CaptureView
from .carve import CarveConfig, carve_votes_many, carved_by_votes
from .grid import VoxelGrid

__all__ = ["BOUNDARY_SUBSAMPLES", "boundary_fill", "boundary_layers", "boundary_voxels", "outer_rim", "part_volumes",
           "rim_labels", "sub_offsets", "surface_config"]

BOUNDARY_SUBSAMPLES = 2
"""sub-points per axis of a boundary voxel (2 x 2 x 2): the centre rule at half the voxel's step. Finer sampling
converges: 3 per axis moved the CPU demo table's and chair's masses by 0.1% and 0.03%
(benchmarks/results/mass_stability_cpu.json) at 3.4x the sub-points"""


def surface_config(cfg: CarveConfig) -> CarveConfig:
    """The setting whose vote places the surface that a boundary voxel's share is measured against: ``cfg`` with its
    depth margin no wider than 0 (module doc)."""
    return replace(cfg, depth_margin_voxels=min(cfg.depth_margin_voxels, 0.0))


def boundary_voxels(solid: np.ndarray, layers: int = 1) -> np.ndarray:
    """bool [X, Y, Z]: the voxels of ``solid`` at most ``layers`` face steps from outside it (1: those with a face
    neighbour outside; the grid's border counts as outside)."""
    from scipy import ndimage  # lazily: a PLY-only export needs no SciPy

    inner = ndimage.binary_erosion(solid, structure=ndimage.generate_binary_structure(3, 1), iterations=layers,
                                   border_value=0)  # fmt: skip
    return solid & ~inner


def boundary_layers(cfg: CarveConfig) -> int:
    """How deep the voxels whose share is measured reach into the solid: one layer, plus the layers that a positive
    depth margin keeps in front of the surface (under them lies the layer that the surface cuts; module doc)."""
    return 1 + math.ceil(max(cfg.depth_margin_voxels, 0.0) - 1e-9)


def sub_offsets(n: int) -> Float[Tensor, "S 3"]:
    """The ``n^3`` sub-point offsets of a voxel, in voxels from its centre: the centres of its ``n x n x n``
    sub-cells (n = 1: the centre itself)."""
    t = (torch.arange(n, dtype=torch.float32) + 0.5) / n - 0.5
    return torch.stack(torch.meshgrid(t, t, t, indexing="ij"), -1).reshape(-1, 3)


def outer_rim(solid: np.ndarray) -> np.ndarray:
    """bool [X, Y, Z]: the voxels outside ``solid`` with a face neighbour in it."""
    from scipy import ndimage

    return ndimage.binary_dilation(solid, structure=ndimage.generate_binary_structure(3, 1)) & ~solid


def rim_labels(labels: np.ndarray) -> np.ndarray:
    """int [X, Y, Z]: ``labels`` (-1 outside the solid) with each unlabelled voxel that has a labelled face neighbour
    given that neighbour's label (the first along -x, +x, -y, +y, -z, +z): the part that a share of a voxel outside
    the solid belongs to."""
    out = labels.copy()
    padded = np.pad(labels, 1, constant_values=-1)
    X, Y, Z = labels.shape
    for axis in range(3):
        for step in (-1, 1):
            sl = [slice(1, X + 1), slice(1, Y + 1), slice(1, Z + 1)]
            sl[axis] = slice(1 + step, labels.shape[axis] + 1 + step)
            nb = padded[tuple(sl)]
            take = (out < 0) & (nb >= 0)
            out[take] = nb[take]
    return out


def part_volumes(fill: np.ndarray, labels: np.ndarray, num_parts: int, voxel_size: float) -> np.ndarray:
    """float64 [P]: each part's volume, scene units^3: the shares ``fill`` of its voxels and of the voxels outside the
    solid next to them (:func:`rim_labels`; ``labels`` -1 outside the solid)."""
    lab = rim_labels(labels)
    has = (fill > 0) & (lab >= 0)
    return np.bincount(lab[has], fill[has].astype(np.float64), minlength=num_parts)[:num_parts] * voxel_size**3


@torch.no_grad()
def boundary_fill(
    grid: VoxelGrid,
    solids: Sequence[np.ndarray],
    cfgs: Sequence[CarveConfig],
    views: Sequence[CaptureView],
    depths: Sequence[Tensor],
    *,
    subsamples: int = BOUNDARY_SUBSAMPLES,
    device: torch.device | str = "cpu",
) -> list[np.ndarray]:
    """float32 [X, Y, Z] per solid: the share of each voxel that the volume counts (module doc): 1 inside
    ``solids[i]``; on its boundary (:func:`boundary_voxels`, :func:`boundary_layers`) the share of the voxel's
    ``subsamples^3`` sub-points that ``cfgs[i]``'s free-space vote (``views``' cameras, ``depths`` their surface
    depths: :func:`.carve.carve_votes_many`) keeps at the rendered surface (:func:`surface_config`); the same share
    on the voxels just outside it whose centres ``cfgs[i]``'s own vote carves (:func:`outer_rim`; not those that
    other rules removed); 0 elsewhere. ``subsamples`` <= 1: the solids as they are (whole voxels)."""
    fills = [np.asarray(s, dtype=np.float32) for s in solids]
    if subsamples <= 1 or not solids:
        return fills
    if len(cfgs) != len(solids):
        raise ValueError(f"boundary_fill: {len(solids)} solids but {len(cfgs)} carving settings.")
    edges = [boundary_voxels(s, boundary_layers(c)) for s, c in zip(solids, cfgs)]
    rims = [outer_rim(s) for s in solids]
    idx = np.argwhere(np.logical_or.reduce(edges) | np.logical_or.reduce(rims))
    if not len(idx):
        return fills
    row = np.full(grid.shape, -1, np.int64)
    row[tuple(idx.T)] = np.arange(len(idx))
    centres = grid.centres(torch.from_numpy(idx).to(device))
    offsets = torch.cat([sub_offsets(subsamples), torch.zeros(1, 3)]).to(centres)  # the sub-points, then the centre
    points = (centres[:, None, :] + offsets * grid.voxel_size).reshape(-1, 3)
    surface = [surface_config(c) for c in cfgs]
    votes = carve_votes_many(grid, views, depths, surface, device=device, points=points)
    # the rim's centres under the variants' own votes where those differ from the surface's (a positive margin):
    # one point per voxel
    wider = [i for i, c in enumerate(cfgs) if c.depth_margin_voxels > 0]
    own = dict(zip(wider, carve_votes_many(grid, views, depths, [cfgs[i] for i in wider], device=device,
                                           points=centres))) if wider else {}  # fmt: skip
    for i, (fill, edge, rim) in enumerate(zip(fills, edges, rims)):
        kept = ~carved_by_votes(votes[i], surface[i]).reshape(len(idx), -1)
        share = kept[:, :-1].float().mean(1).cpu().numpy()
        carved = (carved_by_votes(own[i], cfgs[i]) if i in own else ~kept[:, -1]).cpu().numpy()
        rim = rim & carved[np.maximum(row, 0)]  # (row >= 0 on every rim voxel)
        fill[edge] = share[row[edge]]
        fill[rim] = share[row[rim]]
    return fills
