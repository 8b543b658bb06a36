"""The simulator export (physgs_nerfstudio.sim): mass properties against analytic bodies, and the written files
opened by the simulators' own loaders (MuJoCo, yourdfpy, pxr) against the mass report."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from physgs_nerfstudio.sim.body import body_from_masses, elements, mass_carriers
from physgs_nerfstudio.sim.frame import ObjectFrame

IDENTITY = ObjectFrame(np.eye(3), np.zeros(3))


def _body(solid: np.ndarray, a: float, mass: float, wall: bool = False):
    """The body of one part of one material: the whole mass solid or on the walls."""
    parts = np.where(solid, 0, -1)
    mix = solid[..., None].astype(np.float64)
    fill = solid.astype(np.float32)
    se, we = elements(solid, parts, mix, fill, np.zeros(3), a, IDENTITY)
    masses = np.zeros((2, 1, 1))
    masses[1 if wall else 0, 0, 0] = mass
    return body_from_masses(masses, mass_carriers(se, we, 1)), se, we


def test_box_inertia_is_exact():
    a, (nx, ny, nz), rho = 0.01, (10, 6, 4), 1000.0
    solid = np.zeros((nx + 2, ny + 2, nz + 2), bool)
    solid[1:-1, 1:-1, 1:-1] = True
    X, Y, Z = nx * a, ny * a, nz * a
    M = rho * X * Y * Z
    b, _, _ = _body(solid, a, M)
    np.testing.assert_allclose(b.com_m, [(1 + nx / 2) * a, (1 + ny / 2) * a, (1 + nz / 2) * a], rtol=1e-12)
    want = M / 12 * np.diag([Y * Y + Z * Z, X * X + Z * Z, X * X + Y * Y])
    np.testing.assert_allclose(b.inertia, want, rtol=1e-9, atol=1e-15)


def test_box_shell_inertia_is_exact():
    """A hollow box: its mass on its six faces (thin plates), the analytic thin-walled box."""
    a, (nx, ny, nz) = 0.01, (10, 6, 4)
    solid = np.zeros((nx, ny, nz), bool)
    solid[:] = True
    X, Y, Z = nx * a, ny * a, nz * a
    M = 2.0
    b, _, _ = _body(solid, a, M, wall=True)
    area = 2 * (X * Y + Y * Z + X * Z)
    mz, mx, my = (M * s / area for s in (X * Y, Y * Z, X * Z))  # per face, normal along z, x, y
    Ixx = 2 * mz * (Y * Y / 12 + Z * Z / 4) + 2 * mx * (Y * Y + Z * Z) / 12 + 2 * my * (Z * Z / 12 + Y * Y / 4)
    Iyy = 2 * mz * (X * X / 12 + Z * Z / 4) + 2 * my * (X * X + Z * Z) / 12 + 2 * mx * (Z * Z / 12 + X * X / 4)
    Izz = 2 * mz * (X * X + Y * Y) / 12 + 2 * mx * (Y * Y / 12 + X * X / 4) + 2 * my * (X * X / 12 + Y * Y / 4)
    np.testing.assert_allclose(np.diag(b.inertia), [Ixx, Iyy, Izz], rtol=1e-9)
    assert np.abs(b.inertia - np.diag(np.diag(b.inertia))).max() < 1e-12


def test_hollow_cylinder_inertia():
    """A tube (inner radius r1, outer r2, height h) of voxels: I_zz = M (r1^2 + r2^2) / 2,
    I_xx = M (3 (r1^2 + r2^2) + h^2) / 12, within the voxels' staircase."""
    a, r1, r2, h, rho = 0.001, 0.02, 0.04, 0.06, 2700.0
    n = round(2 * r2 / a) + 2
    c = (np.arange(n) + 0.5) * a - n * a / 2
    x, y = np.meshgrid(c, c, indexing="ij")
    ring = (x * x + y * y <= r2 * r2) & (x * x + y * y >= r1 * r1)
    solid = np.repeat(ring[:, :, None], round(h / a), 2)
    M = rho * math.pi * (r2 * r2 - r1 * r1) * h
    b, _, _ = _body(solid, a, M)
    s = r1 * r1 + r2 * r2
    np.testing.assert_allclose(np.diag(b.inertia), [M * (3 * s + h * h) / 12, M * (3 * s + h * h) / 12, M * s / 2],
                               rtol=5e-3)  # fmt: skip
    np.testing.assert_allclose(b.com_m[:2], [n * a / 2, n * a / 2], atol=1e-9)


