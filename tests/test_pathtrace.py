"""Path-traced scenes (Mitsuba 3): meshes with the primitives' volumes, label maps and depth that agree with the
project's exact ray caster, shadows on the support, and the simulated VLM answering on the path-traced images."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from PIL import Image

from physgs_nerfstudio.synth import SynthConfig, generate_scene, load_ground_truth
from physgs_nerfstudio.synth.appearance import LIGHT_DIR
from physgs_nerfstudio.synth.dataset import scene_layout
from physgs_nerfstudio.synth.geometry import (
    Box,
    Capsule,
    Cup,
    Cylinder,
    Frustum,
    Half,
    Shade,
    Sphere,
    Torus,
    Tube,
)
from physgs_nerfstudio.synth.meshing import orient_faces, part_mesh
from physgs_nerfstudio.synth.render import Intrinsics, camera_rays, cast

PRIMS = [
    Box((0.3, 0.2, 0.1)), Sphere(0.1), Cylinder(0.05, 0.2), Frustum(0.1, 0.04, 0.15), Frustum(0.1, 0.0, 0.2),
    Capsule(0.03, 0.1), Torus(0.08, 0.02), Tube(0.05, 0.03, 0.1), Cup(0.04, 0.1, 0.008, 0.01),
    Shade(0.15, 0.08, 0.2, 0.01), Half(Capsule(0.05, 0.17), axis=0, sign=-1.0), Half(Torus(0.04, 0.01), axis=0),
    Half(Torus(0.04, 0.01), axis=1), Half(Sphere(0.1)),
]  # fmt: skip


def _why_no_mitsuba() -> str | None:
    try:
        from physgs_nerfstudio.synth.pathtrace import available
    except ImportError as err:
        return str(err)
    return available()


NO_MITSUBA = _why_no_mitsuba()
needs_mitsuba = pytest.mark.skipif(NO_MITSUBA is not None, reason=f"path tracer unavailable: {NO_MITSUBA}")


@pytest.mark.parametrize("prim", PRIMS, ids=lambda p: p.kind)
def test_meshes_enclose_the_primitives_volume(prim):
    v, n, f = part_mesh(prim, 0.004)
    mesh = trimesh.Trimesh(v, orient_faces(v, n, f), process=True)  # merges the bands' shared vertices
    assert mesh.volume == pytest.approx(prim.volume(), rel=0.012)
    # every vertex on the surface, its normal outward: just inside behind it, just outside in front of it
    inside = prim.contains(v - 5e-4 * n)
    outside = ~prim.contains(v + 5e-4 * n)
    assert inside.mean() > 0.9 and outside.mean() > 0.9  # (vertices on a crease carry one face's normal)


@needs_mitsuba
def test_path_traced_labels_and_depth_agree_with_the_ray_caster(tmp_path):
    cfg = {"object": "mug", "seed": 11, "shape": "drawn", "support": "floor", "pose": "standing", "views": 2,
           "resolution": 48, "num_points": 500}  # fmt: skip
    a = generate_scene(SynthConfig(out=tmp_path / "project", **cfg))
    b = generate_scene(SynthConfig(out=tmp_path / "mitsuba", renderer="mitsuba", spp=8, **cfg))
    gt = load_ground_truth(b)
    assert gt["parameters"]["renderer"] == "mitsuba"
    assert load_ground_truth(a)["parts"] == gt["parts"]  # the same layout and truth
    for fr in gt["frames"]:
        pa = np.asarray(Image.open(a / fr["part_path"]))
        pb = np.asarray(Image.open(b / fr["part_path"]))
        assert (pa == pb).mean() > 0.97  # tessellation moves only silhouette pixels
        assert len(np.unique(pb)) >= 3  # object parts and the floor
        da, db = np.load(a / fr["depth_path"]), np.load(b / fr["depth_path"])
        same = (pa == pb) & (pa > 0)
        assert np.median(np.abs(da[same] - db[same]) / da[same]) < 2e-3
        rgb_a = np.asarray(Image.open(a / fr["file_path"]), float)
        rgb_b = np.asarray(Image.open(b / fr["file_path"]), float)
        assert rgb_b.std() > 10 and np.abs(rgb_a - rgb_b).mean() > 3  # a different image of the same scene


@needs_mitsuba
def test_the_object_casts_a_shadow_on_the_support(tmp_path):
    """Floor pixels that the sun cannot see (a ray cast towards it hits the object: the project's exact caster) are
    darker in the path-traced image than the floor pixels it lights."""
    cfg = SynthConfig(out=tmp_path / "s", object="crate", seed=3, shape="drawn", support="floor", views=1,
                      resolution=64, elevation_deg=(30.0, 30.0), renderer="mitsuba", spp=16, num_points=500)
    out = generate_scene(cfg)
    gt = load_ground_truth(out)
    floor = next(p["id"] for p in gt["parts"] if p["object"] == "floor")
    fr = gt["frames"][0]
    c2w = np.array(json.loads((out / "transforms.json").read_text())["frames"][0]["transform_matrix"])
    K = Intrinsics.from_fov(64, 64, cfg.fov_deg)
    origins, dirs, zfac = camera_rays(K, c2w)
    depth = np.load(out / fr["depth_path"]).ravel()
    on_floor = np.asarray(Image.open(out / fr["part_path"])).ravel() == floor
    points = origins[on_floor] + dirs[on_floor] * (depth[on_floor] / zfac[on_floor])[:, None]
    parts = scene_layout(cfg).parts
    sun = np.broadcast_to(LIGHT_DIR, points.shape).copy()
    shadowed = cast(parts, points + 1e-4 * sun, sun).part >= 0
    assert shadowed.sum() >= 15 and shadowed.mean() < 0.6
    lum = (np.asarray(Image.open(out / fr["file_path"]).convert("L"), float).ravel()[on_floor] / 255) ** 2.2
    assert lum[shadowed].mean() < 0.6 * lum[~shadowed].mean()


@needs_mitsuba
def test_simulated_vlm_answers_on_a_path_traced_scene(tmp_path):
    from physgs_nerfstudio.perception import PerceptionConfig, run_perception
    from physgs_nerfstudio.perception.segment_builtin import BuiltinSegmenterConfig
    from physgs_nerfstudio.perception.simulated import SimulatedConfig

    out = generate_scene(SynthConfig(out=tmp_path / "s", object="pan", seed=2, shape="drawn", support="table",
                                     views=2, resolution=48, renderer="mitsuba", spp=8, num_points=500))  # fmt: skip
    res = run_perception(PerceptionConfig(data=out, vlm=SimulatedConfig(), segmenter=BuiltinSegmenterConfig(),
                                          progress=False))  # fmt: skip
    assert res.observations > 0
    names = {m["name"] for m in load_ground_truth(out)["materials"]}
    assert set(res.materials) & names
