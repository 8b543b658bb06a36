"""Object families of the mass benchmark: a builder per family whose seed varies the object, and the fixed split.

A family is a parametric builder ``build(draw) -> parts`` (:mod:`.draw`): the canonical draw is one fixed object,
a seeded draw varies its dimensions, proportions, part counts, wall thickness, hollow or solid, and each part's
material (among the family's plausible ones) and density (inside that material's library range). Today's twelve
presets (:mod:`.objects`) are families whose canonical draw is the preset; this module adds eleven more.

Every part's truth stays exact: its material volume is its primitive's closed form (:mod:`.geometry`), its
density the drawn one, its mass the product; parts of one object never overlap.

`DEVELOPMENT` and `HELD_OUT` fix which families may be looked at while choosing the method's defaults and which
only measure them; the held-out ones are all new shapes (the twelve presets had the defaults chosen on them).
`POSES` names the resting poses each family can take on a support (:mod:`.support`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from .draw import CANONICAL, Draw
from .geometry import Box, Cylinder, Frustum, Half, Mesh, Torus, Tube
from .objects import DEFAULT_MESH_DIR, OBJECTS, WOODS, Part, _p, mesh_file, rotation

Pose = str  # "standing" (as built) | "lying" (turned onto its side) | "stand" (on a small stand)


def bowl(d: Draw = CANONICAL) -> list[Part]:
    """A flared bowl: a frustum shell open at the top."""
    rt, h = d.uniform(0.06, 0.13, 0.09), d.uniform(0.04, 0.09, 0.06)
    rb = d.uniform(0.45 * rt, 0.75 * rt, 0.55 * 0.09)
    mat = d.material(("ceramic", "porcelain", "glass", "stainless_steel", "bamboo", "polypropylene"), "ceramic")
    return [_p("bowl", Frustum(rb, rt, h), mat, h / 2, shell=d.uniform(0.002, 0.006, 0.004), open_ends=("top",))]


def bucket(d: Draw = CANONICAL) -> list[Part]:
    """A tapered bucket (frustum shell, open top) with an arched handle over its rim."""
    rt, h = d.uniform(0.10, 0.16, 0.13), d.uniform(0.18, 0.30, 0.24)
    rb = d.uniform(0.75 * rt, 0.92 * rt, 0.85 * 0.13)
    minor = d.uniform(0.003, 0.006, 0.004)
    return [
        _p("pail", Frustum(rb, rt, h), d.material(("hdpe", "polypropylene", "steel", "aluminium"), "hdpe"), h / 2,
           shell=d.uniform(0.0008, 0.003, 0.002), open_ends=("top",)),
        # half ring in the xz plane above the rim (local y >= 0 is world z >= rim)
        _p("handle", Half(Torus(rt + minor + 0.002, minor), axis=1), d.material(("steel", "polypropylene"), "steel"),
           h, rot=rotation("x", 90)),
    ]


def kettle(d: Draw = CANONICAL) -> list[Part]:
    """A closed kettle body with a knob on its lid and a handle on its side."""
    r, h = d.uniform(0.07, 0.10, 0.085), d.uniform(0.14, 0.24, 0.18)
    body = d.material(("stainless_steel", "aluminium", "ceramic", "polypropylene"), "stainless_steel")
    wall = d.uniform(0.0008, 0.004, 0.0015)
    kr, kh = d.uniform(0.01, 0.02, 0.015), d.uniform(0.01, 0.025, 0.018)
    minor = d.uniform(0.006, 0.01, 0.008)
    major = min(d.uniform(0.04, 0.065, 0.05), h / 2 - minor - 0.005)
    return [
        _p("body", Cylinder(r, h), body, h / 2, shell=wall),
        _p("knob", Cylinder(kr, kh), d.material(("abs", "oak", "polypropylene"), "abs"), h + kh / 2),
        _p("handle", Half(Torus(major, minor), axis=0), d.material(("abs", "polypropylene", "oak"), "abs"), h / 2,
           x=r, rot=rotation("x", 90)),
    ]


def lidded_box(d: Draw = CANONICAL) -> list[Part]:
    """A box open at the top with a shallow lid (a box open at the bottom) resting on it."""
    w, dp, h = d.uniform(0.12, 0.40, 0.25), d.uniform(0.10, 0.30, 0.18), d.uniform(0.06, 0.22, 0.12)
    lid_h = d.uniform(0.015, 0.05, 0.03)
    t = d.uniform(0.002, 0.010, 0.004)
    mat = d.material(("cardboard", "plywood", "oak", "steel", "polypropylene", "hdpe"), "cardboard")
    lid = d.material(("cardboard", "plywood", "oak", "steel", "polypropylene", "hdpe"), "cardboard")
    return [
        _p("box", Box((w, dp, h)), mat, h / 2, shell=t, open_ends=("top",)),
        _p("lid", Box((w, dp, lid_h)), lid, h + lid_h / 2, shell=t, open_ends=("bottom",)),
    ]


def book(d: Draw = CANONICAL) -> list[Part]:
    """A block of pages, with hard covers and a spine or without."""
    w, dp, t = d.uniform(0.12, 0.30, 0.21), d.uniform(0.10, 0.22, 0.15), d.uniform(0.01, 0.06, 0.03)
    pages = d.material(("paper",), "paper")
    if not d.coin(0.6, True):
        return [_p("pages", Box((w, dp, t)), pages, t / 2)]
    c = d.uniform(0.0015, 0.004, 0.0025)
    cover = d.material(("cardboard", "leather", "paper"), "cardboard")
    return [
        _p("cover_bottom", Box((w, dp, c)), cover, c / 2),
        _p("pages", Box((w - c, dp, t)), pages, c + t / 2, x=c / 2),
        _p("cover_top", Box((w, dp, c)), cover, c + t + c / 2),
        _p("spine", Box((c, dp, t)), cover, c + t / 2, x=-(w - c) / 2),
    ]


def plank(d: Draw = CANONICAL) -> list[Part]:
    """A board of wood, lying on its widest face."""
    length, w, t = d.uniform(0.3, 1.2, 0.6), d.uniform(0.06, 0.25, 0.14), d.uniform(0.012, 0.05, 0.022)
    mat = d.material(WOODS + ("plywood", "mdf", "particleboard"), "pine")
    return [_p("board", Box((length, w, t)), mat, t / 2)]


def pipe(d: Draw = CANONICAL) -> list[Part]:
    """A length of pipe (a tube) lying along x."""
    r, length = d.uniform(0.01, 0.06, 0.025), d.uniform(0.2, 0.8, 0.5)
    wall = d.uniform(0.08 * r, 0.25 * r, 0.003)
    mat = d.material(("pvc", "steel", "copper", "aluminium", "hdpe", "cast_iron"), "pvc")
    return [_p("pipe", Tube(r, r - wall, length), mat, r, rot=rotation("y", 90))]


def bin_(d: Draw = CANONICAL) -> list[Part]:
    """A waste bin: a round or square shell open at the top."""
    h = d.uniform(0.25, 0.45, 0.32)
    t = d.uniform(0.0008, 0.004, 0.002)
    mat = d.material(("polypropylene", "steel", "stainless_steel", "aluminium", "hdpe"), "polypropylene")
    if d.coin(0.5, True):
        return [_p("bin", Cylinder(d.uniform(0.09, 0.16, 0.12), h), mat, h / 2, shell=t, open_ends=("top",))]
    side = d.uniform(0.18, 0.30, 0.24)
    return [_p("bin", Box((side, d.uniform(0.7, 1.0, 1.0) * side, h)), mat, h / 2, shell=t, open_ends=("top",))]


def toy_car(d: Draw = CANONICAL) -> list[Part]:
    """A toy car: a body, a cabin on top, four wheels against the body's sides."""
    bl, bw, bh = d.uniform(0.08, 0.20, 0.14), d.uniform(0.04, 0.08, 0.06), d.uniform(0.02, 0.04, 0.03)
    wr, ww = d.uniform(0.012, 0.025, 0.018), d.uniform(0.008, 0.016, 0.012)
    wr = min(wr, (bl / 2 - 0.006) / 2)  # a front and a rear wheel 2 mm apart at least: parts never overlap
    clear = d.uniform(0.3 * wr, 0.8 * wr, 0.5 * 0.018)
    cl, ch = d.uniform(0.4, 0.7, 0.55) * bl, d.uniform(0.5, 1.0, 0.8) * bh
    body = d.material(("abs", "oak", "aluminium", "steel", "polystyrene"), "abs")
    parts = [
        _p("body", Box((bl, bw, bh)), body, clear + bh / 2),
        _p("cabin", Box((cl, 0.85 * bw, ch)), d.material(("abs", "oak", "polycarbonate"), "abs"), clear + bh + ch / 2),
    ]
    tyre = d.material(("natural_rubber", "abs", "rubber"), "natural_rubber")
    along_y = rotation("x", 90)
    wx = bl / 2 - wr - 0.004
    for i, (sx, sy) in enumerate(((1, 1), (1, -1), (-1, 1), (-1, -1))):
        parts.append(_p(f"wheel_{i}", Cylinder(wr, ww), tyre, wr, x=sx * wx, y=sy * (bw + ww) / 2, rot=along_y))
    return parts