def test_rotated_frame_rotates_the_tensor():
    a, solid = 0.01, np.ones((6, 3, 2), bool)
    b0, _, _ = _body(solid, a, 1.0)
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # object x = scene y
    parts, mix = np.zeros(solid.shape, int), np.ones((*solid.shape, 1))
    se, we = elements(solid, parts, mix, solid.astype(np.float32), np.zeros(3), a, ObjectFrame(R, np.zeros(3)))
    b1 = body_from_masses(np.array([[[1.0]], [[0.0]]]), mass_carriers(se, we, 1))
    np.testing.assert_allclose(b1.inertia, R.T @ b0.inertia @ R, atol=1e-15)



def test_element_masses_keep_every_kilogram():
    """A core part enclosed by a shell part, both hollow and both solid, two materials: the elements carry the
    parts' masses exactly (the enclosed part's wall lies in its voxels: it has no face onto the outside)."""
    from physgs_nerfstudio.sim.body import element_masses

    solid = np.ones((8, 8, 8), bool)
    parts = np.zeros(solid.shape, int)
    parts[3:5, 3:5, 3:5] = 1
    mix = np.zeros((*solid.shape, 2))
    mix[..., 0] = 0.7
    mix[..., 1] = 0.3
    se, we = elements(solid, parts, mix, solid.astype(np.float32), np.zeros(3), 0.01, IDENTITY)
    masses = np.array([[[1.0, 0.5], [0.2, 0.1]], [[0.3, 0.0], [0.4, 0.6]]])  # [solid/wall, part, material]
    for e, m in ((se, masses[0]), (we, masses[1])):
        got = element_masses(e, m, 2)
        np.testing.assert_allclose(np.bincount(e.part, got, minlength=2), m.sum(1), rtol=1e-12)
    b = body_from_masses(masses, mass_carriers(se, we, 2))
    assert b.mass_kg == pytest.approx(masses.sum(), rel=1e-12)
    np.testing.assert_allclose(b.com_m, [0.04, 0.04, 0.04], atol=1e-12)  # everything symmetric about the centre

# ------------------------------------------------------------------ the written object
def _box_silhouette(view, half, step=0.01):
    """The exact mask of the box [-half, half] in ``view``: a dense lattice of its points projected (OpenCV)."""
    import torch

    axes = [torch.arange(-h, h + 1e-9, step) for h in half]
    p = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3).float()
    V = view.viewmat.float()
    c = p @ V[:3, :3].T + V[:3, 3]
    uv = c @ view.K.float().T
    u, w = (uv[:, 0] / uv[:, 2]).floor().long(), (uv[:, 1] / uv[:, 2]).floor().long()
    ok = (c[:, 2] > 0) & (u >= 0) & (u < view.width) & (w >= 0) & (w < view.height)
    mask = torch.zeros(view.height, view.width, dtype=torch.bool)
    mask[w[ok], u[ok]] = True
    return mask


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """A two-part box (oak and hollow glass halves) carved from 8 views' exact silhouettes, its mass report and its
    sim folder."""
    import torch
    from helpers.shapes import ring_views

    from physgs_nerfstudio.export.command import LoadedRun, run_export
    from physgs_nerfstudio.export.shapes import field_from, solid_box
    from physgs_nerfstudio.geometry import GeometryConfig
    from physgs_nerfstudio.mass import MassConfig, mass_draws
    from physgs_nerfstudio.sim import SimConfig

    means, scales, quats = solid_box((0.6, 0.4, 0.3), 0.05)
    labels = (means[:, 0] > 0).long()
    pf = field_from(means, 0.5 * scales, quats, densities=[700.0, 2500.0], labels=labels,
                    thickness_m=[None, 0.003], names=["oak", "glass"], metres_per_unit=0.5)  # fmt: skip
    mass = MassConfig(geometry=GeometryConfig(resolution=24, backend="reference", variants=False), n_samples=2000,
                      seed=1)  # fmt: skip
    out = tmp_path_factory.mktemp("sim") / "export"
    views = ring_views(pf.subset(torch.arange(1)), (0, 0, 0), 1.8, n=8, elevations=(-20.0, 50.0), size=40)
    for v in views:
        v.mask = _box_silhouette(v, (0.3, 0.2, 0.15))
    run = LoadedRun(pf, None, views, [], None)
    res = run_export(run, out, mass=mass, outputs=("mass", "sim"), quiet=True,
                     sim=SimConfig(samples=32, collision="hull"))  # fmt: skip
    draws = mass_draws(pf, res.geometry, mass)
    return {"pf": pf, "res": res, "dir": out / "sim", "report": res.mass, "draws": draws, "run": run, "mass": mass,
            "manifest": json.loads((out / "sim" / "manifest.json").read_text())}  # fmt: skip


