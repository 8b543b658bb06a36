"""Hidden open space: solid the views could not carve that no seen surface encloses.

Carving keeps every voxel that no view sees past (module doc of :mod:`.carve`): the inside of a closed object, but
also the space *under* a part that every view looks down on. Under a table top shot only from above (the
`indoor_room` layout: 15 cameras 1.75-4.27 m high, the top at 0.75 m) that space was kept as solid, 3.6x the
table's volume; under a chair's seat it is carved only by the few low views, so the chair's volume swings with the
carving's vote (benchmarks/README.md, sessions 12, 16, 20, 23).

The two differ in what surrounds them. An object's inside is enclosed by its surface, which the views saw and the
Gaussians sample. Hidden space under a top is enclosed by the top on one side only: below and to the sides it ends
where the lowest views' rays grazed the top's edges, a boundary that no Gaussian lies on. So a voxel is *hidden open
space* when, for most of the 26 lattice directions, a ray from it leaves the solid into carved space without
touching the *skin*: the voxels within ``skin_voxels`` (6-connected steps) of a Gaussian that some view sees on its
rendered surface (:func:`.gaussians.surface_views`). A ray that leaves the solid below the support plane or beyond
the Gaussians' support polytope (the cuts of :mod:`.extent` and :func:`.reconstruct._cut_below`: the object's unseen
underside) counts as enclosed, as one that reaches the skin. Skin voxels are never removed.

Why these choices:

- The skin is thickened (``skin_voxels`` = 2 by default): the surface Gaussians' centres are a scattered sample of
  the surface, not a closed digital surface. Undilated, the rays left the CPU demo shoe's solid through the gaps
  from a quarter of its inside (its voxels in its parts: 23,795 of 31,033 kept); with 2 and 3 voxels 99.98% and
  99.99% were kept, and the chair, table, dumbbell, stool and mug kept 98.4-100% of theirs (seed 7373).
- A step along a diagonal is blocked by any skin voxel of the unit cube it crosses (its *supercover*), so that rays
  cannot slip diagonally through a skin one voxel thick.
- The majority (``min_open_fraction`` = 0.5): a voxel under a top has the top above it and open space below and to
  the sides (most directions open); a voxel inside the top itself, between its seen upper face and its unseen
  lower face, has the top's skin above and around it (most directions enclosed).

Limits: the space within the skin's reach under a seen edge stays (the skin of a top's side faces, grown by 2
steps, encloses the two layers under the top sideways), so a thin top shot only from above keeps about two voxels of
hidden space under it (`indoor_room` at the demo's 15 mm voxels: 3.63x -> 1.77x the table's volume). The 26 lattice
directions are coarse: from the middle of a square table aligned with the grid, the horizontal diagonals run into
its legs, which enclose.

Cost: for each direction a pointer-doubling scan (each voxel looks 1, 2, 4, ... steps ahead), about
``26 x (2 log2 n + 7)`` whole-grid tensor operations on the solid's bounding box.
"""

from __future__ import annotations

import itertools

import numpy as np
import torch
from jaxtyping import Bool, Float
from torch import Tensor

__all__ = ["LATTICE_DIRECTIONS", "hidden_open_space", "open_fraction", "skin_from_points"]

LATTICE_DIRECTIONS: tuple[tuple[int, int, int], ...] = tuple(
    d for d in itertools.product((-1, 0, 1), repeat=3) if any(d))  # fmt: skip
"""The 26 directions of the 3x3x3 lattice (faces, edges and corners)."""

_UNRESOLVED, _OPEN, _CLOSED = 0, 1, 2


def _shift(a: Tensor, d: tuple[int, ...], fill: int | bool) -> Tensor:
    """``out[v] = a[v + d]`` (``fill`` where ``v + d`` is outside the grid)."""
    out = torch.full_like(a, fill)
    src = tuple(slice(max(0, s), n + min(0, s)) for s, n in zip(d, a.shape))
    dst = tuple(slice(max(0, -s), n + min(0, -s)) for s, n in zip(d, a.shape))
    if all(x.stop > x.start for x in src):
        out[dst] = a[src]
    return out


