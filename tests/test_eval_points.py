"""Friction / Shore hardness point annotations, sampled from exported fields; NeRF2Physics point predictions."""

import json
import math
from pathlib import Path
from statistics import NormalDist

import numpy as np
import pytest

from physgs_nerfstudio.eval.adapters import points
from physgs_nerfstudio.eval.command import EvalCommand, run_eval
from physgs_nerfstudio.eval.errors import EvalInputError
from physgs_nerfstudio.eval.sampling import PointField, VoxelField
from physgs_nerfstudio.materials import hardness

VS = 0.1
N = 4


def _centre(i, j, k):
    return [(i + 0.5) * VS, (j + 0.5) * VS, (k + 0.5) * VS]


MPU = 2.0  # metres per scene unit


def _grid(path: Path, hard_soft=60.0, hard_hard=120.0):
    """The export's voxel layout (export/voxel.py): friction = 0.2 + x (linear: trilinear is exact between
    centres) with variance 0.05^2; hardness A_eq by x half; one empty voxel."""
    c = (np.arange(N) + 0.5) * VS
    x = np.broadcast_to(c[:, None, None], (N, N, N))
    fr = 0.2 + x
    hd = np.where(x < 0.2, hard_soft, hard_hard)
    occ = np.ones((N, N, N), np.uint8)
    occ[0, 0, 0] = 0
    fr = np.where(occ > 0, fr, np.nan)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, origin_scene=np.zeros(3), voxel_size_scene=np.float64(VS), origin_m=np.zeros(3),
                        voxel_size_m=np.float64(VS * MPU), kinetic_friction_mean=fr.astype(np.float32),
                        kinetic_friction_total=np.full((N, N, N), 0.05**2, np.float32),
                        shore_hardness_mean=hd.astype(np.float32), occupancy=occ, meta=np.array("{}"))


def _annotations(tmp: Path) -> Path:
    pts = {"objects": {
        "shoe": {"scene": "scene1", "points": [
            {"id": "f1", "xyz": _centre(1, 1, 1), "property": "kinetic_friction", "value": 0.30},
            {"id": "f2", "xyz": [0.22, 0.17, 0.21], "property": "friction", "value": 0.50},
            {"id": "h1", "xyz": _centre(3, 2, 2), "property": "shore_hardness", "value": 70, "scale": "D"},
            {"id": "h2", "xyz": _centre(0, 2, 2), "property": "hardness", "value": 55, "scale": "A"},
            {"id": "out", "xyz": [5.0, 5.0, 5.0], "property": "kinetic_friction", "value": 0.4},
            {"id": "empty", "xyz": _centre(0, 0, 0), "property": "kinetic_friction", "value": 0.4},
        ]},
        "mug": {"points": [{"id": "px", "pixel": [3, 1], "property": "kinetic_friction", "value": 0.6}]},
    }}
    p = tmp / "points.json"
    p.write_text(json.dumps(pts))
    return p


def test_voxel_sampling_and_shore_scales(tmp_path):
    ann = _annotations(tmp_path)
    _grid(tmp_path / "results" / "scene1" / "export" / "grid.npz")
    mp = np.zeros((3, 5))
    mp[1, 3] = 0.55
    (tmp_path / "results" / "mug").mkdir()
    np.savez(tmp_path / "results" / "mug" / "canonical.npz", kinetic_friction=mp)
    result = run_eval(EvalCommand(dataset="points", ground_truth=ann, predictions=(str(tmp_path / "results"),)))
    rows = {r.item: r for r in result.items}
    assert rows["shoe/f1"].pred == pytest.approx(0.2 + 1.5 * VS, rel=1e-6)
    assert rows["shoe/f2"].pred == pytest.approx(0.2 + 0.22, rel=1e-6)  # trilinear on a linear field
    assert rows["shoe/f1"].distribution == "normal"
    assert rows["shoe/f1"].nll == pytest.approx(-math.log(NormalDist(0.2 + 1.5 * VS, 0.05).pdf(0.30)), rel=1e-5)
    # hardness: the export's A_eq compared in the reading's own scale
    assert rows["shoe/h1"].pred == pytest.approx(float(hardness.from_canonical(120.0, "D")))
    assert rows["shoe/h1"].scale == "D"
    assert rows["shoe/h2"].pred == pytest.approx(float(hardness.from_canonical(60.0, "A")))
    assert rows["shoe/h1"].ADE == pytest.approx(abs(70 - float(hardness.from_canonical(120.0, "D"))))
    assert rows["mug/px"].pred == pytest.approx(0.55)
    missing = {m.item: m.reason for m in result.missing}
    assert set(missing) == {"shoe/out", "shoe/empty"}
    assert "outside the exported field" in missing["shoe/out"]
    fr = next(a for a in result.aggregates if a.prop == "kinetic_friction" and a.group == "all")
    assert (fr.n_expected, fr.n_scored, fr.n_missing) == (5, 3, 2)
    assert {a.group for a in result.aggregates} == {"all", "shoe", "mug"}


