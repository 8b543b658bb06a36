"""A family member posed on a support, as in a person's capture: the layouts of the mass benchmark.

`suite_layout(name, seed, ...)` builds one object of a family (:mod:`.families`; canonical or drawn from the seed),
turns it about z, rests it in a pose and puts a support under it:

* poses: ``standing`` (as the family builds it, resting on z = 0), ``lying`` (turned a quarter about y onto its
  side), ``stand`` (on a small round stand, a part of its own); ``drawn`` picks one of the family's poses.
* supports: ``floor`` (a wide slab of flooring, part "floor"), ``table`` (a table top, part "tabletop", narrower,
  so its edge is in view), ``none``
  (the object floats, as the presets always did); ``drawn`` picks floor or table. A support and a stand are parts
  with role ``ground`` and their own library material and texture: they are seen by the cameras and never part
  of the object's truth.

The draws of pose, support, turn and materials use a generator of their own (seed, family), so the same seed
gives the same object (:mod:`.draw`) in every placement.
"""

from __future__ import annotations

import zlib
from pathlib import Path

import numpy as np

from .families import FAMILIES, family_parts
from .geometry import Box, Cylinder
from .objects import DEFAULT_MESH_DIR, Layout, Part, rotation

SUPPORT_MATERIALS: dict[str, tuple[str, ...]] = {
    "floor": ("concrete", "laminated_flooring", "carpet", "marble", "granite", "oak"),
    "table": ("oak", "pine", "walnut", "mdf", "marble", "glass", "granite", "plywood"),
}
STAND_MATERIALS: tuple[str, ...] = ("oak", "marble", "walnut", "steel", "granite", "abs")
SUPPORTS: tuple[str, ...] = ("none", "floor", "table", "drawn")
POSES: tuple[str, ...] = ("standing", "lying", "stand", "drawn")
SUPPORTED_ELEVATION_DEG: tuple[float, float] = (10.0, 60.0)  # cameras above the support, as a person holds them
FLOATING_ELEVATION_DEG: tuple[float, float] = (-10.0, 60.0)  # the presets' band (they float)


def _surface_bounds(parts: list[Part], rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """World bounds of the parts' surfaces from surface samples (tighter than the boxes of rotated parts)."""
    pts = [p.to_world(p.primitive.sample_surface(4000, rng)[0]) for p in parts]
    allp = np.concatenate(pts)
    return allp.min(0), allp.max(0)


def _posed(parts: list[Part], pose: str, turn_deg: float, rng: np.random.Generator) -> list[Part]:
    """Parts turned about z; for ``lying`` also laid on their side, recentred on the z axis and resting on z = 0."""
    rot = rotation("z", turn_deg)
    if pose == "lying":
        rot = rot @ rotation("y", 90)
    moved = [p.placed(rot, (0.0, 0.0, 0.0)) for p in parts]
    if pose != "lying":
        return moved  # the family's own frame already rests on z = 0, centred on the z axis
    lo, hi = _surface_bounds(moved, rng)
    shift = np.array([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]])
    return [p.placed(np.eye(3), shift) for p in moved]


def _slab(name: str, side_x: float, side_y: float, thickness: float, material: str, z_top: float) -> Part:
    return Part(name, Box((side_x, side_y, thickness)), material, translation=np.array([0.0, 0.0, z_top - thickness / 2]),
                role="ground", object=name)  # fmt: skip


def suite_layout(name: str, seed: int, *, shape: str = "drawn", support: str = "drawn", pose: str = "drawn",
                 mesh_dir: Path = DEFAULT_MESH_DIR) -> Layout:  # fmt: skip
    """Layout of family `name` (module doc): ``shape`` canonical | drawn, ``support`` and ``pose`` as above."""
    if name not in FAMILIES:
        raise KeyError(f"unknown family {name!r}; families: {', '.join(FAMILIES)}")
    if shape not in ("canonical", "drawn") or support not in SUPPORTS or pose not in POSES:
        raise ValueError(f"shape must be canonical|drawn, support one of {SUPPORTS}, pose one of {POSES}; "
                         f"got {shape!r}, {support!r}, {pose!r}")  # fmt: skip
    fam = FAMILIES[name]
    rng = np.random.default_rng([int(seed), zlib.crc32(name.encode()), 71])
    if pose == "drawn":
        pose = fam.poses[int(rng.integers(len(fam.poses)))]
    if support == "drawn":
        support = ("floor", "table")[int(rng.integers(2))]
    turn = float(rng.uniform(0.0, 360.0)) if shape == "drawn" else 0.0
    obj = [p.placed(np.eye(3), (0.0, 0.0, 0.0), obj=name)
           for p in _posed(family_parts(name, None if shape == "canonical" else seed, mesh_dir), pose, turn, rng)]
    lo, hi = _surface_bounds(obj, rng)
    foot = float(max(hi[0] - lo[0], hi[1] - lo[1]))
    ground: list[Part] = []
    if pose == "stand":
        h = float(rng.uniform(0.015, 0.04))
        r = float(max(0.6 * foot, 0.03)) * float(rng.uniform(0.6, 0.9))
        mat = STAND_MATERIALS[int(rng.integers(len(STAND_MATERIALS)))]
        ground.append(Part("stand", Cylinder(r, h), mat, translation=np.array([0.0, 0.0, h / 2]), role="ground",
                           object="stand"))  # fmt: skip
        obj = [p.placed(np.eye(3), (0.0, 0.0, h)) for p in obj]
        lo, hi = lo + [0, 0, h], hi + [0, 0, h]
    if support != "none":
        mats = SUPPORT_MATERIALS[support]
        mat = mats[int(rng.integers(len(mats)))]
        side = max(0.6, (6.0 if support == "floor" else 2.5) * foot)
        aspect = 1.0 if support == "floor" else float(rng.uniform(0.6, 1.0))
        name_ = "floor" if support == "floor" else "tabletop"
        ground.append(_slab(name_, side, side * aspect, float(rng.uniform(0.02, 0.04)), mat, 0.0))
    framed = obj + [g for g in ground if g.object == "stand"]
    flo, fhi = _surface_bounds(framed, rng)
    center, radius = (flo + fhi) / 2, float(np.linalg.norm(fhi - flo) / 2)
    elevation = FLOATING_ELEVATION_DEG if support == "none" else SUPPORTED_ELEVATION_DEG
    return Layout(f"{name}:{pose}:{support}", "indoor", obj + ground, center, radius, elevation)
