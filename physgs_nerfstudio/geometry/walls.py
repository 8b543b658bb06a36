"""Each part's wall area, sheet share and curvature on the carved solid (:func:`part_areas`), its concavities and
the seams between parts.

* **Wall area per part.** Marching cubes (level 0.5) of the solid smoothed by a Gaussian of ``area_sigma`` = 0.5
  voxel: on the raw 0/1 grid the staircase overstates the area (by 4% on a turned box, 9% on a sphere, 11-15%
  on a tilted two-voxel sheet); smoothed, by at most 1.5%, 4% and 9%, and a one-voxel sheet survives (a
  wider kernel erases it). Each face belongs to the part of the solid
  voxel nearest to it. A face counts fully where the solid under it is bulky (a closed hollow part, filled
  because no view sees its inside) and half where the solid is a sheet at most ``2 * sheet_voxels`` voxels
  thick and spread as a plate (``MIN_PLATE``; an open wall whose two sides were both reconstructed: each side is
  one copy of the wall; a rod as thin as a sheet has its faces on one side). A face that
  is no sheet face and borders a *concavity* (empty space more than ``concavity_voxels`` inside the visual hull,
  :func:`concavities`) but not the ordinary outside counts 0: it is the inner face of a wall carved thicker than
  a sheet, whose outer face is counted (a pan's inside, a vase's at low resolution: both faces counted in full
  doubled the wall), or the top of the fill that no view saw past (inside a cup below its rim), which is no wall.
* **Wall curvature per part** (:func:`.mesh.face_mean_curvature`). A hollow part's wall lies *inside* its fully counted
  faces: a wall of thickness ``t`` under a face of area ``dA`` and mean curvature ``H`` holds
  ``dA (t - H t^2 + K t^3 / 3)``, less than ``dA t`` on a convex face (a bottle's glass 3 mm thick inside a 35 mm
  radius: 4% less; a tube of 10 mm radius with a 2 mm wall: 10% less). Each part records the area of its fully counted faces and
  their integrated mean curvature ``M = sum |e| theta_e / 2`` over the mesh's edges (dihedral angles, each edge's
  share split between its two faces), which the mass turns into the wall's volume
  (:func:`physgs_nerfstudio.mass.integrate.wall_volume`). On voxelised shapes (smoothed as above) ``M`` is within
  1% of a cylinder's, 3% of a box's and 5-7% of a sphere's (whose area is 4-10% high too, so that ``M / A``
  is within 4%). Sheet faces need no term: the two sides of a wall enclose its middle surface, their half areas
  add up to it, and the middle surface times ``t`` is the wall's volume.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from .carve import bounding_box
from .grid import GeometryError, VoxelGrid

__all__ = ["MIN_PLATE", "PartGeometry", "concavities", "face_mean_curvature", "part_areas", "seam_areas"]

MIN_PLATE = 0.25
"""a sheet face counts half only where the thin solid is a plate: the second-largest spread of its voxels in the
plate window is at least this times the largest (:func:`_plate_like`; a rod as thin as a sheet has its faces on
one outer side)"""


@dataclass
class PartGeometry:
    volume: np.ndarray
    """[P] solid volume per part (scene units^3)"""
    area: np.ndarray
    """[P] wall area per part (scene units^2): sheet faces count half"""
    sheet_share: np.ndarray
    """[P] share of each part's faces that lie on a sheet"""
    surface: np.ndarray
    """[P] whole surface area per part (scene units^2): every face counted once, the volume that moving the
    part's surface out by one unit of length adds (the mass's surface offset, :mod:`physgs_nerfstudio.mass`)"""
    full_area: np.ndarray | None = None
    """[P] area of the fully counted faces per part (scene units^2): those whose wall lies inside them"""
    curvature: np.ndarray | None = None
    """[P] integrated mean curvature of those faces per part (scene units; module doc, "Wall curvature")"""


