"""Triangle meshes of the generator's primitives, for an external renderer (:mod:`.pathtrace`).

`part_mesh(prim, spacing)` returns vertices, outward vertex normals and faces in the primitive's local frame, with
edges no longer than about `spacing` (so that per-vertex colours carry the procedural textures). Solids of
revolution (cylinder, frustum, cup, tube, shade, sphere, capsule, torus) are revolved from their meridian profile,
one band per profile segment, so that creases stay sharp; half solids cut through their axis are revolved over half a
turn and closed by their meridian section; boxes are six gridded faces; meshes are their own triangles. The meshes
are for rendering only: the truth (volumes, masses) never comes from them.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from .geometry import Box, Capsule, Cup, Cylinder, Frustum, Half, Mesh, Primitive, Shade, Sphere, Torus, Tube

MeshArrays = tuple[np.ndarray, np.ndarray, np.ndarray]  # vertices [V, 3], normals [V, 3], faces [F, 3]


def _arc(cz: float, r: float, a0: float, a1: float, n: int) -> list[tuple[float, float]]:
    """`n` points (rho, z) on the meridian arc of radius `r` around (0, cz), from angle a0 to a1 (radians)."""
    return [(r * math.cos(a), cz + r * math.sin(a)) for a in np.linspace(a0, a1, n)]


def profile(prim: Primitive) -> list[list[tuple[float, float]]]:
    """The meridian profile (rho, z) of a solid of revolution as polylines, walked with the solid on the left (so
    that (dz, -drho) is the outward normal)."""
    if isinstance(prim, Cylinder):
        r, h = prim.radius, prim.height / 2
        return [[(0.0, -h), (r, -h), (r, h), (0.0, h)]]
    if isinstance(prim, Frustum):
        h = prim.height / 2
        return [[(0.0, -h), (prim.r_bottom, -h), (prim.r_top, h), (0.0, h)]]
    if isinstance(prim, Cup):
        r, h, ri = prim.radius, prim.height / 2, prim.radius - prim.wall
        zb = -h + prim.bottom
        return [[(0.0, -h), (r, -h), (r, h), (ri, h), (ri, zb), (0.0, zb)]]
    if isinstance(prim, Tube):
        h = prim.height / 2
        return [[(prim.r_inner, -h), (prim.r_outer, -h), (prim.r_outer, h), (prim.r_inner, h), (prim.r_inner, -h)]]
    if isinstance(prim, Shade):
        f, h = prim._frustum(), prim.height / 2
        off = prim.wall * math.sqrt(1 + f.slope**2)
        return [[(f.r_bottom - off, -h), (f.r_bottom, -h), (f.r_top, h), (f.r_top - off, h), (f.r_bottom - off, -h)]]
    if isinstance(prim, Sphere):
        return [_arc(0.0, prim.radius, -math.pi / 2, math.pi / 2, 33)]
    if isinstance(prim, Capsule):
        r, h = prim.radius, prim.length / 2
        return [_arc(-h, r, -math.pi / 2, 0.0, 17) + _arc(h, r, 0.0, math.pi / 2, 17)]
    if isinstance(prim, Torus):
        a = np.linspace(-math.pi, math.pi, 33)
        return [[(prim.major + prim.minor * math.cos(t), prim.minor * math.sin(t)) for t in a]]
    raise TypeError(f"{prim.kind} is not a solid of revolution")


def _subdivide(poly: list[tuple[float, float]], spacing: float) -> list[np.ndarray]:
    """Each segment of a polyline as its own run of points at most `spacing` apart (runs share end points)."""
    runs = []
    for (r0, z0), (r1, z1) in itertools.pairwise(poly):
        n = max(1, math.ceil(math.hypot(r1 - r0, z1 - z0) / spacing))
        t = np.linspace(0.0, 1.0, n + 1)[:, None]
        runs.append(np.array([r0, z0]) * (1 - t) + np.array([r1, z1]) * t)
    return runs


def _merge_smooth(runs: list[np.ndarray]) -> list[np.ndarray]:
    """Join consecutive runs whose directions differ by less than 20 degrees (arcs stay one smooth band)."""
    out = [runs[0]]
    for run in runs[1:]:
        a, b = out[-1][-1] - out[-1][-2], run[1] - run[0]
        cos = float(a @ b / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-300))
        if cos > math.cos(math.radians(20)):
            out[-1] = np.concatenate([out[-1], run[1:]])
        else:
            out.append(run)
    return out


def _band(run: np.ndarray, theta: np.ndarray) -> MeshArrays:
    """A run of profile points revolved over the angles `theta`: vertices, normals (from the profile) and faces."""
    d = np.gradient(run, axis=0) if len(run) > 2 else np.repeat(run[1:] - run[:1], len(run), 0)
    nrz = np.stack([d[:, 1], -d[:, 0]], 1)
    nrz /= np.maximum(np.linalg.norm(nrz, axis=1, keepdims=True), 1e-300)
    c, s = np.cos(theta)[None, :], np.sin(theta)[None, :]
    rho, z = run[:, 0:1], run[:, 1:2] * np.ones_like(c)
    v = np.stack([rho * c, rho * s, z], -1).reshape(-1, 3)
    nr, nz = nrz[:, 0:1], nrz[:, 1:2] * np.ones_like(c)
    n = np.stack([nr * c, nr * s, nz], -1).reshape(-1, 3)
    m = len(theta)
    i, j = np.meshgrid(np.arange(len(run) - 1), np.arange(m - 1), indexing="ij")
    a, b = i * m + j, (i + 1) * m + j
    f = np.concatenate([np.stack([a, b, b + 1], -1).reshape(-1, 3), np.stack([a, b + 1, a + 1], -1).reshape(-1, 3)])
    return v, n, f


def _concat(pieces: list[MeshArrays]) -> MeshArrays:
    vs, ns, fs, k = [], [], [], 0
    for v, n, f in pieces:
        vs.append(v)
        ns.append(n)
        fs.append(f + k)
        k += len(v)
    return np.concatenate(vs), np.concatenate(ns), np.concatenate(fs)


def _fan(poly: np.ndarray, normal: np.ndarray, to3d) -> MeshArrays:
    """A convex planar polygon (2-D points) closed by a fan around its centroid, mapped to 3-D by `to3d`."""
    pts = np.concatenate([poly.mean(0, keepdims=True), poly])
    k = len(poly)
    f = np.stack([np.zeros(k, int), 1 + np.arange(k), 1 + (np.arange(k) + 1) % k], 1)
    v = to3d(pts)
    return v, np.tile(normal, (len(v), 1)), f


def revolved(prim: Primitive, spacing: float, theta0: float = 0.0, theta1: float = 2 * math.pi) -> MeshArrays:
    runs = [r for poly in profile(prim) for r in _merge_smooth(_subdivide(poly, spacing))]
    rmax = max(float(np.max(r[:, 0])) for r in runs)
    n = max(24, math.ceil(rmax * (theta1 - theta0) / spacing))
    theta = np.linspace(theta0, theta1, n + 1)
    return _concat([_band(r, theta) for r in runs])


def _box(size: tuple[float, float, float], spacing: float) -> MeshArrays:
    h = np.asarray(size, float) / 2
    pieces = []
    for ax in range(3):
        u, w = [a for a in range(3) if a != ax]
        nu, nw = (max(1, math.ceil(2 * h[a] / spacing)) for a in (u, w))
        gu, gw = np.meshgrid(np.linspace(-h[u], h[u], nu + 1), np.linspace(-h[w], h[w], nw + 1), indexing="ij")
        i, j = np.meshgrid(np.arange(nu), np.arange(nw), indexing="ij")
        a, b = i * (nw + 1) + j, (i + 1) * (nw + 1) + j
        f = np.concatenate([np.stack([a, b, b + 1], -1).reshape(-1, 3), np.stack([a, b + 1, a + 1], -1).reshape(-1, 3)])
        for sign in (-1.0, 1.0):
            v = np.zeros((gu.size, 3))
            v[:, u], v[:, w], v[:, ax] = gu.ravel(), gw.ravel(), sign * h[ax]
            nrm = np.zeros(3)
            nrm[ax] = sign
            pieces.append((v, np.tile(nrm, (len(v), 1)), f))
    return _concat(pieces)


def _half(prim: Half, spacing: float) -> MeshArrays:
    base = prim.base
    if isinstance(base, Box):
        h = base.half_extents().copy()
        v, n, f = _box(tuple(np.where(np.arange(3) == prim.axis, h, 2 * h)), spacing)
        v[:, prim.axis] += prim.sign * h[prim.axis] / 2
        return v, n, f
    if prim.axis == 2:  # cut across the axis of revolution: revolve the profile on the kept side, close with a disc
        v, n, f = revolved(base, spacing)
        keep = prim.sign * v[:, 2] >= -1e-12
        v = v.copy()
        v[~keep, 2] = 0.0  # fold the cut side onto the cut plane (rendering only)
        n = np.where(keep[:, None], n, np.array([0.0, 0.0, -prim.sign]))
        return v, n, f
    lo = {(0, 1.0): -math.pi / 2, (0, -1.0): math.pi / 2, (1, 1.0): 0.0, (1, -1.0): math.pi}[(prim.axis, prim.sign)]
    shell = revolved(base, spacing, lo, lo + math.pi)
    caps = []
    for theta, side in ((lo, -1.0), (lo + math.pi, 1.0)):
        direction = np.array([math.cos(theta), math.sin(theta), 0.0])
        normal = side * np.array([-math.sin(theta), math.cos(theta), 0.0])
        for poly in profile(base):
            pts = np.asarray(poly)
            if isinstance(base, (Tube, Shade, Torus)):
                loop = pts
            else:  # a meridian section through the axis: the profile and its mirror image
                loop = np.concatenate([pts, pts[::-1] * np.array([-1.0, 1.0])])
            caps.append(_fan(loop, normal, lambda q, d=direction: q[:, :1] * d + q[:, 1:2] * np.array([0, 0, 1.0])))
    return _concat([shell, *caps])


def part_mesh(prim: Primitive, spacing: float) -> MeshArrays:
    """Vertices, outward normals and faces of `prim` in its local frame (module doc)."""
    if isinstance(prim, Box):
        return _box(prim.size, spacing)
    if isinstance(prim, Half):
        return _half(prim, spacing)
    if isinstance(prim, Mesh):
        m = prim.mesh
        return np.asarray(m.vertices, float), np.asarray(m.vertex_normals, float), np.asarray(m.faces, np.int64)
    return revolved(prim, spacing)


def orient_faces(v: np.ndarray, n: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Faces wound so that their geometric normal agrees with the vertex normals (outward)."""
    e = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    flip = np.einsum("ij,ij->i", e, n[f].sum(1)) < 0
    out = f.copy()
    out[flip] = f[flip][:, [0, 2, 1]]
    return out
