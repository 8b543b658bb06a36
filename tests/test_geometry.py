"""Object geometry from masks and depth (physgs_nerfstudio.geometry) on analytic shapes whose volumes are known
exactly: Gaussians on the surfaces of a box, a sphere and an open cup, seen by a ring of cameras whose masks are
the rendered silhouettes; a floor under the object; hollow and solid parts of one material."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from helpers.shapes import (
    box_on_floor,
    box_surface,
    flat_gaussians,
    geometry_of,
    pixel_rays,
    ring_views,
    whole_voxel_volume,
)

from physgs_nerfstudio.export.shapes import field_from, shell_sphere
from physgs_nerfstudio.geometry import GeometryConfig, MaskObservation, reconstruct_object
from physgs_nerfstudio.geometry.carve import mask_hull
from physgs_nerfstudio.geometry.gaussians import render_depth
from physgs_nerfstudio.geometry.select import capture_centre
from physgs_nerfstudio.mass import MassConfig, integrate_mass, mass_draws


def cup_surface(radius, height, spacing):
    """An open cup: a thin cylindrical wall and a bottom disc (both sides of the wall reconstructed)."""
    n_ang = max(12, round(2 * math.pi * radius / spacing))
    n_h = max(2, round(height / spacing))
    th = torch.arange(n_ang, dtype=torch.float64) / n_ang * 2 * math.pi
    hz = (torch.arange(n_h, dtype=torch.float64) + 0.5) / n_h * height
    T, Z = torch.meshgrid(th, hz, indexing="ij")
    wall = torch.stack([radius * torch.cos(T), radius * torch.sin(T), Z], -1).reshape(-1, 3)
    wn = torch.stack([torch.cos(T), torch.sin(T), torch.zeros_like(T)], -1).reshape(-1, 3)
    g = torch.arange(-radius, radius, spacing, dtype=torch.float64) + spacing / 2
    X, Y = torch.meshgrid(g, g, indexing="ij")
    disc = torch.stack([X, Y, torch.zeros_like(X)], -1).reshape(-1, 3)
    disc = disc[(disc[:, :2] ** 2).sum(1) <= radius**2]
    p = torch.cat([wall, disc])
    n = torch.cat([wn, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand_as(disc)])
    return flat_gaussians(p, n, spacing * 0.5)



@pytest.fixture(scope="module")
def box():
    means, scales, quats = box_surface((0.4, 0.3, 0.2), 0.02)
    pf = field_from(means, scales, quats, densities=[700.0], names=["oak"], thickness_m=[None])
    return pf, ring_views(pf, (0, 0, 0), 1.5)


def test_box_volume_from_carving(box):
    pf, views = box
    geo = geometry_of(pf, views)
    v = geo.volumes[0].sum()
    # the centre test is unbiased to first order; the depth margin is 0 on a plane (carve_views.depth_slack)
    assert 0.95 * 0.024 <= v <= 1.1 * 0.024
    # every variant stays close: the geometric uncertainty is honest, not wide
    assert np.all(np.abs(geo.volumes.sum(1) / v - 1) < 0.25)


def test_unselected_boundary_gaussians_still_block_the_depth(box):
    """A strict selection (object probability >= 0.9) leaves out the box's Gaussians whose footprints straddle the
    masks' edges, as a coarse segmentation leaves out an object's rim. Rendered
    alone, the selected ones are partly see-through where those are missing; at the median depth the depth carved
    the box away there (under 0.9x), but the surface depth (transmittance 0.8) needs only a fifth of the ray
    stopped, so the box keeps its volume (0.97x)."""
    pf, views = box
    strict = _select(min_prob=0.9)
    alone = geometry_of(pf, views, select=strict)
    assert int(alone.selection.selected.sum()) < 0.9 * len(pf.means)
    assert 0.95 * 0.024 <= alone.volumes[0].sum() <= 1.1 * 0.024


def test_lifting_falls_back_to_one_view_per_call_when_a_group_runs_out_of_gpu_memory(box, monkeypatch, caplog):
    """A group of views in one rasterizer call that runs out of GPU memory is lifted again view by view: the same
    evidence, and a warning instead of a failed export."""
    from physgs_nerfstudio.geometry import gaussians

    pf, views = box
    views = views[:5]
    expect = gaussians.lift_masks(pf, views, backend="reference", views_per_call=1)
    real = gaussians.lift_views
    calls = []

    def lift_views(*a, views_per_call=1, **k):
        calls.append(views_per_call)
        if views_per_call > 1:
            raise torch.cuda.OutOfMemoryError("CUDA out of memory (simulated)")
        return real(*a, views_per_call=views_per_call, **k)

    monkeypatch.setattr(gaussians, "lift_views", lift_views)
    monkeypatch.setattr(torch.cuda, "empty_cache", lambda: None)
    with caplog.at_level("WARNING"):
        got = gaussians.lift_masks(pf, views, backend="reference", views_per_call=3)
    assert calls == [3, 1, 1, 1, 2, 1, 1]
    assert "one at a time" in caplog.text
    for a, b in zip(got, expect):
        torch.testing.assert_close(a, b)
    assert float(expect[0].sum()) > 0


@pytest.mark.xfail(strict=True, reason="known regression: the support rule (support.find_support) takes the box's own "
                   "bottom face, a level ring around the slab of strays under it, for a support and cuts there "
                   "(1.026x against 0.988x without the strays)")
def test_the_extent_of_the_seen_gaussians_ends_an_unseen_bottom_at_the_seen_faces(box):
    """Gaussians hidden under a box's unseen bottom (a slab of them 2.5 voxels under it, every view above the box)
    would stretch the Gaussians' polytope and keep the solid under the bottom that no view carves; the polytope is
    the seen Gaussians' only, so the bottom ends where the seen side faces end, as without the strays."""
    pf, _ = box
    means, scales, quats = box_surface((0.4, 0.3, 0.2), 0.02)
    h = 0.42 / 40  # about the voxel of a 40-voxel grid over the box and its padding
    g = torch.arange(-0.12, 0.1201, 0.02)
    X, Y = torch.meshgrid(g, g[(g > -0.1) & (g < 0.1)], indexing="ij")
    under = torch.stack([X.reshape(-1), Y.reshape(-1), torch.full((X.numel(),), -0.1 - 2.5 * h)], 1)
    up = torch.tensor([[0.0, 0.0, 1.0]]).double().expand_as(under)
    s_means, s_scales, s_quats = flat_gaussians(under.double(), up, 0.01)
    pf2 = field_from(torch.cat([means, s_means]), torch.cat([scales, s_scales]), torch.cat([quats, s_quats]),
                     densities=[700.0], names=["oak"], thickness_m=[None])
    views = ring_views(pf2, (0, 0, 0), 1.5, n=16, elevations=(35.0, 60.0))
    seen = geometry_of(pf2, views, resolution=40, variants=False)
    above = ring_views(pf, (0, 0, 0), 1.5, n=16, elevations=(35.0, 60.0))
    plain = geometry_of(pf, above, resolution=40, variants=False)
    v_seen, v_plain = (float(x.volumes[0].sum()) for x in (seen, plain))
    print("box", 0.024, "without strays", v_plain, "with strays", v_seen)
    slab = 0.24 * 0.18 * h  # the strays' footprint, a voxel deep
    assert abs(v_seen - v_plain) <= 0.5 * slab  # the seen faces end it where the box without strays ends
    assert abs(v_seen / 0.024 - 1) < 0.1


