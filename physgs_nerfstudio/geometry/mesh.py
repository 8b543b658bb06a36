"""Measures of a triangle mesh: the integrated mean curvature per face (:mod:`.parts`' wall curvature)."""

from __future__ import annotations

import numpy as np

__all__ = ["face_mean_curvature"]


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
