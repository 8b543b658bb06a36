"""The object's extent from its Gaussians: a voxel beyond every Gaussian of the object is not the object.

Carving keeps the space that no view sees past (:mod:`.carve`); under an object shot from above that is also a slab
of the domain's padding. The Gaussians are the splat's only evidence of surface, so the solid is cut to their
*support polytope*: for a fixed set of directions ``u`` (the 26 lattice directions and a Fibonacci set), a voxel
centre ``x`` is kept when ``u . x <= max_i u . mu_i + pad`` for every ``u``. It contains the Gaussians' convex hull,
tends to it as directions are added, costs one [N, D] product, and with the lattice directions cuts the flat bottom
of an upright object in an oriented capture exactly. Concavities (between a table's legs) are left to the views.

Only the Gaussians that some view sees on its rendered surface count (:func:`.gaussians.surface_excess`): under an
unseen underside a splat keeps Gaussians that no view sees, and those would leave a layer of false solid; the seen
faces around the underside end it. The outlier count is that of the whole selection, so the seen Gaussians'
polytope is never wider than all of theirs.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor

from ..render.projection import quat_to_rotmat
from .grid import VoxelGrid

__all__ = ["support_directions", "support_excess", "within_support"]


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
                    quats: Tensor | None = None, chunk: int = 1 << 16, skip: int = 0) -> Float[Tensor, D]:  # fmt: skip
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