def concavities(hull: np.ndarray, solid: np.ndarray, depth_voxels: float = 2.0) -> np.ndarray:
    """bool [X, Y, Z]: the object's concavities (a cup's inside): the empty voxels of ``solid`` that lie more than
    ``depth_voxels`` inside the visual ``hull`` (:func:`physgs_nerfstudio.geometry.carve.mask_hull`: space
    that no silhouette carves, only depth) and that the solid surrounds, with solid on both sides of them along
    some grid axis. The depth keeps out the layer between the hull and the solid that the masks' blur leaves around
    any object; the surrounding keeps out a layer that depth carved off a flat face (a closed box's top), which
    lies against the solid on one side only."""
    from scipy import ndimage

    # the hull eroded by a ball of radius ``depth_voxels`` (outside the grid counts as outside the hull): the voxels
    # whose nearest voxel outside the hull lies farther than that, by the exact Euclidean distance transform. A ball
    # structuring element needs (2 r + 1)^3 of memory and time per voxel: a few pixels of a fine grid on a small
    # object are tens of voxels, and such an erosion runs out of memory
    padded = np.pad(np.asarray(hull, dtype=bool), 1, constant_values=False)
    deep = (ndimage.distance_transform_edt(padded)[1:-1, 1:-1, 1:-1] > depth_voxels) & ~solid
    if not deep.any():
        return deep
    enclosed = np.zeros_like(deep)
    for axis in range(solid.ndim):
        before = np.maximum.accumulate(solid, axis=axis)
        after = np.flip(np.maximum.accumulate(np.flip(solid, axis), axis=axis), axis)
        enclosed |= before & after
    return deep & enclosed


def part_areas(grid: VoxelGrid, solid: np.ndarray, parts: np.ndarray, num_parts: int, *,
               sheet_voxels: float = 1.5, area_sigma: float = 0.5, concave: np.ndarray | None = None,
               device: torch.device | str = "cpu") -> PartGeometry:  # fmt: skip
    """Per-part volume and wall area of ``solid`` (module doc). Computed on the solid's bounding box (with a margin
    for the smoothing and the sheet window): the same faces, nearest voxels and sheet test as on the whole grid.
    ``concave`` (:func:`concavities`): a face that is no sheet face and whose voxel borders a concavity but not the
    ordinary outside is the inner face of a wall whose outer face is counted (a cup carved with a thick wall, a
    pan's inside) or the top of an unseen fill (under a cup's rim): it counts 0. A sheet face counts half only
    where the thin solid is a plate (:data:`MIN_PLATE`). ``device``: where the plate test's tables are summed (the
    splat's device)."""
    from scipy import ndimage  # lazily: a PLY-only export needs no SciPy
    from skimage.measure import marching_cubes
    h = grid.voxel_size
    vol = np.bincount(parts[solid], minlength=num_parts).astype(np.float64) * h**3
    if not solid.any():
        zero = np.zeros(num_parts)
        return PartGeometry(vol, zero, zero.copy(), zero.copy(), zero.copy(), zero.copy())
    # empty voxels kept around the solid: the sheet test's ball and the plate test's window fit inside
    m = max(int(np.floor(sheet_voxels)) + 2, _plate_window(sheet_voxels))
    lo, hi = bounding_box(solid)
    lo, hi = np.maximum(lo - m, 0), np.minimum(hi + m, solid.shape)
    crop = tuple(slice(a, b) for a, b in zip(lo, hi))
    solid, parts = solid[crop], parts[crop]
    concave = concave[crop] if concave is not None else None
    pad = 2
    padded = np.pad(solid, pad).astype(np.float32)
    if area_sigma > 0:
        padded = ndimage.gaussian_filter(padded, area_sigma)
    if not padded.max() > 0.5:  # a solid too thin or small to have a surface (marching cubes refuses it)
        raise GeometryError(
            f"the object came out empty: carving left {int(solid.sum())} solid voxel(s), too few for a surface. "
            "The masks and the views hardly agree: check the object masks (perception/masks) and the poses, try a "
            "finer --mass.geometry.resolution, or select the object with --bbox.")  # fmt: skip
    verts, faces, _, _ = marching_cubes(padded, 0.5)
    tri = verts[faces]  # [T, 3, 3] in padded voxel index units
    fa = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1) * h**2
    centroid = tri.mean(1) - pad  # cropped voxel-index coordinates (voxel i has its centre at i)
    fv = np.clip(np.rint(centroid).astype(np.int64), 0, np.asarray(solid.shape) - 1)
    nv = _nearest_solid(solid, fv)
    pid = parts[nv]
    sheet = _sheet_faces(solid, nv, sheet_voxels)
    if sheet.any():
        idx = np.flatnonzero(sheet)
        sheet[idx] = _plate_like(solid, tuple(a[idx] for a in nv), _plate_window(sheet_voxels), MIN_PLATE, device)
    factor = np.where(sheet, 0.5, 1.0)
    if concave is not None and concave.any():
        inner = solid & _dilate_faces(concave)
        outer = solid & _dilate_faces(~solid & ~concave)
        factor[~sheet & inner[nv] & ~outer[nv]] = 0.0
    ok = pid >= 0
    # per part, the faces' areas added in their order (np.add.at's sums, bit for bit)
    full = factor == 1.0
    curv = face_mean_curvature(verts, faces) * h
    area, sheet_area, total_area, full_area, curvature = (
        np.bincount(pid[ok], x[ok], minlength=num_parts).astype(np.float64, copy=False)
        for x in (fa * factor, fa * sheet, fa, fa * full, curv * full))  # fmt: skip
    share = np.divide(sheet_area, total_area, out=np.zeros_like(area), where=total_area > 0)
    return PartGeometry(vol, area, share, total_area, full_area, curvature)


