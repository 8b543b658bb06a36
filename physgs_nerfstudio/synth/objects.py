"""Parts, object presets (metric sizes, library materials) and scene layouts.

A `Part` is one primitive placed in the world with one material and a volume model:

* ``solid``: the material fills the primitive (`Primitive.volume`).
* ``shell``: a hollow part with wall thickness ``thickness_m``. For an open vessel (`Cup`, `Tube`,
  `Shade`) the primitive *is* the wall, so its wall must equal ``thickness_m`` and the material volume is
  the primitive's volume; for a closed envelope (box, cylinder, frustum, sphere, capsule, torus, half
  solids) the material volume is `Primitive.shell_volume(thickness_m, open_ends)`.

Objects are built in their own frame (z up, resting on z = 0, centred on the z axis); parts of one object
never overlap (they may touch), so the object's mass is the sum of its parts' masses. Frames are metres.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from .geometry import (
    Box,
    Capsule,
    Cup,
    Cylinder,
    Frustum,
    Half,
    Mesh,
    Primitive,
    Shade,
    Sphere,
    Torus,
    Tube,
    _Difference,
)

VolumeModel = Literal["solid", "shell"]
Role = Literal["object", "ground"]

DEFAULT_MESH_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data"


def rotation(axis: str, degrees: float) -> np.ndarray:
    """Rotation matrix about a coordinate axis ("x", "y" or "z")."""
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    if axis == "x":
        m = [[1, 0, 0], [0, c, -s], [0, s, c]]
    elif axis == "y":
        m = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    elif axis == "z":
        m = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    else:
        raise ValueError(f"axis must be x, y or z, got {axis!r}")
    r = np.array(m, dtype=float)
    r[np.abs(r) < 1e-15] = 0.0
    return r


@dataclass(frozen=True, eq=False)
class Part:
    name: str
    primitive: Primitive
    material: str
    volume_model: VolumeModel = "solid"
    thickness_m: float | None = None
    open_ends: tuple[str, ...] = ()
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    role: Role = "object"
    object: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "rotation", np.asarray(self.rotation, dtype=float).reshape(3, 3))
        object.__setattr__(self, "translation", np.asarray(self.translation, dtype=float).reshape(3))
        if self.volume_model not in ("solid", "shell"):
            raise ValueError(f"{self.name}: volume_model must be 'solid' or 'shell'")
        if self.volume_model == "shell":
            if self.thickness_m is None or self.thickness_m <= 0:
                raise ValueError(f"{self.name}: a shell part needs thickness_m > 0")
            wall = getattr(self.primitive, "wall", None)
            if isinstance(self.primitive, _Difference) and not math.isclose(wall, self.thickness_m, rel_tol=1e-9):
                raise ValueError(f"{self.name}: {self.primitive.kind} wall {wall} != thickness_m {self.thickness_m}")
        elif self.open_ends:
            raise ValueError(f"{self.name}: open_ends only apply to shell parts")

    # -- volumes -------------------------------------------------------------------------------
    def material_volume(self) -> float:
        """Volume of material in m^3 (closed form, see module docstring)."""
        if self.volume_model == "solid" or isinstance(self.primitive, _Difference):
            return self.primitive.volume()
        return self.primitive.shell_volume(float(self.thickness_m), self.open_ends)

    def outer(self) -> Primitive:
        """The solid bounded by the part's outer surface (a vessel's wall and its cavity), in the part's frame."""
        return self.primitive._outer() if isinstance(self.primitive, _Difference) else self.primitive

    def enclosed_volume(self) -> float:
        """Volume enclosed by the outer surface (cavities of open vessels included)."""
        return self.outer().volume()

    # -- frames --------------------------------------------------------------------------------
    def to_local(self, p: np.ndarray) -> np.ndarray:
        return (p - self.translation) @ self.rotation

    def dir_to_local(self, d: np.ndarray) -> np.ndarray:
        return d @ self.rotation

    def to_world(self, p: np.ndarray) -> np.ndarray:
        return p @ self.rotation.T + self.translation

    def dir_to_world(self, d: np.ndarray) -> np.ndarray:
        return d @ self.rotation.T

    def world_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        h = self.primitive.half_extents()
        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * h
        w = self.to_world(corners)
        return w.min(0), w.max(0)

    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        return self.translation.copy(), float(np.linalg.norm(self.primitive.half_extents()))

    def placed(self, rot: np.ndarray, trans: Sequence[float], obj: str | None = None) -> Part:
        """This part moved by world transform (rot, trans) applied after its own pose."""
        rot = np.asarray(rot, dtype=float)
        return Part(
            self.name, self.primitive, self.material, self.volume_model, self.thickness_m, self.open_ends,
            rot @ self.rotation, rot @ self.translation + np.asarray(trans, dtype=float), self.role,
            self.object if obj is None else obj,
        )

    def describe(self) -> dict:
        return {
            "name": self.name,
            "object": self.object,
            "role": self.role,
            "primitive": self.primitive.params(),
            "rotation": self.rotation.round(12).tolist(),
            "translation": self.translation.round(12).tolist(),
            "volume_model": self.volume_model,
            "thickness_m": self.thickness_m,
            "open_ends": list(self.open_ends),
        }


