"""Mass integration on analytic Gaussian clouds with known shape, density and thickness."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from physgs_nerfstudio.export.grid import VoxelGrid, splat
from physgs_nerfstudio.export.mass import MassConfig, integrate_mass, mass_geometry
from physgs_nerfstudio.export.occupancy import OccupancyConfig, compute_occupancy, volume_weights
from physgs_nerfstudio.export.shapes import field_from, material_nig, shell_sphere, solid_box, solid_cylinder

OCC = OccupancyConfig(resolution=64, progress=False)
BOX = (1.0, 0.6, 0.4)
SPACING = 0.05


def cfg(**kw) -> MassConfig:
    kw.setdefault("n_samples", 2000)
    return MassConfig(occupancy=OCC, **kw)


@pytest.fixture(scope="module")
def box_field():
    means, scales, quats = solid_box(BOX, SPACING)
    return field_from(means, 0.5 * scales, quats, densities=[800.0])


@pytest.fixture(scope="module")
def box_geometry(box_field):
    return mass_geometry(box_field, cfg())


@pytest.fixture(scope="module")
def sphere_field():
    means, scales, quats = shell_sphere(0.5, 0.02)
    return field_from(means, scales, quats, densities=[2400.0], thickness_m=[0.004])


def test_splat_matches_brute_force():
    g = torch.Generator().manual_seed(0)
    n = 40
    means, scales = torch.rand(n, 3, generator=g), 0.03 + 0.1 * torch.rand(n, 3, generator=g)
    quats, op = torch.randn(n, 4, generator=g), torch.rand(n, generator=g)
    grid = VoxelGrid.from_bounds(torch.full((3,), -0.2), torch.full((3,), 1.2), 20)
    w, wv = splat(grid, means, quats, scales, op, values=torch.ones(n, 2), cutoff=12.0, pair_budget=777,
                  filter_sigma=0.01)  # fmt: skip
    idx = torch.stack(torch.meshgrid(*[torch.arange(s) for s in grid.shape], indexing="ij"), -1).reshape(-1, 3)
    q = quats / quats.norm(dim=-1, keepdim=True)
    w_, x, y, z = q.unbind(-1)
    R = torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w_ * z), 2 * (x * z + w_ * y),
                     2 * (x * y + w_ * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w_ * x),
                     2 * (x * z - w_ * y), 2 * (y * z + w_ * x), 1 - 2 * (x * x + y * y)], -1).reshape(n, 3, 3)
    cov = R @ torch.diag_embed(scales**2 + 0.01**2) @ R.transpose(1, 2)
    d = grid.centres(idx)[:, None, :] - means[None]
    m = torch.einsum("vni,nij,vnj->vn", d, torch.linalg.inv(cov), d)
    ref = (op * torch.exp(-0.5 * m)).sum(1)
    assert torch.allclose(w, ref, atol=1e-5 * float(ref.max()))
    assert torch.allclose(wv[:, 1], ref, atol=1e-5 * float(ref.max()))


def test_solid_box_mass(box_field, box_geometry):
    r = integrate_mass(box_field, cfg(), geometry=box_geometry)
    truth = 800.0 * math.prod(BOX)
    assert r.mean_kg == pytest.approx(truth, rel=0.03)
    assert r.median_kg == pytest.approx(truth, rel=0.03)
    assert r.volume_m3 == pytest.approx(math.prod(BOX), rel=0.03)
    assert r.materials[0].volume_model == "solid" and r.materials[0].volume_share == pytest.approx(1.0)


def test_solid_cylinder_mass():
    means, scales, quats = solid_cylinder(0.3, 0.5, 0.03)
    pf = field_from(means, 0.5 * scales, quats, densities=[2700.0])
    r = integrate_mass(pf, cfg())
    assert r.mean_kg == pytest.approx(2700.0 * math.pi * 0.3**2 * 0.5, rel=0.03)


def test_shell_sphere_mass(sphere_field):
    r = integrate_mass(sphere_field, cfg())
    area = 4 * math.pi * 0.5**2
    assert r.materials[0].volume_model == "shell"
    assert r.area_m2 == pytest.approx(area, rel=0.03)
    assert r.mean_kg == pytest.approx(area * 0.004 * 2400.0, rel=0.03)
    # forced solid: the filled ball (sheet voxels counted half)
    solid = integrate_mass(sphere_field, cfg(volume_model="solid"))
    assert solid.mean_kg == pytest.approx(4 / 3 * math.pi * 0.5**3 * 2400.0, rel=0.03)


def test_sheet_correction_only_applies_to_cavities(sphere_field, box_geometry):
    occ = compute_occupancy(sphere_field, OCC)
    w = volume_weights(occ)
    assert (w == 0.5).any() and w.sum() < occ.solid.sum()
    box_occ = box_geometry.occupancy
    assert (volume_weights(box_occ) == box_occ.solid).all()  # no cavity: nothing halved


def _width(r):
    return r.interval_kg[1] - r.interval_kg[0]


def test_interval_widens_with_weaker_posterior(box_field, box_geometry):
    tight = integrate_mass(box_field, cfg(), geometry=box_geometry)
    base = material_nig([800.0], kappa=50.0, a=20.0, rel_sd=0.05)
    ref = integrate_mass(replace(box_field, nig=base), cfg(), geometry=box_geometry)
    larger_b = replace(base, b=base.b * 4)
    smaller_kappa = replace(base, kappa=base.kappa * 0 + 0.5)
    wb = _width(integrate_mass(replace(box_field, nig=larger_b), cfg(), geometry=box_geometry))
    wk = _width(integrate_mass(replace(box_field, nig=smaller_kappa), cfg(), geometry=box_geometry))
    assert _width(tight) < _width(ref) < wb
    assert _width(ref) < wk
    assert wb / _width(ref) == pytest.approx(2.0, rel=0.15)  # predictive scale ~ sqrt(b)


def test_interval_covers_truth_and_is_calibrated(box_field, box_geometry):
    truth = 800.0 * math.prod(BOX)
    r = integrate_mass(replace(box_field, nig=material_nig([800.0], rel_sd=0.05)),
                       cfg(level=0.9, density_draw="predictive"),
                       geometry=box_geometry, keep_samples=True)  # fmt: skip
    assert r.covers(truth)
    assert r.samples is not None and np.mean(r.samples <= r.interval_kg[1]) == pytest.approx(0.95, abs=0.01)
    # with a 5% density sd the 90% interval spans about +-1.645 * 5%
    assert (r.interval_kg[1] - r.interval_kg[0]) / r.median_kg == pytest.approx(2 * 1.645 * 0.05, rel=0.15)


def test_seeded_and_reproducible(box_field, box_geometry):
    a = integrate_mass(box_field, cfg(seed=3), geometry=box_geometry)
    b = integrate_mass(box_field, cfg(seed=3), geometry=box_geometry)
    c = integrate_mass(box_field, cfg(seed=4), geometry=box_geometry)
    assert a.interval_kg == b.interval_kg and a.interval_kg != c.interval_kg


def test_mass_scales_with_metres_per_unit(box_field, box_geometry, sphere_field):
    r1 = integrate_mass(box_field, cfg(), geometry=box_geometry)
    r2 = integrate_mass(replace(box_field, metres_per_unit=2.0), cfg())
    assert r2.mean_kg == pytest.approx(8 * r1.mean_kg, rel=1e-6)
    s1 = integrate_mass(sphere_field, cfg())
    s2 = integrate_mass(replace(sphere_field, metres_per_unit=0.1), cfg())
    assert s2.mean_kg == pytest.approx(0.01 * s1.mean_kg, rel=1e-6)  # shell: area ~ scale^2, thickness in m
    with pytest.raises(ValueError, match="metres_per_unit"):
        integrate_mass(replace(box_field, metres_per_unit=2.0), cfg(), geometry=box_geometry)


def test_two_materials_and_ambiguity():
    means, scales, quats = solid_box(BOX, SPACING)
    labels = (means[:, 0] > 0).long()
    pf = field_from(means, 0.5 * scales, quats, densities=[500.0, 2000.0], labels=labels)
    geo = mass_geometry(pf, cfg())
    r = integrate_mass(pf, cfg(), geometry=geo)
    half = math.prod(BOX) / 2
    assert r.mean_kg == pytest.approx(half * 2500.0, rel=0.04)
    for m in r.materials:
        assert m.volume_share == pytest.approx(0.5, abs=0.03)
    assert geo.num_segments == 2
    # an ambiguous material posterior everywhere: wide interval spanning both single-material masses
    amb = replace(pf, alpha=torch.ones_like(pf.alpha))
    ra = integrate_mass(amb, cfg(segments="object"))
    assert ra.interval_kg[0] < 1.1 * 500.0 * 2 * half and ra.interval_kg[1] > 0.9 * 2000.0 * 2 * half
    assert ra.mean_kg == pytest.approx(1250.0 * 2 * half, rel=0.04)


def test_bbox_selects_object(box_field):
    means, scales, quats = solid_box((0.3, 0.3, 0.3), SPACING, centre=(2.0, 0.0, 0.0))
    two = field_from(torch.cat([box_field.means, means]), torch.cat([box_field.scales, 0.5 * scales]),
                     torch.cat([box_field.quats, quats]), densities=[800.0])  # fmt: skip
    occ = replace(OCC, bbox=(1.7, -0.3, -0.3, 2.3, 0.3, 0.3), resolution=48)
    r = integrate_mass(two, MassConfig(occupancy=occ, n_samples=500))
    assert r.mean_kg == pytest.approx(800.0 * 0.027, rel=0.05)


def test_small_box_path_matches_pair_path():
    from physgs_nerfstudio.export.shapes import random_cloud

    means, scales, quats, op, _ = random_cloud(3000, seed=1)
    grid = VoxelGrid.from_bounds(torch.full((3,), -1.1), torch.full((3,), 1.1), 40)
    kw = dict(values=torch.rand(3000, 3), filter_sigma=0.5 * grid.voxel_size, cutoff=5.0)
    w1, v1 = splat(grid, means, quats, scales, op, **kw)
    w2, v2 = splat(grid, means, quats, scales, op, small_box=0, **kw)
    assert torch.allclose(w1, w2, atol=1e-4) and torch.allclose(v1, v2, atol=1e-4)