def test_nearest_voxel_and_ply_nearest_gaussian(tmp_path):
    g = tmp_path / "grid.npz"
    _grid(g)
    s = VoxelField(g).sample(np.array([[0.22, 0.17, 0.21]]), "kinetic_friction", "nearest")
    assert s.mean[0] == pytest.approx(0.2 + 2.5 * VS)
    metres = VoxelField(g, "metres").sample(np.array([[0.22 * MPU, 0.17 * MPU, 0.21 * MPU]]), "kinetic_friction")
    assert metres.mean[0] == pytest.approx(0.2 + 0.22, rel=1e-6)
    from plyfile import PlyData, PlyElement

    v = np.array([(0, 0, 0, 0.3, 60.0), (1, 0, 0, 0.7, 110.0)],
                 dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("friction", "f4"), ("hardness", "f4")])
    ply = tmp_path / "g.ply"
    PlyData([PlyElement.describe(v, "vertex")]).write(str(ply))
    f = PointField(ply, max_distance=0.5)
    s = f.sample(np.array([[0.1, 0, 0], [0.9, 0, 0], [5, 5, 5]]), "kinetic_friction")
    assert s.mean[0] == pytest.approx(0.3) and s.mean[1] == pytest.approx(0.7) and np.isnan(s.mean[2])
    assert s.std is None
    # the export's PLY layout: <key>_mean / <key>_total (variance), positions in scene units + metres header
    v2 = np.array([(0, 0, 0, 0.3, 0.01), (1, 0, 0, 0.7, 0.04)],
                  dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("kinetic_friction_mean", "f4"),
                         ("kinetic_friction_total", "f4")])
    ply2 = tmp_path / "export.ply"
    PlyData([PlyElement.describe(v2, "vertex")], comments=["physgs " + json.dumps({"metres_per_unit": MPU})]).write(str(ply2))
    s2 = PointField(ply2, frame="metres").sample(np.array([[0.9 * MPU, 0, 0]]), "kinetic_friction")
    assert s2.mean[0] == pytest.approx(0.7) and s2.std[0] == pytest.approx(0.2)
    with pytest.raises(EvalInputError, match="metres_per_unit"):
        PointField(ply, frame="metres")


def test_world_frame_points_use_dataparser_transforms(tmp_path):
    """Annotations in the dataset frame are mapped to the export's scene frame: scale * (R x + t)."""
    ann = tmp_path / "pts.csv"
    # world point w maps to scene point s = 0.5 * (R w + t) with R = swap x/y, t = (0.1, 0, 0)
    s_target = np.array([0.25, 0.15, 0.15])
    R = np.array([[0, 1, 0], [1, 0, 0], [0, 0, 1]], float)
    t = np.array([0.1, 0.0, 0.0])
    w = R.T @ (s_target / 0.5 - t)
    ann.write_text("object,point,property,value,x,y,z\nobj,a,friction,0.4," + ",".join(map(str, w)) + "\n")
    _grid(tmp_path / "res" / "obj" / "grid.npz")
    (tmp_path / "res" / "obj" / "dataparser_transforms.json").write_text(
        json.dumps({"transform": np.c_[R, t].tolist(), "scale": 0.5}))
    ds = points.read_point_annotations(ann)
    (p,) = points.sample_export_predictions(ds, tmp_path / "res", frame="world")
    assert p.mean == pytest.approx(0.2 + s_target[0], rel=1e-6)
    (tmp_path / "res" / "obj" / "dataparser_transforms.json").unlink()
    with pytest.raises(EvalInputError, match="0 dataparser_transforms.json"):
        points.sample_export_predictions(ds, tmp_path / "res", frame="world")


