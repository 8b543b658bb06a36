"""The viewer as a measuring instrument (physgs_nerfstudio/viewer): the click query against brute force and the
rasterizer, the fixed-scale outputs on a trained scene, and selection-to-mass against `physgs export`."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from helpers.nerfstudio_scenes import blob_gaussians, look_at_c2w
from nerfstudio.data.scene_box import OrientedBox

from physgs_nerfstudio.bayes import NIG
from physgs_nerfstudio.geometry.capture import viewmat_from_c2w
from physgs_nerfstudio.materials.hardness import from_canonical
from physgs_nerfstudio.render import rasterize
from physgs_nerfstudio.render.projection import covariance_3d, project_gaussians
from physgs_nerfstudio.viewer.display import GaussianMaterials, gaussian_channels, pixel_statistics
from physgs_nerfstudio.viewer.mass import Selection, box_from_obb, box_from_rectangle, selection_mass_config
from physgs_nerfstudio.viewer.query import query_pixel, ray_weights
from physgs_nerfstudio.viewer.scales import colourise, property_scales

SIZE = 40
KEYS = ("density", "kinetic_friction", "shore_hardness", "youngs_modulus")
LOG = (True, False, False, True)


def _splat(seed: int = 0):
    g = blob_gaussians(seed, per_object=150)
    n = g["means"].shape[0]
    gen = torch.Generator().manual_seed(seed)
    g["opacities"] = 0.15 + 0.8 * torch.rand(n, generator=gen)  # partial opacity: transmittance matters
    g["scales"] = 0.02 + 0.05 * torch.rand(n, 3, generator=gen)
    c2w = torch.tensor(look_at_c2w(np.array([1.5, 0.4, 0.6]))[:3], dtype=torch.float32)
    K = torch.tensor([[SIZE * 1.1, 0, SIZE / 2], [0, SIZE * 1.1, SIZE / 2], [0, 0, 1]], dtype=torch.float32)
    return g, c2w, K


def _materials(n: int, seed: int = 0) -> GaussianMaterials:
    gen = torch.Generator().manual_seed(seed)
    pi = torch.softmax(3 * torch.randn(n, 3, generator=gen), -1)
    measured = torch.rand(n, generator=gen) > 0.3
    ev = torch.rand(n, generator=gen) * 5
    return GaussianMaterials(pi, measured, ev, ev + 2, torch.rand(n, generator=gen))


def _nig() -> NIG:
    tau = torch.tensor([[math.log(2400), 0.5, 85.0, math.log(7e10)], [math.log(7800), 0.4, 130.0, math.log(2e11)],
                        [math.log(1100), 0.9, 40.0, math.log(5e6)]], dtype=torch.float64)  # fmt: skip
    ones = torch.ones_like(tau)
    return NIG(tau, 4 * ones, 3 * ones, torch.tensor([[0.1, 0.01, 20.0, 0.2]] * 3, dtype=torch.float64))


def _brute_force_weights(g, viewmat, K, u, v) -> dict[int, float]:
    """Per-Gaussian blending weights at one pixel, one Gaussian at a time in float64 (gsplat's rules)."""
    proj = project_gaussians(g["means"].double(), covariance_3d(g["quats"].double(), g["scales"].double()),
                             viewmat[None].double(), K[None].double(), SIZE, SIZE)  # fmt: skip
    order = sorted((float(proj.depths[0, i]), i) for i in range(len(g["means"])) if proj.radii[0, i] > 0)
    T, out = 1.0, {}
    for _, i in order:
        dx, dy = float(proj.means2d[0, i, 0]) - (u + 0.5), float(proj.means2d[0, i, 1]) - (v + 0.5)
        a, b, c = (float(x) for x in proj.conics[0, i])
        sig = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
        alpha = min(0.999, float(g["opacities"][i]) * math.exp(-sig))
        if sig < 0 or alpha < 1 / 255:
            continue
        if T * (1 - alpha) <= 1e-4:
            break
        out[i] = alpha * T
        T *= 1 - alpha
    return out


PIXELS = [(20, 20), (14, 22), (27, 17), (8, 30), (2, 2)]


@pytest.mark.parametrize("pixel", PIXELS)
def test_ray_weights_match_brute_force_and_the_rasterizer(pixel):
    g, c2w, K = _splat()
    viewmat = viewmat_from_c2w(c2w)
    u, v = pixel
    rw = ray_weights(g["means"], g["quats"], g["scales"], g["opacities"], viewmat, K, SIZE, SIZE, (u + 0.3, v + 0.7))
    oracle = _brute_force_weights(g, viewmat, K, u, v)
    assert set(rw.ids.tolist()) == set(oracle)
    for i, w in zip(rw.ids.tolist(), rw.weights.tolist()):
        assert w == pytest.approx(oracle[i], rel=1e-4, abs=1e-6)
    # the full-frame render (another implementation of the compositing) at that pixel
    colors = torch.rand(len(g["means"]), 5, generator=torch.Generator().manual_seed(1))
    img, alpha, _ = rasterize(g["means"], g["quats"], g["scales"], g["opacities"], colors, viewmat[None], K[None],
                              SIZE, SIZE, render_mode="RGB+ED")  # fmt: skip
    assert rw.accumulation == pytest.approx(float(alpha[0, v, u, 0]), abs=1e-5)
    expect = (rw.weights[:, None] * colors[rw.ids]).sum(0)
    assert torch.allclose(expect, img[0, v, u, :5], atol=1e-5)
    if rw.accumulation > 0.01:
        assert rw.expected_depth() == pytest.approx(float(img[0, v, u, 5]), rel=1e-4)


def test_query_equals_the_displayed_pixel_statistics():
    """The click answer is what the viewer's pixel shows: same mixture, same moments."""
    g, c2w, K = _splat()
    viewmat = viewmat_from_c2w(c2w)
    gm = _materials(len(g["means"]))
    nig = _nig()
    img, _, _ = rasterize(g["means"], g["quats"], g["scales"], g["opacities"], gaussian_channels(gm), viewmat[None],
                          K[None], SIZE, SIZE)  # fmt: skip
    stats = pixel_statistics(img[0], nig, LOG, min_coverage=0.5)
    checked = 0
    for u, v in PIXELS:
        rw = ray_weights(g["means"], g["quats"], g["scales"], g["opacities"], viewmat, K, SIZE, SIZE, (u, v))
        q = query_pixel(rw, gm, nig, LOG, property_keys=KEYS, material_names=["ceramic", "steel", "rubber"],
                        camera_to_world=c2w, K=K, pixel=(u, v))  # fmt: skip
        assert q.measured == bool(stats.shown[v, u, 0])
        if not q.measured:
            assert q.properties == {} and q.materials == []
            continue
        checked += 1
        top = torch.argsort(stats.pi[v, u], descending=True)[:3]
        assert [m["id"] - 1 for m in q.materials] == top.tolist()
        for m, k in zip(q.materials, top.tolist()):
            assert m["probability"] == pytest.approx(float(stats.pi[v, u, k]), abs=1e-4)
        for i, key in enumerate(KEYS):
            pr = q.properties[key]
            assert pr["mean"] == pytest.approx(float(stats.fields["mean"][v, u, i]), rel=1e-4)
            assert pr["epistemic_std"] ** 2 == pytest.approx(float(stats.fields["epistemic"][v, u, i]), rel=1e-3)
            assert pr["aleatoric_std"] ** 2 == pytest.approx(float(stats.fields["aleatoric"][v, u, i]), rel=1e-3)
        s = q.properties["shore_hardness"]["shore"]
        want = "D" if q.properties["shore_hardness"]["mean"] > 90 else "A"
        assert s["scale"] == want
        assert s["reading"] == pytest.approx(float(from_canonical(q.properties["shore_hardness"]["mean"], want)))
        # the point projects back onto the clicked pixel's centre, at the first-surface depth
        pc = viewmat.double() @ torch.tensor([*q.point, 1.0], dtype=torch.float64)
        assert float(pc[2]) == pytest.approx(q.surface_depth, rel=1e-5)
        assert float(K[0, 0] * pc[0] / pc[2] + K[0, 2]) == pytest.approx(u + 0.5, abs=1e-3)
        assert float(K[1, 1] * pc[1] / pc[2] + K[1, 2]) == pytest.approx(v + 0.5, abs=1e-3)
    assert checked >= 2


def test_unhit_and_unmeasured_rays():
    g, c2w, K = _splat()
    viewmat = viewmat_from_c2w(c2w)
    gm = _materials(len(g["means"]))
    gm.measured[:] = False
    rw = ray_weights(g["means"], g["quats"], g["scales"], g["opacities"], viewmat, K, SIZE, SIZE, (20, 20))
    q = query_pixel(rw, gm, _nig(), LOG, property_keys=KEYS, material_names=["a", "b", "c"], camera_to_world=c2w,
                    K=K, pixel=(20, 20))  # fmt: skip
    assert q.hit and not q.measured and q.properties == {} and "Not measured" in q.lines()[-1]
    far = torch.tensor(look_at_c2w(np.array([30.0, 0.0, 0.0]), np.array([60.0, 0.0, 0.0]))[:3], dtype=torch.float32)
    rw = ray_weights(g["means"], g["quats"], g["scales"], g["opacities"], viewmat_from_c2w(far), K, SIZE, SIZE, (20, 20))
    q = query_pixel(rw, gm, _nig(), LOG, property_keys=KEYS, material_names=["a", "b", "c"], camera_to_world=far,
                    K=K, pixel=(20, 20))  # fmt: skip
    assert not q.hit and q.point is None and json.loads(json.dumps(q.to_dict()))["hit"] is False
    with pytest.raises(ValueError, match="outside"):
        ray_weights(g["means"], g["quats"], g["scales"], g["opacities"], viewmat, K, SIZE, SIZE, (SIZE, 3))


def test_crop_box_and_rectangle_to_box():
    R = torch.tensor(np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]), dtype=torch.float64)  # 90 deg about z
    T, S = torch.tensor([0.1, 0.2, 0.3]), torch.tensor([0.4, 0.2, 0.6])
    sel = box_from_obb(T, R, S)
    assert sel.bbox == pytest.approx((0.0, 0.0, 0.0, 0.2, 0.4, 0.6)) and "rotated" in sel.note
    pts = torch.rand(2000, 3, generator=torch.Generator().manual_seed(0)) - 0.2
    inside = OrientedBox(R.float(), T, S).within(pts)
    lo, hi = torch.tensor(sel.bbox[:3]), torch.tensor(sel.bbox[3:])
    assert bool(((pts[inside] >= lo) & (pts[inside] <= hi)).all())
    assert box_from_obb(T, torch.eye(3), S).note == ""
    # rectangle: only the measured Gaussians whose centres project into it
    g, c2w, K = _splat()
    viewmat = viewmat_from_c2w(c2w)
    measured = torch.zeros(len(g["means"]), dtype=torch.bool)
    measured[:150] = True  # the sphere (first object) only
    sel = box_from_rectangle(g["means"], measured, viewmat, K, SIZE, SIZE, ((0.0, 0.0), (1.0, 1.0)))
    sphere = g["means"][:150].double()
    assert sel.bbox == pytest.approx((*sphere.amin(0).tolist(), *sphere.amax(0).tolist()), abs=1e-6)
    with pytest.raises(ValueError, match="no Gaussian with material evidence"):
        box_from_rectangle(g["means"], measured, viewmat, K, SIZE, SIZE, ((0.0, 0.0), (0.01, 0.01)))