def _tensor_from_principal(moments, R) -> np.ndarray:
    return R @ np.diag(moments) @ R.T


def test_manifest_names_every_file(exported):
    man, d = exported["manifest"], exported["dir"]
    on_disk = sorted(p.relative_to(d).as_posix() for p in d.rglob("*") if p.is_file() and p.name != "manifest.json")
    assert man["files"] == on_disk
    assert man["units"]["length"] == "m" and man["frame"]["up"].startswith("+z")
    assert man["body"]["mass_kg"] == pytest.approx(exported["report"].mean_kg, rel=1e-12)


def test_mujoco_loads_the_body_of_the_report(exported):
    mujoco = pytest.importorskip("mujoco")
    model = mujoco.MjModel.from_xml_path(str(exported["dir"] / "object.xml"))
    body = exported["manifest"]["body"]
    b = model.nbody - 1
    assert model.body_mass[b] == pytest.approx(exported["report"].mean_kg, rel=1e-6)
    np.testing.assert_allclose(model.body_ipos[b], body["com_m"], rtol=1e-6, atol=1e-9)
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, model.body_iquat[b])
    I = np.asarray(body["inertia_kg_m2"])
    np.testing.assert_allclose(_tensor_from_principal(model.body_inertia[b], R.reshape(3, 3)), I,
                               rtol=0, atol=1e-6 * np.abs(I).max())  # fmt: skip


def test_solid_body_matches_the_particles(exported):
    """An independent sum: the MPM particles' mass and first moment give the body's mass and centre of mass."""
    z = np.load(exported["dir"] / "particles.npz")
    m, x = z["mass_kg"], z["position_m"].astype(np.float64)
    assert m.sum() == pytest.approx(exported["report"].mean_kg, rel=0.01)
    assert np.allclose(z["density_kg_m3"] * z["volume_m3"], m, rtol=1e-5)
    assert (z["poisson_ratio"] > 0).all() and (z["youngs_modulus_pa"] > 0).all()
    com = (m[:, None] * x).sum(0) / m.sum()
    voxel = float(np.cbrt(z["volume_m3"].max()))
    np.testing.assert_allclose(com, exported["manifest"]["body"]["com_m"], atol=voxel)  # walls' faces -> voxels
    cfg = json.loads((exported["dir"] / "mpm_config.json").read_text())
    assert cfg["physgs"]["total_mass_kg"] == pytest.approx(m.sum()) and 0 < cfg["nu"] < 0.5 and cfg["E"] > 0


def test_drop_onto_a_plane_comes_to_rest(exported):
    """From 5 cm above the floor: it comes to rest on its lowest point (z = 0 of its frame) without sinking into the
    floor, and never gains energy. MuJoCo's contacts are soft: an impact at 1 m/s sinks a few millimetres for a few
    steps (scene.xml keeps MuJoCo's default contact stiffness)."""
    mujoco = pytest.importorskip("mujoco")
    model = mujoco.MjModel.from_xml_path(str(exported["dir"] / "scene.xml"))
    model.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_ENERGY
    data = mujoco.MjData(model)
    data.qpos[2] = 0.05
    mujoco.mj_forward(model, data)
    e0 = float(data.energy.sum())
    geoms = [i for i in range(model.ngeom) if "collision" in model.geom(i).name]
    verts = [model.mesh_vert[model.mesh_vertadr[j]:model.mesh_vertadr[j] + model.mesh_vertnum[j]]
             for j in (model.geom_dataid[i] for i in geoms)]  # each in its geom's frame  # fmt: skip
    low = lambda: min(float((data.geom_xpos[i] + v @ data.geom_xmat[i].reshape(3, 3).T)[:, 2].min())
                      for i, v in zip(geoms, verts))  # fmt: skip
    assert low() == pytest.approx(0.05, abs=1e-6)  # the frame's origin is the lowest point
    lowest, top = np.inf, -np.inf
    for _ in range(int(1.5 / model.opt.timestep)):
        mujoco.mj_step(model, data)
        top = max(top, float(data.energy.sum()))
        lowest = min(lowest, low())
    assert top <= e0 + 1e-6 * abs(e0) + 1e-9
    assert -0.01 < lowest < 0.0  # the impact's transient (metres)
    assert abs(low()) < 5e-4 and abs(data.qpos[2]) < 5e-4  # at rest on the floor, not in it
    assert np.abs(data.qvel).max() < 1e-3


