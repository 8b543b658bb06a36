"""The boundary with hidden open space (physgs_nerfstudio.geometry.hidden, "The boundary with hidden open space"):
the kept voxels with a face onto the space the rules removed count half a voxel in the volume, and the mass's
Monte Carlo draws their occupancy uniformly in [0, 1]."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from physgs_nerfstudio.geometry.hidden import hidden_boundary


def _oracle(kept: np.ndarray, removed: np.ndarray) -> np.ndarray:
    """Brute force: a kept voxel with one of its six face neighbours in ``removed``."""
    out = np.zeros_like(kept)
    X, Y, Z = kept.shape
    for x, y, z in np.argwhere(kept):
        for d in ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)):
            n = (x + d[0], y + d[1], z + d[2])
            if 0 <= n[0] < X and 0 <= n[1] < Y and 0 <= n[2] < Z and removed[n]:
                out[x, y, z] = True
    return out


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), shape=st.tuples(*[st.integers(1, 7)] * 3), p=st.floats(0.05, 0.9))
def test_the_boundary_is_the_kept_voxels_facing_removed_space(seed, shape, p):
    rng = np.random.default_rng(seed)
    solid = rng.random(shape) < p
    kept = solid & (rng.random(shape) < 0.6)
    removed = solid & ~kept
    got = hidden_boundary(torch.from_numpy(kept), torch.from_numpy(removed)).numpy()
    np.testing.assert_array_equal(got, _oracle(kept, removed))
    assert not (got & ~kept).any()  # only kept voxels, never the removed space itself


def test_a_plate_over_removed_space_has_its_lower_layer_as_boundary():
    """A plate 3 voxels thick over a removed layer: the boundary is the plate's lowest layer (diagonal neighbours
    do not count), and a plate with nothing removed under it has none."""
    kept = np.zeros((6, 6, 8), bool)
    kept[1:5, 1:5, 4:7] = True
    removed = np.zeros_like(kept)
    removed[1:5, 1:5, 2:4] = True
    removed[0, 0, 3] = True  # touches the plate's corner voxel (1, 1, 4) along an edge only
    got = hidden_boundary(torch.from_numpy(kept), torch.from_numpy(removed)).numpy()
    want = np.zeros_like(kept)
    want[1:5, 1:5, 4] = True
    np.testing.assert_array_equal(got, want)
    assert not hidden_boundary(torch.from_numpy(kept), torch.zeros_like(torch.from_numpy(kept))).any()


@pytest.fixture(scope="module")
def table_geometries():
    """The table of test_hidden_space shot from above (every view 35-75 degrees up), its boundary voxels at half,
    and the same geometry with every boundary voxel whole."""
    from dataclasses import replace

    from helpers.shapes import geometry_of, ring_views, table_on_floor

    pf, only_obj = table_on_floor()
    views = ring_views(pf, (0, 0, 0.3), 2.2, n=18, elevations=(35.0, 55.0, 75.0), mask_pf=only_obj)
    half = geometry_of(pf, views, resolution=64)
    assert half.hidden_boundary is not None
    whole = replace(half, volumes=half.volumes + 0.5 * half.hidden_boundary, hidden_boundary=None, hidden_edge=None)
    return pf, half, whole


def test_the_volume_counts_the_boundary_at_half(table_geometries):
    """Every variant's part volumes are the whole-voxel ones less half the boundary's, the boundary is the kept
    voxels under the top (on the rule's side of the object), and the table's volume comes nearer its truth."""
    _, half, whole = table_geometries
    truth = 0.8 * 0.5 * 0.04 + 4 * 0.04 * 0.04 * 0.5
    assert whole.hidden_boundary is None and whole.hidden_boundary_fill == 1.0
    assert half.hidden_boundary is not None and half.hidden_boundary_fill == 0.5
    assert half.hidden_boundary.shape == half.volumes.shape
    n = half.summary()["hidden_boundary_voxels"]
    assert n == int(half.hidden_edge.sum())
    # the boundary's volume: its voxels' shares (geometry/partial.py: the surface cuts some of them)
    h3 = half.grid.voxel_size**3
    assert float(half.hidden_boundary[0].sum()) == pytest.approx(float(half.occupancy[half.hidden_edge].sum()) * h3)
    assert whole.summary()["hidden_boundary_voxels"] is None
    assert n > 0.5 * (0.8 * 0.5) / half.grid.voxel_size**2  # at least half the top's footprint: its underside
    print("truth", truth, "whole", whole.volumes[0].sum(), "half", half.volumes[0].sum(), "boundary voxels", n)
    assert abs(half.volumes[0].sum() - truth) < abs(whole.volumes[0].sum() - truth)


def test_the_voxel_grid_writes_the_fill_that_the_volume_counts(table_geometries, tmp_path):
    """voxels.npz's ``fill`` is the occupancy (1 inside the solid, a share around its surface: geometry/partial.py),
    halved on the boundary with hidden open space, 0 away from the solid, and sums to the nominal volume."""
    from physgs_nerfstudio.export.voxel import load_voxel_grid, write_voxel_grid
    from physgs_nerfstudio.geometry.partial import outer_rim

    pf, half, whole = table_geometries
    for geo in (half, whole):
        d = load_voxel_grid(write_voxel_grid(pf, tmp_path / "voxels.npz", geo))
        fill = d["fill"]
        solid = d["occupancy"] > 0
        assert fill.dtype == np.float32 and fill.min() >= 0 and fill.max() <= 1
        assert not fill[~solid & ~outer_rim(solid)].any()
        expected = geo.occupancy.copy()
        if geo.hidden_edge is not None:
            expected[geo.hidden_edge] *= 0.5
        np.testing.assert_array_equal(fill, expected)
        assert float(fill.sum()) * geo.grid.voxel_size**3 == pytest.approx(float(geo.volumes[0].sum()), rel=1e-6)
    np.testing.assert_array_equal(d["fill"], whole.occupancy)  # "whole": no half voxel


def test_the_mass_draws_the_boundary_occupancy(table_geometries):
    """The Monte Carlo's part volume is V_g + (o - 1/2) B_g, the variant g drawn uniformly and o ~ U(0, 1): its
    interval against the quantiles of that mixture of uniforms (root finding on its CDF, an oracle that shares
    no code with the Monte Carlo); with every boundary voxel whole there is no such draw."""
    from scipy.optimize import brentq

    from physgs_nerfstudio.mass import MassConfig, integrate_mass

    pf, half, whole = table_geometries
    n = 40000
    cfg = {"n_samples": n, "seed": 5, "structure": "solid", "seam_offset_voxels": 0.0, "surface_offset_voxels": 0.0}
    rep = integrate_mass(pf, half, MassConfig(**cfg), keep_samples=True)
    V, B = half.volumes[:, 0], half.hidden_boundary[:, 0]
    mpu3 = float(pf.metres_per_unit) ** 3
    lo_v, hi_v = (V - 0.5 * B) * mpu3, (V + 0.5 * B) * mpu3
    cdf = lambda x: float(np.mean(np.clip((x - lo_v) / np.maximum(hi_v - lo_v, 1e-30), 0.0, 1.0)))
    want = [brentq(lambda x, q=q: cdf(x) - q, 0.0, 2 * hi_v.max()) for q in (0.05, 0.95)]
    got = rep.parts[0]["volume_interval_m3"]
    assert got[0] == pytest.approx(want[0], rel=0.01) and got[1] == pytest.approx(want[1], rel=0.01)
    assert rep.interval_kg[0] <= rep.median_kg <= rep.interval_kg[1]
    assert rep.interval_kg[0] <= rep.mean_kg <= rep.interval_kg[1]
    # whole voxels: the variants alone, each one volume
    flat = integrate_mass(pf, whole, MassConfig(**cfg))
    vw = whole.volumes[:, 0] * mpu3
    assert vw.min() - 1e-12 <= flat.parts[0]["volume_interval_m3"][0]
    assert flat.parts[0]["volume_interval_m3"][1] <= vw.max() + 1e-12


def test_the_skin_band_is_checked():
    from physgs_nerfstudio.geometry import GeometryConfig

    with pytest.raises(ValueError, match="hidden_skin_band"):
        GeometryConfig(hidden_skin_band=-0.5)
    assert GeometryConfig().hidden_skin_band == 0.5


def test_a_plate_filled_through_its_thickness_keeps_less_under_it_with_the_narrow_skin_band():
    """A 2.5 cm top filled with layers of Gaussians through its thickness (as a GPU splat fills a thin plate), shot
    from above: with a whole voxel's band the inner layers' centres, within a voxel behind the rendered upper face,
    sample the skin and it reaches under the top; with half a voxel (the default) less hidden space stays under it.
    Both keep the top."""
    from helpers.shapes import box_surface, flat_gaussians, geometry_of, on_tile_floor, ring_views

    t = 0.025
    parts = [box_surface((0.8, 0.5, t), 0.02, centre=(0.0, 0.0, 0.5 + t / 2))]
    X, Y = torch.meshgrid(torch.arange(-0.39, 0.4, 0.02, dtype=torch.float64),
                          torch.arange(-0.24, 0.25, 0.02, dtype=torch.float64), indexing="ij")  # fmt: skip
    for k in range(3):
        p = torch.stack([X, Y, torch.full_like(X, 0.5 + t * (k + 1) / 4)], -1).reshape(-1, 3)
        parts.append(flat_gaussians(p, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand_as(p), 0.01))
    parts += [box_surface((0.04, 0.04, 0.5), 0.02, centre=(x, y, 0.25)) for x in (-0.37, 0.37) for y in (-0.22, 0.22)]
    pf, only = on_tile_floor([torch.cat(c) for c in zip(*parts)], 1.2)
    views = ring_views(pf, (0, 0, 0.3), 2.2, n=18, elevations=(35.0, 55.0, 75.0), mask_pf=only)
    truth = 0.8 * 0.5 * t + 4 * 0.04 * 0.04 * 0.5
    wide = geometry_of(pf, views, resolution=64, hidden_skin_band=1.0)
    narrow = geometry_of(pf, views, resolution=64)
    v_wide, v_narrow = float(wide.volumes[0].sum()), float(narrow.volumes[0].sum())
    print("truth", truth, "band 1", v_wide, "band 0.5", v_narrow)
    assert truth < v_narrow < v_wide
    top = narrow.grid.centres(torch.from_numpy(np.argwhere(narrow.occupancy > 0.5)))[:, 2]
    assert float((top > 0.5).float().mean()) > 0.3  # the top is still there