def seam_areas(parts: np.ndarray, num_parts: int, voxel_size: float) -> np.ndarray:
    """float64 [P, P], symmetric, zero diagonal: the area between each two parts inside the solid (scene units^2),
    the voxel faces shared by a voxel of one and a voxel of the other (``parts``: int [X, Y, Z], -1 outside the
    solid). A part's seam with another lies inside the object, where no view sees it: its place is the nearest
    surface evidence carried inwards (:func:`voxel_mixture`), so the mass's Monte Carlo moves it
    (:mod:`physgs_nerfstudio.mass.integrate`, "Seams")."""
    counts = np.zeros(num_parts * num_parts, np.int64)
    for axis in range(parts.ndim):
        n = parts.shape[axis]
        a = np.take(parts, np.arange(n - 1), axis=axis)
        b = np.take(parts, np.arange(1, n), axis=axis)
        on = (a >= 0) & (b >= 0) & (a != b)
        counts += np.bincount(a[on] * num_parts + b[on], minlength=num_parts * num_parts)
    m = counts.reshape(num_parts, num_parts).astype(np.float64)
    return (m + m.T) * voxel_size**2


def _nearest_solid(solid: np.ndarray, at: np.ndarray, radius: int = 3) -> tuple[np.ndarray, ...]:
    """Index arrays of the solid voxel nearest to each voxel ``at`` [F, 3] (Euclidean; ties to the first offset in
    (distance, x, y, z) order). A face lies within a voxel or so of the solid, so the offsets are tried nearest
    first up to ``radius`` voxels, only for the faces still unresolved; a distance transform answers the rest."""
    shape = np.asarray(solid.shape)
    out = at.copy()
    todo = np.flatnonzero(~solid[tuple(at.T)])
    if len(todo):
        o = np.arange(-radius, radius + 1)
        offs = np.stack(np.meshgrid(o, o, o, indexing="ij"), -1).reshape(-1, 3)
        offs = offs[np.lexsort((offs[:, 2], offs[:, 1], offs[:, 0], (offs**2).sum(1)))][1:]
        for off in offs:
            q = at[todo] + off
            inb = ((q >= 0) & (q < shape)).all(1)
            hit = np.zeros(len(todo), bool)
            hit[inb] = solid[tuple(q[inb].T)]
            out[todo[hit]] = q[hit]
            todo = todo[~hit]
            if not len(todo):
                break
    if len(todo):  # farther than ``radius``: the exact transform
        from scipy import ndimage

        _, near = ndimage.distance_transform_edt(~solid, return_indices=True)
        out[todo] = np.stack([n[tuple(at[todo].T)] for n in near], -1)
    return tuple(out.T)


def _sheet_faces(solid: np.ndarray, nv: tuple[np.ndarray, ...], sheet_voxels: float) -> np.ndarray:
    """bool per face: the solid's largest inscribed distance (Euclidean distance to the nearest empty voxel of the
    grid) within a cube of half-width ``ceil(sheet_voxels) + 1`` around the face's voxel ``nv`` is at most
    ``sheet_voxels``. Without a distance transform: a voxel's inscribed distance exceeds ``s`` exactly when every
    grid voxel within distance ``s`` of it is solid (the erosion by that ball, the grid's outside counted solid
    as the transform does), and the cube's maximum exceeds ``s`` when an eroded voxel lies in the cube (the eroded
    voxels dilated by the cube, three one-dimensional maximum filters, looked up per face)."""
    from scipy import ndimage

    s = float(sheet_voxels)
    k = int(np.floor(s))
    o = np.arange(-k, k + 1)
    ball = (o[:, None, None] ** 2 + o[None, :, None] ** 2 + o[None, None, :] ** 2) <= s * s
    core = _erode(solid, ball) if k > 0 else solid.copy()
    r = int(np.ceil(s)) + 1
    near = core.view(np.uint8)
    for axis in range(near.ndim):  # a window of [c - r, c + r], nothing beyond the grid
        near = ndimage.maximum_filter1d(near, 2 * r + 1, axis=axis, mode="constant", cval=0)
    return near[nv] == 0