def test_sphere_volume_and_area():
    R = 0.25
    means, scales, quats = shell_sphere(R, 0.015)
    pf = field_from(means, scales, quats, densities=[1000.0], names=["ceramic"], thickness_m=[None])
    views = ring_views(pf, (0, 0, 0), 1.4)
    geo = geometry_of(pf, views, resolution=48)
    true_v = 4 / 3 * math.pi * R**3
    assert 0.95 * true_v <= geo.volumes[0].sum() <= 1.25 * true_v
    # a closed hollow object's carved solid is bulky: its wall area counts once (no sheet halving)
    assert geo.areas[0].sum() == pytest.approx(4 * math.pi * R**2, rel=0.25)
    assert geo.sheet_share.max() < 0.2


def test_open_cup_inside_is_carved_by_depth():
    R, H = 0.15, 0.2
    means, scales, quats = cup_surface(R, H, 0.012)
    pf = field_from(means, scales, quats, densities=[2400.0], names=["ceramic"], thickness_m=[0.004])
    views = ring_views(pf, (0, 0, H / 2), 1.2, n=24, elevations=(15.0, 45.0, 75.0))
    full = math.pi * R**2 * H
    with_depth = geometry_of(pf, views, resolution=40)
    hull = mask_hull(with_depth.grid, views, _carve()).sum() * with_depth.grid.voxel_size**3  # the silhouette vote
    assert hull >= 0.95 * full  # silhouettes alone fill the cup
    assert with_depth.volumes[0].sum() < 0.6 * hull  # depth sees into it
    # the carved wall is a sheet: its area counts each side half
    assert with_depth.sheet_share[np.argmax(with_depth.volumes[0])] > 0.5


def _carve(**kw):
    from physgs_nerfstudio.geometry import CarveConfig

    return CarveConfig(**kw)



def test_floor_is_not_the_object():
    pf, only_obj, obj = box_on_floor()
    views = ring_views(pf, (0, 0, 0.15), 1.6, elevations=(15.0, 40.0, 70.0), mask_pf=only_obj)
    geo = geometry_of(pf, views)
    sel = geo.selection.selected
    print("selected object share", float(sel[: len(obj[0])].float().mean()), "floor share",
          float(sel[len(obj[0]) :].float().mean()), "volume", geo.volumes[0].sum())
    # only floor Gaussians hidden under the object or touching its base may be kept
    assert bool(sel[len(obj[0]) :].float().mean() < 0.05)
    assert 0.95 * 0.3**3 <= geo.volumes[0].sum() <= 1.3 * 0.3**3
    assert np.allclose(capture_centre(views), [0, 0, 0.15], atol=1e-3)


def test_the_support_around_the_object_ends_the_solid_between_voxels():
    """The masks hold the box alone, so the floor is background; the support it stands on is still found in the ring
    around its base (:func:`physgs_nerfstudio.geometry.support.find_support`), the grid has a layer of voxel faces on
    it, and no voxel of the solid lies under it or straddles it. Switched off, the grid and the solid are as the
    carving left them."""
    from physgs_nerfstudio.geometry.select import SelectConfig
    from physgs_nerfstudio.geometry.support import SupportConfig

    pf, only_obj, _ = box_on_floor()
    views = ring_views(pf, (0, 0, 0.15), 1.6, elevations=(15.0, 40.0, 70.0), mask_pf=only_obj)
    geo = geometry_of(pf, views, resolution=40)
    plane = geo.selection.plane
    assert plane is not None and not geo.selection.plane_in_masks  # found around the object, not in its masks
    assert geo.selection.support is not None and not bool((geo.selection.support & geo.selection.selected).any())
    assert abs(plane.normal[2]) > 0.999 and abs(plane.offset + 1e-3) < 0.01
    k = (plane.offset - geo.grid.origin[2]) / geo.grid.voxel_size
    assert abs(k - round(k)) < 1e-6  # a layer of faces on the plane
    ijk = np.argwhere(geo.solid)
    z = np.asarray(geo.grid.origin)[2] + (ijk[:, 2] + 0.5) * geo.grid.voxel_size
    assert (z - plane.offset >= 0.5 * geo.grid.voxel_size - 1e-9).all()
    assert 0.9 * 0.3**3 <= geo.volumes[0].sum() <= 1.2 * 0.3**3
    off = geometry_of(pf, views, resolution=40, select=SelectConfig(support=SupportConfig(enabled=False)))
    assert off.selection.plane is None and off.selection.support is None


