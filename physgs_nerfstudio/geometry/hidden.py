"""Hidden open space: solid the views could not carve that no seen surface encloses.

Carving keeps every voxel that no view sees past (:mod:`.carve`): the inside of a closed object, but also the space
*under* a part that every view looks down on (a table top shot from above, a chair's seat). An object's inside is
enclosed by its surface, which the views saw and the Gaussians sample; the space under a top is enclosed by the top
on one side only. So a voxel is *hidden open space* when, for most of the 26 lattice directions, a ray from it leaves
the solid into carved space without touching the *skin*, the seen surface. A ray that leaves the solid below the
support plane or beyond the Gaussians' support polytope (the object's unseen underside) counts as enclosed. Skin
voxels are never removed. A step along a diagonal is blocked by any skin voxel of the unit cube it crosses, so that
rays cannot slip through a skin one voxel thick.

The skin (:func:`skin_centred`). Its samples are the surface Gaussians (those some view sees on its rendered
surface, :func:`.gaussians.surface_excess`): their means and the ends of their axes at one standard deviation
(:data:`SKIN_SIGMAS`, :func:`gaussian_samples`). A scattered sample leaves gaps that rays leak through, so a voxel is
also skin when the samples within ``window`` voxels of it each way have their centroid within ``tolerance`` voxels
of its centre: around a gap the samples surround the voxel and the gap closes; off a face or past an edge they lie on one side and
the skin does not grow. It is about 1 + 2 x tolerance voxels thick across a face.

Seen samples (``GeometryConfig.hidden_skin_seen``). An axis end counts only where some view sees it on its rendered
surface, within the band plus its Gaussian's smallest standard deviation: a needle-shaped Gaussian tilted across a
thin top puts one end under the top's unseen underside, and that skin would enclose the space under it.

The skin's band (``GeometryConfig.hidden_skin_band``). The skin's Gaussians are those whose centre some view sees
at most the band behind its rendered depth: a splat fills a thin plate through its thickness, and a wider band
samples the plate's unseen lower face, whose skin encloses space under it.

The majority (``min_open_fraction``, :data:`MIN_OPEN_FRACTION` = 0.5): a voxel under a top has the top above it and
open space below and to the sides; a voxel inside the top has the top's skin above and around it.

The open half (``min_open_half``). The lowest views see a little under a top near its edges, and the Gaussians that
render that underside lie a voxel or two below it; their skin blocks the sideways rays under the top, and only the
9 downward rays stay open, no majority. So a voxel is also hidden open space when all the directions of one *half*
(the 9 with a step along one grid axis, one way) are open and at least one of the 8 *across* that half is: a thick
top whose upper face's skin does not reach its lower part is closed across by its seen sides and stays.

Passes (:data:`HIDDEN_PASSES`). What one pass removes is open space to the rays of the next, so the rules run again
on what they leave until a pass removes nothing: a closed object whose first pass removes nothing is unchanged.

The boundary with hidden open space (:func:`hidden_boundary`). The skin reaches a voxel or more past its samples,
so the last kept voxel at the boundary with the removed space holds the object's unseen surface somewhere inside
it, or lies just outside it; its expected occupancy is about 1/2 (0.53-0.63 against the truth on recorded GPU
rooms), so the volume counts it as half a voxel, and the mass's Monte Carlo draws its occupancy
uniformly in [0, 1] (:mod:`physgs_nerfstudio.mass.integrate`, "Unseen boundary"). A seen face needs no such count:
the carving's centre test is unbiased there.

Limits: the space within the skin's reach under a seen edge stays (about a voxel under a thin top shot only from
above), and the 26 lattice directions are coarse.

Cost: per direction a pointer-doubling scan (each voxel looks 1, 2, 4, ... steps ahead) on the solid's bounding
box; the carving's variants share the skin and run together (:func:`without_hidden_space_many`, the same voxels as
each alone; tests/test_hidden_space.py checks both against a direct ray march).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator

import numpy as np
import torch
from jaxtyping import Bool, Float, Int, UInt8
from torch import Tensor

from ..render.projection import quat_to_rotmat

__all__ = ["HIDDEN_PASSES", "LATTICE_DIRECTIONS", "MIN_OPEN_FRACTION", "SKIN_SIGMAS", "gaussian_samples",
           "hidden_boundary", "hidden_open_rules", "hidden_open_space", "open_counts", "open_fraction", "skin_centred", "without_hidden_space",
           "without_hidden_space_many"]

LATTICE_DIRECTIONS: tuple[tuple[int, int, int], ...] = tuple(
    d for d in itertools.product((-1, 0, 1), repeat=3) if any(d))  # fmt: skip
"""The 26 directions of the 3x3x3 lattice (faces, edges and corners)."""

HIDDEN_PASSES = 8
"""the most passes of the rules ("Passes"): they stop earlier, at the first pass that removes nothing, so this only
bounds the cost; a single pass left the CPU demo table and chair 2-3% heavier
(benchmarks/results/mass_stability_cpu.json)"""

SKIN_SIGMAS = 1.0
"""the skin's samples: the surface Gaussians' means and the ends of their axes at this many standard deviations
(:func:`gaussian_samples`), where a splat's footprint ends on the surface it renders"""

