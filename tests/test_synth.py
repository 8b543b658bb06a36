"""Generated scenes: exact volumes and masses, camera model, nerfstudio loading, determinism, speed."""

from __future__ import annotations

import hashlib
import json
import math
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from physgs_nerfstudio.materials import load_library
from physgs_nerfstudio.synth import SUITE, SynthCommand, SynthConfig, generate_scene, load_ground_truth
from physgs_nerfstudio.synth import dataset as synth_dataset
from physgs_nerfstudio.synth.geometry import (
    Box,
    Capsule,
    Cup,
    Cylinder,
    Frustum,
    Half,
    Mesh,
    Shade,
    Sphere,
    Torus,
    Tube,
    monte_carlo_volume,
)
from physgs_nerfstudio.synth.objects import DEFAULT_MESH_DIR, Layout, Part, build_layout, build_object
from physgs_nerfstudio.synth.render import Intrinsics, project

PRIMITIVES = [
    Box((0.3, 0.2, 0.1)),
    Sphere(0.1),
    Cylinder(0.05, 0.2),
    Frustum(0.1, 0.04, 0.15),
    Frustum(0.1, 0.0, 0.2),
    Capsule(0.03, 0.1),
    Torus(0.08, 0.02),
    Tube(0.05, 0.03, 0.1),
    Cup(0.04, 0.1, 0.008, 0.01),
    Shade(0.15, 0.08, 0.2, 0.01),
    Half(Capsule(0.05, 0.17), axis=2),
    Half(Torus(0.04, 0.01), axis=0, sign=-1.0),
]


@pytest.mark.parametrize("prim", PRIMITIVES, ids=lambda p: p.kind)
def test_closed_form_volume_matches_monte_carlo(prim):
    est, se = monte_carlo_volume(prim, 300_000, np.random.default_rng(1))
    assert abs(est - prim.volume()) < 4.5 * se + 1e-12, (est, prim.volume(), se)


@pytest.mark.parametrize("prim", PRIMITIVES, ids=lambda p: p.kind)
def test_rays_hit_the_surface_from_outside(prim):
    rng = np.random.default_rng(2)
    pts, nrm = prim.sample_surface(3000, rng)
    assert pts.shape == (3000, 3) and np.allclose(np.linalg.norm(nrm, axis=1), 1.0)
    d = -nrm + 0.3 * rng.normal(size=nrm.shape)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = pts - 1.0 * d
    hit = prim.intersect(o, d)
    assert np.all(np.isfinite(hit.t)) and np.all(hit.t <= 1.0 + 1e-9)  # the aimed-at point or an occluder
    p = o + hit.t[:, None] * d
    eps = 1e-6
    assert prim.contains(p + eps * d).mean() > 0.999  # entering the solid ...
    assert (~prim.contains(p - eps * d)).mean() > 0.999  # ... from outside
    assert np.einsum("ij,ij->i", hit.normal, d).max() <= 1e-9  # normals face the ray
    far = prim.intersect(pts + 1.0 * d, d)  # rays starting past the solid, pointing away: no hit
    assert not np.any(np.isfinite(far.t))


def _wall_mc(inside_env, distance_to_open_surface, half, t, n=400_000, seed=3):
    rng = np.random.default_rng(seed)
    p = (rng.random((n, 3)) * 2 - 1) * half
    in_wall = inside_env(p) & (distance_to_open_surface(p) < t)
    box = float(np.prod(2 * half))
    frac = in_wall.mean()
    return box * frac, box * math.sqrt(frac * (1 - frac) / n)