def test_structure_per_part_not_per_material(tmp_path):
    """Two steel boxes: the masks over the left one are answered hollow (2 mm), over the right one solid."""
    left = box_surface((0.2, 0.2, 0.2), 0.02, centre=(-0.3, 0.0, 0.0))
    right = box_surface((0.2, 0.2, 0.2), 0.02, centre=(0.3, 0.0, 0.0))
    means, scales, quats = (torch.cat([a, b]) for a, b in zip(left, right))
    pf = field_from(means, scales, quats, densities=[7850.0], names=["steel"], thickness_m=[0.002])
    views = ring_views(pf, (0, 0, 0), 1.6)
    lpf = field_from(*left, densities=[7850.0], names=["steel"])
    rpf = field_from(*right, densities=[7850.0], names=["steel"])
    lm = render_depth(lpf, views, backend="reference")
    rm = render_depth(rpf, views, backend="reference")
    obs = []
    for v, a, b in zip(views, lm, rm):
        obs.append(MaskObservation(v.name, (a.alpha > 0.5).numpy() & ~(b.alpha > 0.5).numpy(), "steel", 0.9, 0.002))
        obs.append(MaskObservation(v.name, (b.alpha > 0.5).numpy() & ~(a.alpha > 0.5).numpy(), "steel", 0.9, None))
    cfg = GeometryConfig(resolution=56, backend="reference", select=_select(bridge_cells=1, cluster_cells=4))
    geo = reconstruct_object(pf, pf.pi(), views, obs, [0.002], cfg, material_names=["steel"])
    assert geo.num_parts == 2
    xs = [float(np.argwhere(geo.parts == p)[:, 0].mean()) for p in range(2)]
    hollow_part, solid_part = (0, 1) if xs[0] < xs[1] else (1, 0)
    assert geo.structure.p_hollow[hollow_part] > 0.9 and geo.structure.p_hollow[solid_part] < 0.1
    assert geo.structure.thickness_m()[hollow_part] == pytest.approx(0.002, rel=0.1)
    rep = integrate_mass(pf, geo, MassConfig(n_samples=2000))
    solid_mass = 7850 * 0.2**3
    shell_mass = 7850 * 6 * 0.2**2 * 0.002
    # 1.4 cm voxels on a 20 cm box: half a voxel on every face is +-21% of the solid box's volume; the interval
    # samples that (the depth margin and the extent's variants) and holds the truth
    assert 0.8 * (solid_mass + shell_mass) <= rep.mean_kg <= 1.45 * (solid_mass + shell_mass)
    assert rep.interval_kg[0] <= solid_mass + shell_mass <= rep.interval_kg[1]
    assert rep.interval_kg[0] <= rep.median_kg <= rep.interval_kg[1]
    assert rep.interval_kg[0] <= rep.mean_kg <= rep.interval_kg[1]


def _select(**kw):
    from physgs_nerfstudio.geometry import SelectConfig

    return SelectConfig(**kw)


def test_mass_interval_from_the_same_samples(box):
    pf, views = box
    geo = geometry_of(pf, views)
    rep = integrate_mass(pf, geo, MassConfig(n_samples=3000, seed=1), keep_samples=True)
    s = rep.samples
    assert rep.mean_kg == pytest.approx(float(s.mean()))
    assert rep.median_kg == pytest.approx(float(np.median(s)))
    assert rep.interval_kg == pytest.approx((float(np.quantile(s, 0.05)), float(np.quantile(s, 0.95))))
    assert rep.interval_kg[0] <= rep.median_kg <= rep.interval_kg[1]
    assert rep.interval_kg[0] <= rep.mean_kg <= rep.interval_kg[1]
    # no view answered hollow or solid here: the prior's P(hollow) = 0.27 makes a quarter of the samples shells, so
    # the magnitude is checked with the structure fixed: solid oak, the carved volume within its variants' spread
    solid = integrate_mass(pf, geo, MassConfig(n_samples=3000, seed=1, structure="solid"))
    assert 0.9 * 700 * 0.024 <= solid.mean_kg <= 1.15 * 700 * 0.024


def test_the_report_says_how_much_one_resolution_unit_of_surface_holds(box):
    """``surface_layer_share`` = S u / V: the carved box's against the true box's (0.52 m^2 of surface,
    0.024 m^3), the object's the same for one solid part; the printed caption calls an object coarse from half
    of its mass in one unit on, and says whether a finer grid or finer views would help."""
    from physgs_nerfstudio.export.report import _layer_caption

    pf, views = box
    rep = integrate_mass(pf, geometry_of(pf, views), MassConfig(n_samples=200, structure="solid"))
    g = rep.geometry
    assert g["surface_layer_share"] == pytest.approx(0.52 * g["resolution_unit_m"] / 0.024, rel=0.15)
    (part,) = rep.parts
    assert part["surface_layer_share"] == pytest.approx(g["surface_layer_share"])
    assert g["surface_layer_share"] < 0.5 and "coarse" not in _layer_caption(g)
    assert f"{100 * g['surface_layer_share']:.0f}% of the mass" in _layer_caption(g)
    thin = {**g, "surface_layer_share": 1.0, "pixel_footprint_voxels": 0.67,
            "grid": {"shape": [128, 102, 117]}}
    assert "coarse" in _layer_caption(thin) and "~50%" in _layer_caption(thin)
    assert "--mass.geometry.resolution (now 128)" in _layer_caption(thin)
    assert "more or closer views" in _layer_caption({**thin, "pixel_footprint_voxels": 1.5})
    assert _layer_caption({}) == ""
    # a hollow part's wall does not move with its faces: a mug whose solid is its light handle is not coarse
    from physgs_nerfstudio.mass.integrate import _mass_layer_share

    mass, layer = np.array([1.0, 3.0]), [0.5, 0.1]
    assert _mass_layer_share(mass, layer, np.array([True, False])) == pytest.approx(0.5 * 1 / 4)
    assert _mass_layer_share(mass, layer, np.array([False, False])) is None
    assert _mass_layer_share(mass, [None, 0.1], np.array([True, False])) is None


def test_the_report_says_how_much_of_the_surface_no_view_saw(box):
    """``unseen_surface_share``: the box seen from all around (cameras above and below it) has every face
    placed by the views; seen only from above, its bottom (0.12 of its 0.52 m^2) ends where the polytope of
    the seen Gaussians ends it, and the caption says so. The face count against a loop over voxels."""
    from physgs_nerfstudio.export.report import _unseen_caption
    from physgs_nerfstudio.geometry.reconstruct import unseen_face_share

    pf, views = box
    around = geometry_of(pf, views, variants=False)
    above = geometry_of(pf, ring_views(pf, (0, 0, 0), 1.5, n=16, elevations=(35.0, 60.0)), variants=False)
    assert around.unseen_surface_share < 0.03
    assert above.unseen_surface_share == pytest.approx(0.12 / 0.52, abs=0.06)
    assert above.summary()["unseen_surface_share"] == above.unseen_surface_share
    line = _unseen_caption({"unseen_surface_share": 0.23})
    assert "23% of the solid's surface lies where no view saw" in line
    assert _unseen_caption({"unseen_surface_share": 0.01}) == "" and _unseen_caption({}) == ""
    rng = np.random.default_rng(0)
    solid, unseen = rng.random((6, 5, 7)) < 0.5, rng.random((6, 5, 7)) < 0.3
    total = hidden = 0
    for i, j, k in np.argwhere(solid):
        for d in ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)):
            n = (i + d[0], j + d[1], k + d[2])
            inside = all(0 <= n[a] < solid.shape[a] for a in range(3))
            if inside and solid[n]:
                continue
            total += 1
            hidden += bool(inside and unseen[n])
    assert unseen_face_share(solid, unseen) == pytest.approx(hidden / total)