MIN_OPEN_FRACTION = 0.5
"""a voxel is hidden open space when its rays leave the solid without meeting the skin in more than this share of
the 26 lattice directions ("The majority": under a top, the space below and to the sides is open)"""

_UNRESOLVED, _OPEN, _CLOSED = 0, 1, 2


def _shift(a: Tensor, d: tuple[int, ...], fill: int | bool) -> Tensor:
    """``out[..., v] = a[..., v + d]`` over ``a``'s last ``len(d)`` axes (``fill`` where ``v + d`` is outside)."""
    out = torch.full_like(a, fill)
    lead = (slice(None),) * (a.dim() - len(d))
    dims = a.shape[a.dim() - len(d):]
    src = tuple(slice(max(0, s), n + min(0, s)) for s, n in zip(d, dims))
    dst = tuple(slice(max(0, -s), n + min(0, -s)) for s, n in zip(d, dims))
    if all(x.stop > x.start for x in src):
        out[lead + dst] = a[lead + src]
    return out


def _in_grid(points: Float[Tensor, "N 3"], origin: Tensor | np.ndarray, voxel_size: float,
             shape: tuple[int, int, int]) -> tuple[Float[Tensor, "M 3"], Tensor]:  # fmt: skip
    """The points inside the grid, in voxel units (voxel v spans [v, v + 1)), float64, and their voxels [M, 3]."""
    o = torch.as_tensor(np.asarray(origin, dtype=np.float64), device=points.device)
    p = (points.double() - o) / voxel_size
    ij = torch.floor(p).long()
    ok = ((ij >= 0) & (ij < torch.as_tensor(shape, device=points.device))).all(1)
    return p[ok], ij[ok]


def gaussian_samples(means: Float[Tensor, "N 3"], scales: Float[Tensor, "N 3"], quats: Float[Tensor, "N 4"],
                     sigmas: float = SKIN_SIGMAS) -> Float[Tensor, "M 3"]:  # fmt: skip
    """Each Gaussian's mean and the six ends of its axes at ``sigmas`` standard deviations: a sample of the surface
    that the Gaussians cover, denser than their means where they are large and few."""
    if not len(means):
        return means
    axes = quat_to_rotmat(quats.to(means.dtype)) * (sigmas * scales.to(means.dtype))[:, None, :]  # columns: scaled axes
    ends = torch.cat([means[:, None, :] + axes.transpose(1, 2), means[:, None, :] - axes.transpose(1, 2)], 1)
    return torch.cat([means, ends.reshape(-1, 3)])


def _box_sum(a: Tensor, w: int) -> Tensor:
    """Sum of ``a`` over the (2w + 1)^3 window around each voxel of its first three axes (zeros outside)."""
    for axis in range(3):
        pad = [0] * (2 * a.dim())
        pad[2 * (a.dim() - 1 - axis)] = pad[2 * (a.dim() - 1 - axis) + 1] = w
        c = torch.nn.functional.pad(a, pad).cumsum(axis)
        c = torch.cat([torch.zeros_like(c.narrow(axis, 0, 1)), c], axis)
        n = a.shape[axis]
        a = c.narrow(axis, 2 * w + 1, n) - c.narrow(axis, 0, n)
    return a