def test_shell_volumes_match_distance_to_boundary():
    """shell_volume = material within distance t of the outer surface (closed walls only), by Monte Carlo
    with an independent distance computation."""
    t = 0.02
    box = Box((0.3, 0.2, 0.12))
    h = box.half_extents()
    est, se = _wall_mc(box.contains, lambda p: np.min(h - np.abs(p), axis=1), h, t)
    assert abs(est - box.shell_volume(t)) < 4.5 * se

    cyl = Cylinder(0.1, 0.2)  # open top: the top face is not a wall
    dist = lambda p: np.minimum(0.1 - np.hypot(p[:, 0], p[:, 1]), p[:, 2] + 0.1)
    est, se = _wall_mc(cyl.contains, dist, cyl.half_extents(), t)
    assert abs(est - cyl.shell_volume(t, ("top",))) < 4.5 * se

    fr = Frustum(0.12, 0.05, 0.2)  # open at both ends: only the lateral wall
    k = fr.slope
    dist = lambda p: (fr.radius_at(p[:, 2]) - np.hypot(p[:, 0], p[:, 1])) / math.sqrt(1 + k * k)
    est, se = _wall_mc(fr.contains, dist, fr.half_extents(), t)
    assert abs(est - fr.shell_volume(t, ("top", "bottom"))) < 4.5 * se

    cap = Capsule(0.06, 0.15)
    dist = lambda p: 0.06 - np.hypot(np.hypot(p[:, 0], p[:, 1]), p[:, 2] - np.clip(p[:, 2], -0.075, 0.075))
    est, se = _wall_mc(cap.contains, dist, cap.half_extents(), t)
    assert abs(est - cap.shell_volume(t)) < 4.5 * se

    tor = Torus(0.1, 0.04)
    dist = lambda p: 0.04 - np.hypot(np.hypot(p[:, 0], p[:, 1]) - 0.1, p[:, 2])
    est, se = _wall_mc(tor.contains, dist, tor.half_extents(), t)
    assert abs(est - tor.shell_volume(t)) < 4.5 * se
    assert math.isclose(Sphere(0.1).shell_volume(t), 4 / 3 * math.pi * (0.1**3 - 0.08**3))


def test_closed_form_matches_trimesh_for_a_fine_cylinder():
    import trimesh

    mesh = trimesh.creation.cylinder(radius=0.05, height=0.2, sections=512)
    cyl = Cylinder(0.05, 0.2)
    assert math.isclose(mesh.volume, cyl.volume(), rel_tol=1e-4)
    assert math.isclose(mesh.area, cyl.surface_area(), rel_tol=1e-4)


def test_shell_part_checks_its_wall():
    with pytest.raises(ValueError, match="wall"):
        Part("body", Cup(0.04, 0.1, 0.005, 0.008), "ceramic", "shell", 0.004)
    with pytest.raises(ValueError, match="thickness"):
        Part("body", Cylinder(0.04, 0.1), "glass", "shell", None)


@pytest.mark.parametrize("name", SUITE)
def test_suite_masses_are_density_times_volume(name):
    cfg = SynthConfig(out=Path("unused"), object=name)
    scene = synth_dataset.resolve_scene(cfg)
    records = synth_dataset.part_records(scene)
    lib = load_library("indoor")
    total = 0.0
    for rec, part in zip(records, scene.layout.parts):
        rho = lib[rec["material"]].properties["density"].typical
        assert rec["density_kg_m3"] == pytest.approx(rho, rel=1e-12)
        assert rec["mass_kg"] == pytest.approx(rho * rec["volume_m3"], rel=1e-8)
        if rec["volume_model"] == "shell":
            assert rec["thickness_m"] > 0 and rec["volume_m3"] < rec["enclosed_volume_m3"]
        elif not isinstance(part.primitive, (Tube, Cup, Shade)):  # those are walls around a cavity
            assert rec["volume_m3"] == pytest.approx(rec["enclosed_volume_m3"], rel=1e-12)
        total += rec["mass_kg"]
    assert 0.1 <= total <= 20.0, f"{name}: implausible mass {total} kg"
    # parts of one object do not overlap (they may touch): Monte Carlo over the object's bounds
    parts = scene.layout.parts
    lo = np.min([p.world_bounds()[0] for p in parts], axis=0)
    hi = np.max([p.world_bounds()[1] for p in parts], axis=0)
    pts = lo + np.random.default_rng(4).random((200_000, 3)) * (hi - lo)
    inside = np.stack([p.primitive.contains(p.to_local(pts)) for p in parts])
    overlap = (inside.sum(0) > 1).mean() * float(np.prod(hi - lo))
    assert overlap <= 1e-3 * sum(p.material_volume() for p in parts)


def test_mug_volume_is_the_ceramic_wall():
    body = next(p for p in build_object("mug") if p.name == "body")
    r, h, t, b = 0.042, 0.10, 0.005, 0.008
    assert body.material_volume() == pytest.approx(math.pi * (r * r * h - (r - t) ** 2 * (h - b)), rel=1e-12)