# ---------------------------------------------------------------------------------------------- trained scene
@pytest.fixture(scope="module")
def trained(viewer_run):
    from nerfstudio.utils.eval_utils import eval_setup

    config, data, gt = viewer_run
    trainer_config, pipeline, _, _ = eval_setup(config, test_mode="inference")
    pipeline.model.eval()
    return config, data, gt, trainer_config, pipeline


@pytest.mark.slow
def test_trained_scene_click_matches_what_the_viewer_shows(trained):
    from physgs_nerfstudio.viewer.display import gaussian_materials

    _, _, _, _, pipeline = trained
    m = pipeline.model
    cam = pipeline.datamanager.train_dataset.cameras[0:1]
    with torch.no_grad():
        out = m.get_outputs_for_camera(cam)
    W, H = int(cam.width), int(cam.height)
    K, c2w = cam.get_intrinsics_matrices()[0], cam.camera_to_worlds[0]
    gm = gaussian_materials(m)
    scales = property_scales(m.property_keys)
    shown = torch.nonzero(out["material_id"][..., 0] > 0)
    assert len(shown) > 0, "the mug is not in view 0"
    v, u = (int(x) for x in shown.float().mean(0).round())
    rw = ray_weights(m.means, m.quats, torch.exp(m.scales), torch.sigmoid(m.opacities)[:, 0], viewmat_from_c2w(c2w),
                     K, W, H, (u, v))  # fmt: skip
    q = query_pixel(rw, gm, m.material_nig(), m.log_space, property_keys=m.property_keys,
                    material_names=list(m.legend.names), camera_to_world=c2w, K=K, pixel=(u, v))  # fmt: skip
    assert q.hit and q.measured and q.evidence["views"] >= 1
    assert q.expected_depth == pytest.approx(float(out["depth"][v, u, 0]), rel=1e-4)
    want = colourise(torch.tensor([[q.properties["density"]["mean"]]]), scales["density"])[0]
    assert torch.allclose(out["density"][v, u], want, atol=2e-2)  # the colour the viewer paints there
    # the background corner: opaque environment, no material evidence -> dimmed RGB, no answer
    rw = ray_weights(m.means, m.quats, torch.exp(m.scales), torch.sigmoid(m.opacities)[:, 0], viewmat_from_c2w(c2w),
                     K, W, H, (0, 0))  # fmt: skip
    q0 = query_pixel(rw, gm, m.material_nig(), m.log_space, property_keys=m.property_keys,
                     material_names=list(m.legend.names), camera_to_world=c2w, K=K, pixel=(0, 0))  # fmt: skip
    assert not q0.measured
    assert torch.allclose(out["density"][0, 0], m.viewer_settings.dim * out["rgb"][0, 0])