def _erode(solid: np.ndarray, ball: np.ndarray) -> np.ndarray:
    """``scipy.ndimage.binary_erosion(solid, ball, border_value=1)`` for a symmetric ``ball`` of odd side: the AND of
    ``solid`` shifted by each of the ball's offsets, the grid's outside counted solid (a few times faster than
    SciPy's voxel-by-voxel loop on a 19-voxel ball)."""
    r = ball.shape[0] // 2
    padded = np.pad(solid, r, constant_values=True)
    X, Y, Z = solid.shape
    out = solid.copy()
    for dx, dy, dz in np.argwhere(ball):
        if (dx, dy, dz) != (r, r, r):
            out &= padded[dx : dx + X, dy : dy + Y, dz : dz + Z]
    return out


def _dilate_faces(mask: np.ndarray) -> np.ndarray:
    """``scipy.ndimage.binary_dilation(mask, generate_binary_structure(3, 1))``: ``mask`` and its six face
    neighbours' (nothing beyond the grid), by shifted ORs."""
    out = mask.copy()
    for axis in range(mask.ndim):
        head = [slice(None)] * mask.ndim
        tail = [slice(None)] * mask.ndim
        head[axis], tail[axis] = slice(1, None), slice(None, -1)
        out[tuple(head)] |= mask[tuple(tail)]
        out[tuple(tail)] |= mask[tuple(head)]
    return out


def _plate_window(sheet_voxels: float) -> int:
    """Half-width of the window in which a thin solid's extent is measured: twice the widest sheet's thickness."""
    return 2 * int(np.ceil(2 * sheet_voxels)) + 1