def test_unknown_material_fails_loudly(monkeypatch):
    layout = Layout("x", "indoor", [Part("p", Sphere(0.1), "unobtainium")], np.zeros(3), 0.1, (0.0, 30.0))
    monkeypatch.setattr(synth_dataset, "build_layout", lambda *a, **k: layout)
    with pytest.raises(KeyError, match="unobtainium"):
        synth_dataset.resolve_scene(SynthConfig(out=Path("unused"), object="mug"))


# ------------------------------------------------------------------------------------------ datasets


@pytest.fixture(scope="module")
def crate_dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("synth") / "crate"
    t0 = time.perf_counter()
    generate_scene(SynthConfig(out=out, object="crate", views=24, resolution=128, elevation_deg=(20.0, 60.0)))
    return out, time.perf_counter() - t0


def test_24_views_at_128_take_a_few_seconds(crate_dataset):
    out, seconds = crate_dataset
    assert len(list((out / "images").glob("*.png"))) == 24
    assert seconds < 20.0, f"generation took {seconds:.1f} s"


def _camera(out: Path):
    tf = json.loads((out / "transforms.json").read_text())
    K = Intrinsics(tf["w"], tf["h"], tf["fl_x"], tf["fl_y"], tf["cx"], tf["cy"])
    return tf, K


def test_known_surface_point_lands_on_its_pixel_with_its_depth(crate_dataset):
    out, _ = crate_dataset
    tf, K = _camera(out)
    gt = load_ground_truth(out)
    assert tf["camera_model"] == "OPENCV" and tf["k1"] == tf["k2"] == tf["p1"] == tf["p2"] == 0.0
    top_centre = np.array([[0.0, 0.0, 0.25]])  # centre of the crate's lid (box 0.40 x 0.30 x 0.25 on z = 0)
    for frame, gtf in zip(tf["frames"], gt["frames"]):
        c2w = np.array(frame["transform_matrix"])
        uv, z = project(K, c2w, top_centre)
        u, v = int(np.floor(uv[0, 0])), int(np.floor(uv[0, 1]))
        depth = np.load(out / gtf["depth_path"])
        part = np.asarray(Image.open(out / gtf["part_path"]))
        assert part[v, u] == 1
        assert depth[v, u] == pytest.approx(z[0], rel=0.03)  # the lid is tilted: depth varies over a pixel
        # exactly: the ray through that pixel's centre meets the lid plane at the stored z-depth
        d = c2w[:3, :3] @ np.array([(u + 0.5 - K.cx) / K.fx, -(v + 0.5 - K.cy) / K.fy, -1.0])
        t = (0.25 - c2w[2, 3]) / d[2]  # with d's camera-z = -1, t is the z-depth
        hit = c2w[:3, 3] + t * d
        assert np.linalg.norm(hit - top_centre[0]) < 3 * z[0] / K.fx  # within a pixel or so of the point
        assert depth[v, u] == pytest.approx(t, rel=1e-6)


def test_depth_back_projects_onto_the_hit_part(crate_dataset):
    out, _ = crate_dataset
    tf, K = _camera(out)
    gt = load_ground_truth(out)
    part = build_layout("crate").parts[0]
    frame, gtf = tf["frames"][5], gt["frames"][5]
    c2w = np.array(frame["transform_matrix"])
    depth = np.load(out / gtf["depth_path"])
    v, u = np.nonzero(depth > 0)
    z = depth[v, u].astype(np.float64)
    cam = np.stack([(u + 0.5 - K.cx) / K.fx * z, -(v + 0.5 - K.cy) / K.fy * z, -z], 1)
    world = cam @ c2w[:3, :3].T + c2w[:3, 3]
    ray = world - c2w[:3, 3]
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    local = part.to_local(world)
    step = 1e-4  # float32 depth: ~1e-7 relative
    assert part.primitive.contains(part.to_local(world + step * ray)).mean() > 0.999
    assert (~part.primitive.contains(part.to_local(world - step * ray))).mean() > 0.999
    assert local.shape[0] > 500


def test_label_maps_agree(crate_dataset):
    out, _ = crate_dataset
    gt = load_ground_truth(out)
    lut = np.array([0] + [p["material_id"] for p in gt["parts"]])
    for f in gt["frames"][:4]:
        part = np.asarray(Image.open(out / f["part_path"]))
        mat = np.asarray(Image.open(out / f["material_path"]))
        depth = np.load(out / f["depth_path"])
        assert np.array_equal(mat, lut[part])
        assert np.array_equal(part > 0, depth > 0)
    assert gt["materials"][0]["name"] == "cardboard"
    assert gt["total_mass_kg"] == pytest.approx(sum(p["mass_kg"] for p in gt["parts"]))


