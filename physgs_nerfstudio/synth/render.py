"""Pinhole cameras on an orbit and analytic ray casting of placed primitives.

Conventions (nerfstudio / OpenGL): camera-to-world ``c2w`` [4, 4]; the camera looks down its -z axis, y up,
x right. Pixel (u, v) (column, row) has its centre at (u + 0.5, v + 0.5), as nerfstudio's ray generator
assumes; a camera-frame point (x, y, z) projects to u = cx + fx x / (-z), v = cy - fy y / (-z), and its
z-depth is -z.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .appearance import Look, albedo, background, shade
from .objects import Part

GOLDEN_ANGLE = math.pi * (3 - math.sqrt(5))


@dataclass(frozen=True)
class Intrinsics:
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def from_fov(cls, width: int, height: int, fov_deg: float) -> Intrinsics:
        """Square pixels; `fov_deg` is the horizontal field of view."""
        f = 0.5 * width / math.tan(math.radians(fov_deg) / 2)
        return cls(width, height, f, f, width / 2, height / 2)

    def matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])


def look_at(eye: np.ndarray, target: np.ndarray, up: Sequence[float] = (0.0, 0.0, 1.0)) -> np.ndarray:
    """OpenGL camera-to-world matrix of a camera at `eye` looking at `target`."""
    forward = np.asarray(target, float) - np.asarray(eye, float)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-9:  # looking straight along `up`
        right = np.cross(forward, (0.0, 1.0, 0.0))
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, true_up, -forward, eye
    return c2w


def orbit_poses(n: int, center: np.ndarray, radius: float, elevation_deg: tuple[float, float],
                azimuth0_deg: float = 0.0) -> np.ndarray:
    """`n` cameras spread evenly (Fibonacci spiral) over the band of a sphere between two elevations,
    all looking at `center`: [n, 4, 4] camera-to-world."""
    lo, hi = (math.radians(e) for e in elevation_deg)
    if not -math.pi / 2 < lo <= hi < math.pi / 2:
        raise ValueError(f"elevation range must lie strictly inside (-90, 90) degrees, got {elevation_deg}")
    i = np.arange(n) + 0.5
    sin_el = math.sin(lo) + (math.sin(hi) - math.sin(lo)) * i / n  # equal area in the band
    el = np.arcsin(sin_el)
    az = math.radians(azimuth0_deg) + GOLDEN_ANGLE * np.arange(n)
    eyes = np.asarray(center, float) + radius * np.stack(
        [np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1
    )
    return np.stack([look_at(e, center) for e in eyes])


def camera_rays(K: Intrinsics, c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays through pixel centres in row-major order: origins [HW, 3], unit directions [HW, 3] and the
    factor turning distance along the ray into z-depth [HW]."""
    v, u = np.meshgrid(np.arange(K.height) + 0.5, np.arange(K.width) + 0.5, indexing="ij")
    d_cam = np.stack([(u - K.cx) / K.fx, -(v - K.cy) / K.fy, -np.ones_like(u)], -1).reshape(-1, 3)
    norm = np.linalg.norm(d_cam, axis=1)
    d_cam /= norm[:, None]
    dirs = d_cam @ c2w[:3, :3].T
    origins = np.broadcast_to(c2w[:3, 3], dirs.shape).copy()
    return origins, dirs, 1.0 / norm