def skin_centred(points: Float[Tensor, "N 3"], origin: Tensor | np.ndarray, voxel_size: float,
                 shape: tuple[int, int, int], window_voxels: int, tolerance_voxels: float) -> Bool[Tensor, "X Y Z"]:
    """bool grid: the voxels that hold one of ``points`` (scene units, on a grid of ``origin`` and ``voxel_size``),
    and those whose window of ``window_voxels`` voxels each way holds points whose centroid lies within
    ``tolerance_voxels`` of the voxel's centre (module doc, "The skin"): the gaps between the points of a surface are
    closed, because the points around a gap surround it, but the skin does not grow past a surface's edge or off its
    face, where the points all lie on one side."""
    dev = points.device
    p, ij = _in_grid(points, origin, voxel_size, shape)
    if not len(p):
        return torch.zeros(shape, dtype=torch.bool, device=dev)
    flat = (ij[:, 0] * shape[1] + ij[:, 1]) * shape[2] + ij[:, 2]
    acc = torch.zeros(shape[0] * shape[1] * shape[2], 4, dtype=torch.float64, device=dev)
    acc.index_add_(0, flat, torch.cat([torch.ones_like(p[:, :1]), p], 1))
    acc = acc.reshape(*shape, 4)
    skin = acc[..., 0] > 0
    if window_voxels > 0:
        box = _box_sum(acc, int(window_voxels))
        count = box[..., 0]
        dist2 = torch.zeros(shape, dtype=torch.float64, device=dev)
        for axis in range(3):  # the centroid's offset from the voxel's centre, one axis at a time
            centre = torch.arange(shape[axis], device=dev, dtype=torch.float64) + 0.5
            view = [1, 1, 1]
            view[axis] = shape[axis]
            dist2 += (box[..., 1 + axis] / count.clamp_min(0.5) - centre.reshape(view)) ** 2
        skin |= (count > 0.5) & (dist2 <= tolerance_voxels**2)  # counts are whole numbers; the sums subtract
    return skin


def _blocked(skin: Bool[Tensor, "X Y Z"], d: tuple[int, int, int]) -> Bool[Tensor, "X Y Z"]:
    """The voxels whose step along ``d`` crosses a skin voxel: any voxel of the unit cube between it and its
    neighbour along ``d`` (the step's supercover) is skin."""
    blocked = torch.zeros_like(skin)
    for e in itertools.product(*[(0, s) if s else (0,) for s in d]):
        if any(e):
            blocked |= _shift(skin, e, False)
    return blocked


def _open_rays(solid: Bool[Tensor, "*B X Y Z"], skin: Bool[Tensor, "X Y Z"], closed: Bool[Tensor, "X Y Z"] | None
               ) -> Iterator[tuple[tuple[int, int, int], Bool[Tensor, "*B X Y Z"]]]:  # fmt: skip
    """For each of the 26 lattice directions, the voxels whose ray in it is open (:func:`open_fraction`); ``solid``
    may hold a batch of solids (leading axes) that share one ``skin`` and ``closed``."""
    if closed is None:
        closed = torch.zeros_like(skin)
    dims = solid.shape[-3:]
    lead = (slice(None),) * (solid.dim() - 3)
    for d in LATTICE_DIRECTIONS:
        nxt_solid = _shift(solid, d, False)
        state = torch.where(_shift(closed, d, False), _CLOSED, _OPEN).to(torch.uint8).expand_as(solid).clone()
        state.masked_fill_(nxt_solid, _UNRESOLVED).masked_fill_(_blocked(skin, d), _CLOSED)
        step = 1
        # pointer doubling: an unresolved voxel (its next voxel is solid, the step not blocked) takes the state of
        # the voxel ``step`` ahead, which after the rounds so far holds the end of its own ray up to ``step`` - 1
        # further on. Every ray ends inside the grid (a solid voxel at its edge looks out of the grid: open), so
        # the voxels within ``step`` of the far edge are resolved by then and only the rest is read and written.
        while step < max(dims) and int(state.min()) == _UNRESOLVED:
            e = tuple(step * s for s in d)
            src = lead + tuple(slice(max(0, s), n + min(0, s)) for s, n in zip(e, dims))
            dst = lead + tuple(slice(max(0, -s), n + min(0, -s)) for s, n in zip(e, dims))
            here = state[dst]
            state[dst] = torch.where(here == _UNRESOLVED, state[src], here)
            step *= 2
        yield d, state == _OPEN


