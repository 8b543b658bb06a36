"""The estimators of benchmarks/accuracy.py on a tiny hand-made observation set with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers.benchmarks import load_benchmark

from physgs_nerfstudio.materials import load_library


@pytest.fixture(scope="module")
def acc():
    return load_benchmark("accuracy.py", "physgs_bench_accuracy")


@pytest.fixture(scope="module")
def library():
    return load_library("indoor")


def obs(view, mask_id, material, conf, density, friction=0.5, hardness=100.0):
    return {
        "view": view, "mask_id": mask_id, "level": "part", "material": material, "confidence": conf,
        "properties": {"density": density, "kinetic_friction": friction, "shore_hardness": hardness,
                       "youngs_modulus": 1e9, "thickness_m": None},
    }


def make_scene(acc):
    """Two parts: body (ceramic, 1e-4 m^3, 2300 kg/m^3) and handle (steel, 1e-5 m^3, 7850 kg/m^3).

    view v0: a body mask (answered wrongly: porcelain 2400) and a handle mask (steel 8000)
    view v1: a body mask (ceramic 2200) and a handle mask (steel 7700)
    view v2: a body mask (ceramic 2400), no handle mask; plus a whole mask over both parts (ceramic 2300).
    """
    parts = [
        acc.PartTruth(1, "body", "ceramic", 1e-4, 0.23, {"density": 2300.0, "kinetic_friction": 0.5, "shore_hardness": 100.0}),
        acc.PartTruth(2, "handle", "steel", 1e-5, 0.0785, {"density": 7850.0, "kinetic_friction": 0.4, "shore_hardness": 120.0}),
    ]
    masks = {
        ("v0", 0): acc.MaskInfo("v0", 0, "part", 100, {1: 100}),
        ("v0", 1): acc.MaskInfo("v0", 1, "part", 10, {2: 10}),
        ("v1", 0): acc.MaskInfo("v1", 0, "part", 100, {1: 100}),
        ("v1", 1): acc.MaskInfo("v1", 1, "part", 10, {2: 10}),
        ("v2", 0): acc.MaskInfo("v2", 0, "part", 100, {1: 100}),
        ("v2", 1): acc.MaskInfo("v2", 1, "whole", 110, {1: 100, 2: 10}),
    }
    observations = [
        obs("v0", 0, "porcelain", 1.0, 2400.0),
        obs("v0", 1, "steel", 1.0, 8000.0, 0.4, 120.0),
        obs("v1", 0, "ceramic", 1.0, 2200.0),
        obs("v1", 1, "steel", 1.0, 7700.0, 0.4, 120.0),
        obs("v2", 0, "ceramic", 0.8, 2400.0),
        obs("v2", 0, "porcelain", 0.2, 2500.0),
        obs("v2", 1, "ceramic", 1.0, 2300.0),
    ]
    visible = {("v0", 1): 100, ("v0", 2): 10, ("v1", 1): 100, ("v1", 2): 10, ("v2", 1): 100, ("v2", 2): 10}
    return acc.SceneData("toy", parts, ["v0", "v1", "v2"], masks, observations, visible)


def test_single_view_uses_first_view_top_candidate(acc, library):
    scene = make_scene(acc)
    e0 = acc.estimate_single_view(scene, library, start=0)
    assert e0.part_material == ["porcelain", "steel"]
    assert e0.part_props["density"] == [2400.0, 8000.0]
    assert e0.mass_kg == pytest.approx(1e-4 * 2400 + 1e-5 * 8000)
    # start at v2: the body's best mask there is the part mask (IoU 1), the handle is covered only by the
    # whole mask in v2 (its top candidate: ceramic)
    e2 = acc.estimate_single_view(scene, library, start=2)
    assert e2.part_material == ["ceramic", "ceramic"]
    assert e2.part_props["density"] == [2400.0, 2300.0]


def test_average_majority_and_plain_mean(acc, library):
    scene = make_scene(acc)
    e = acc.estimate_average(scene, library)
    # body: votes ceramic (v1, v2 part, v2 whole -> dominated by the body) 3 vs porcelain 1
    assert e.part_material == ["ceramic", "steel"]
    ceramic = (2200.0 + 0.8 * 2400.0 + 2300.0) / (1 + 0.8 + 1)
    steel = (8000.0 + 7700.0) / 2
    assert e.part_props["density"][0] == pytest.approx(ceramic)
    assert e.part_props["density"][1] == pytest.approx(steel)
    assert e.part_props["kinetic_friction"][1] == pytest.approx(0.4)
    assert e.mass_kg == pytest.approx(1e-4 * ceramic + 1e-5 * steel)


def test_physgs_evidence_weights(acc, library):
    scene = make_scene(acc)
    names = ["ceramic", "porcelain", "steel"]
    ev = acc.part_evidence(scene, names, acc.MapFusionConfig())
    lw_whole = acc.MapFusionConfig().level_weights["whole"]
    # body: ceramic 1 (v1) + 0.8 (v2) + whole mask 1.0 * lw * 100/110; porcelain 1 + 0.2
    assert ev[0, 0] == pytest.approx(1 + 0.8 + lw_whole * 100 / 110)
    assert ev[0, 1] == pytest.approx(1.2)
    assert ev[0, 2] == 0
    # handle: steel 2; ceramic from the whole mask at overlap 10/110
    assert ev[1, 2] == pytest.approx(2.0)
    assert ev[1, 0] == pytest.approx(lw_whole * 10 / 110)


def test_physgs_mass_and_interval(acc, library):
    scene = make_scene(acc)
    cfg = acc.PhysGSConfig(n_samples=4000, seed=0)
    e = acc.estimate_physgs(scene, library, cfg)
    lo, hi = e.interval
    assert lo < e.mass_kg < hi
    assert e.part_material == ["ceramic", "steel"]
    # the mass is the volume-weighted mixture mean; plausible range for a ceramic body + steel handle
    assert 0.2 < e.mass_kg < 0.4
    assert lo <= scene.mass_kg <= hi
    # MAP variant: the part densities are exactly the per-material NIG predictive means
    from physgs_nerfstudio.fusion.properties import fuse_properties, legend_names

    names = legend_names(scene.observations, library)
    post = fuse_properties(scene.observations, library, names)
    p = list(acc.PROPERTY_KEYS).index("density")
    nig = post.posterior
    v = nig.aleatoric()[:, p] + nig.epistemic()[:, p]
    mean = np.exp(nig.tau[:, p].numpy() + v.numpy() / 2)
    em = acc.estimate_physgs(scene, library, acc.PhysGSConfig(n_samples=100, map_material=True))
    assert em.part_props["density"][0] == pytest.approx(mean[names.index("ceramic")], rel=1e-6)
    assert em.part_props["density"][1] == pytest.approx(mean[names.index("steel")], rel=1e-6)
    # with the material fixed, posterior draws (the material's mean only) give a narrower interval than
    # predictive draws (mean + the spread of single values)
    e_pred = acc.estimate_physgs(scene, library, acc.PhysGSConfig(n_samples=4000, map_material=True,
                                                                  density_draw="predictive"))
    e_post = acc.estimate_physgs(scene, library, acc.PhysGSConfig(n_samples=4000, map_material=True,
                                                                  density_draw="posterior"))
    assert (e_post.interval[1] - e_post.interval[0]) < (e_pred.interval[1] - e_pred.interval[0])


def test_unobserved_part_falls_back(acc, library):
    scene = make_scene(acc)
    scene.observations = [o for o in scene.observations if o["mask_id"] == 0 and o["view"] != "v2"]
    for est in (acc.estimate_single_view(scene, library), acc.estimate_average(scene, library),
                acc.estimate_physgs(scene, library, acc.PhysGSConfig(n_samples=100))):
        assert est.fallbacks == 1
        assert est.part_material[1] is None
        assert math.isfinite(est.mass_kg)


def test_summary_metrics(acc, library):
    scene = make_scene(acc)
    ests = [acc.estimate_physgs(scene, library, acc.PhysGSConfig(n_samples=500))]
    s = acc.summarize_method([scene], ests)
    assert s["APE"] == pytest.approx(abs(ests[0].mass_kg - scene.mass_kg) / scene.mass_kg)
    assert s["coverage90"] in (0.0, 1.0)
    assert 0 <= s["material_acc"] <= 1


def _split_scene(acc, n_views):
    parts = [acc.PartTruth(1, "body", "ceramic", 1e-4, 0.23, {"density": 2300.0, "kinetic_friction": 0.5,
                                                               "shore_hardness": 100.0})]
    views = [f"v{i}" for i in range(n_views)]
    masks = {(v, 0): acc.MaskInfo(v, 0, "part", 100, {1: 100}) for v in views}
    observations = [o for v in views for o in (obs(v, 0, "ceramic", 0.6, 2300.0), obs(v, 0, "steel", 0.4, 7850.0))]
    return acc.SceneData("split", parts, views, masks, observations, {(v, 1): 100 for v in views})


def test_dominant_weights_recover_the_material_predictive_weights_blend(acc, library):
    """A part answered in every view with the same 60/40 split between its material (ceramic, 2300 kg/m^3) and
    a much denser wrong one (steel): estimator (c) (dominant weights, the default) converges to the ceramic
    estimate of the argmax variant (c') as views accumulate; (c-pred) (alpha / sum) keeps ~40% of steel's
    density blended in however many views there are."""
    assert acc.PhysGSConfig().material_weights == "dominant" and acc.PhysGSConfig().density_draw == "posterior"
    gaps = []
    for n_views in (5, 20, 80):
        scene = _split_scene(acc, n_views)
        dom = acc.estimate_physgs(scene, library, acc.PhysGSConfig(n_samples=2000))
        pred = acc.estimate_physgs(scene, library, acc.PhysGSConfig(n_samples=2000, material_weights="predictive"))
        argmax = acc.estimate_physgs(scene, library, acc.PhysGSConfig(n_samples=2000, map_material=True,
                                                                      material_weights="predictive"))
        assert dom.part_material == pred.part_material == argmax.part_material == ["ceramic"]
        rho = argmax.part_props["density"][0]
        assert rho == pytest.approx(2300.0, rel=0.01)
        assert pred.part_props["density"][0] > 1.5 * rho
        gaps.append(dom.part_props["density"][0] / rho - 1)
        assert dom.interval[0] <= scene.mass_kg <= dom.interval[1]
    assert gaps[0] > gaps[1] > gaps[2] >= 0 and gaps[2] < 1e-3 and gaps[0] > 0.05  # concentrates with evidence
    res = acc.evaluate_scenes([_split_scene(acc, 80)], library, acc.PhysGSConfig(n_samples=500))
    assert res["physgs"]["posterior"]["APE"] < 0.01
    assert res["physgs_predictive_weights"]["posterior"]["APE"] > 0.3
    table = acc.markdown_table(res, res["draws"])
    assert "(c-pred)" in table and "90% cov. (mean-density draws) | 90% cov. (full-predictive draws)" in table


def test_active_first_within_and_table(acc):
    """The --active section's bookkeeping on hand-made curves: the first k within the target, and the table's
    means over the objects."""
    ks = [4, 8, 12]
    assert acc.first_within(ks, np.array([0.30, 0.10, 0.05]), 0.10) == 8
    assert acc.first_within(ks, np.array([0.30, 0.20, 0.15]), 0.10) is None

    def row(obj, n, ape25, q_abs, within):
        return {"object": obj, "estimator": "c", "policy": "random", "queries_all": n, "ape_all": 0.01,
                "ape_at_25pct": ape25, "queries_to_abs5": q_abs, "queries_to_rel5": n,
                "within_abs5_at_25pct": within, "within_rel5_at_25pct": 0.0}

    table = acc.active_table([row("mug", 40, 0.02, 4.0, 1.0), row("pan", 20, 0.04, 10.0, 0.5)])
    lines = table.splitlines()
    assert len(lines) == 3  # header, rule, the one (estimator, policy) present
    # mean APE at 25% (0.02 + 0.04) / 2; within 5 pts (1 + 0.5) / 2; fraction of queries (4/40 + 10/20) / 2
    assert lines[2] == "| (c) mixture mean | random | 0.0100 | 0.0300 | 75% | 0% | 0.30 | 1.00 |"