def test_urdf_loads_with_yourdfpy(exported):
    yourdfpy = pytest.importorskip("yourdfpy")
    robot = yourdfpy.URDF.load(str(exported["dir"] / "object.urdf"), build_scene_graph=False, load_meshes=False)
    link = next(iter(robot.link_map.values()))
    body = exported["manifest"]["body"]
    assert link.inertial.mass == pytest.approx(exported["report"].mean_kg, rel=1e-12)
    np.testing.assert_allclose(link.inertial.origin[:3, 3], body["com_m"], rtol=1e-12)
    np.testing.assert_allclose(link.inertial.inertia, body["inertia_kg_m2"], rtol=1e-12)
    assert len(link.collisions) >= 2 and len(link.visuals) == 2


def test_usd_mass_api(exported):
    pytest.importorskip("pxr")
    from pxr import Usd, UsdGeom, UsdPhysics, UsdShade
    from scipy.spatial.transform import Rotation

    stage = Usd.Stage.Open(str(exported["dir"] / "object.usda"))
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0 and UsdGeom.GetStageUpAxis(stage) == "Z"
    prim = stage.GetDefaultPrim()
    assert prim.HasAPI(UsdPhysics.RigidBodyAPI) and prim.HasAPI(UsdPhysics.MassAPI)
    api = UsdPhysics.MassAPI(prim)
    body = exported["manifest"]["body"]
    assert api.GetMassAttr().Get() == pytest.approx(exported["report"].mean_kg, rel=1e-6)  # float32
    np.testing.assert_allclose(np.array(api.GetCenterOfMassAttr().Get()), body["com_m"], rtol=1e-6, atol=1e-7)
    q = api.GetPrincipalAxesAttr().Get()
    R = Rotation.from_quat([*q.GetImaginary(), q.GetReal()]).as_matrix()
    I = np.asarray(body["inertia_kg_m2"])
    np.testing.assert_allclose(_tensor_from_principal(np.array(api.GetDiagonalInertiaAttr().Get()), R), I,
                               atol=1e-5 * np.abs(I).max())  # fmt: skip
    mats = [p for p in stage.Traverse() if p.HasAPI(UsdPhysics.MaterialAPI)]
    assert len(mats) == 2
    coll = [p for p in stage.Traverse() if p.HasAPI(UsdPhysics.CollisionAPI)]
    bound = UsdShade.MaterialBindingAPI(coll[0]).ComputeBoundMaterial("physics")[0]
    assert bound.GetPrim().HasAPI(UsdPhysics.MaterialAPI)


def test_samples_reproduce_the_interval(exported):
    """32 samples: the Monte Carlo's own rows (their masses are those draws), so their spread is the report's:
    the count inside its 90% interval is Binomial(32, 0.9) and their mean within 3 standard errors of its mean."""
    rows = json.loads((exported["dir"] / "samples" / "samples.json").read_text())["samples"]
    m = np.array([r["mass_kg"] for r in rows])
    assert len(m) == 32
    np.testing.assert_allclose(m, exported["draws"].total_kg[:32], rtol=1e-12)
    rep = exported["report"]
    inside = int(((m >= rep.interval_kg[0]) & (m <= rep.interval_kg[1])).sum())
    assert inside >= 32 * 0.9 - 3 * math.sqrt(32 * 0.9 * 0.1)
    sd = exported["draws"].total_kg.std()
    assert abs(m.mean() - rep.mean_kg) < 3 * sd / math.sqrt(32)
    assert m.std() > 0.3 * sd  # they spread; not 32 copies of the mean


def test_sample_files_load(exported):
    mujoco = pytest.importorskip("mujoco")
    rows = json.loads((exported["dir"] / "samples" / "samples.json").read_text())["samples"]
    model = mujoco.MjModel.from_xml_path(str(exported["dir"] / "samples" / "007" / "object.xml"))
    assert model.body_mass[1] == pytest.approx(rows[7]["mass_kg"], rel=1e-9)
    pytest.importorskip("pxr")
    from pxr import Usd, UsdPhysics

    stage = Usd.Stage.Open(str(exported["dir"] / "samples" / "007" / "object.usda"))
    prim = stage.GetDefaultPrim()
    assert UsdPhysics.MassAPI(prim).GetMassAttr().Get() == pytest.approx(rows[7]["mass_kg"], rel=1e-6)
    assert any(p.HasAPI(UsdPhysics.CollisionAPI) for p in stage.Traverse())  # the meshes come by reference