def test_a_walls_cap_is_the_widest_variants_volume(box):
    """A hollow part's wall holds at most the part's largest carved volume over the variants, whatever the sample's
    own variant: carving every other variant down to 0.01% of the box leaves every sample as it was, while carving
    the widest one down too crushes the walls under the new cap."""
    from dataclasses import replace

    pf, views = box
    geo = geometry_of(pf, views)
    assert geo.volumes.shape[0] > 1
    widest = geo.volumes.argmax(0)
    others = np.full(geo.volumes.shape, 1e-4)
    others[widest, np.arange(geo.volumes.shape[1])] = 1.0
    cfg = MassConfig(n_samples=2000, seed=3, structure="hollow")
    base = integrate_mass(pf, geo, cfg, keep_samples=True).samples
    kept = integrate_mass(pf, replace(geo, volumes=geo.volumes * others), cfg, keep_samples=True).samples
    np.testing.assert_allclose(kept, base, rtol=1e-12)
    crushed = integrate_mass(pf, replace(geo, volumes=geo.volumes * 1e-4), cfg, keep_samples=True).samples
    assert np.all(crushed <= base + 1e-12) and np.median(crushed) < 0.1 * np.median(base)


def test_material_quantiles_keep_spatial_shares_and_switch_ambiguous_parts_together():
    """A part whose voxels are sure but differ keeps its volume shares at every level; a part whose voxels are
    all equally unsure switches material as a whole at the mixture's cumulative weight (brute-force oracle)."""
    from physgs_nerfstudio.geometry.parts import material_quantiles

    rng = np.random.default_rng(3)
    parts = np.full((6, 5, 4), -1)
    parts[:3] = 0
    parts[3:] = 1
    mixture = np.zeros((6, 5, 4, 3))
    sure = rng.random((3, 5, 4)) < 0.2  # part 0: 20% of its voxels surely material 2, the rest surely 0
    mixture[:3, ..., 2] = sure
    mixture[:3, ..., 0] = ~sure
    mixture[3:] = [0.7, 0.3, 0.0]  # part 1: every voxel 70/30 between materials 0 and 1
    pm = np.stack([mixture[:3].reshape(-1, 3).mean(0), mixture[3:].reshape(-1, 3).mean(0)])
    q = material_quantiles(parts, mixture, 2, pm, levels=20)
    np.testing.assert_allclose(q.sum(-1), 1.0)
    np.testing.assert_allclose(q[0, :, 2], sure.mean())
    u = (np.arange(20) + 0.5) / 20
    brute = np.stack([(u < 0.7), (u >= 0.7), np.zeros(20, bool)], -1).astype(float)
    np.testing.assert_allclose(q[1], brute)


def test_pooled_part_alpha_is_the_weighted_mean_of_member_posteriors():
    """Pooled Dirichlet per part against a brute-force loop over Gaussians (weights opacity x observed share;
    Gaussians outside the grid, outside every part or with zero weight count for nothing)."""
    from physgs_nerfstudio.geometry.grid import VoxelGrid
    from physgs_nerfstudio.geometry.parts import pooled_part_alpha

    rng = np.random.default_rng(5)
    grid = VoxelGrid.from_bounds(np.zeros(3), np.ones(3), 6)
    parts = rng.integers(-1, 3, size=grid.shape)
    n, K = 400, 5
    means = torch.from_numpy(rng.uniform(-0.1, 1.1, (n, 3)))
    opac = torch.from_numpy(rng.uniform(0, 1, n))
    observed = torch.from_numpy(rng.choice([0.0, 0.5, 1.0], n))
    alpha = torch.from_numpy(1.0 + rng.gamma(1.0, 2.0, (n, K)))
    pooled, support = pooled_part_alpha(grid, parts, 3, means, opac, alpha, observed)
    acc, tot = np.zeros((3, K)), np.zeros(3)
    h = grid.voxel_size
    for i in range(n):  # the oracle: one Gaussian at a time
        ijk = np.floor((means[i].numpy() - np.asarray(grid.origin)) / h).astype(int)
        if (ijk < 0).any() or (ijk >= np.asarray(grid.shape)).any():
            continue
        p = parts[tuple(ijk)]
        w = float(opac[i]) * float(observed[i])
        if p < 0 or w <= 0:
            continue
        acc[p] += w * alpha[i].numpy()
        tot[p] += w
    np.testing.assert_allclose(support, tot, rtol=1e-12)
    np.testing.assert_allclose(pooled[tot > 0], acc[tot > 0] / tot[tot > 0, None], rtol=1e-12)


def test_pooled_part_material_is_sharper_than_the_mean_of_member_weights():
    """A part seen as oak in most views, with a few weakly observed Gaussians and boundary bleed onto steel:
    averaging the members' dominance weights keeps a metal tail; pooling their posteriors first does not,
    and the pooled weights are the dominance of the mean posterior (independent Monte Carlo check)."""
    from physgs_nerfstudio.bayes.mixture import material_mixture_weights

    K = 12
    rng = np.random.default_rng(0)
    ev = np.zeros((300, K))
    ev[:, 0] = rng.uniform(0.5, 6.0, 300)  # oak: 0.5 to 6 views' worth of evidence
    ev[:30, 3] = rng.uniform(0.5, 2.0, 30)  # steel bleed on a tenth of the Gaussians
    alpha = torch.from_numpy(1.0 + ev)
    mean_of_weights = material_mixture_weights(alpha).mean(0)
    pooled = material_mixture_weights(alpha.mean(0, keepdim=True))[0]
    assert float(pooled[0]) > float(mean_of_weights[0]) + 0.03
    assert float(pooled[3]) < 0.85 * float(mean_of_weights[3])
    theta = rng.dirichlet(alpha.mean(0).numpy(), size=200_000)
    mc = np.bincount(theta.argmax(1), minlength=K) / len(theta)
    np.testing.assert_allclose(pooled.numpy(), mc, atol=5e-3)