def test_nerfstudio_parser_loads_and_cameras_look_at_the_object(crate_dataset):
    from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig

    out, _ = crate_dataset
    try:  # nerfstudio reads ply_file_path through open3d, which needs system libraries (libusb)
        import open3d  # noqa: F401

        with_points = True
    except ImportError:
        with_points = False
    outputs = NerfstudioDataParserConfig(data=out, load_3D_points=with_points).setup().get_dataparser_outputs("train")
    cams = outputs.cameras
    assert len(outputs.image_filenames) == cams.camera_to_worlds.shape[0] >= 20
    if with_points:
        assert outputs.metadata["points3D_xyz"].shape[0] > 1000
    T = outputs.dataparser_transform.numpy()
    centre = np.array([0.0, 0.0, 0.125])  # the crate's centre
    c = outputs.dataparser_scale * (T[:, :3] @ centre + T[:, 3])
    for i in range(cams.camera_to_worlds.shape[0]):
        c2w = np.eye(4)
        c2w[:3] = cams.camera_to_worlds[i].numpy()
        K = Intrinsics(int(cams.width[i]), int(cams.height[i]), float(cams.fx[i]), float(cams.fy[i]),
                       float(cams.cx[i]), float(cams.cy[i]))
        uv, z = project(K, c2w, c[None])
        assert z[0] > 0
        assert np.all(np.abs(uv[0] - [K.cx, K.cy]) < 0.1 * K.width), uv


def test_seed_point_cloud_is_on_the_surfaces(crate_dataset):
    from plyfile import PlyData

    out, _ = crate_dataset
    vertex = PlyData.read(str(out / "points.ply"))["vertex"]
    xyz = np.stack([vertex["x"], vertex["y"], vertex["z"]], 1).astype(np.float64)
    rgb = np.stack([vertex["red"], vertex["green"], vertex["blue"]], 1)
    assert xyz.shape[0] == 20000 + 2000 and rgb.dtype == np.uint8 and rgb.std() > 5
    surface = xyz[:20000]
    half = np.array([0.20, 0.15, 0.125])
    gap = np.min(np.abs(np.abs(surface - [0.0, 0.0, 0.125]) - half), axis=1)  # distance to the nearest face
    assert np.all(gap < 1e-6)


def _digest(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def test_same_seed_gives_identical_bytes(tmp_path):
    cfg = {"object": "mug", "views": 3, "resolution": 48, "num_points": 2000}
    a = generate_scene(SynthConfig(out=tmp_path / "a", seed=5, **cfg))
    b = generate_scene(SynthConfig(out=tmp_path / "b", seed=5, **cfg))
    c = generate_scene(SynthConfig(out=tmp_path / "c", seed=6, **cfg))
    da, db, dc = _digest(a), _digest(b), _digest(c)
    assert len(da) == 3 * 4 + 3 and da == db
    assert da["images/frame_00000.png"] != dc["images/frame_00000.png"]
    with pytest.raises(FileExistsError):
        generate_scene(SynthConfig(out=tmp_path / "a", seed=5, **cfg))


def test_scene_layouts_and_command(tmp_path, capsys):
    SynthCommand(out=tmp_path / "patch", object="outdoor_patch", views=2, resolution=32, num_points=500).main()
    gt = load_ground_truth(tmp_path / "patch")
    assert gt["env"] == "outdoor"
    terrain = {p["material"] for p in gt["parts"] if p["role"] == "ground"}
    assert {"grass", "gravel", "mud"} <= terrain
    assert gt["total_mass_kg"] == pytest.approx(sum(p["mass_kg"] for p in gt["parts"] if p["role"] == "object"))
    assert "outdoor_patch" in capsys.readouterr().out
    room = build_layout("indoor_room")
    assert {p.object for p in room.parts} >= {"table", "mug", "chair", "crate"}


@pytest.mark.skipif(not (DEFAULT_MESH_DIR / "bunny.obj").is_file(), reason="shared bunny mesh absent")
def test_bunny_mesh_is_closed_and_its_volume_checks_out():
    mesh = Mesh(str(DEFAULT_MESH_DIR / "bunny.obj"))
    assert mesh.mesh.is_watertight
    est, se = monte_carlo_volume(mesh, 60_000, np.random.default_rng(5))
    assert abs(est - mesh.volume()) < 4.5 * se
