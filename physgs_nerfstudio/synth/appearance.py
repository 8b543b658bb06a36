"""Procedural appearance: per-material base colour and 3D solid texture, shading, environment background.

Textures are functions of the hit point in the part's local frame (so they stay put across views, as a
radiance field needs); colours are perturbed per part from a realistic base colour per material (the
library's ``color`` is a legend colour, not an appearance). Everything is a pure function of its inputs and
a seed: identical inputs give identical bytes.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

# realistic sRGB base colours; materials not listed fall back to their library legend colour, muted
BASE_COLORS: dict[str, tuple[int, int, int]] = {
    # wood
    "wood": (150, 105, 65), "oak": (165, 120, 70), "pine": (215, 180, 125), "maple": (210, 170, 120),
    "walnut": (95, 65, 45), "bamboo": (200, 170, 110), "plywood": (200, 160, 110), "mdf": (170, 135, 95),
    "particleboard": (180, 150, 110), "cork": (170, 130, 90), "laminated_flooring": (185, 145, 100),
    # metal
    "steel": (150, 152, 158), "stainless_steel": (185, 188, 192), "cast_iron": (62, 62, 65),
    "aluminium": (190, 195, 200), "copper": (190, 110, 70), "brass": (195, 160, 80), "bronze": (160, 110, 60),
    "titanium": (150, 148, 145), "chrome_plated": (210, 212, 215), "silver": (200, 200, 205),
    "metal": (140, 140, 145),
    # plastic
    "abs": (70, 70, 75), "polypropylene": (225, 225, 215), "hdpe": (235, 235, 230), "ldpe": (230, 230, 225),
    "pvc": (200, 200, 205), "polycarbonate": (220, 225, 230), "acrylic": (230, 235, 240),
    "nylon": (235, 230, 215), "polystyrene": (240, 240, 240), "pet": (210, 225, 230), "silicone": (200, 90, 80),
    # ceramic, glass
    "ceramic": (232, 226, 214), "porcelain": (245, 245, 242), "terracotta": (190, 100, 65),
    "glass": (130, 160, 150),
    # fabric, leather, flooring
    "cotton": (222, 215, 198), "polyester": (90, 110, 150), "wool": (180, 170, 150), "denim": (70, 90, 130),
    "nylon_fabric": (60, 60, 70), "leather": (120, 75, 45), "faux_leather": (60, 45, 40), "carpet": (140, 80, 80),
    # foam, rubber, paper
    "polyurethane_foam": (230, 220, 150), "memory_foam": (235, 235, 225), "eps": (245, 245, 245),
    "rubber": (42, 42, 44), "natural_rubber": (52, 48, 44), "neoprene": (35, 35, 38), "eva": (80, 80, 85),
    "paper": (240, 238, 230), "cardboard": (180, 145, 100),
    # stone
    "concrete": (150, 150, 145), "marble": (230, 228, 222), "granite": (130, 125, 125),
    "plaster": (235, 232, 225), "wax": (240, 230, 200),
    # outdoor
    "asphalt": (62, 62, 64), "brick": (160, 75, 55), "gravel": (140, 135, 125), "pebbles": (150, 140, 130),
    "rock": (120, 115, 110), "sand": (210, 190, 145), "soil": (105, 80, 55), "mud": (80, 62, 45),
    "clay": (170, 110, 70), "dirt_road": (150, 120, 90), "grass": (80, 135, 55), "shrubs": (60, 100, 45),
    "moss": (90, 120, 50), "leaf_litter": (130, 95, 55), "bark": (90, 65, 45), "tree_trunk": (100, 75, 55),
    "wood_chips": (160, 115, 75), "rubber_mulch": (110, 60, 45), "artificial_turf": (60, 150, 60),
    "water": (60, 90, 110), "snow": (240, 242, 248), "ice": (200, 220, 235),
}

# texture by material name first, then by library category
_TEXTURE_BY_NAME = {
    "laminated_flooring": "wood", "bark": "bark", "tree_trunk": "bark", "leather": "leather",
    "faux_leather": "leather", "carpet": "carpet", "cardboard": "cardboard", "paper": "paper",
    "marble": "marble", "asphalt": "asphalt", "brick": "brick", "gravel": "gravel", "pebbles": "gravel",
    "leaf_litter": "gravel", "wood_chips": "gravel", "rubber_mulch": "gravel", "sand": "sand", "soil": "soil",
    "dirt_road": "soil", "clay": "soil", "mud": "mud", "grass": "grass", "shrubs": "grass", "moss": "grass",
    "artificial_turf": "grass", "snow": "sand", "water": "glass", "ice": "glass", "glass": "glass",
}
_TEXTURE_BY_CATEGORY = {
    "wood": "wood", "metal": "metal", "plastic": "plastic", "ceramic": "ceramic", "glass": "glass",
    "fabric": "fabric", "flooring": "wood", "foam": "foam", "rubber": "rubber", "paper": "paper",
    "stone": "stone", "pavement": "stone", "terrain": "stone", "vegetation": "grass", "man_made": "plastic",
    "water": "glass",
}


@dataclass(frozen=True)
class Look:
    """How a part looks: texture kind, albedo colour (0..1) and gloss."""

    texture: str
    color: tuple[float, float, float]
    specular: float  # Blinn-Phong highlight strength
    shininess: float
    reflect: float  # mirror reflection of the environment (Fresnel-weighted)


_GLOSS = {  # texture -> (specular, shininess, reflect)
    "metal": (0.55, 60.0, 0.30), "glass": (0.9, 150.0, 0.45), "ceramic": (0.45, 90.0, 0.10),
    "plastic": (0.25, 40.0, 0.05), "marble": (0.35, 80.0, 0.08), "mud": (0.30, 40.0, 0.04),
    "leather": (0.15, 25.0, 0.0), "wood": (0.08, 20.0, 0.0), "rubber": (0.05, 10.0, 0.0),
}


def texture_kind(name: str, category: str) -> str:
    return _TEXTURE_BY_NAME.get(name) or _TEXTURE_BY_CATEGORY.get(category, "plastic")


def stable_seed(*items: object) -> int:
    """Deterministic 32-bit seed from a tuple of items (unlike Python's salted hash)."""
    return zlib.crc32(repr(items).encode()) & 0xFFFFFFFF


def part_look(name: str, category: str, legend_color: tuple[int, int, int], seed: int) -> Look:
    """Appearance of one part: the material's base colour perturbed (brightness and tint) by `seed`."""
    base = BASE_COLORS.get(name)
    if base is None:  # mute the legend colour towards grey
        base = tuple(int(0.5 * c + 0.5 * 128) for c in legend_color)
    rng = np.random.default_rng(seed)
    col = np.asarray(base, float) / 255.0
    col = col * rng.uniform(0.85, 1.12) * rng.uniform(0.94, 1.06, 3)
    kind = texture_kind(name, category)
    spec, shin, refl = _GLOSS.get(kind, (0.03, 10.0, 0.0))
    return Look(kind, tuple(float(c) for c in np.clip(col, 0.0, 1.0)), spec, shin, refl)


# ------------------------------------------------------------------------------------------ noise


def _hash01(ix: np.ndarray, iy: np.ndarray, iz: np.ndarray, seed: int) -> np.ndarray:
    h = (ix.astype(np.int64).astype(np.uint32) * np.uint32(0x8DA6B343)) ^ (
        iy.astype(np.int64).astype(np.uint32) * np.uint32(0xD8163841)
    ) ^ (iz.astype(np.int64).astype(np.uint32) * np.uint32(0xCB1AB31F)) ^ np.uint32(seed & 0xFFFFFFFF)
    h ^= h >> np.uint32(13)
    h *= np.uint32(0x5BD1E995)
    h ^= h >> np.uint32(15)
    return h.astype(np.float64) / 4294967296.0


def value_noise(p: np.ndarray, seed: int) -> np.ndarray:
    """Smooth 3D value noise in [0, 1) at points p [N, 3] (lattice spacing 1)."""
    i = np.floor(p)
    f = p - i
    w = f * f * (3 - 2 * f)
    i = i.astype(np.int64)
    out = np.zeros(p.shape[0])
    for dx in (0, 1):
        wx = w[:, 0] if dx else 1 - w[:, 0]
        for dy in (0, 1):
            wy = w[:, 1] if dy else 1 - w[:, 1]
            for dz in (0, 1):
                wz = w[:, 2] if dz else 1 - w[:, 2]
                out += wx * wy * wz * _hash01(i[:, 0] + dx, i[:, 1] + dy, i[:, 2] + dz, seed)
    return out


def fbm(p: np.ndarray, freq: float, seed: int, octaves: int = 3) -> np.ndarray:
    """Fractal sum of value noise in [0, 1)."""
    total, amp, norm = np.zeros(p.shape[0]), 1.0, 0.0
    for o in range(octaves):
        total += amp * value_noise(p * (freq * 2**o), seed + 101 * o)
        norm += amp
        amp *= 0.5
    return total / norm


def _cells(p: np.ndarray, freq: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Blocky cells (stones, pebbles): a random value per cell and the distance to the cell border (0..0.5)."""
    q = p * freq + 0.35 * (fbm(p, freq * 0.8, seed + 9, 2)[:, None] - 0.5)
    i = np.floor(q)
    f = q - i
    border = np.min(np.minimum(f, 1 - f), axis=1)
    return _hash01(i[:, 0], i[:, 1], i[:, 2], seed), border


# --------------------------------------------------------------------------------------- textures


def albedo(look: Look, p: np.ndarray, seed: int) -> np.ndarray:
    """Albedo [N, 3] in 0..1 of a part at local points p [N, 3] (metres)."""
    c = np.asarray(look.color)[None, :]
    n = p.shape[0]
    k = look.texture
    if n == 0:
        return np.zeros((0, 3))
    if k in ("wood", "bark"):
        # growth rings around a tilted axis, distorted by noise, plus fine fibre streaks along the axis
        rng = np.random.default_rng(seed)
        axis = np.array([1.0, 0.15, 0.1]) + 0.2 * rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        off = rng.uniform(-0.3, 0.3, 3)
        q = p + off
        along = q @ axis
        radial = np.linalg.norm(q - along[:, None] * axis, axis=1)
        ring = np.sin(2 * np.pi * (radial * 55 + 3.0 * fbm(p, 6.0, seed)))
        streak = fbm(np.stack([along * 4, radial * 300, radial * 300], 1), 1.0, seed + 3, 2)
        shade = 0.82 + 0.12 * ring + 0.12 * (streak - 0.5)
        if k == "bark":
            shade = 0.7 + 0.5 * (fbm(p, 40.0, seed, 3) - 0.5) + 0.15 * np.sin(2 * np.pi * p[:, 1] * 40)
        return c * shade[:, None]
    if k == "metal":  # brushed: anisotropic fine noise
        brush = fbm(p * np.array([3.0, 1.0, 60.0]), 40.0, seed, 2)
        return c * (0.93 + 0.12 * (brush - 0.5))[:, None] + 0.04 * (fbm(p, 8.0, seed + 1, 2) - 0.5)[:, None]
    if k == "glass":
        return c * (0.55 + 0.05 * fbm(p, 10.0, seed, 2))[:, None]
    if k in ("plastic", "rubber"):
        amp = 0.05 if k == "plastic" else 0.10
        return c * (1.0 + amp * (fbm(p, 30.0, seed, 3) - 0.5))[:, None]
    if k == "ceramic":
        speck = value_noise(p * 400.0, seed) > 0.93
        tone = 1.0 + 0.04 * (fbm(p, 12.0, seed + 2, 2) - 0.5)
        return c * (tone - 0.25 * speck)[:, None]
    if k in ("fabric", "carpet"):
        f = 180.0 if k == "fabric" else 90.0
        weave = 0.5 + 0.5 * np.sin(2 * np.pi * f * p[:, 0]) * np.sin(2 * np.pi * f * (p[:, 1] + p[:, 2]))
        pile = fbm(p, 60.0, seed, 3)
        return c * (0.85 + 0.12 * weave + 0.15 * (pile - 0.5))[:, None]
    if k == "leather":
        grain = fbm(p, 250.0, seed, 2)
        pores = (value_noise(p * 500.0, seed + 5) > 0.8) * 0.1
        return c * (0.9 + 0.2 * (grain - 0.5) - pores)[:, None]
    if k == "foam":
        return c * (1.0 - 0.25 * (value_noise(p * 300.0, seed) > 0.7))[:, None]
    if k == "cardboard":
        flutes = 0.5 + 0.5 * np.sin(2 * np.pi * 120 * (p[:, 0] + 0.3 * p[:, 1]))
        fibre = fbm(p, 80.0, seed, 3)
        return c * (0.9 + 0.05 * flutes + 0.15 * (fibre - 0.5))[:, None]
    if k == "paper":
        return c * (0.97 + 0.06 * (fbm(p, 120.0, seed, 2) - 0.5))[:, None]
    if k == "marble":
        vein = np.abs(np.sin(2 * np.pi * (p @ np.array([6.0, 3.0, 2.0]) + 4 * fbm(p, 5.0, seed, 4))))
        return c * (1.0 - 0.35 * (1 - vein) ** 8)[:, None]
    if k == "brick":
        row = np.floor(p[:, 2] / 0.065)
        col = np.floor(p[:, 0] / 0.21 + 0.5 * (row % 2))
        mortar = (np.abs((p[:, 2] / 0.065) - row - 0.5) > 0.42) | (np.abs(p[:, 0] / 0.21 + 0.5 * (row % 2) - col - 0.5) > 0.46)
        tone = 0.85 + 0.3 * _hash01(row, col, np.zeros_like(row), seed)
        out = c * tone[:, None]
        out[mortar] = np.array([0.72, 0.70, 0.66])
        return out
    if k == "gravel":
        val, border = _cells(p, 30.0, seed)
        tone = 0.65 + 0.6 * val
        gap = np.clip(border / 0.08, 0, 1)
        tint = 0.06 * (_hash01(np.floor(val * 1000), np.zeros(n), np.zeros(n), seed)[:, None] - 0.5)
        return (c * (tone * (0.45 + 0.55 * gap))[:, None]) + tint
    if k == "asphalt":
        speck = value_noise(p * 250.0, seed) > 0.85
        return c * (0.9 + 0.2 * (fbm(p, 40.0, seed + 1, 2) - 0.5) + 0.6 * speck)[:, None]
    if k == "sand":
        return c * (0.92 + 0.16 * (value_noise(p * 400.0, seed) - 0.5) + 0.1 * (fbm(p, 3.0, seed + 1, 2) - 0.5))[:, None]
    if k in ("soil", "mud"):
        clumps = fbm(p, 25.0, seed, 4)
        wet = 0.2 * (fbm(p, 2.5, seed + 4, 2) - 0.5) if k == "mud" else 0.0
        return c * (0.8 + 0.4 * (clumps - 0.5) - wet)[:, None]
    if k == "grass":
        blades = fbm(p * np.array([1.0, 1.0, 0.2]), 150.0, seed, 2)
        patches = fbm(p, 3.0, seed + 7, 3)
        col = c * (0.7 + 0.6 * (blades - 0.5))[:, None]
        dry = np.array([0.62, 0.58, 0.30])
        mix = np.clip((patches - 0.55) * 3.0, 0, 0.6)[:, None]
        return col * (1 - mix) + dry * mix * (0.8 + 0.4 * blades[:, None])
    # stone and anything else: multi-scale speckle
    return c * (0.88 + 0.2 * (fbm(p, 20.0, seed, 3) - 0.5) + 0.12 * (value_noise(p * 300.0, seed + 1) - 0.5))[:, None]


# ------------------------------------------------------------------------------ lighting and sky

LIGHT_DIR = np.array([0.45, 0.3, 0.84]) / np.linalg.norm([0.45, 0.3, 0.84])


def background(dirs: np.ndarray, env: str, seed: int) -> np.ndarray:
    """Environment colour [N, 3] for world ray directions [N, 3] (z up): a room or a sky with soft clutter.
    It depends on the direction only (an environment at infinity), so it is consistent across views."""
    z = dirs[:, 2:3]
    if env == "outdoor":
        sky = np.array([0.55, 0.70, 0.90]) * (1 - z.clip(0, 1)) * 0.4 + np.array([0.35, 0.55, 0.85]) * z.clip(0, 1)
        sky = sky + np.array([0.85, 0.88, 0.90]) * (1 - z.clip(0, 1)) ** 8 * 0.6
        ground = np.array([0.35, 0.38, 0.25])
        base = np.where(z > 0, sky, ground)
        palette = np.array([[0.30, 0.42, 0.22], [0.45, 0.50, 0.35], [0.25, 0.33, 0.20]])
        band = np.exp(-(z / 0.12) ** 2)  # tree line / hills near the horizon
    else:
        wall = np.array([0.78, 0.74, 0.68])
        floor = np.array([0.45, 0.40, 0.36])
        ceil = np.array([0.90, 0.89, 0.86])
        base = np.where(z < -0.1, floor, np.where(z > 0.6, ceil, wall))
        palette = np.array([[0.55, 0.45, 0.38], [0.40, 0.46, 0.52], [0.62, 0.60, 0.50]])
        band = np.exp(-((z - 0.1) / 0.35) ** 2)  # furniture and shelves around eye level
    n1 = fbm(dirs * 2.0 + 10.0, 1.0, seed, 3)
    n2 = fbm(dirs * 2.0 - 10.0, 1.0, seed + 1, 2)
    idx = np.minimum((n2 * 3 * 0.999).astype(int), 2)
    mask = np.clip((n1 - 0.45) * 4.0, 0.0, 1.0)[:, None] * band
    return base * (1 - 0.8 * mask) + palette[idx] * 0.8 * mask


def shade(alb: np.ndarray, look_spec: np.ndarray, look_shin: np.ndarray, look_refl: np.ndarray, normal: np.ndarray,
          view_dir: np.ndarray, env: str, seed: int) -> np.ndarray:
    """Lambert + hemisphere ambient + Blinn-Phong + Fresnel environment reflection.

    alb [N, 3]; per-pixel gloss arrays [N]; normal [N, 3] (flipped to face the viewer); view_dir [N, 3] =
    direction of the camera ray (towards the surface)."""
    v = -view_dir
    ndv = np.einsum("ij,ij->i", normal, v)
    normal = np.where((ndv < 0)[:, None], -normal, normal)
    ndv = np.abs(ndv)
    ndl = np.clip(normal @ LIGHT_DIR, 0.0, None)
    ambient = 0.28 + 0.14 * (normal[:, 2] + 1) / 2
    col = alb * (ambient + 0.72 * ndl)[:, None]
    h = LIGHT_DIR[None, :] + v
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    ndh = np.clip(np.einsum("ij,ij->i", normal, h), 0.0, 1.0)
    col += (look_spec * ndh**look_shin * (ndl > 0))[:, None]
    if np.any(look_refl > 0):
        refl_dir = view_dir + 2 * ndv[:, None] * normal
        fresnel = 0.2 + 0.8 * (1 - ndv) ** 5
        col += (look_refl * fresnel)[:, None] * background(refl_dir, env, seed)
    return np.clip(col, 0.0, 1.0)