def test_a_failed_selection_neither_replaces_the_masks_nor_coarsens_the_grid(box, monkeypatch):
    """A selection that holds far-away Gaussians as well as the object (as a 7,000-step GPU run's floaters did)
    renders a silhouette that most views' masks disagree with, and stretches the voxel domain. The masks then stay
    (cut to the silhouette, not replaced by it), and the carving is redone on a grid fitted to the carved solid:
    the box keeps its volume."""
    import physgs_nerfstudio.geometry.reconstruct as rec
    from physgs_nerfstudio.export.shapes import field_from as make

    pf, views = box
    g = torch.Generator().manual_seed(1)
    far = torch.tensor([2.5, -2.0, 1.5]) + 0.3 * torch.randn(300, 3, generator=g)
    means = torch.cat([pf.means, far])
    scales = torch.cat([pf.scales, torch.full((300, 3), 0.15)])
    quats = torch.cat([pf.quats, torch.tensor([[1.0, 0, 0, 0]]).repeat(300, 1)])
    both = make(means, scales, quats, densities=[700.0], names=["oak"], thickness_m=[None])
    real = rec.select_object

    def everything(gs, vs, cfg=None, **kw):  # the failure: every Gaussian counts as the object
        sel = real(gs, vs, cfg, **kw)
        return rec.ObjectSelection(sel.prob, torch.ones_like(sel.selected), sel.centre, sel.num_clusters)

    monkeypatch.setattr(rec, "select_object", everything)
    assert geometry_of(both, views).selection.outside_hull == 300  # the masks' hull drops the far ones; without it:
    monkeypatch.setattr(rec, "drop_outside_hull", lambda *a: None)
    geo = geometry_of(both, views)
    assert geo.selection.num_selected == both.num_gaussians
    assert 0.93 * 0.024 <= geo.volumes[0].sum() <= 1.12 * 0.024
    assert geo.grid.voxel_size < 0.02  # fitted to the box (0.4 m); the 5 m spread gave 0.09


def test_the_masks_hull_drops_gaussians_outside_the_masks_whatever_their_probability(box, monkeypatch):
    """Floaters that only a few views see, over masks that bled, can get a high lifted probability and, one 3-D
    cluster with the object, join it. The hull test counts every view whose frame holds a centre, seen or not:
    centres outside the carving's masks in enough of them are dropped; the object stays whole, and so does its
    volume."""
    import physgs_nerfstudio.geometry.reconstruct as rec
    import physgs_nerfstudio.geometry.select as sel
    from physgs_nerfstudio.export.shapes import field_from as make

    pf, views = box
    n_obj = pf.num_gaussians
    t = torch.linspace(0.21, 0.8, 150)  # a trail of floaters from the box's +x face (x = 0.2) out to 0.8 m
    trail = torch.stack([t, torch.zeros_like(t), torch.zeros_like(t)], -1)
    both = make(torch.cat([pf.means, trail]), torch.cat([pf.scales, torch.full((150, 3), 0.004)]),
                torch.cat([pf.quats, torch.tensor([[1.0, 0, 0, 0]]).repeat(150, 1)]), densities=[700.0],
                names=["oak"], thickness_m=[None])  # fmt: skip
    n = both.num_gaussians
    # the lifted probability says "object" everywhere (the failure this test is about)
    monkeypatch.setattr(sel, "lift_masks", lambda g, vs, **kw: (torch.full((n,), 5.0, dtype=torch.float64),
                                                                 torch.zeros(n, dtype=torch.float64)))  # fmt: skip
    with monkeypatch.context() as m:  # without the masks' hull
        m.setattr(rec, "drop_outside_hull", lambda *a: None)
        without = geometry_of(both, views).selection
    with pytest.raises(ValueError, match="hull_vote_fraction"):
        _select(hull_vote_fraction=2.0)
    assert bool(without.selected[n_obj:].all())  # the trail is one cluster with the box
    geo = geometry_of(both, views)
    kept = geo.selection.selected
    assert float(kept[:n_obj].float().mean()) == 1.0
    # a point near the +x face projects into the box's silhouette from most azimuths; 15 cm out it does not
    assert not bool(kept[n_obj:][t > 0.35].any())
    assert geo.selection.outside_hull >= int((t > 0.35).sum())
    assert 0.95 * 0.024 <= geo.volumes[0].sum() <= 1.1 * 0.024


def test_hull_view_weights_are_each_masks_recall_of_the_majority():
    """:func:`hull_view_weights` against a loop over views and points (the oracle), on random votes with some
    points framed by no view and one view that frames nothing."""
    from physgs_nerfstudio.geometry.select import hull_view_weights

    g = torch.Generator().manual_seed(5)
    V, n = 9, 400
    framed = torch.rand(V, n, generator=g) < 0.7
    framed[3] = False
    framed[:, :20] = False
    outside = framed & (torch.rand(V, n, generator=g) < torch.linspace(0.05, 0.9, V)[:, None])
    want = np.ones(V)
    member = [framed[:, j].sum() > 0 and 2 * outside[:, j].sum() < framed[:, j].sum() for j in range(n)]
    for i in range(V):
        held = [j for j in range(n) if member[j] and framed[i, j]]
        if held:
            want[i] = sum(1 for j in held if not outside[i, j]) / len(held)
    got = hull_view_weights(framed, outside).numpy()
    np.testing.assert_allclose(got, want, rtol=1e-12)
    assert got[3] == 1.0 and got[0] > got[-1]


