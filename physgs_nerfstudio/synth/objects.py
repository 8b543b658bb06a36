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

from ..errors import PhysGSError
from .draw import CANONICAL, Draw, MaterialDraw
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


class MissingMeshError(PhysGSError, FileNotFoundError):
    """A mesh the object needs (bunny.obj, armadillo.obj) is not in the mesh folder; the message names the flag."""


def mesh_file(mesh_dir: Path, file: str, needed_by: str) -> Path:
    """``mesh_dir/file``, or :class:`MissingMeshError` saying what needs it and which flag names its folder."""
    path = Path(mesh_dir) / file
    if not path.is_file():
        raise MissingMeshError(
            f"{path} not found: {needed_by} needs {file} (one of the Stanford meshes bunny.obj, armadillo.obj: "
            "data/sdf/ of NVlabs/instant-ngp); pass the folder that holds them with --mesh-dir DIR (physgs synth, "
            "physgs demo, benchmarks/mass_suite.py).")  # fmt: skip
    return path


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
    density_u: float | None = None  # where the true density lies in the material's range (None: typical)

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
        if self.density_u is not None and not 0.0 <= self.density_u <= 1.0:
            raise ValueError(f"{self.name}: density_u must lie in [0, 1], got {self.density_u}")

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
            self.object if obj is None else obj, self.density_u,
        )

    def describe(self) -> dict:
        drawn = {} if self.density_u is None else {"density_u": round(self.density_u, 12)}
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
            **drawn,
        }


def _p(name: str, prim: Primitive, material: str | MaterialDraw, z: float = 0.0, *, x: float = 0.0,
       y: float = 0.0, rot: np.ndarray | None = None, shell: float | None = None, open_ends: Sequence[str] = ()
       ) -> Part:  # fmt: skip
    mat, u = (material.name, material.density_u) if isinstance(material, MaterialDraw) else (material, None)
    return Part(
        name, prim, mat, "shell" if shell else "solid", shell, tuple(open_ends),
        np.eye(3) if rot is None else rot, np.array([x, y, z]), density_u=u,
    )


def _tube(d: Draw, r_out: float, height: float, wall: tuple[float, float], canonical: tuple[float, float]
          ) -> tuple[Tube, float]:  # fmt: skip
    """A tube of outer radius `r_out` and a wall drawn in `wall`; canonical: (inner radius, wall) as stated."""
    if d.canonical:
        r_in, t = canonical
    else:
        t = d.uniform(*wall, 0.0)
        r_in = r_out - t
    return Tube(r_out, r_in, height), t


# ---------------------------------------------------------------------------------------- objects
# Each preset is a parametric family: `d` draws its dimensions, counts, walls and materials (draw.py); the
# canonical draw (the default) is the fixed object that `physgs demo` and the tests use.

WOODS = ("oak", "pine", "maple", "walnut", "bamboo", "wood")
STEELS = ("steel", "stainless_steel", "aluminium", "chrome_plated")


def mug(d: Draw = CANONICAL) -> list[Part]:
    r, h = d.uniform(0.032, 0.052, 0.042), d.uniform(0.075, 0.125, 0.10)
    wall, bottom = d.uniform(0.003, 0.007, 0.005), d.uniform(0.005, 0.012, 0.008)
    minor = d.uniform(0.004, 0.008, 0.006)
    major = min(d.uniform(0.022, 0.034, 0.030), h / 2 - minor - 0.002)
    return [
        _p("body", Cup(r, h, wall, bottom), d.material(("ceramic", "porcelain", "terracotta"), "ceramic"), h / 2,
           shell=wall),
        # half ring in the xz plane, cut flush with the body's tangent plane x = r
        _p("handle", Half(Torus(major, minor), axis=0), d.material(("steel", "ceramic", "porcelain", "abs"), "steel"),
           h / 2, x=r, rot=rotation("x", 90)),
    ]