def test_n2p_point_predictions_decode_shore_d_plus_100(tmp_path):
    ann = _annotations(tmp_path)
    ds = points.read_point_annotations(ann)
    pred = tmp_path / "n2p_hardness.json"
    pred.write_text(json.dumps({"shoe": {"h1": [160.0, 180.0], "h2": [50.0, 60.0]}}))
    preds = points.read_n2p_point_predictions(pred, ds)
    from physgs_nerfstudio.eval.scorer import score

    result = score(ds.measurements, preds)
    rows = {r.item: r for r in result.items}
    # 170 = Shore D 70 in NeRF2Physics' encoding -> compared in D: exactly the reading
    assert rows["shoe/h1"].pred == pytest.approx(70.0)
    assert rows["shoe/h1"].ADE == pytest.approx(0.0)
    assert rows["shoe/h1"].low == pytest.approx(60.0) and rows["shoe/h1"].high == pytest.approx(80.0)
    assert rows["shoe/h2"].pred == pytest.approx(55.0)
    assert rows["shoe/h2"].covered is True
    assert len(result.missing) == 5  # the friction points and the pixel point have no prediction here


def test_csv_annotations(tmp_path):
    p = tmp_path / "pts.csv"
    p.write_text("object,point,property,value,scale,x,y,z,u,v\n"
                 "cup,a,kinetic_friction,0.3,,0.1,0.1,0.1,,\n"
                 "cup,b,shore_hardness,40,D,,,,12,7\n")
    ds = points.read_point_annotations(p)
    assert [m.item for m in ds.measurements] == ["cup/a", "cup/b"]
    assert ds.queries[1].pixel == (12.0, 7.0) and ds.queries[1].view == "canonical"
    assert ds.measurements[1].scale == "D"


@pytest.mark.parametrize(
    "point, match",
    [
        ({"id": "h", "xyz": [0, 0, 0], "property": "shore_hardness", "value": 50},
         r"hardness reading without a scale"),
        ({"id": "h", "xyz": [0, 0, 0], "pixel": [1, 2], "property": "kinetic_friction", "value": 0.3},
         r"exactly one location"),
        ({"id": "h", "xyz": [0, 0], "property": "kinetic_friction", "value": 0.3}, r"xyz must have 3 numbers"),
        ({"id": "h", "xyz": [0, 0, 0], "property": "density", "value": 3}, r"not a point property"),
        ({"id": "h", "xyz": [0, 0, 0], "property": "shore_hardness", "value": 50, "scale": "Mohs"},
         r"unknown hardness scale 'Mohs'"),
    ],
)
def test_malformed_point_annotations(tmp_path, point, match):
    p = tmp_path / "bad.json"
    p.write_text(json.dumps({"objects": {"o": {"points": [point]}}}))
    with pytest.raises(EvalInputError, match=r"bad\.json, object 'o', point 0: .*" + match):
        points.read_point_annotations(p)


def test_malformed_csv_annotation_line(tmp_path):
    p = tmp_path / "bad.csv"
    p.write_text("object,point,property,value,x,y,z\ncup,a,friction,0.3,0,0,0\ncup,b,friction,slippery,0,0,0\n")
    with pytest.raises(EvalInputError, match=r"bad\.csv, line 3: value is not a number"):
        points.read_point_annotations(p)


def test_malformed_voxel_grid(tmp_path):
    g = tmp_path / "grid.npz"
    np.savez(g, voxel_size=np.array(0.1), kinetic_friction=np.zeros((2, 2, 2)))
    with pytest.raises(EvalInputError, match=r"grid\.npz, array 'origin_scene': missing"):
        VoxelField(g)
    np.savez(g, origin=np.zeros(3), voxel_size=np.array(0.1), density=np.zeros((2, 2, 2)))
    with pytest.raises(EvalInputError, match=r"no array for property 'kinetic_friction'"):
        VoxelField(g).sample(np.zeros((1, 3)), "kinetic_friction")