def test_the_weighed_hull_keeps_a_part_that_many_views_lost(box, monkeypatch):
    """When two views in five lost two thirds of the box (the built-in segmenter at 512 px lost the table's top in a
    third of the views), a count of their votes at a hull vote fraction of 0.35 drops much of the lost part's
    Gaussians (30%); weighed by each mask's recall, the views that lost it say less and the box stays whole. A far
    floater, outside every mask, still goes either way."""
    from dataclasses import replace

    import physgs_nerfstudio.geometry.select as sel

    pf, views = box
    keep = pf.means[:, 0] > 0.07  # the box (x in [-0.2, 0.2]) without its two thirds at x < 0.07 (a table's top)
    rest = field_from(pf.means[keep], pf.scales[keep], pf.quats[keep], densities=[700.0], names=["oak"],
                      thickness_m=[None])  # fmt: skip
    lost = {i for k in range(0, len(views), 5) for i in (k, k + 1)}
    renders = render_depth(rest, [views[i] for i in sorted(lost)], backend="reference")
    masks = dict(zip(sorted(lost), (r.alpha > 0.5 for r in renders)))
    damaged = [replace(v, mask=masks[i]) if i in lost else v for i, v in enumerate(views)]
    means = torch.cat([pf.means.float(), torch.tensor([[0.0, 0.0, 0.6]])])
    cfg = _select(hull_vote_fraction=0.35)

    def counted(vs):  # every view's vote 1
        with monkeypatch.context() as m:
            m.setattr(sel, "hull_view_weights", lambda f, *a: torch.ones(len(f), dtype=torch.float64))
            return sel.outside_mask_hull(means, vs, cfg)

    weighed = sel.outside_mask_hull(means, damaged, cfg)
    assert float(counted(damaged)[:-1][~keep].float().mean()) > 0.2  # much of the lost part goes with a count
    assert not bool(weighed[:-1].any())
    assert bool(counted(damaged)[-1]) and bool(weighed[-1])
    # with every mask whole, each view weighs 1 and the two votes agree
    assert torch.equal(sel.outside_mask_hull(means, views, cfg), counted(views))


def test_masks_that_lost_a_part_do_not_carve_it(box):
    """A segmenter drops a part of the object in some views. Those views agree with the object's silhouette well
    enough to keep their masks, but the masks do not carve (the views' depth does: :mod:`.free_space`), so the part
    stays."""
    from dataclasses import replace

    pf, views = box
    damaged = []
    for i, v in enumerate(views):
        m = v.mask.clone()
        if i % 3 == 0:  # a third of the views lose the object's left third (a "part")
            cols = torch.nonzero(m.any(0)).squeeze(1)
            m[:, : int(cols.min() + (cols.max() - cols.min()) / 3)] = False
        damaged.append(replace(v, mask=m))
    kept = geometry_of(pf, damaged).volumes[0].sum()
    assert 0.93 * 0.024 <= kept <= 1.1 * 0.024


def capsule_surface(radius, length, spacing):
    """Flat Gaussians on a capsule along z (a cylinder of ``length`` with hemispherical caps; ``length`` 0: a
    sphere)."""
    pts, nrm = [], []
    if length > 0:
        n_ang = max(8, round(2 * math.pi * radius / spacing))
        n_h = max(2, round(length / spacing))
        th = torch.arange(n_ang, dtype=torch.float64) / n_ang * 2 * math.pi
        hz = (torch.arange(n_h, dtype=torch.float64) + 0.5) / n_h * length - length / 2
        T, Z = torch.meshgrid(th, hz, indexing="ij")
        pts.append(torch.stack([radius * torch.cos(T), radius * torch.sin(T), Z], -1).reshape(-1, 3))
        nrm.append(torch.stack([torch.cos(T), torch.sin(T), torch.zeros_like(T)], -1).reshape(-1, 3))
    n = max(8, round(2 * math.pi * radius**2 / spacing**2))
    i = torch.arange(n, dtype=torch.float64) + 0.5
    zz = i / n
    phi = math.pi * (3 - math.sqrt(5)) * i
    r = torch.sqrt(1 - zz * zz)
    for sign in (1.0, -1.0):
        nn = torch.stack([r * torch.cos(phi), r * torch.sin(phi), sign * zz], -1)
        pts.append(radius * nn + torch.tensor([0.0, 0.0, sign * length / 2], dtype=torch.float64))
        nrm.append(nn)
    return flat_gaussians(torch.cat(pts), torch.cat(nrm), spacing * 0.5)


def exact_capsule_masks(views, length, radius):
    """The capsule's exact silhouette per view: pixel-centre rays that pass within ``radius`` of its axis segment
    (sampled every length/100), independent of the Gaussians and of any rendering."""
    seg = torch.zeros(101, 3, dtype=torch.float64)
    seg[:, 2] = torch.linspace(-length / 2, length / 2, 101, dtype=torch.float64)
    for v in views:
        c, d = pixel_rays(v)
        best = torch.full((v.height, v.width), float("inf"), dtype=torch.float64)
        for p in seg:
            w = p - c
            s = (d * w).sum(-1, keepdim=True).clamp_min(0)
            best = torch.minimum(best, (c + s * d - p).norm(dim=-1))
        v.mask = best <= radius
    return views


@pytest.mark.parametrize("radius, length, opacity, spacing", [(0.1, 0.0, 0.5, 0.012), (0.02, 0.3, 0.8, 0.01)])
def test_compact_solids_are_not_carved_from_the_front_by_the_surface_depth(radius, length, opacity, spacing):
    """A solid sphere (26 px across) and a thin solid rod (6 px wide) whose surface Gaussians are not opaque: a
    pixel's expected depth mixes the front surface with the back one and lies behind the front (it carved the front
    away: 0.60x and 0.85x of the true volume); the surface depth stays on the front surface. Masks are the exact
    silhouettes, so the volume is the depth rule's alone."""
    means, scales, quats = capsule_surface(radius, length, spacing)
    pf = field_from(means, scales, quats, densities=[1000.0], names=["c"], thickness_m=[None], opacity=opacity)
    views = exact_capsule_masks(ring_views(pf, (0, 0, 0), 1.0 if length == 0 else 0.9, n=16), length, radius)
    true_v = math.pi * radius**2 * length + 4 / 3 * math.pi * radius**3
    # (whole voxels: the rules' carving compared, without partial volume's shares)
    kw = {"resolution": 48, "variants": False}
    got = whole_voxel_volume(geometry_of(pf, views, carve=_carve(), **kw)) / true_v
    assert 0.9 <= got <= 1.12