def _plate_like(solid: np.ndarray, at: tuple[np.ndarray, ...], half: int, min_plate: float,
                device: torch.device | str = "cpu") -> np.ndarray:  # fmt: skip
    """bool per voxel ``at``: the solid in the cube of half-width ``half`` around it spreads in two directions (a
    plate: the second-largest eigenvalue of its voxels' covariance is at least ``min_plate`` x the largest), not in
    one (a rod, whose cross-section is as thin as a sheet is thick, but whose faces are its one outer side). Window
    sums of the voxel count and the coordinates' first and second moments come from summed-area tables, built
    on ``device`` (the splat's: built on the host, the tables took 0.12-0.23 s per carving variant of a 500k-Gaussian GPU run). Every table entry is an integer far below 2^53, so the float64 sums are
    exact in any order and the device changes no result."""
    X, Y, Z = solid.shape
    dev = torch.device(device)
    w = torch.from_numpy(np.ascontiguousarray(solid)).to(dev, torch.float64)
    i, j, k = (torch.arange(n, dtype=torch.float64, device=dev) for n in (X, Y, Z))
    # channels: w, w i, w j, w k, w i^2, w j^2, w k^2, w i j, w i k, w j k (the order of the moments below)
    powers = ((0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (2, 0, 0), (0, 2, 0), (0, 0, 2), (1, 1, 0), (1, 0, 1),
              (0, 1, 1))  # fmt: skip
    sat = torch.zeros((len(powers), X + 1, Y + 1, Z + 1), dtype=torch.float64, device=dev)
    for ch, (a, b, c) in enumerate(powers):
        sat[ch, 1:, 1:, 1:] = w * (i**a)[:, None, None] * (j**b)[None, :, None] * (k**c)[None, None, :]
    for axis in (1, 2, 3):
        sat = sat.cumsum(axis)
    cen = torch.from_numpy(np.stack(at, -1).astype(np.int64)).to(dev)  # [F, 3]
    lo = (cen - half).clamp_min(0)
    hi = torch.minimum(cen + half + 1, torch.tensor(solid.shape, device=dev))
    flat = sat.reshape(len(powers), -1)
    sums = torch.zeros((len(powers), len(cen)), dtype=torch.float64, device=dev)
    for sx in (0, 1):
        for sy in (0, 1):
            for sz in (0, 1):
                x, y, z = (hi[:, d] if on else lo[:, d] for d, on in enumerate((sx, sy, sz)))
                sign = (-1) ** (3 - sx - sy - sz)
                sums += sign * flat[:, (x * (Y + 1) + y) * (Z + 1) + z]
    n = sums[0].clamp_min(1.0)
    mu = sums[1:4] / n
    m2 = torch.empty((len(cen), 3, 3), dtype=torch.float64, device=dev)
    for (a, b), ch in zip(((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)), range(4, 10)):
        m2[:, a, b] = m2[:, b, a] = sums[ch] / n - mu[a] * mu[b]
    ev = sym3_eigvalsh(m2)  # ascending
    return (ev[:, 1] >= min_plate * ev[:, 2].clamp_min(1e-12)).cpu().numpy()


def sym3_eigvalsh(m: Tensor) -> Tensor:
    """float64 [F, 3]: the eigenvalues, ascending, of the symmetric 3 x 3 matrices ``m`` [F, 3, 3], in closed form
    (the trigonometric solution of the characteristic cubic), on ``m``'s device, without a solver library. Near a
    repeated eigenvalue it keeps about 1e-7 of the matrix's scale (tests/test_geometry_fast_paths.py)."""
    m = m.double()
    q = m.diagonal(dim1=1, dim2=2).sum(1) / 3.0
    a01, a02, a12 = m[:, 0, 1], m[:, 0, 2], m[:, 1, 2]
    d0, d1, d2 = m[:, 0, 0] - q, m[:, 1, 1] - q, m[:, 2, 2] - q
    p = torch.sqrt((d0**2 + d1**2 + d2**2 + 2.0 * (a01**2 + a02**2 + a12**2)) / 6.0)
    iso = p <= 1e-12 * q.abs().clamp_min(1e-300)  # a multiple of the identity (or zero): one triple eigenvalue
    ps = torch.where(iso, torch.ones_like(p), p)
    b00, b11, b22, b01, b02, b12 = d0 / ps, d1 / ps, d2 / ps, a01 / ps, a02 / ps, a12 / ps
    det = b00 * (b11 * b22 - b12**2) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02)
    phi = torch.arccos((det / 2.0).clamp(-1.0, 1.0)) / 3.0
    hi = q + 2.0 * p * torch.cos(phi)
    lo = q + 2.0 * p * torch.cos(phi + 2.0 * math.pi / 3.0)
    out = torch.stack([lo, 3.0 * q - hi - lo, hi], -1)
    out = torch.where(iso[:, None], q[:, None].expand_as(out), out)
    return out.sort(dim=1).values  # rounding can swap the middle one with an end by an ulp


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Row-wise cross product of [N, 3] arrays (np.cross, about 3x faster on many rows)."""
    out = np.empty(np.broadcast_shapes(u.shape, v.shape))
    out[:, 0] = u[:, 1] * v[:, 2] - u[:, 2] * v[:, 1]
    out[:, 1] = u[:, 2] * v[:, 0] - u[:, 0] * v[:, 2]
    out[:, 2] = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    return out


def face_mean_curvature(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """float64 [T]: each triangle's share of the mesh's integrated mean curvature ``sum_e |e| theta_e / 2``
    (``theta_e``: the signed angle between the normals of the two faces at edge ``e``, positive where the surface
    is convex; each edge's term split equally between its two faces). Edges not shared by exactly two faces give
    nothing. ``faces`` are wound as scikit-image's marching cubes winds them around a field that is larger inside
    (its winding's normals point inwards). Units: those of ``verts``."""
    verts = np.asarray(verts, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    T = len(faces)
    out = np.zeros(T)
    if T == 0:
        return out
    tri = verts[faces]
    n = _cross(tri[:, 2] - tri[:, 0], tri[:, 1] - tri[:, 0])  # outward for this winding
    n /= np.maximum(np.sqrt(np.einsum("ij,ij->i", n, n)), 1e-300)[:, None]
    a = np.concatenate([faces[:, 0], faces[:, 1], faces[:, 2]])  # directed edges a -> b of face fid
    b = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0]])
    fid = np.tile(np.arange(T), 3)
    key = np.minimum(a, b) * len(verts) + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    ks = key[order]
    start = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
    count = np.diff(np.r_[start, len(ks)])
    first = start[count == 2]
    i, j = order[first], order[first + 1]
    e = verts[b[i]] - verts[a[i]]
    length = np.sqrt(np.einsum("ij,ij->i", e, e))
    n1, n2 = n[fid[i]], n[fid[j]]
    sin = np.einsum("ij,ij->i", _cross(n2, n1), e) / np.maximum(length, 1e-300)
    theta = np.arctan2(sin, np.einsum("ij,ij->i", n1, n2))
    half = 0.25 * length * theta  # |e| theta / 2, half of it to each face
    out += np.bincount(fid[i], half, minlength=T)
    out += np.bincount(fid[j], half, minlength=T)
    return out
