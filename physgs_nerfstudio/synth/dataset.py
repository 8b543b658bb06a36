"""Write a generated scene as a nerfstudio dataset with ground truth (`generate_scene`).

Layout of the output directory (see docs/architecture.md, "Generated scenes")::

    transforms.json          fl_x fl_y cx cy w h, camera_model OPENCV (zero distortion), frames, ply_file_path
    points.ply               seed point cloud (surface samples + far background shell), with colours
    images/frame_00000.png   RGB
    gt/part/frame_00000.png      part id (1..P, 0 = background), 8-bit
    gt/material/frame_00000.png  index into ground_truth.json["materials"] + 1 (0 = background), 8-bit
    gt/depth/frame_00000.npy     float32 z-depth in metres (0 = background)
    ground_truth.json        parts, materials, volumes, masses, generator parameters

Every file is written to a temporary name and renamed; transforms.json and ground_truth.json come last, so a
directory holding them is complete. Output bytes depend only on the configuration (seed included).
"""

from __future__ import annotations

import io
import json
import math
import os
import shutil
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from PIL import Image

from ..materials import PROPERTY_KEYS, Material, load_library
from .appearance import albedo, background, part_look, shade, stable_seed
from .objects import DEFAULT_MESH_DIR, Layout, Part, all_names, build_layout
from .render import Intrinsics, orbit_poses, render_view

GENERATOR_VERSION = "1"


@dataclass
class SynthConfig:
    """A generated scene with known materials, written as a nerfstudio dataset."""

    out: Path = Path("synth_scene")
    """Output directory (the dataset root)."""
    object: str = "mug"
    """Object preset or scene layout (see `physgs_nerfstudio.synth.objects.all_names()`)."""
    views: int = 24
    """Number of camera views."""
    seed: int = 0
    """Seed of everything random (layout jitter, colours, textures, point cloud, camera azimuth)."""
    resolution: int = 128
    """Image width and height in pixels."""
    fov_deg: float = 50.0
    """Horizontal field of view."""
    radius: float | None = None
    """Camera distance from the look-at point in metres; None frames the object (see `fill`)."""
    fill: float = 0.85
    """With radius=None: the object's bounding sphere spans this fraction of the field of view."""
    elevation_deg: tuple[float, float] | None = None
    """Camera elevation band in degrees, e.g. (0, 60) for an upper hemisphere; None = the layout's default."""
    env: str | None = None
    """Material library ("indoor" | "outdoor"); None = the layout's own."""
    num_points: int = 20000
    """Seed points sampled on the surfaces (points.ply)."""
    background_points: int = 2000
    """Seed points on a far sphere carrying the environment's colour (0 = none)."""
    property_jitter: float = 0.0
    """0 = each material's true properties are the library's typical values; > 0 = drawn per material as
    typical * exp(jitter * N(0, 1)), clipped to the library range (the truth then differs from the prior)."""
    supersample: int = 1
    """RGB supersampling factor per axis (ground-truth maps are always sampled at pixel centres)."""
    mesh_dir: Path = DEFAULT_MESH_DIR
    """Where optional meshes (bunny.obj) are read from."""
    shape: Literal["canonical", "drawn"] = "canonical"
    """canonical: the object's fixed preset; drawn: a family member whose dimensions, parts, walls, materials and
    densities the seed draws (synth/families.py; families only)."""
    support: Literal["none", "floor", "table", "drawn"] = "none"
    """none (the object floats), floor, table, or drawn (floor or table from the seed): a support seen by the
    cameras (synth/support.py; families only)."""
    pose: Literal["standing", "lying", "stand", "drawn"] = "standing"
    """standing, lying (on its side), stand (on a small stand) or drawn (one of the family's poses)."""
    renderer: Literal["project", "mitsuba"] = "project"
    """project (the built-in ray caster) or mitsuba (path traced; needs the pathtrace extra, synth/pathtrace.py)."""
    spp: int = 64
    """Samples per pixel of the mitsuba renderer."""
    overwrite: bool = False
    """Replace an existing dataset in `out`."""


# ------------------------------------------------------------------------------------------- files