@pytest.mark.slow
def test_selection_mass_equals_physgs_export_with_the_same_box(trained, tmp_path):
    from physgs_nerfstudio.export.command import ExportCommand, run_from_pipeline
    from physgs_nerfstudio.geometry import GeometryConfig
    from physgs_nerfstudio.mass import MassConfig
    from physgs_nerfstudio.viewer.display import gaussian_materials
    from physgs_nerfstudio.viewer.mass import selection_mass

    config, _, _, trainer_config, pipeline = trained
    m = pipeline.model
    cam = pipeline.datamanager.train_dataset.cameras[0:1]
    sel = box_from_rectangle(m.means.detach(), gaussian_materials(m).measured, viewmat_from_c2w(cam.camera_to_worlds[0]),
                             cam.get_intrinsics_matrices()[0], int(cam.width), int(cam.height), ((0, 0), (1, 1)))  # fmt: skip
    mass = MassConfig(geometry=GeometryConfig(resolution=32), n_samples=300)
    run = run_from_pipeline(trainer_config.get_base_dir(), pipeline)
    lines = []
    _, path = selection_mass(run, mass, sel, tmp_path / "viewer", progress=lines.append)
    assert path.exists() and lines and json.loads(path.read_text())["selection"]["source"] == "rectangle"
    cfg = selection_mass_config(mass, sel)
    ExportCommand(load_config=config, output_dir=tmp_path / "export", outputs=("mass",), mass=cfg, device="cpu").main()
    exported = json.loads((tmp_path / "export" / "report.json").read_text())["mass"]
    ours = json.loads(path.read_text())["mass"]
    for key in ("mean_kg", "median_kg", "interval_kg", "volume_m3"):
        assert ours[key] == pytest.approx(exported[key], rel=1e-9), key
    assert [(x["name"], x["mass_mean_kg"]) for x in ours["materials"]] == [
        (x["name"], pytest.approx(x["mass_mean_kg"], rel=1e-9)) for x in exported["materials"]]  # fmt: skip
    assert ours["geometry"]["selected_gaussians"] == exported["geometry"]["selected_gaussians"] > 0
    # the box restricts the object: one far from the splat selects nothing
    far = Selection((50.0, 50.0, 50.0, 51.0, 51.0, 51.0), "crop box")
    with pytest.raises(ValueError):
        selection_mass(run, mass, far, tmp_path / "far")


