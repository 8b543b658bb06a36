"""benchmarks/mass_suite.py's scoring: the exact three-factor error split, the support's counted mass from a voxel
grid through nerfstudio's dataparser transform, and the per-split summary."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from helpers.benchmarks import load_benchmark

from physgs_nerfstudio.synth.support import suite_layout

ms = load_benchmark("mass_suite.py", "mass_suite_bench")


def _gt(parts):
    return {"parts": parts, "total_mass_kg": sum(p["mass_kg"] for p in parts if p["role"] == "object")}


def test_the_error_split_multiplies_to_the_mass_ratio():
    gt = _gt([
        {"role": "object", "material": "ceramic", "volume_model": "shell", "volume_m3": 2e-4, "enclosed_volume_m3": 8e-4,
         "mass_kg": 0.46},
        {"role": "object", "material": "steel", "volume_model": "solid", "volume_m3": 1e-5, "enclosed_volume_m3": 1e-5,
         "mass_kg": 0.0785},
        {"role": "ground", "material": "oak", "volume_model": "solid", "volume_m3": 1.0, "mass_kg": 750.0},
    ])  # fmt: skip
    rep = {"mean_kg": 0.9, "geometry": {"volume_m3": 1.1e-3}, "parts": [
        {"material": "ceramic", "volume_m3": 9e-4, "area_m2": 0.05, "structure": {"p_hollow": 0.8, "thickness_m": 0.004}},
        {"material": "steel", "volume_m3": 2e-4, "area_m2": 0.01, "structure": {"p_hollow": 0.1, "thickness_m": 0.003}},
    ]}  # fmt: skip
    e = ms.error_split(gt, rep)
    assert e["volume"] * e["structure"] * e["density"] == pytest.approx(0.9 / (0.46 + 0.0785), rel=1e-12)
    assert e["volume"] == pytest.approx(1.1e-3 / 8.1e-4)
    pred_mat = 9e-4 * 0.2 + min(9e-4, 0.05 * 0.004) * 0.8 + 2e-4 * 0.9 + min(2e-4, 0.01 * 0.003) * 0.1
    assert e["structure"] == pytest.approx((pred_mat / 1.1e-3) / (2.1e-4 / 8.1e-4))
    assert e["structure_right"] == 1.0  # ceramic called hollow, steel solid


def test_support_mass_counts_the_voxels_inside_the_floor(tmp_path):
    layout = suite_layout("bowl", 5, support="floor", pose="standing")
    floor = next(p for p in layout.parts if p.object == "floor")
    # a grid in scene units: world = (scene / s - t) @ R with a rotation, a shift and a scale
    a = math.radians(30)
    R = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1.0]])
    t, s = np.array([0.1, -0.2, 0.05]), 2.5
    h_m = 0.01
    n = 20
    origin_world = np.array([-0.1, -0.1, -0.1])  # 20 voxels of 1 cm: z from -0.1 to 0.1, the floor's top at z = 0
    idx = np.indices((n, n, n)).reshape(3, -1).T
    world = origin_world + (idx + 0.5) * h_m
    assert np.allclose(ms._to_world(s * (world @ R.T + t), np.c_[R, t], s), world)  # the inverse of p_s = s (R p + t)
    # the grid itself, axis-aligned in scene units (R = identity in its dataparser transform)
    fill = np.ones((n, n, n), np.float32) * 0.5
    part_id = np.where(np.indices((n, n, n))[0] < n // 2, 0, 1).astype(np.int32)  # two parts: x below / above 0
    part_id[0, 0, 0] = -1  # a voxel of no part is left out
    run = tmp_path / "run"
    (run / "runs" / "x").mkdir(parents=True)
    (run / "runs" / "x" / "dataparser_transforms.json").write_text(json.dumps(
        {"transform": np.c_[np.eye(3), t].tolist(), "scale": s}))  # fmt: skip
    export = tmp_path / "export"
    export.mkdir()
    np.savez(export / "voxels.npz", fill=fill, part_id=part_id, origin_scene=s * (origin_world + t),
             voxel_size_scene=np.float64(s * h_m), voxel_size_m=np.float64(h_m), meta=np.array("{}"))
    rep_parts = [{"mass_mean_kg": 3.0}, {"mass_mean_kg": 0.2}]  # e.g. a solid part and a hollow one
    kg = ms.support_mass(run, export, layout.parts, rep_parts)
    below = (world[:, 2] < 0) & (world[:, 2] > -floor.primitive.size[2])  # voxel centres inside the slab
    pid = part_id.reshape(-1)
    assert below.sum() > 0
    share = [(below & (pid == p)).sum() / (pid == p).sum() for p in (0, 1)]
    assert kg == pytest.approx(3.0 * share[0] + 0.2 * share[1], rel=1e-9)
    assert ms.support_mass(run, tmp_path / "none", layout.parts, rep_parts) is None


def test_summary_per_split_and_renderer():
    def row(fam, truth, pred, lo, hi, counted, renderer="project"):
        return {"family": fam, "renderer": renderer, "truth_kg": truth, "pred_kg": pred, "covered": lo <= truth <= hi,
                "ape": abs(pred - truth) / truth, "half_width_rel": (hi - lo) / 2 / pred,
                "off_2x": pred > 2 * truth or pred < truth / 2, "support_counted": counted,
                "error": {"volume": pred / truth}}  # fmt: skip

    rows = [row("mug", 1.0, 1.1, 0.9, 1.3, False), row("chair", 2.0, 5.0, 4.0, 6.0, True),
            row("kettle", 1.0, 0.9, 0.5, 0.95, False), {"family": "jar", "renderer": "project", "failed": "demo: x"},
            row("jar", 1.0, 1.0, 0.8, 1.2, True, renderer="mitsuba")]  # fmt: skip
    summary = {(s["renderer"], s["split"]): s for s in ms.summarize(rows)}
    dev = summary[("project", "development")]
    assert dev["objects"] == 2 and dev["median_ape"] == pytest.approx((0.1 + 1.5) / 2)
    assert dev["coverage"] == 0.5 and dev["off_2x"] == 1 and dev["support_counted_share"] == 0.5
    held = summary[("project", "held_out")]
    assert held["objects"] == 1 and held["failed"] == 1 and held["coverage"] == 0.0
    assert summary[("mitsuba", "held_out")]["support_counted_share"] == 1.0
    text = ms.table(ms.summarize(rows), "baseline")
    assert len(text.splitlines()) == 2 + 3 and "held_out" in text  # header, rule, three groups


def test_the_suite_and_the_demo_pass_their_mesh_dir_to_the_scene(tmp_path):
    """--mesh-dir of the suite and of `physgs demo` is the folder the figurine and bunny scenes read their mesh from
    (an empty folder: the missing mesh is named inside it, before anything is rendered)."""
    from rich.console import Console

    from physgs_nerfstudio.demo import DemoCommand
    from physgs_nerfstudio.synth.objects import MissingMeshError

    empty = tmp_path / "meshes"
    empty.mkdir()
    with pytest.raises(MissingMeshError, match=f"^{empty}/(bunny|armadillo).obj not found"):
        ms.write_scene("figurine", 70001, "project", "none", tmp_path / "scene", 1, mesh_dir=empty)
    assert ms._args(["--mesh-dir", str(empty)]).mesh_dir == empty and ms._args([]).mesh_dir is None
    with pytest.raises(MissingMeshError, match=f"^{empty}/bunny.obj not found"):
        DemoCommand(output_dir=tmp_path / "demo", object="bunny", mesh_dir=empty).stage_scene(Console(quiet=True))