def chair(d: Draw = CANONICAL) -> list[Part]:
    leg_h, seat_t = d.uniform(0.38, 0.50, 0.44), d.uniform(0.018, 0.035, 0.025)
    sw, sd = d.uniform(0.36, 0.50, 0.44), d.uniform(0.36, 0.48, 0.42)
    back_h, back_t = d.uniform(0.25, 0.50, 0.40), d.uniform(0.015, 0.03, 0.02)
    wood = d.material(("oak", "pine", "plywood", "walnut", "mdf", "polypropylene"), "oak")
    parts = [
        _p("seat", Box((sw, sd, seat_t)), wood, leg_h + seat_t / 2),
        _p("back", Box((sw, back_t, back_h)), wood, d.derived(leg_h + seat_t + back_h / 2, leg_h + seat_t + 0.20),
           y=d.derived(-(sd - back_t) / 2, -0.20)),
    ]
    hollow = d.coin(0.5, True)
    r = d.uniform(0.010, 0.020, 0.012)
    lx, ly = d.uniform(0.7 * sw / 2, sw / 2 - r, 0.19), d.uniform(0.7 * sd / 2, sd / 2 - r, 0.18)
    leg_mat = d.material(STEELS[:3], "aluminium") if hollow else d.material(WOODS, "oak")
    for i, (sx, sy) in enumerate(((1, 1), (1, -1), (-1, 1), (-1, -1))):
        if hollow:
            tube, t = _tube(d, r, leg_h, (0.0015, 0.003), (0.010, 0.002))
            parts.append(_p(f"leg_{i}", tube, leg_mat, leg_h / 2, x=lx * sx, y=ly * sy, shell=t))
        else:
            parts.append(_p(f"leg_{i}", Cylinder(r, leg_h), leg_mat, leg_h / 2, x=lx * sx, y=ly * sy))
    return parts


def hammer(d: Draw = CANONICAL) -> list[Part]:
    length, hr = d.uniform(0.24, 0.38, 0.30), d.uniform(0.011, 0.017, 0.014)
    hl, hw = d.uniform(0.09, 0.16, 0.13), d.uniform(0.022, 0.036, 0.03)
    parts = [_p("handle", Cylinder(hr, length), d.material(WOODS[:5] + ("abs",), "oak"), length / 2)]
    if d.coin(0.7, True):
        gl = d.uniform(0.08, 0.14, 0.12)
        grip = Tube(d.derived(hr + d.uniform(0.002, 0.005, 0.0), 0.018), hr, gl)
        parts.append(_p("grip", grip, d.material(("natural_rubber", "rubber", "neoprene", "leather"), "natural_rubber"),
                        gl / 2))
    head_mat = d.material(("steel", "stainless_steel", "cast_iron", "brass", "natural_rubber"), "steel")
    parts.append(_p("head", Box((hl, hw, hw)), head_mat, d.derived(length + hw / 2, 0.315)))
    return parts


def bottle(d: Draw = CANONICAL) -> list[Part]:
    r, body_h, t = d.uniform(0.025, 0.045, 0.035), d.uniform(0.12, 0.24, 0.18), d.uniform(0.0015, 0.004, 0.003)
    sh, nr, nl = d.uniform(0.025, 0.05, 0.04), d.uniform(0.010, 0.016, 0.013), d.uniform(0.03, 0.07, 0.05)
    cr, ch = d.derived(nr + 0.002, 0.015), d.uniform(0.012, 0.025, 0.02)
    glass = d.material(("glass", "pet", "hdpe"), "glass")
    return [
        _p("body", Cylinder(r, body_h), glass, body_h / 2, shell=t, open_ends=("top",)),
        _p("shoulder", Frustum(r, nr, sh), glass, d.derived(body_h + sh / 2, 0.20), shell=t,
           open_ends=("top", "bottom")),
        _p("neck", Cylinder(nr, nl), glass, d.derived(body_h + sh + nl / 2, 0.245), shell=t,
           open_ends=("top", "bottom")),
        _p("cap", Cylinder(cr, ch), d.material(("polypropylene", "hdpe", "aluminium", "cork"), "polypropylene"),
           d.derived(body_h + sh + nl + ch / 2, 0.28)),
    ]