def open_fraction(solid: Bool[Tensor, "X Y Z"], skin: Bool[Tensor, "X Y Z"],
                  closed: Bool[Tensor, "X Y Z"] | None = None) -> Float[Tensor, "X Y Z"]:  # fmt: skip
    """For every voxel, the share of the 26 lattice directions in which the ray from it (one lattice step at a
    time) leaves ``solid`` without touching ``skin``: a step is blocked when any voxel of the unit cube it crosses is
    skin; a ray whose first voxel outside the solid is ``closed`` (or that is blocked) is enclosed; one that leaves
    the grid is open. Values outside the solid are meaningless (module doc)."""
    return open_counts(solid, skin, closed)[0].float() / len(LATTICE_DIRECTIONS)


def open_counts(solid: Bool[Tensor, "*B X Y Z"], skin: Bool[Tensor, "X Y Z"],
                closed: Bool[Tensor, "X Y Z"] | None = None) -> tuple[Int[Tensor, "*B X Y Z"], Int[Tensor, "*B X Y Z"]]:
    """For every voxel, how many of the 26 lattice directions are open (:func:`open_fraction`), and the most that
    are open among the 9 of one *half* (the directions with a positive, or a negative, step along one of the grid's
    three axes) where at least one of the 8 directions *across* it (no step along that axis) is open too; 0 where no
    half has one (module doc, "The open half"). ``solid`` may hold a batch of solids (leading axes)."""
    total = torch.zeros(solid.shape, dtype=torch.uint8, device=solid.device)
    halves = torch.zeros((6, *solid.shape), dtype=torch.uint8, device=solid.device)
    across = torch.zeros((3, *solid.shape), dtype=torch.bool, device=solid.device)
    for d, is_open in _open_rays(solid, skin, closed):
        total += is_open
        for axis, s in enumerate(d):
            if s:
                halves[2 * axis + int(s > 0)] += is_open
            else:
                across[axis] |= is_open
    halves *= across.repeat_interleave(2, 0)
    return total, halves.amax(0)


def _rules_in_box(solid: Bool[Tensor, "*B X Y Z"], skin: Bool[Tensor, "X Y Z"], closed: Bool[Tensor, "X Y Z"] | None,
                  min_open_fraction: float, min_open_half: int | None) -> UInt8[Tensor, "*B X Y Z"]:  # fmt: skip
    total, half = open_counts(solid, skin, closed)
    majority = total.float() / len(LATTICE_DIRECTIONS) > min_open_fraction
    by_half = half >= min_open_half if min_open_half is not None else torch.zeros_like(majority)
    rule = torch.where(majority, 1, torch.where(by_half, 2, 0)).to(torch.uint8)
    return rule * (solid & ~skin)


def _box(solid: Bool[Tensor, "*B X Y Z"]) -> tuple[slice, slice, slice] | None:
    """The bounding box of every solid's voxels (over the batch) grown by one voxel, within the grid; None if empty.
    The rules on it are the rules on the whole grid: a ray from a solid voxel leaves the solid inside it."""
    occupied = solid.reshape(-1, *solid.shape[-3:]).any(0)
    if not bool(occupied.any()):
        return None
    idx = torch.nonzero(occupied)
    lo = (idx.amin(0) - 1).clamp_min(0)
    hi = torch.minimum(idx.amax(0) + 2, torch.as_tensor(occupied.shape, device=solid.device))
    return tuple(slice(int(a), int(b)) for a, b in zip(lo, hi))


def hidden_open_rules(solid: Bool[Tensor, "*B X Y Z"], skin: Bool[Tensor, "X Y Z"],
                      closed: Bool[Tensor, "X Y Z"] | None = None, min_open_fraction: float = MIN_OPEN_FRACTION,
                      min_open_half: int | None = None) -> UInt8[Tensor, "*B X Y Z"]:  # fmt: skip
    """uint8 grid: which rule makes each voxel hidden open space (module doc): 0 none; 1 the majority (no skin, open
    in more than ``min_open_fraction`` of the directions); 2 the open half alone (no skin, not a majority, and,
    unless ``min_open_half`` is None, at least that many of the 9 directions of one half open with one across it;
    "The open half"). Computed on the solid's bounding box grown by one voxel. ``solid`` may hold a batch of solids
    (leading axes) that share ``skin`` and ``closed``: the same as each alone."""
    out = torch.zeros(solid.shape, dtype=torch.uint8, device=solid.device)
    box = _box(solid)
    if box is None:
        return out
    lead = (slice(None),) * (solid.dim() - 3)
    out[lead + box] = _rules_in_box(solid[lead + box], skin[box], closed[box] if closed is not None else None,
                                    min_open_fraction, min_open_half)  # fmt: skip
    return out