def project(K: Intrinsics, c2w: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points [N, 3] -> pixel coordinates [N, 2] (u, v; continuous, centres at +0.5) and z-depth [N]."""
    w2c = np.linalg.inv(c2w)
    pc = points @ w2c[:3, :3].T + w2c[:3, 3]
    z = -pc[:, 2]
    uv = np.stack([K.cx + K.fx * pc[:, 0] / z, K.cy - K.fy * pc[:, 1] / z], 1)
    return uv, z


@dataclass
class CastResult:
    part: np.ndarray  # [N] int, index into parts, -1 = background
    t: np.ndarray  # [N] distance along the ray (inf on miss)
    normal: np.ndarray  # [N, 3] world normal
    local: np.ndarray  # [N, 3] hit point in the hit part's local frame


def cast(parts: Sequence[Part], origins: np.ndarray, dirs: np.ndarray) -> CastResult:
    """Nearest hit over all parts (bounding-sphere culled), vectorised over rays."""
    n = origins.shape[0]
    best_t = np.full(n, np.inf)
    best_part = np.full(n, -1, dtype=np.int64)
    best_n = np.zeros((n, 3))
    best_local = np.zeros((n, 3))
    for k, part in enumerate(parts):
        c, r = part.bounding_sphere()
        oc = c - origins
        along = np.einsum("ij,ij->i", oc, dirs)
        miss2 = np.einsum("ij,ij->i", oc, oc) - along**2
        idx = np.nonzero((miss2 <= r * r) & (along + r > 0) & (along - r < best_t))[0]
        if idx.size == 0:
            continue
        o_l = part.to_local(origins[idx])
        d_l = part.dir_to_local(dirs[idx])
        hit = part.primitive.intersect(o_l, d_l)
        closer = hit.t < best_t[idx]
        sel = idx[closer]
        best_t[sel] = hit.t[closer]
        best_part[sel] = k
        best_n[sel] = part.dir_to_world(hit.normal[closer])
        best_local[sel] = o_l[closer] + hit.t[closer, None] * d_l[closer]
    return CastResult(best_part, best_t, best_n, best_local)


@dataclass
class View:
    rgb: np.ndarray  # [H, W, 3] uint8
    part: np.ndarray  # [H, W] int, part index + 1 (0 = background)
    depth: np.ndarray  # [H, W] float32 z-depth in metres (0 = background)


def render_view(parts: Sequence[Part], looks: Sequence[Look], look_seeds: Sequence[int], K: Intrinsics,
                c2w: np.ndarray, env: str, seed: int, supersample: int = 1) -> View:
    """Render one view: shaded RGB (optionally supersampled s x s, box-filtered) and, at pixel centres,
    the part map and z-depth."""
    origins, dirs, zfac = camera_rays(K, c2w)
    hit = cast(parts, origins, dirs)
    part_map = (hit.part + 1).reshape(K.height, K.width)
    depth = np.where(hit.part >= 0, hit.t * zfac, 0.0).astype(np.float32).reshape(K.height, K.width)
    if supersample > 1:
        s = supersample
        Ks = Intrinsics(K.width * s, K.height * s, K.fx * s, K.fy * s, K.cx * s, K.cy * s)
        o_s, d_s, _ = camera_rays(Ks, c2w)
        rgb = _shade_hits(parts, looks, look_seeds, cast(parts, o_s, d_s), d_s, env, seed)
        rgb = rgb.reshape(K.height, s, K.width, s, 3).mean(axis=(1, 3))
    else:
        rgb = _shade_hits(parts, looks, look_seeds, hit, dirs, env, seed).reshape(K.height, K.width, 3)
    rgb8 = np.clip(np.round(rgb * 255.0), 0, 255).astype(np.uint8)
    return View(rgb8, part_map, depth)


def _shade_hits(parts: Sequence[Part], looks: Sequence[Look], look_seeds: Sequence[int], hit: CastResult,
                dirs: np.ndarray, env: str, seed: int) -> np.ndarray:
    n = dirs.shape[0]
    rgb = background(dirs, env, seed)
    alb = np.zeros((n, 3))
    spec, shin, refl = np.zeros(n), np.ones(n), np.zeros(n)
    for k, look in enumerate(looks):
        m = hit.part == k
        if not np.any(m):
            continue
        alb[m] = albedo(look, hit.local[m], look_seeds[k])
        spec[m], shin[m], refl[m] = look.specular, look.shininess, look.reflect
    fg = hit.part >= 0
    if np.any(fg):
        rgb[fg] = shade(alb[fg], spec[fg], shin[fg], refl[fg], hit.normal[fg], dirs[fg], env, seed)
    return rgb