def jar(d: Draw = CANONICAL) -> list[Part]:
    """A jar (a cylinder shell open at the top) with a lid (a shallow cylinder shell open at the bottom)."""
    r, h = d.uniform(0.03, 0.07, 0.045), d.uniform(0.07, 0.18, 0.11)
    t = d.uniform(0.002, 0.005, 0.003)
    lid_h = d.uniform(0.01, 0.025, 0.015)
    return [
        _p("jar", Cylinder(r, h), d.material(("glass", "ceramic", "pet"), "glass"), h / 2, shell=t, open_ends=("top",)),
        _p("lid", Cylinder(r, lid_h), d.material(("steel", "aluminium", "polypropylene"), "steel"), h + lid_h / 2,
           shell=d.uniform(0.0005, 0.002, 0.001), open_ends=("bottom",)),
    ]


FIGURINE_MESHES: tuple[tuple[str, float], ...] = (("bunny.obj", 0.155), ("armadillo.obj", 0.2))  # file, ~height m


def figurine(d: Draw = CANONICAL, mesh_dir: Path = DEFAULT_MESH_DIR) -> list[Part]:
    """A solid figurine of one of the shared meshes (bunny, armadillo), scaled to a drawn size."""
    file, _ = d.choice(FIGURINE_MESHES, FIGURINE_MESHES[0])
    path = mesh_file(mesh_dir, file, "the figurine family")
    unit = Mesh(str(path), 1.0)
    height = d.uniform(0.08, 0.30, 0.15)
    mesh = Mesh(str(path), height / (2 * float(unit.half_extents()[1])))  # the shared meshes are y-up
    mat = d.material(("ceramic", "plaster", "porcelain", "bronze", "oak", "marble", "wax", "abs"), "ceramic")
    return [_p(Path(file).stem, mesh, mat, float(mesh.half_extents()[1]), rot=rotation("x", 90))]