def shoe(d: Draw = CANONICAL) -> list[Part]:
    length, width, sole = d.uniform(0.22, 0.32, 0.28), d.uniform(0.08, 0.12, 0.10), d.uniform(0.015, 0.035, 0.025)
    ur = d.uniform(0.035, width / 2, 0.05)
    ul = d.derived(length - 2 * ur - d.uniform(0.0, 0.02, 0.0), 0.17)
    upper = d.material(("leather", "faux_leather", "polyester", "cotton", "nylon_fabric"), "leather")
    return [
        _p("sole", Box((length, width, sole)), d.material(("natural_rubber", "rubber", "eva"), "natural_rubber"),
           sole / 2),
        # half capsule along x, flat side down on the sole; the cut face is the open side of the shell
        _p("upper", Half(Capsule(ur, ul), axis=0, sign=-1.0), upper, sole, rot=rotation("y", 90),
           shell=d.uniform(0.0015, 0.004, 0.002)),
    ]


def table(d: Draw = CANONICAL) -> list[Part]:
    leg_h, top_t = d.uniform(0.65, 0.78, 0.72), d.uniform(0.018, 0.04, 0.025)
    tw, td = d.uniform(0.7, 1.4, 1.0), d.uniform(0.5, 0.9, 0.6)
    top = d.material(("oak", "pine", "walnut", "mdf", "plywood", "particleboard", "glass", "marble"), "oak")
    parts = [_p("top", Box((tw, td, top_t)), top, leg_h + top_t / 2)]
    hollow = d.coin(0.6, True)
    r = d.uniform(0.015, 0.03, 0.02)
    lx, ly = d.uniform(0.35 * tw, tw / 2 - r - 0.01, 0.45), d.uniform(0.3 * td, td / 2 - r - 0.01, 0.25)
    leg_mat = d.material(STEELS[:3], "steel") if hollow else d.material(WOODS, "oak")
    for i, (sx, sy) in enumerate(((1, 1), (1, -1), (-1, 1), (-1, -1))):
        if hollow:
            tube, t = _tube(d, r, leg_h, (0.0015, 0.003), (0.018, 0.002))
            parts.append(_p(f"leg_{i}", tube, leg_mat, leg_h / 2, x=lx * sx, y=ly * sy, shell=t))
        else:
            parts.append(_p(f"leg_{i}", Cylinder(r, leg_h), leg_mat, leg_h / 2, x=lx * sx, y=ly * sy))
    return parts


def pan(d: Draw = CANONICAL) -> list[Part]:
    r, h = d.uniform(0.09, 0.16, 0.13), d.uniform(0.035, 0.07, 0.05)
    wall, bottom = d.uniform(0.002, 0.006, 0.004), d.uniform(0.003, 0.008, 0.005)
    hl, hw, ht = d.uniform(0.12, 0.22, 0.18), d.uniform(0.02, 0.035, 0.03), d.uniform(0.015, 0.025, 0.022)
    metal = d.material(("cast_iron", "stainless_steel", "aluminium", "copper", "steel"), "cast_iron")
    return [
        _p("pan", Cup(r, h, wall, bottom), metal, h / 2, shell=wall),
        _p("handle", Box((hl, hw, ht)), d.material(("oak", "walnut", "abs", "stainless_steel", "silicone"), "oak"),
           d.derived(h - ht / 2 - 0.004, 0.035), x=r + hl / 2),
    ]


def lamp(d: Draw = CANONICAL) -> list[Part]:
    br, bh = d.uniform(0.06, 0.12, 0.09), d.uniform(0.012, 0.03, 0.02)
    pr, pl = d.uniform(0.007, 0.014, 0.01), d.uniform(0.30, 0.55, 0.40)
    pole, pt = _tube(d, pr, pl, (0.001, 0.003), (0.008, 0.002))
    bulb_r = d.uniform(0.022, 0.035, 0.03)
    bulb_z = d.derived(bh + pl + bulb_r, 0.45)
    rb = d.uniform(0.11, 0.19, 0.16)
    rt, sh = d.uniform(0.5 * rb, 0.8 * rb, 0.09), d.uniform(0.14, 0.24, 0.20)
    sw = d.uniform(0.001, 0.003, 0.002)
    base = d.material(("steel", "cast_iron", "marble", "oak", "brass"), "steel")
    return [
        _p("base", Cylinder(br, bh), base, bh / 2),
        _p("pole", pole, d.material(("brass", "steel", "aluminium", "chrome_plated"), "brass"),
           d.derived(bh + pl / 2, 0.22), shell=pt),
        _p("bulb", Sphere(bulb_r), "glass", bulb_z, shell=0.0008),
        _p("shade", Shade(rb, rt, sh, sw), d.material(("cotton", "polyester", "paper", "pvc"), "cotton"),
           d.derived(bulb_z - 0.05, 0.40), shell=sw),
    ]