def _p(name: str, prim: Primitive, material: str, z: float = 0.0, *, x: float = 0.0, y: float = 0.0,
       rot: np.ndarray | None = None, shell: float | None = None, open_ends: Sequence[str] = ()) -> Part:
    return Part(
        name, prim, material, "shell" if shell else "solid", shell, tuple(open_ends),
        np.eye(3) if rot is None else rot, np.array([x, y, z]),
    )


# ---------------------------------------------------------------------------------------- objects


def mug() -> list[Part]:
    r, h = 0.042, 0.10
    return [
        _p("body", Cup(r, h, 0.005, 0.008), "ceramic", h / 2, shell=0.005),
        # half ring in the xz plane, cut flush with the body's tangent plane x = r
        _p("handle", Half(Torus(0.030, 0.006), axis=0), "steel", h / 2, x=r, rot=rotation("x", 90)),
    ]


def chair() -> list[Part]:
    leg_h, seat_t = 0.44, 0.025
    parts = [
        _p("seat", Box((0.44, 0.42, seat_t)), "oak", leg_h + seat_t / 2),
        _p("back", Box((0.44, 0.02, 0.40)), "oak", leg_h + seat_t + 0.20, y=-0.20),
    ]
    for i, (sx, sy) in enumerate(((1, 1), (1, -1), (-1, 1), (-1, -1))):
        parts.append(_p(f"leg_{i}", Tube(0.012, 0.010, leg_h), "aluminium", leg_h / 2, x=0.19 * sx, y=0.18 * sy,
                        shell=0.002))
    return parts


def hammer() -> list[Part]:
    return [
        _p("handle", Cylinder(0.014, 0.30), "oak", 0.15),
        _p("grip", Tube(0.018, 0.014, 0.12), "natural_rubber", 0.06),
        _p("head", Box((0.13, 0.03, 0.03)), "steel", 0.315),
    ]


def bottle() -> list[Part]:
    t = 0.003
    return [
        _p("body", Cylinder(0.035, 0.18), "glass", 0.09, shell=t, open_ends=("top",)),
        _p("shoulder", Frustum(0.035, 0.013, 0.04), "glass", 0.20, shell=t, open_ends=("top", "bottom")),
        _p("neck", Cylinder(0.013, 0.05), "glass", 0.245, shell=t, open_ends=("top", "bottom")),
        _p("cap", Cylinder(0.015, 0.02), "polypropylene", 0.28),
    ]


def shoe() -> list[Part]:
    sole = 0.025
    return [
        _p("sole", Box((0.28, 0.10, sole)), "natural_rubber", sole / 2),
        # half capsule along x, flat side down on the sole; the cut face is the open side of the shell
        _p("upper", Half(Capsule(0.05, 0.17), axis=0, sign=-1.0), "leather", sole, rot=rotation("y", 90),
           shell=0.002),
    ]


def table() -> list[Part]:
    leg_h, top_t = 0.72, 0.025
    parts = [_p("top", Box((1.0, 0.6, top_t)), "oak", leg_h + top_t / 2)]
    for i, (sx, sy) in enumerate(((1, 1), (1, -1), (-1, 1), (-1, -1))):
        parts.append(_p(f"leg_{i}", Tube(0.02, 0.018, leg_h), "steel", leg_h / 2, x=0.45 * sx, y=0.25 * sy,
                        shell=0.002))
    return parts


def pan() -> list[Part]:
    r, h = 0.13, 0.05
    return [
        _p("pan", Cup(r, h, 0.004, 0.005), "cast_iron", h / 2, shell=0.004),
        _p("handle", Box((0.18, 0.03, 0.022)), "oak", 0.035, x=r + 0.09),
    ]


def lamp() -> list[Part]:
    return [
        _p("base", Cylinder(0.09, 0.02), "steel", 0.01),
        _p("pole", Tube(0.01, 0.008, 0.40), "brass", 0.22, shell=0.002),
        _p("bulb", Sphere(0.03), "glass", 0.45, shell=0.0008),
        _p("shade", Shade(0.16, 0.09, 0.20, 0.002), "cotton", 0.40, shell=0.002),
    ]


def crate() -> list[Part]:
    return [_p("box", Box((0.40, 0.30, 0.25)), "cardboard", 0.125, shell=0.004)]