@dataclass(frozen=True)
class Family:
    name: str
    build: Callable[..., list[Part]]
    poses: tuple[Pose, ...] = ("standing",)
    needs_meshes: bool = False

    def parts(self, d: Draw = CANONICAL, mesh_dir: Path = DEFAULT_MESH_DIR) -> list[Part]:
        return self.build(d, mesh_dir) if self.needs_meshes else self.build(d)


_ALL = ("standing", "lying", "stand")
FAMILIES: dict[str, Family] = {f.name: f for f in (
    Family("mug", OBJECTS["mug"], ("standing", "stand")),
    Family("chair", OBJECTS["chair"]),
    Family("hammer", OBJECTS["hammer"], ("lying",)),
    Family("bottle", OBJECTS["bottle"], _ALL),
    Family("shoe", OBJECTS["shoe"], ("standing",)),
    Family("table", OBJECTS["table"]),
    Family("pan", OBJECTS["pan"], ("standing",)),
    Family("lamp", OBJECTS["lamp"]),
    Family("crate", OBJECTS["crate"], ("standing",)),
    Family("stool", OBJECTS["stool"]),
    Family("dumbbell", OBJECTS["dumbbell"], ("standing",)),
    Family("vase", OBJECTS["vase"], ("standing", "stand")),
    Family("bowl", bowl, ("standing", "stand")),
    Family("bucket", bucket, ("standing",)),
    Family("book", book, ("standing", "stand")),
    Family("plank", plank, ("standing",)),
    Family("kettle", kettle, ("standing",)),
    Family("lidded_box", lidded_box, ("standing", "stand")),
    Family("pipe", pipe, ("standing",)),
    Family("bin", bin_, ("standing",)),
    Family("toy_car", toy_car, ("standing", "stand")),
    Family("jar", jar, ("standing", "lying", "stand")),
    Family("figurine", figurine, ("standing", "stand"), needs_meshes=True),
)}  # fmt: skip

# Defaults of the method may be chosen on DEVELOPMENT only; HELD_OUT measures them (all new shapes).
DEVELOPMENT: tuple[str, ...] = (
    "mug", "chair", "hammer", "bottle", "shoe", "table", "pan", "lamp", "crate", "stool", "dumbbell", "vase",
    "bowl", "bucket", "book", "plank",
)
HELD_OUT: tuple[str, ...] = ("kettle", "lidded_box", "pipe", "bin", "toy_car", "jar", "figurine")


def split_of(family: str) -> str:
    """ "development" or "held_out" (KeyError for a name in neither)."""
    if family in DEVELOPMENT:
        return "development"
    if family in HELD_OUT:
        return "held_out"
    raise KeyError(f"{family!r} is in neither split; families: {', '.join(FAMILIES)}")


def family_parts(name: str, seed: int | None, mesh_dir: Path = DEFAULT_MESH_DIR) -> list[Part]:
    """Parts of family `name` drawn from `seed` (None: its canonical draw), in the object's own frame."""
    if name not in FAMILIES:
        raise KeyError(f"unknown family {name!r}; families: {', '.join(FAMILIES)}")
    d = CANONICAL if seed is None else Draw.seeded(seed, name)
    return FAMILIES[name].parts(d, mesh_dir)