def _atomic_write(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _png(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(arr).save(buf, format="PNG", compress_level=6)
    return buf.getvalue()


def _npy(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=False)
    return buf.getvalue()


def _json(obj: object) -> bytes:
    return (json.dumps(obj, indent=2, sort_keys=False) + "\n").encode()


def ply_bytes(points: np.ndarray, colors: np.ndarray) -> bytes:
    """Binary little-endian PLY with float32 x y z and uchar red green blue."""
    n = points.shape[0]
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {n}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    ).encode()
    rec = np.zeros(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "u1"), ("g", "u1"), ("b", "u1")])
    rec["x"], rec["y"], rec["z"] = points[:, 0], points[:, 1], points[:, 2]
    rec["r"], rec["g"], rec["b"] = colors[:, 0], colors[:, 1], colors[:, 2]
    return header + rec.tobytes()


def _r(x: float, digits: int = 10) -> float:
    """Round for JSON: stable text, far below any tolerance that matters."""
    return float(f"{x:.{digits}g}")


# ----------------------------------------------------------------------------------------- scenes


@dataclass
class Scene:
    """A resolved layout: parts, their library materials and true property values."""

    layout: Layout
    materials: list[Material]  # used materials, in order of first use (ids 1..M)
    part_material: list[int]  # per part: index into `materials`
    properties: list[dict[str, float]]  # per material: true property values (canonical units)
    env: str = "indoor"
    part_seeds: list[int] = field(default_factory=list)


def scene_names() -> tuple[str, ...]:
    """Presets, scenes and object families (synth/families.py)."""
    from .families import FAMILIES

    return tuple(dict.fromkeys(all_names() + tuple(FAMILIES)))


def scene_layout(cfg: SynthConfig) -> Layout:
    """The preset or scene as it always was, or (shape, support or pose set) a family member on a support."""
    from .families import FAMILIES
    from .support import suite_layout

    if (cfg.shape, cfg.support, cfg.pose) == ("canonical", "none", "standing") and cfg.object in all_names():
        return build_layout(cfg.object, cfg.seed, cfg.mesh_dir)
    if cfg.object not in FAMILIES:
        raise KeyError(f"shape/support/pose apply to object families only, not {cfg.object!r}; families: "
                       f"{', '.join(FAMILIES)}")  # fmt: skip
    return suite_layout(cfg.object, cfg.seed, shape=cfg.shape, support=cfg.support, pose=cfg.pose,
                        mesh_dir=cfg.mesh_dir)  # fmt: skip


def part_density(part: Part, mat: Material, default: float) -> float:
    """A part's true density: log-uniform in its material's library range at ``part.density_u`` (a drawn family
    member, draw.py), else `default` (the material's, typical unless jittered)."""
    if part.density_u is None:
        return default
    pr = mat.properties["density"]
    return float(pr.low * (pr.high / pr.low) ** part.density_u)


def resolve_scene(cfg: SynthConfig) -> Scene:
    """Build the layout and bind each part to its library material (KeyError if a material is missing)."""
    if cfg.object not in scene_names():
        raise KeyError(f"unknown object or scene {cfg.object!r}; choose from: {', '.join(scene_names())}")
    layout = scene_layout(cfg)
    env = cfg.env or layout.env
    lib = load_library(env)
    materials: list[Material] = []
    part_material: list[int] = []
    for part in layout.parts:
        name = lib.resolve(part.material)
        if name is None:
            raise KeyError(
                f"part {part.object}/{part.name}: material {part.material!r} is not in the {env!r} library "
                f"({', '.join(lib.names)})"
            )
        mat = lib[name]
        if mat not in materials:
            materials.append(mat)
        part_material.append(materials.index(mat))
    rng = np.random.default_rng([cfg.seed, 11])
    properties = []
    for mat in materials:
        props = {}
        for key in PROPERTY_KEYS:
            pr = mat.properties[key]
            value = pr.typical
            if cfg.property_jitter > 0:
                value = float(np.clip(pr.typical * math.exp(cfg.property_jitter * rng.normal()), pr.low, pr.high))
            props[key] = value
        properties.append(props)
    seeds = [stable_seed(cfg.seed, i, p.object, p.name) for i, p in enumerate(layout.parts)]
    return Scene(layout, materials, part_material, properties, env, seeds)