def stool() -> list[Part]:
    leg_h = 0.45
    parts = [_p("seat", Cylinder(0.17, 0.03), "pine", leg_h + 0.015)]
    for i in range(3):
        a = 2 * math.pi * i / 3
        parts.append(_p(f"leg_{i}", Cylinder(0.015, leg_h), "pine", leg_h / 2, x=0.12 * math.cos(a),
                        y=0.12 * math.sin(a)))
    parts.append(_p("footrest", Torus(0.145, 0.007), "steel", 0.18))
    return parts


def dumbbell() -> list[Part]:
    r_plate, bar_r = 0.09, 0.014
    along_x = rotation("y", 90)
    return [
        _p("bar", Cylinder(bar_r, 0.36), "steel", r_plate, rot=along_x),
        _p("grip", Tube(0.018, bar_r, 0.12), "natural_rubber", r_plate, rot=along_x),
        _p("plate_0", Tube(r_plate, bar_r, 0.03), "cast_iron", r_plate, x=0.13, rot=along_x),
        _p("plate_1", Tube(r_plate, bar_r, 0.03), "cast_iron", r_plate, x=-0.13, rot=along_x),
    ]


def vase() -> list[Part]:
    return [_p("vase", Cup(0.06, 0.25, 0.004, 0.008), "porcelain", 0.125, shell=0.004)]


def _figurine(file: str, material: str, scale: float, mesh_dir: Path) -> list[Part]:
    path = Path(mesh_dir) / file
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found: this preset needs the shared mesh data")
    mesh = Mesh(str(path), scale)
    h = mesh.half_extents()  # the shared meshes are y-up: stand them up in a z-up world
    return [_p(Path(file).stem, mesh, material, h[1], rot=rotation("x", 90))]


def bunny(mesh_dir: Path = DEFAULT_MESH_DIR) -> list[Part]:
    """Solid ceramic Stanford bunny, 15 cm long (``bunny.obj`` in ``mesh_dir``, its holes capped)."""
    return _figurine("bunny.obj", "ceramic", 1.0, mesh_dir)


def armadillo(mesh_dir: Path = DEFAULT_MESH_DIR) -> list[Part]:
    """Solid plaster armadillo figurine, 33 cm tall (``armadillo.obj`` in ``mesh_dir``)."""
    return _figurine("armadillo.obj", "plaster", 0.2, mesh_dir)


MESH_OBJECTS: dict[str, Callable[[Path], list[Part]]] = {"bunny": bunny, "armadillo": armadillo}


OBJECTS: dict[str, Callable[[], list[Part]]] = {
    "mug": mug,
    "chair": chair,
    "hammer": hammer,
    "bottle": bottle,
    "shoe": shoe,
    "table": table,
    "pan": pan,
    "lamp": lamp,
    "crate": crate,
    "stool": stool,
    "dumbbell": dumbbell,
    "vase": vase,
}

SUITE: tuple[str, ...] = (
    "mug", "chair", "hammer", "bottle", "shoe", "table", "pan", "lamp", "crate", "stool", "dumbbell", "vase",
)


def build_object(name: str, *, rot_z_deg: float = 0.0, at: Sequence[float] = (0.0, 0.0, 0.0),
                 instance: str | None = None) -> list[Part]:
    """Parts of preset `name`, turned about z and moved to `at`, tagged with the instance name."""
    if name not in OBJECTS:
        raise KeyError(f"unknown object {name!r}; presets: {', '.join(OBJECTS)}")
    tag = instance or name
    return [p.placed(rotation("z", rot_z_deg), at, obj=tag) for p in OBJECTS[name]()]


# ----------------------------------------------------------------------------------------- layouts


@dataclass(eq=False)
class Layout:
    """Everything the renderer needs to know about a scene besides materials' appearance."""

    name: str
    env: str  # material library ("indoor" | "outdoor") and background style
    parts: list[Part]
    center: np.ndarray  # where the cameras look
    radius: float  # radius of the region the cameras frame
    elevation_deg: tuple[float, float]  # default camera elevation range


def _frame(parts: Sequence[Part]) -> tuple[np.ndarray, float]:
    objs = [p for p in parts if p.role == "object"] or list(parts)
    lo = np.min([p.world_bounds()[0] for p in objs], axis=0)
    hi = np.max([p.world_bounds()[1] for p in objs], axis=0)
    return (lo + hi) / 2, float(np.linalg.norm(hi - lo) / 2)


def _ground(name: str, size_x: float, size_y: float, material: str, x: float = 0.0, y: float = 0.0,
            thickness: float = 0.05) -> Part:
    return Part(name, Box((size_x, size_y, thickness)), material, translation=np.array([x, y, -thickness / 2]),
                role="ground", object="ground")