def hidden_boundary(kept: Bool[Tensor, "*B X Y Z"], removed: Bool[Tensor, "*B X Y Z"]) -> Bool[Tensor, "*B X Y Z"]:
    """The voxels of ``kept`` with a face onto ``removed`` (6-connected), the space the hidden open space rules
    removed: the kept voxels whose outer side no view saw (module doc, "The boundary with hidden open space")."""
    near = torch.zeros_like(kept)
    for axis in range(3):
        for step in (-1, 1):
            d = tuple(step if a == axis else 0 for a in range(3))
            near |= _shift(removed, d, False)
    return kept & near


def hidden_open_space(solid: Bool[Tensor, "X Y Z"], skin: Bool[Tensor, "X Y Z"],
                      closed: Bool[Tensor, "X Y Z"] | None = None, min_open_fraction: float = MIN_OPEN_FRACTION,
                      min_open_half: int | None = None) -> Bool[Tensor, "X Y Z"]:  # fmt: skip
    """bool grid: the solid's voxels that are hidden open space by either rule (:func:`hidden_open_rules`)."""
    return hidden_open_rules(solid, skin, closed, min_open_fraction, min_open_half) > 0


def without_hidden_space(solid: Bool[Tensor, "X Y Z"], skin: Bool[Tensor, "X Y Z"],
                         closed: Bool[Tensor, "X Y Z"] | None = None, min_open_fraction: float = MIN_OPEN_FRACTION,
                         min_open_half: int | None = None, passes: int = 1
                         ) -> tuple[Bool[Tensor, "X Y Z"], dict[str, int]]:  # fmt: skip
    """``solid`` without its hidden open space (:func:`hidden_open_rules`), the rules run again on what they leave
    until a pass removes nothing or ``passes`` have run ("Passes"); and how many voxels each rule removed in all
    ("majority", "open_half")."""
    kept, removed = without_hidden_space_many(solid[None], skin, closed, min_open_fraction, min_open_half, passes)
    return kept[0], removed[0]


def without_hidden_space_many(solids: Bool[Tensor, "B X Y Z"], skin: Bool[Tensor, "X Y Z"],
                              closed: Bool[Tensor, "X Y Z"] | None = None, min_open_fraction: float = MIN_OPEN_FRACTION,
                              min_open_half: int | None = None, passes: int = 1, max_voxels: int = 2**25
                              ) -> tuple[Bool[Tensor, "B X Y Z"], list[dict[str, int]]]:  # fmt: skip
    """:func:`without_hidden_space` of each of ``solids`` (the carving's variants), which share ``skin`` and
    ``closed``: run together, about ``max_voxels`` of their common bounding box at a time, so that the skin's
    blocked steps are found once for all of them (the same result as one at a time)."""
    kept = solids.clone()
    removed = [{"majority": 0, "open_half": 0} for _ in range(len(solids))]
    box = _box(solids)
    if box is None:
        return kept, removed
    sk, cl = skin[box], closed[box] if closed is not None else None
    per = max(1, int(max_voxels) // max(1, sk.numel()))
    for c0 in range(0, len(solids), per):
        part = kept[c0:c0 + per][(slice(None), *box)]
        for _ in range(passes):
            rule = _rules_in_box(part, sk, cl, min_open_fraction, min_open_half)
            counts = torch.stack([(rule == 1).flatten(1).sum(1), (rule == 2).flatten(1).sum(1)], 1).tolist()
            for i, (n_majority, n_half) in enumerate(counts):
                removed[c0 + i]["majority"] += n_majority
                removed[c0 + i]["open_half"] += n_half
            if not any(a + b for a, b in counts):
                break
            part = part & (rule == 0)
        kept[(slice(c0, c0 + per), *box)] = part
    return kept, removed