@pytest.mark.parametrize("transmittance", [0.5, 0.8])
def test_surface_depth_is_the_transmittance_crossing(transmittance):
    """reference_surface_depth against a direct per-pixel loop: composite the Gaussians that the rasterizer used at
    a pixel (their alphas recovered from colour renders of one-hot indicators), front to back, and find the densest
    point of the one that crosses the level along the pixel's ray by sampling its density on the ray."""
    from physgs_nerfstudio.render import rasterize, reference_surface_depth
    from physgs_nerfstudio.render.projection import covariance_3d

    g = torch.Generator().manual_seed(3)
    n = 40
    means = torch.randn(n, 3, generator=g) * 0.15
    scales = 0.03 + 0.05 * torch.rand(n, 3, generator=g)
    quats = torch.randn(n, 4, generator=g)
    quats = quats / quats.norm(dim=1, keepdim=True)
    opac = 0.2 + 0.7 * torch.rand(n, generator=g)
    prec = torch.linalg.inv(covariance_3d(quats.double(), scales.double()))
    views = ring_views(field_from(means, scales, quats), (0, 0, 0), 1.2, n=3, size=24)
    checked = 0
    for v in views:
        got = reference_surface_depth(means, quats, scales, opac, v.viewmat, v.K, 24, 24, transmittance=transmittance)
        w, _, _ = rasterize(means, quats, scales, opac, torch.eye(n), v.viewmat[None], v.K[None], 24, 24,
                            backend="reference")  # blending weight of each Gaussian at each pixel  # fmt: skip
        R, t, K = v.viewmat[:3, :3].double(), v.viewmat[:3, 3].double(), v.K.double()
        z = (means.double() @ R.T + t)[:, 2]
        order = torch.argsort(z)
        for y in range(0, 24, 3):
            for x in range(0, 24, 3):
                acc = torch.cumsum(w[0, y, x, order], 0)  # 1 - transmittance after each Gaussian
                hit = torch.nonzero(acc >= 1 - transmittance - 1e-6)
                if not len(hit):
                    assert math.isinf(float(got[y, x]))
                    continue
                i = int(order[hit[0, 0]])
                ray = torch.tensor([(x + 0.5 - K[0, 2]) / K[0, 0], (y + 0.5 - K[1, 2]) / K[1, 1], 1.0],
                                   dtype=torch.float64) @ R  # the pixel's ray, world, per unit of camera z
                cam = -R.T @ t
                zs = torch.linspace(float(z[i]) - 0.5, float(z[i]) + 0.5, 20001, dtype=torch.float64)
                off = cam + zs[:, None] * ray - means[i].double()
                want = float(zs[torch.argmin(((off @ prec[i]) * off).sum(-1))])
                assert float(got[y, x]) == pytest.approx(want, abs=1e-4)
                checked += 1
    assert checked > 20


def test_a_parts_whole_surface_is_reported(box):
    """The part's whole surface is the box's (marching cubes of the carved solid against 2 (0.4 x 0.3 + 0.4 x 0.2 +
    0.3 x 0.2) m^2), per variant, and the report carries the nominal variant's."""
    pf, views = box
    geo = geometry_of(pf, views)
    assert geo.surface_areas.shape == geo.volumes.shape
    assert geo.surface_areas[0].sum() == pytest.approx(2 * (0.12 + 0.08 + 0.06), rel=0.1)
    rep = integrate_mass(pf, geo, MassConfig(n_samples=200, seed=3, structure="solid"))
    assert rep.parts[0]["surface_area_m2"] == pytest.approx(float(geo.surface_areas[0, 0]))


def test_seam_areas_count_the_faces_between_parts():
    """seam_areas against a brute-force loop over voxel pairs on random labels, and the contact of two stacked
    blocks: their shared face, exactly."""
    from physgs_nerfstudio.geometry.walls import seam_areas

    rng = np.random.default_rng(4)
    lab = rng.integers(-1, 4, size=(5, 6, 4))
    want = np.zeros((4, 4))
    for x, y, z in np.ndindex(lab.shape):
        for d in ((1, 0, 0), (0, 1, 0), (0, 0, 1)):
            u, v, w = x + d[0], y + d[1], z + d[2]
            if u < lab.shape[0] and v < lab.shape[1] and w < lab.shape[2]:
                a, b = lab[x, y, z], lab[u, v, w]
                if a >= 0 and b >= 0 and a != b:
                    want[a, b] += 1
                    want[b, a] += 1
    np.testing.assert_array_equal(seam_areas(lab, 4, 1.0), want)
    blocks = np.full((10, 10, 10), -1)
    blocks[2:8, 3:7, 1:5] = 0  # 6 x 4 voxels of contact at z = 5
    blocks[2:8, 3:7, 5:9] = 1
    got = seam_areas(blocks, 2, 0.01)
    assert got[0, 1] == got[1, 0] == pytest.approx(24 * 0.01**2) and got[0, 0] == got[1, 1] == 0


def test_seam_transfer_moves_volume_between_touching_parts_only():
    """Each sample's transfers sum to zero; a part's gain has the variance of its seams' areas times the offset's
    spread, summed over its seams (Monte Carlo against the closed form); a part without seams gains nothing."""
    from physgs_nerfstudio.mass.integrate import seam_transfer

    seams = np.array([[0.0, 2.0, 0.5, 0.0], [2.0, 0.0, 1.0, 0.0], [0.5, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]])
    t = seam_transfer(seams, 0.3, np.random.default_rng(0), 200000)
    np.testing.assert_allclose(t.sum(1), 0.0, atol=1e-12)
    want = (seams**2).sum(1) * 0.3**2
    np.testing.assert_allclose(t.var(0)[:3], want[:3], rtol=0.02)
    assert not t[:, 3].any()
    assert not seam_transfer(np.zeros((3, 3)), 0.3, np.random.default_rng(0), 10).any()