def test_without_usd_core_the_rest_is_written(exported, tmp_path, monkeypatch):
    from physgs_nerfstudio.sim import SimConfig, write
    from physgs_nerfstudio.sim.write import write_sim

    monkeypatch.setattr(write, "usd_available", lambda: False)
    files = write_sim(exported["pf"], exported["res"].geometry, exported["draws"], exported["report"], tmp_path,
                      SimConfig(samples=2))  # fmt: skip
    names = {p.name for p in files}
    assert {"object.xml", "object.urdf", "particles.npz", "manifest.json"} <= names and "object.usda" not in names
    assert json.loads((tmp_path / "manifest.json").read_text())["usd"].startswith("not written")

# ------------------------------------------------------------------ refusals
def _refused(exported, tmp_path, **changes):
    from physgs_nerfstudio.export.command import run_export
    from physgs_nerfstudio.sim import SimConfig, SimError

    run = exported["run"]
    pf = replace(run.field, **changes.pop("field", {}))
    geo = replace(exported["res"].geometry, **changes) if changes else exported["res"].geometry
    out = tmp_path / "export"
    with pytest.raises(SimError) as err:
        run_export(replace(run, field=pf), out, mass=exported["mass"], outputs=("ply", "mass", "sim"), quiet=True,
                   geometry=geo, sim=SimConfig(collision="hull"))  # fmt: skip
    assert not out.exists() and not list(tmp_path.iterdir())  # nothing written, no staging left
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith("sim: ")
    return msg


def test_refuses_an_assumed_scale(exported, tmp_path):
    assert "--scale" in _refused(exported, tmp_path, field={"scale_source": "metric_dataset"})


def test_refuses_an_empty_object(exported, tmp_path):
    geo = exported["res"].geometry
    empty = np.zeros_like(geo.solid)
    assert "empty" in _refused(exported, tmp_path, solid=empty, occupancy=np.zeros_like(geo.fill()), hidden_edge=None)


def test_refuses_one_voxel(exported, tmp_path):
    geo = exported["res"].geometry
    one = np.zeros_like(geo.solid)
    one[tuple(np.argwhere(geo.solid)[0])] = True
    assert "1 solid voxel," in _refused(exported, tmp_path, solid=one, occupancy=one.astype(np.float32),
                                        hidden_edge=None)  # fmt: skip


def test_meshes_are_closed_and_coacd_decomposes_a_step():
    """A step-shaped solid: its visual mesh is watertight with the voxels' volume; its convex hull overfills the
    step, CoACD's pieces do not (and each is convex)."""
    import trimesh

    from physgs_nerfstudio.sim.mesh import collision_pieces, part_meshes

    solid = np.zeros((14, 14, 10), bool)
    solid[2:12, 2:12, 2:8] = True
    solid[2:12, 6:12, 5:8] = False
    a = 0.01
    m = part_meshes(solid, np.where(solid, 0, -1), solid.astype(np.float32), np.zeros(3), a, IDENTITY)[0]
    tm = m.trimesh()
    assert tm.is_watertight and tm.volume == pytest.approx(solid.sum() * a**3, rel=0.05)
    (hull,), method = collision_pieces(m, "hull")
    assert method == "hull" and trimesh.Trimesh(*hull).volume > 1.12 * tm.volume
    pytest.importorskip("coacd")
    pieces, method = collision_pieces(m, "coacd")
    assert method == "coacd" and len(pieces) >= 2
    vols = [trimesh.Trimesh(v, f).volume for v, f in pieces]
    assert all(abs(trimesh.Trimesh(v, f).convex_hull.volume - x) < 1e-9 + 1e-3 * x for (v, f), x in zip(pieces, vols))
    assert sum(vols) == pytest.approx(tm.volume, rel=0.05)



def test_export_command_refuses_an_assumed_scale_before_the_geometry(saved_run, tmp_path):
    """`physgs export --outputs sim` on a saved run whose dataset is not known to be metric: one line, nothing
    written (the check runs right after loading, before the object's geometry)."""
    from physgs_nerfstudio.export.command import ExportCommand
    from physgs_nerfstudio.sim import SimError

    out = tmp_path / "export"
    with pytest.raises(SimError) as err:
        ExportCommand(load_config=saved_run, output_dir=out, outputs=("mass", "sim"), device="cpu").main()
    assert "\n" not in str(err.value) and "--scale" in str(err.value) and "metric_dataset" in str(err.value)
    assert not out.exists()