def part_records(scene: Scene) -> list[dict]:
    records = []
    for i, part in enumerate(scene.layout.parts):
        m = scene.part_material[i]
        mat = scene.materials[m]
        volume = part.material_volume()
        density = part_density(part, mat, scene.properties[m]["density"])
        props = {**scene.properties[m], "density": density}
        rec = {"id": i + 1, **part.describe(), "material": mat.name, "material_id": m + 1}
        rec.update(
            volume_m3=_r(volume),
            enclosed_volume_m3=_r(part.enclosed_volume()),
            surface_area_m2=_r(part.primitive.surface_area()),
            density_kg_m3=_r(density),
            mass_kg=_r(density * volume),
            properties={k: _r(v) for k, v in props.items()},
        )
        records.append(rec)
    return records


def sample_points(scene: Scene, n_surface: int, n_background: int, center: np.ndarray, far: float,
                  seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Seed point cloud: `n_surface` points on the parts (by area, at least 32 per part) coloured with their
    albedo under the key light, plus `n_background` points on a sphere of radius `far` with the sky colour."""
    rng = np.random.default_rng([seed, 13])
    parts = scene.layout.parts
    areas = np.array([p.primitive.surface_area() for p in parts])
    counts = np.maximum(32, np.floor(n_surface * areas / areas.sum()).astype(int))
    pts, cols = [], []
    for i, (part, k) in enumerate(zip(parts, counts)):
        p_local, n_local = part.primitive.sample_surface(int(k), rng)
        look = _look(scene, i)
        alb = albedo(look, p_local, scene.part_seeds[i])
        nrm = part.dir_to_world(n_local)
        view = -nrm  # lit as if seen head-on
        col = shade(alb, np.zeros(len(alb)), np.ones(len(alb)), np.zeros(len(alb)), nrm, view, scene.env, seed)
        pts.append(part.to_world(p_local))
        cols.append(col)
    if n_background > 0:
        d = rng.normal(size=(n_background, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        pts.append(center + far * d)
        cols.append(background(d, scene.env, seed))
    p = np.concatenate(pts)
    c = np.clip(np.round(np.concatenate(cols) * 255), 0, 255).astype(np.uint8)
    return p, c


def _look(scene: Scene, i: int):
    mat = scene.materials[scene.part_material[i]]
    return part_look(mat.name, mat.category, mat.color, scene.part_seeds[i])


# ------------------------------------------------------------------------------------- generation


def _prepare_out(cfg: SynthConfig) -> Path:
    out = Path(cfg.out)
    if (out / "transforms.json").exists() or (out / "ground_truth.json").exists():
        if not cfg.overwrite:
            raise FileExistsError(f"{out} already holds a dataset; pass overwrite=True to replace it")
        for sub in ("images", "gt"):
            if (out / sub).is_dir():
                shutil.rmtree(out / sub)
        for name in ("transforms.json", "ground_truth.json", "points.ply"):
            (out / name).unlink(missing_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    return out


def _renderer(cfg: SynthConfig, scene: Scene, looks: list):
    """render(K, c2w, view_index) -> View with the configured renderer (module doc of render.py / pathtrace.py)."""
    parts, seeds = scene.layout.parts, scene.part_seeds
    if cfg.renderer == "project":
        return lambda K, c2w, v: render_view(parts, looks, seeds, K, c2w, scene.env, cfg.seed, cfg.supersample)
    if cfg.renderer != "mitsuba":
        raise ValueError(f"renderer must be 'project' or 'mitsuba', got {cfg.renderer!r}")
    from . import pathtrace

    why = pathtrace.available()
    if why is not None:
        raise RuntimeError(f"renderer mitsuba: {why}")
    tracer = pathtrace.PathTracer(parts, looks, seeds, scene.env, cfg.seed, max(0.002, scene.layout.radius / 60))
    return lambda K, c2w, v: tracer.view(K, c2w, cfg.spp, seed=int(stable_seed(cfg.seed, v) % 2**31))


def generate_scene(cfg: SynthConfig) -> Path:
    """Render `cfg` into a nerfstudio dataset directory and return its path."""
    if cfg.views < 1 or cfg.resolution < 8 or cfg.supersample < 1 or cfg.spp < 1:
        raise ValueError("need views >= 1, resolution >= 8, supersample >= 1 and spp >= 1")
    t_start = time.perf_counter()
    scene = resolve_scene(cfg)
    layout = scene.layout
    if len(layout.parts) > 255 or len(scene.materials) > 255:
        raise ValueError("8-bit label maps hold at most 255 parts and 255 materials")
    out = _prepare_out(cfg)

    K = Intrinsics.from_fov(cfg.resolution, cfg.resolution, cfg.fov_deg)
    half_fov = math.radians(cfg.fov_deg) / 2
    radius = cfg.radius if cfg.radius is not None else layout.radius / (math.sin(half_fov) * cfg.fill)
    elevation = cfg.elevation_deg or layout.elevation_deg
    az0 = float(np.random.default_rng([cfg.seed, 17]).uniform(0, 360))
    poses = orbit_poses(cfg.views, layout.center, radius, elevation, az0)

    looks = [_look(scene, i) for i in range(len(layout.parts))]
    part_to_material = np.array([0] + [m + 1 for m in scene.part_material], dtype=np.uint8)
    frames, gt_frames = [], []
    render = _renderer(cfg, scene, looks)
    for v, c2w in enumerate(poses):
        view = render(K, c2w, v)
        stem = f"frame_{v:05d}"
        paths = {
            "file_path": f"images/{stem}.png",
            "part_path": f"gt/part/{stem}.png",
            "material_path": f"gt/material/{stem}.png",
            "depth_path": f"gt/depth/{stem}.npy",
        }
        _atomic_write(out / paths["file_path"], _png(view.rgb))
        _atomic_write(out / paths["part_path"], _png(view.part.astype(np.uint8)))
        _atomic_write(out / paths["material_path"], _png(part_to_material[view.part]))
        _atomic_write(out / paths["depth_path"], _npy(view.depth))
        frames.append({"file_path": paths["file_path"], "transform_matrix": np.round(c2w, 12).tolist()})
        gt_frames.append(paths)

    pts, cols = sample_points(scene, cfg.num_points, cfg.background_points, layout.center, 4.0 * radius, cfg.seed)
    _atomic_write(out / "points.ply", ply_bytes(pts, cols))

    records = part_records(scene)
    transforms = {
        "camera_model": "OPENCV",
        "fl_x": K.fx, "fl_y": K.fy, "cx": K.cx, "cy": K.cy, "w": K.width, "h": K.height,
        "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
        "ply_file_path": "points.ply",
        "frames": frames,
    }
    objects: dict[str, dict] = {}
    for rec in records:
        if rec["role"] == "object":
            o = objects.setdefault(rec["object"], {"name": rec["object"], "part_ids": [], "mass_kg": 0.0})
            o["part_ids"].append(rec["id"])
            o["mass_kg"] += rec["mass_kg"]
    for o in objects.values():
        o["mass_kg"] = _r(o["mass_kg"])
    params = {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(cfg).items()}
    params.pop("out")
    params.pop("overwrite")
    params["mesh_dir"] = Path(cfg.mesh_dir).name  # no machine-specific paths in the truth file
    ground_truth = {
        "version": GENERATOR_VERSION,
        "generator": "physgs_nerfstudio.synth",
        "object": cfg.object,
        "layout": layout.name,
        "seed": cfg.seed,
        "env": scene.env,
        "parameters": params,
        "units": {"length": "m", "volume": "m^3", "mass": "kg", "density": "kg/m^3",
                  "shore_hardness": "A_eq (materials/hardness.py)", "youngs_modulus": "Pa"},
        "property_keys": list(PROPERTY_KEYS),
        "camera": {"center": np.round(layout.center, 9).tolist(), "radius": _r(radius),
                   "elevation_deg": list(elevation), "fov_deg": cfg.fov_deg},
        "materials": [
            {
                "id": m + 1,
                "name": mat.name,
                "category": mat.category,
                "color": list(mat.color),
                "thickness_m": mat.thickness_m,
                "properties": {k: _r(v) for k, v in scene.properties[m].items()},
                "library": {k: {"typical": pr.typical, "low": pr.low, "high": pr.high}
                            for k, pr in mat.properties.items()},
            }
            for m, mat in enumerate(scene.materials)
        ],
        "parts": records,
        "objects": list(objects.values()),
        "total_mass_kg": _r(sum(r["mass_kg"] for r in records if r["role"] == "object")),
        "frames": gt_frames,
    }
    _atomic_write(out / "ground_truth.json", _json(ground_truth))
    _atomic_write(out / "transforms.json", _json(transforms))
    generate_scene.last_seconds = time.perf_counter() - t_start  # type: ignore[attr-defined]
    return out


def load_ground_truth(path: Path) -> dict:
    """ground_truth.json of a generated dataset directory."""
    return json.loads((Path(path) / "ground_truth.json").read_text())