def crate(d: Draw = CANONICAL) -> list[Part]:
    w, dp, h = d.uniform(0.25, 0.60, 0.40), d.uniform(0.20, 0.45, 0.30), d.uniform(0.15, 0.40, 0.25)
    mat = d.material(("cardboard", "plywood", "pine", "polypropylene", "hdpe"), "cardboard")
    return [_p("box", Box((w, dp, h)), mat, h / 2, shell=d.uniform(0.002, 0.012, 0.004),
               open_ends=d.choice(((), ("top",)), ()))]


def stool(d: Draw = CANONICAL) -> list[Part]:
    leg_h = d.uniform(0.35, 0.65, 0.45)
    sr, st = d.uniform(0.13, 0.21, 0.17), d.uniform(0.02, 0.045, 0.03)
    seat = d.material(("pine", "oak", "walnut", "polypropylene", "bamboo"), "pine")
    parts = [_p("seat", Cylinder(sr, st), seat, leg_h + st / 2)]
    lr = d.uniform(0.012, 0.022, 0.015)
    ring = d.uniform(0.55 * sr, sr - lr - 0.01, 0.12)
    legs = d.material(("pine", "oak", "steel", "aluminium"), "pine")
    n = d.integer(3, 4, 3)
    for i in range(n):
        a = 2 * math.pi * i / n
        parts.append(_p(f"leg_{i}", Cylinder(lr, leg_h), legs, leg_h / 2, x=ring * math.cos(a), y=ring * math.sin(a)))
    if d.coin(0.6, True):
        ft = d.uniform(0.005, 0.01, 0.007)
        parts.append(_p("footrest", Torus(d.derived(ring + lr + ft + 0.001, 0.145), ft),
                        d.material(("steel", "aluminium", "brass"), "steel"), d.derived(d.uniform(0.25, 0.5, 0.0) * leg_h, 0.18)))
    return parts


def dumbbell(d: Draw = CANONICAL) -> list[Part]:
    r_plate, bar_r = d.uniform(0.05, 0.12, 0.09), d.uniform(0.011, 0.016, 0.014)
    bar_l, grip_l = d.uniform(0.28, 0.42, 0.36), d.uniform(0.09, 0.13, 0.12)
    pt, per_side = d.uniform(0.02, 0.04, 0.03), d.integer(1, 2, 1)
    along_x = rotation("y", 90)
    parts = [
        _p("bar", Cylinder(bar_r, bar_l), d.material(("steel", "chrome_plated", "stainless_steel"), "steel"), r_plate,
           rot=along_x),
        _p("grip", Tube(d.derived(bar_r + d.uniform(0.003, 0.006, 0.0), 0.018), bar_r, grip_l),
           d.material(("natural_rubber", "neoprene", "rubber"), "natural_rubber"), r_plate, rot=along_x),
    ]
    plate = d.material(("cast_iron", "steel", "concrete"), "cast_iron")
    x0 = d.derived(grip_l / 2 + d.uniform(0.0, 0.02, 0.0) + pt / 2, 0.13)
    x0 = min(x0, bar_l / 2 - (per_side - 0.5) * pt)
    for k in range(2 * per_side):
        x = (x0 + (k // 2) * pt) * (1 if k % 2 == 0 else -1)
        parts.append(_p(f"plate_{k}", Tube(r_plate, bar_r, pt), plate, r_plate, x=x, rot=along_x))
    return parts


def vase(d: Draw = CANONICAL) -> list[Part]:
    r, h = d.uniform(0.04, 0.09, 0.06), d.uniform(0.15, 0.35, 0.25)
    wall, bottom = d.uniform(0.0025, 0.007, 0.004), d.uniform(0.005, 0.012, 0.008)
    mat = d.material(("porcelain", "ceramic", "glass", "terracotta"), "porcelain")
    return [_p("vase", Cup(r, h, wall, bottom), mat, h / 2, shell=wall)]


def _figurine(file: str, material: str, scale: float, mesh_dir: Path) -> list[Part]:
    path = mesh_file(mesh_dir, file, f"the {Path(file).stem} preset")
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