def indoor_room(rng: np.random.Generator) -> Layout:
    """A floor with a rug, a table with a mug and a bottle, a chair, a crate and a lamp."""
    turn = lambda: float(rng.uniform(-15, 15))
    parts = [_ground("floor", 3.2, 3.2, "laminated_flooring", thickness=0.02)]
    rug = Part("rug", Box((1.6, 1.56, 0.008)), "carpet", translation=np.array([0.0, -0.22, 0.004]),
               role="ground", object="rug")
    parts.append(rug)
    top = 0.008
    parts += build_object("table", rot_z_deg=turn(), at=(0.0, 0.0, top))
    table_top = top + 0.745
    parts += build_object("mug", rot_z_deg=float(rng.uniform(0, 360)), at=(0.2, 0.1, table_top))
    parts += build_object("bottle", at=(-0.25, -0.05, table_top))
    parts += build_object("chair", rot_z_deg=turn(), at=(0.05, -0.65, top))
    parts += build_object("crate", rot_z_deg=turn() + 20, at=(1.05, 0.6, 0.0))
    parts += build_object("lamp", at=(-1.0, 0.7, 0.0))
    center, radius = _frame([p for p in parts if p.role == "object"])
    return Layout("indoor_room", "indoor", parts, center, radius, (15.0, 60.0))


OUTDOOR_TERRAIN: tuple[str, ...] = ("grass", "gravel", "mud", "sand", "soil", "asphalt")


def _guillotine(rng: np.random.Generator, x0: float, y0: float, x1: float, y1: float, depth: int
                ) -> list[tuple[float, float, float, float]]:
    """Random axis-aligned partition of a rectangle into 2**depth rectangles."""
    if depth == 0:
        return [(x0, y0, x1, y1)]
    if (x1 - x0) >= (y1 - y0):
        s = float(rng.uniform(0.35, 0.65)) * (x1 - x0) + x0
        return _guillotine(rng, x0, y0, s, y1, depth - 1) + _guillotine(rng, s, y0, x1, y1, depth - 1)
    s = float(rng.uniform(0.35, 0.65)) * (y1 - y0) + y0
    return _guillotine(rng, x0, y0, x1, s, depth - 1) + _guillotine(rng, x0, s, x1, y1, depth - 1)


def outdoor_patch(rng: np.random.Generator, size: float = 4.0) -> Layout:
    """A square of terrain tiles (grass, gravel, mud, sand, soil, asphalt) with a few stones and a log,
    for friction and hardness maps."""
    rects = _guillotine(rng, -size / 2, -size / 2, size / 2, size / 2, 3)
    order = list(OUTDOOR_TERRAIN) + [str(m) for m in rng.choice(OUTDOOR_TERRAIN, len(rects) - len(OUTDOOR_TERRAIN))]
    order = [order[i] for i in rng.permutation(len(order))]
    parts = [
        _ground(f"tile_{i}", x1 - x0, y1 - y0, mat, x=(x0 + x1) / 2, y=(y0 + y1) / 2)
        for i, ((x0, y0, x1, y1), mat) in enumerate(zip(rects, order))
    ]
    for i in range(3):
        r = float(rng.uniform(0.08, 0.18))
        xy = rng.uniform(-size / 3, size / 3, 2)
        parts.append(Part(f"stone_{i}", Half(Sphere(r)), "rock", translation=np.array([*xy, 0.0]),
                          object=f"stone_{i}"))
    log_r, log_len = 0.07, 0.9
    parts.append(Part("log", Cylinder(log_r, log_len), "wood",
                      rotation=rotation("z", float(rng.uniform(0, 180))) @ rotation("y", 90),
                      translation=np.array([*rng.uniform(-size / 4, size / 4, 2), log_r]), object="log"))
    return Layout("outdoor_patch", "outdoor", parts, np.zeros(3), size * 0.45, (35.0, 70.0))


SCENES: dict[str, Callable[[np.random.Generator], Layout]] = {
    "indoor_room": indoor_room,
    "outdoor_patch": outdoor_patch,
}


def build_layout(name: str, seed: int = 0, mesh_dir: Path = DEFAULT_MESH_DIR) -> Layout:
    """Layout for an object preset (no floor, cameras around it) or a scene (``SCENES``)."""
    rng = np.random.default_rng([seed, 7])
    if name in SCENES:
        return SCENES[name](rng)
    if name in MESH_OBJECTS:
        parts = [p.placed(np.eye(3), (0, 0, 0), obj=name) for p in MESH_OBJECTS[name](mesh_dir)]
    else:
        parts = build_object(name)
    center, radius = _frame(parts)
    return Layout(name, "indoor", parts, center, radius, (-10.0, 60.0))


def all_names() -> tuple[str, ...]:
    return tuple(OBJECTS) + tuple(MESH_OBJECTS) + tuple(SCENES)