def test_panel_elements_are_found_by_nerfstudio(tmp_path):
    """nerfstudio's viewer collects ViewerElements / ViewerControl by walking the pipeline's modules; the panel
    must be found and the walk must end (a public back reference to the model would recurse forever)."""
    from helpers.nerfstudio_scenes import write_blob_scene
    from nerfstudio.data.scene_box import SceneBox
    from nerfstudio.viewer.utils import parse_object
    from nerfstudio.viewer.viewer_elements import ViewerControl, ViewerElement

    from physgs_nerfstudio.nerfstudio import (
        PhysGSDatamanagerConfig,
        PhysGSDataParserConfig,
        PhysGSModelConfig,
    )

    write_blob_scene(tmp_path, num_views=3, size=16)
    dm = PhysGSDatamanagerConfig(dataparser=PhysGSDataParserConfig(data=tmp_path)).setup(device="cpu")
    meta = dm.train_dataparser_outputs.metadata
    model = PhysGSModelConfig(sh_degree=0).setup(scene_box=SceneBox(torch.tensor([[-1.0, -1, -1], [1, 1, 1]])),
                                                 num_train_data=len(dm.train_dataset), metadata=dm.train_dataset.metadata,
                                                 seed_points=(meta["points3D_xyz"], meta["points3D_rgb"]))  # fmt: skip
    holder = torch.nn.Module()
    holder.model = model
    names = [path for path, _ in parse_object(holder, ViewerElement, "Custom Elements")]
    assert any(p.endswith("physical_properties/k_mass") for p in names), names
    assert len(parse_object(holder, ViewerControl, "Custom Elements")) == 1
    assert not any(k.startswith("physical_properties") for k in model.state_dict())  # nothing in checkpoints