def skin_from_points(points: Float[Tensor, "N 3"], origin: Tensor | np.ndarray, voxel_size: float,
                     shape: tuple[int, int, int], skin_voxels: int) -> Bool[Tensor, "X Y Z"]:  # fmt: skip
    """bool grid: the voxels holding one of ``points`` (scene units, on a grid of ``origin`` and ``voxel_size``),
    grown by ``skin_voxels`` 6-connected steps."""
    skin = torch.zeros(shape, dtype=torch.bool, device=points.device)
    if len(points):
        o = torch.as_tensor(np.asarray(origin, dtype=np.float64), device=points.device)
        ij = torch.floor((points.double() - o) / voxel_size).long()
        ok = ((ij >= 0) & (ij < torch.as_tensor(shape, device=points.device))).all(1)
        skin[tuple(ij[ok].T)] = True
    for _ in range(int(skin_voxels)):
        grown = skin.clone()
        for axis in range(3):
            for s in (-1, 1):
                d = [0, 0, 0]
                d[axis] = s
                grown |= _shift(skin, tuple(d), False)
        skin = grown
    return skin


def open_fraction(solid: Bool[Tensor, "X Y Z"], skin: Bool[Tensor, "X Y Z"],
                  closed: Bool[Tensor, "X Y Z"] | None = None) -> Float[Tensor, "X Y Z"]:  # fmt: skip
    """For every voxel, the share of the 26 lattice directions in which the ray from it (one lattice step at a
    time) leaves ``solid`` without touching ``skin``: a step is blocked when any voxel of the unit cube it crosses is
    skin; a ray whose first voxel outside the solid is ``closed`` (or that is blocked) is enclosed; one that leaves
    the grid is open. Values outside the solid are meaningless (module doc)."""
    if closed is None:
        closed = torch.zeros_like(solid)
    n = max(solid.shape)
    total = torch.zeros(solid.shape, dtype=torch.float32, device=solid.device)
    for d in LATTICE_DIRECTIONS:
        subs = [e for e in itertools.product(*[(0, s) if s else (0,) for s in d]) if any(e)]
        blocked = torch.zeros_like(solid)
        for e in subs:
            blocked |= _shift(skin, e, False)
        nxt_solid = _shift(solid, d, False)
        nxt_closed = _shift(closed, d, False)
        state = torch.full(solid.shape, _UNRESOLVED, dtype=torch.uint8, device=solid.device)
        state[~nxt_solid] = _OPEN
        state[~nxt_solid & nxt_closed] = _CLOSED
        state[blocked] = _CLOSED
        step = 1
        while step < n and bool((state == _UNRESOLVED).any()):
            ahead = _shift(state, tuple(step * s for s in d), _OPEN)
            state = torch.where(state == _UNRESOLVED, ahead, state)
            step *= 2
        total += (state == _OPEN).float()
    return total / len(LATTICE_DIRECTIONS)


def hidden_open_space(solid: Bool[Tensor, "X Y Z"], skin: Bool[Tensor, "X Y Z"],
                      closed: Bool[Tensor, "X Y Z"] | None = None, min_open_fraction: float = 0.5
                      ) -> Bool[Tensor, "X Y Z"]:  # fmt: skip
    """bool grid: the solid's voxels that are hidden open space (module doc): not skin, and open in more than
    ``min_open_fraction`` of the directions. Computed on the solid's bounding box grown by one voxel."""
    out = torch.zeros_like(solid)
    if not bool(solid.any()):
        return out
    idx = torch.nonzero(solid)
    lo = (idx.amin(0) - 1).clamp_min(0)
    hi = torch.minimum(idx.amax(0) + 2, torch.as_tensor(solid.shape, device=solid.device))
    box = tuple(slice(int(a), int(b)) for a, b in zip(lo, hi))
    s, k = solid[box], skin[box]
    c = closed[box] if closed is not None else None
    f = open_fraction(s, k, c)
    out[box] = s & ~k & (f > min_open_fraction)
    return out