def _split_in_two(geo):
    """The box's geometry as two parts, split at mid-height, with their seam; every other field the box's."""
    import dataclasses

    from physgs_nerfstudio.bayes.nig import NIG
    from physgs_nerfstudio.geometry.walls import seam_areas
    from physgs_nerfstudio.geometry.structure import PartStructure

    z = np.argwhere(geo.solid)[:, 2]
    cut = int(np.median(z))
    parts = np.where(geo.parts >= 0, (np.indices(geo.parts.shape)[2] >= cut).astype(int), -1)
    h = geo.grid.voxel_size
    st, rep = geo.structure, lambda a: np.repeat(np.asarray(a), 2)
    t = st.thickness
    two = PartStructure(rep(st.hollow_a), rep(st.hollow_b),
                        NIG(t.tau.repeat(2), t.kappa.repeat(2), t.a.repeat(2), t.b.repeat(2)), rep(st.observations))
    vol = np.stack([np.bincount(np.where(geo.solid, parts, -1)[geo.solid], minlength=2) * h**3] * len(geo.volumes))
    return dataclasses.replace(
        geo, parts=parts, part_mixture=np.repeat(geo.part_mixture, 2, 0), volumes=vol,
        areas=np.repeat(geo.areas, 2, 1) / 2, surface_areas=np.repeat(geo.surface_areas, 2, 1) / 2,
        full_areas=None, curvatures=None, sheet_share=np.repeat(geo.sheet_share, 2), structure=two,
        material_levels=None, seam_areas=seam_areas(np.where(geo.solid, parts, -1), 2, h))  # fmt: skip


def test_seams_move_mass_only_between_parts_of_unlike_weight(box):
    """The box cut in two at mid-height. Both halves solid oak: moving their seam moves no mass (the samples are
    the same as without it, drawn in the same order). The upper half hollow with a thin wall: the seam now moves
    the lower half's solid oak, and the mass's spread grows by its density x the seam's area x the offset's spread
    (the difference of the two runs' samples, one draw each)."""
    import dataclasses

    pf, views = box
    geo = _split_in_two(geometry_of(pf, views))
    area = float(geo.seam_areas[0, 1])
    assert area == pytest.approx(0.4 * 0.3, rel=0.15)  # the box's horizontal section
    unit = geo.grid.voxel_size * max(1.0, geo.pixel_voxels)
    kw = {"n_samples": 20000, "seed": 5, "structure": "solid", "surface_offset_voxels": 0.0}
    off = integrate_mass(pf, geo, MassConfig(**kw, seam_offset_voxels=0.0), keep_samples=True)
    on = integrate_mass(pf, geo, MassConfig(**kw), keep_samples=True)  # the default, 1.0
    np.testing.assert_allclose(on.samples, off.samples, rtol=1e-9)
    assert on.parts[0]["seams_m2"] == {"1": pytest.approx(area)} and on.geometry["seam_offset_voxels"] == 1.0
    st = geo.structure
    hollow_top = dataclasses.replace(st, hollow_a=np.array([1e-3, 1e6]), hollow_b=np.array([1e6, 1e-3]))
    g2 = dataclasses.replace(geo, structure=hollow_top)
    kw["structure"] = "auto"
    off = integrate_mass(pf, g2, MassConfig(**kw, seam_offset_voxels=0.0), keep_samples=True)
    on = integrate_mass(pf, g2, MassConfig(**kw, seam_offset_voxels=1.0), keep_samples=True)
    rho = 700.0
    assert float(np.std(on.samples - off.samples)) == pytest.approx(rho * area * unit, rel=0.1)
    assert abs(float(np.mean(on.samples - off.samples))) < 0.05 * rho * area * unit
    assert on.interval_kg[0] <= on.median_kg <= on.interval_kg[1]
    assert on.interval_kg[1] - on.interval_kg[0] > off.interval_kg[1] - off.interval_kg[0]
    with pytest.raises(ValueError, match="seam_offset_voxels"):
        MassConfig(seam_offset_voxels=float("nan"))


def test_the_surface_offset_is_one_normal_draw_for_the_whole_object(box):
    """The solid box, every other draw the same (the offset is drawn last): each sample's mass over its mass without
    the offset is ``g(a z) / E[g(a z)]``, ``g(x) = 1 + x`` outwards and ``exp(x)`` inwards, ``a = S s u / V``. With
    the mean growth from numerical integration (scipy's quad, not the module's closed form), the offsets ``z``
    recovered from those ratios are standard normal by a Kolmogorov-Smirnov test; the mean mass stays (within 4
    Monte Carlo standard errors) and the interval widens. A negative or NaN spread is refused."""
    from scipy import integrate, stats

    pf, views = box
    geo = geometry_of(pf, views)
    kw = {"n_samples": 4000, "seed": 3, "structure": "solid", "seam_offset_voxels": 0.0}
    off = integrate_mass(pf, geo, MassConfig(**kw, surface_offset_voxels=0.0), keep_samples=True)
    on = integrate_mass(pf, geo, MassConfig(**kw, surface_offset_voxels=3.0), keep_samples=True)
    gi = mass_draws(pf, geo, MassConfig(**kw, surface_offset_voxels=0.0)).variant
    unit = geo.grid.voxel_size * max(1.0, geo.pixel_voxels)
    a = geo.surface_areas[gi, 0] * 3.0 * unit / geo.volumes[gi, 0]
    g = lambda x: 1.0 + x if x >= 0 else math.exp(x)
    mean_g = {v: integrate.quad(lambda z, v=v: g(v * z) * stats.norm.pdf(z), -40, 40, points=[0.0])[0]
              for v in np.unique(a)}  # fmt: skip
    grown = on.samples / off.samples * np.array([mean_g[v] for v in a])
    z = np.where(grown >= 1, (grown - 1) / a, np.log(grown) / a)
    assert stats.kstest(z, "norm").pvalue > 0.01
    assert abs(on.mean_kg - off.mean_kg) < 4 * float(np.std(on.samples)) / math.sqrt(len(on.samples))
    assert on.geometry["surface_offset_voxels"] == 3.0
    assert on.interval_kg[1] - on.interval_kg[0] > 1.2 * (off.interval_kg[1] - off.interval_kg[0])
    assert (on.samples > 0).all()
    for bad in (-0.1, float("nan")):
        with pytest.raises(ValueError, match="surface_offset_voxels"):
            MassConfig(surface_offset_voxels=bad)


@pytest.mark.parametrize("value", [0.0, -1.0])
def test_a_voxel_evidence_threshold_of_zero_is_refused(value):
    """0 would let a voxel with no evidence divide its mixture by zero (NaN masses): one line at the config."""
    with pytest.raises(ValueError, match="min_voxel_evidence"):
        GeometryConfig(min_voxel_evidence=value)
