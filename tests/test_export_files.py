"""Round trips of the exported files (PLY, voxel npz, report, maps) and the metric scale options."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from plyfile import PlyData

from physgs_nerfstudio.export.command import LoadedRun, run_export
from physgs_nerfstudio.export.maps import View
from physgs_nerfstudio.export.ply import read_ply_legend, write_property_ply
from physgs_nerfstudio.export.scale import resolve_scale
from physgs_nerfstudio.export.shapes import field_from, solid_box
from physgs_nerfstudio.export.voxel import load_voxel_grid, write_voxel_grid
from physgs_nerfstudio.geometry import GeometryConfig, reconstruct_object
from physgs_nerfstudio.geometry.capture import viewmat_from_c2w
from physgs_nerfstudio.mass import MassConfig


def _views(pf):
    from helpers.shapes import ring_views

    # the fixture is a sparse lattice of small Gaussians: its silhouettes come from the same lattice with
    # Gaussians as wide as the spacing (what training on images of the box would give)
    solid = replace(pf, scales=pf.scales * 4.0)
    return ring_views(pf, (0, 0, 0), 1.8, n=12, elevations=(-20.0, 30.0, 70.0), size=64, mask_pf=solid)


def _geometry(pf, resolution):
    cfg = GeometryConfig(resolution=resolution, backend="reference", variants=False)
    return reconstruct_object(pf, pf.pi(), _views(pf), (), list(pf.thickness_m), cfg, material_names=pf.material_names)


@pytest.fixture(scope="module")
def two_material_field():
    means, scales, quats = solid_box((0.6, 0.4, 0.3), 0.05)
    labels = (means[:, 0] > 0).long()
    pf = field_from(means, 0.5 * scales, quats, densities=[700.0, 2500.0], labels=labels,
                    thickness_m=[None, 0.003], names=["oak", "glass"], metres_per_unit=0.5)  # fmt: skip
    g = torch.Generator().manual_seed(0)
    pf.sh_rest = 0.1 * torch.randn(pf.num_gaussians, 3, 3, generator=g)  # SH degree 1
    pf.sh_dc = torch.randn(pf.num_gaussians, 3, generator=g)
    return pf


def test_ply_round_trip(two_material_field, tmp_path):
    pf = two_material_field
    path = write_property_ply(pf, tmp_path / "f.ply", top_k=2)
    ply = PlyData.read(str(path))
    v = ply["vertex"]
    names = set(v.data.dtype.names)
    splat = {"x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
             "rot_0", "rot_1", "rot_2", "rot_3"} | {f"f_rest_{i}" for i in range(9)}  # fmt: skip
    physgs = {"material_id", "material_index", "material_prob", "material_top0", "material_top1",
              "material_top0_prob", "material_top1_prob", "material_entropy", "alpha_sum"}  # fmt: skip
    props = {f"{k}_{f}" for k in pf.property_keys for f in ("mean", "aleatoric", "epistemic", "total")}
    assert splat | physgs | props <= names
    n = pf.num_gaussians
    assert len(v.data) == n
    np.testing.assert_allclose(np.stack([v["x"], v["y"], v["z"]], 1), pf.means.numpy(), rtol=0, atol=0)
    np.testing.assert_allclose(np.exp(np.stack([v[f"scale_{i}"] for i in range(3)], 1)), pf.scales.numpy(), rtol=1e-5)
    np.testing.assert_allclose(1 / (1 + np.exp(-v["opacity"])), pf.opacities.numpy(), rtol=1e-5)
    # f_rest is channel-major: f_rest_{c*R + j} = sh_rest[:, j, c]
    np.testing.assert_allclose(v["f_rest_4"], pf.sh_rest[:, 1, 1].numpy(), rtol=1e-6)
    labels = (pf.means[:, 0] > 0).numpy()
    assert (v["material_index"] == labels).all() and (v["material_id"] == labels + 1).all()
    fields = pf.fields()
    np.testing.assert_allclose(v["density_mean"], fields["mean"][:, 0].numpy(), rtol=1e-5)
    np.testing.assert_allclose(v["density_total"], fields["total"][:, 0].numpy(), rtol=1e-5)
    assert (v["material_top0_prob"] >= v["material_top1_prob"]).all()
    meta = read_ply_legend(path)
    assert [m["name"] for m in meta["legend"]] == ["oak", "glass"] and meta["legend"][1]["id"] == 2
    assert meta["metres_per_unit"] == 0.5 and meta["units"]["density"] == "kg/m^3"


def test_ply_opens_in_open3d(two_material_field, tmp_path):
    try:
        import open3d as o3d
    except Exception as err:  # noqa: BLE001 - e.g. libusb missing on headless machines
        pytest.skip(f"open3d is not importable here ({type(err).__name__}: {err})")
    path = write_property_ply(two_material_field, tmp_path / "f.ply")
    pcd = o3d.io.read_point_cloud(str(path))
    np.testing.assert_allclose(np.asarray(pcd.points), two_material_field.means.numpy(), atol=1e-6)


def test_voxel_grid_round_trip(two_material_field, tmp_path):
    pf = two_material_field
    path = write_voxel_grid(pf, tmp_path / "v.npz", _geometry(pf, 24))
    d = load_voxel_grid(path)
    shape = d["occupancy"].shape
    assert max(shape) <= 24 + 1 and d["material_prob"].shape == (*shape, 2)
    for k in pf.property_keys:
        assert d[f"{k}_mean"].shape == shape and d[f"{k}_total"].shape == shape
    occ = d["occupancy"].astype(bool)
    assert np.isfinite(d["density_mean"][occ]).all() and np.isnan(d["density_mean"][~occ]).all()
    assert d["meta"]["axis_order"] == "xyz" and d["meta"]["units"]["voxel_size_m"] == "m"
    assert float(d["voxel_size_m"]) == pytest.approx(0.5 * float(d["voxel_size_scene"]))
    # geometry as documented: the occupied voxels' centres span the box (scene units)
    idx = np.argwhere(occ)
    centres = d["origin_scene"] + (idx + 0.5) * float(d["voxel_size_scene"])
    np.testing.assert_allclose(centres.min(0), [-0.3, -0.2, -0.15], atol=0.12)  # carving from 12 views of a sparse lattice: a superset
    np.testing.assert_allclose(centres.max(0), [0.3, 0.2, 0.15], atol=0.12)  # carving from 12 views of a sparse lattice: a superset
    # material index follows the x split, density mean follows the material
    xs = centres[:, 0]
    mi = d["material_index"][occ]
    assert (mi[xs < -0.1] == 0).all() and (mi[xs > 0.1] == 1).all()
    dm = d["density_mean"][occ]
    assert np.median(dm[xs < -0.1]) == pytest.approx(700, rel=0.02)
    assert np.median(dm[xs > 0.1]) == pytest.approx(2500, rel=0.02)


def test_run_export_writes_everything(two_material_field, tmp_path):
    pf = two_material_field
    c2w = torch.tensor([[1.0, 0, 0, 0], [0, 0, -1, -2.0], [0, 1, 0, 0]])  # OpenGL camera on -y looking at +y
    view = View(viewmat_from_c2w(c2w), torch.tensor([[60.0, 0, 32], [0, 60.0, 24], [0, 0, 1]]), 64, 48, "front")
    mass = MassConfig(geometry=GeometryConfig(resolution=32, backend="reference", variants=False), n_samples=500)
    run = LoadedRun(pf, None, _views(pf), [], None)
    res = run_export(run, tmp_path, mass=mass, views=[view], truth_kg=1.0, quiet=True)
    for key in ("ply", "voxels", "maps", "report"):
        assert all(p.exists() for p in res.files[key]), key
    rep = json.loads((tmp_path / "report.json").read_text())
    assert rep["mass"]["mean_kg"] == pytest.approx(res.mass.mean_kg)
    assert rep["mass"]["units"]["mass"] == "kg" and rep["interval_covers_truth"] is False
    assert rep["mass"]["parts"] and rep["mass"]["geometry"]["num_parts"] == len(rep["mass"]["parts"])
    maps = np.load(tmp_path / "maps" / "maps_front.npz")
    m = maps["material"]
    cols = np.nonzero((m >= 0).any(0))[0]
    assert cols.size > 10  # the box is in view; left half oak (0), right half glass (1)
    assert (m[:, cols[:3]][m[:, cols[:3]] >= 0] == 0).all() and (m[:, cols[-3:]][m[:, cols[-3:]] >= 0] == 1).all()


def test_scale_options():
    assert resolve_scale(4.0, warn_if_assumed=False).metres_per_unit == pytest.approx(0.25)
    assert resolve_scale(4.0, scale=0.01).metres_per_unit == pytest.approx(0.0025)
    s = resolve_scale(2.0, known_length=(0, 0, 0, 3, 4, 0, 1.0))  # 5 dataset units = 1 m
    assert s.metres_per_unit == pytest.approx(1.0 / (5 * 2.0)) and s.source == "known_length"
    with pytest.raises(ValueError, match="coincide"):
        resolve_scale(1.0, known_length=(1, 1, 1, 1, 1, 1, 1.0))
    assert math.isclose(resolve_scale(1.0, scale=2.0, known_length=(0, 0, 0, 1, 0, 0, 3.0)).metres_per_unit, 3.0)


@pytest.mark.parametrize("weights", ["dominant", "predictive"])
def test_ply_material_prob_agrees_with_property_columns(tmp_path, weights):
    """One weighting per file: the PLY's material probabilities, mixed over the materials' own predictive
    means (an oracle independent of the writer's property code), give its property mean columns."""
    from dataclasses import replace

    means, scales, quats = solid_box((0.4, 0.3, 0.2), 0.05)
    pf = field_from(means, 0.5 * scales, quats, densities=[300.0, 1200.0, 5000.0], confidence=0.0)
    g = torch.Generator().manual_seed(1)
    # ambiguous posteriors, where dominance and alpha / sum(alpha) differ a lot
    pf = replace(pf, alpha=1.0 + 3.0 * torch.rand(pf.num_gaussians, 3, generator=g), material_weights=weights)
    path = write_property_ply(pf, tmp_path / "w.ply", top_k=3)
    v = PlyData.read(str(path))["vertex"]
    probs = np.zeros((len(v.data), 3))
    for j in range(3):
        probs[np.arange(len(v.data)), v[f"material_top{j}"]] = v[f"material_top{j}_prob"]
    np.testing.assert_allclose(probs.sum(1), 1.0, rtol=1e-5)
    np.testing.assert_array_equal(v["material_prob"], v["material_top0_prob"])
    m = pf.material_means().numpy()  # [K, P], linear units
    for p, key in enumerate(pf.property_keys):
        np.testing.assert_allclose(v[f"{key}_mean"], probs @ m[:, p], rtol=2e-4)
    assert read_ply_legend(path)["material_weights"] == weights
    # the two weightings really differ on this field, so the check above has teeth
    other = replace(pf, material_weights="predictive" if weights == "dominant" else "dominant")
    assert float((other.pi() - pf.pi()).abs().max()) > 0.05


def test_voxel_properties_mix_the_field_weights(two_material_field, tmp_path):
    """The voxel grid's property means are its own material_prob mixed over the materials' means."""
    path = write_voxel_grid(two_material_field, tmp_path / "v.npz", _geometry(two_material_field, 16))
    d = load_voxel_grid(path)
    solid = d["occupancy"].astype(bool)
    m = two_material_field.material_means().numpy()
    np.testing.assert_allclose(d["density_mean"][solid], d["material_prob"][solid] @ m[:, 0], rtol=2e-4)
