"""The solid cut to its Gaussians' support polytope (geometry.gaussians) and the concavity rule of the wall area
(geometry.parts.concavities / part_areas(concave=...)), against independent oracles: scipy's Delaunay point
location for the convex hull, and the analytic areas of a cup."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import Delaunay

from physgs_nerfstudio.geometry.gaussians import (
    support_directions,
    support_excess,
    support_heights,
    within_support,
)
from physgs_nerfstudio.geometry.grid import VoxelGrid
from physgs_nerfstudio.geometry.walls import concavities, part_areas
from physgs_nerfstudio.render.projection import quat_to_rotmat


def test_support_directions_are_unit_and_include_the_axes():
    d = support_directions(50)
    assert d.shape == (76, 3)
    assert torch.allclose(d.norm(dim=1), torch.ones(76, dtype=torch.float64))
    for axis in torch.eye(3, dtype=torch.float64):
        assert bool(((d - axis).norm(dim=1) < 1e-12).any()) and bool(((d + axis).norm(dim=1) < 1e-12).any())


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), pad=st.sampled_from([0.0, 0.5, 1.0]))
def test_within_support_keeps_the_convex_hull_and_cuts_beyond_the_extreme_points(seed, pad):
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(200, 3)) * rng.uniform(0.2, 1.0, size=3)
    grid = VoxelGrid.from_bounds(torch.tensor([-3.0] * 3), torch.tensor([3.0] * 3), 24)
    cand = np.ones(grid.shape, bool)
    kept = within_support(grid, torch.from_numpy(pts).float(), cand, pad_voxels=pad)
    ijk = np.argwhere(cand)
    x = grid.centres(torch.from_numpy(ijk)).double().numpy()
    in_hull = Delaunay(pts).find_simplex(x) >= 0
    assert kept[tuple(ijk[in_hull].T)].all()  # never cuts into the convex hull
    # beyond the points' extreme along any axis by more than the pad: cut
    beyond = ((x > pts.max(0) + pad * grid.voxel_size + 1e-6) | (x < pts.min(0) - pad * grid.voxel_size - 1e-6)).any(1)
    assert not kept[tuple(ijk[beyond].T)].any()
    # only candidates are ever kept
    part = np.zeros(grid.shape, bool)
    part[:12] = True
    assert not (within_support(grid, torch.from_numpy(pts).float(), part, pad) & ~part).any()


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_support_excess_of_ellipsoids_against_their_covariances(seed):
    """The excess beyond the ellipsoids' support polytope against an oracle written with covariances: a
    one-sigma ellipsoid's support along u is u . mu + sqrt(u^T Sigma u), Sigma = R diag(s^2) R^T (R from the
    unit quaternion (w, x, y, z)); every pad's kept set is the excess's threshold."""
    rng = np.random.default_rng(seed)
    n = 40
    mu = rng.uniform(0.2, 0.8, (n, 3))
    s = rng.uniform(0.005, 0.05, (n, 3))
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    R = np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                  np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                  np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], 1)  # fmt: skip
    sigma = R @ (s[:, :, None] ** 2 * np.swapaxes(R, 1, 2))
    grid = VoxelGrid((0.0, 0.0, 0.0), 0.05, (20, 20, 20))
    cand = rng.random(grid.shape) < 0.3
    d = support_directions(30).numpy()
    h = (mu @ d.T + np.sqrt(np.einsum("di,nij,dj->nd", d, sigma, d))).max(0)
    x_c = (np.argwhere(cand) + 0.5) * grid.voxel_size
    oracle = (x_c @ d.T - h).max(1) / grid.voxel_size
    got = support_excess(grid, torch.from_numpy(mu).float(), cand, 30, torch.from_numpy(s).float(),
                         torch.from_numpy(q).float())  # fmt: skip
    assert np.allclose(got, oracle, atol=1e-4)
    for pad in (0.0, 1.0):
        kept = within_support(grid, torch.from_numpy(mu).float(), cand, pad, 30, torch.from_numpy(s).float(),
                              torch.from_numpy(q).float())  # fmt: skip
        sure = np.abs(oracle - pad) > 1e-3  # voxels not on the threshold itself
        assert (kept[tuple(np.argwhere(cand)[sure].T)] == (oracle <= pad)[sure]).all()
        assert not (kept & ~cand).any()


def test_within_support_cuts_the_unseen_slab_under_an_object():
    """The case it is for: a box of surface points standing on z = 0, carved solid down to z = -0.3 (space under
    it that no view saw past): the slab is cut, the box kept."""
    rng = np.random.default_rng(0)
    u = rng.uniform(size=(4000, 2))
    faces = []
    for axis in range(3):
        for v in (0.0, 1.0):
            p = np.insert(u, axis, v, axis=1)
            faces.append(p)
    pts = np.concatenate(faces)
    grid = VoxelGrid.from_bounds(torch.tensor([-0.3, -0.3, -0.3]), torch.tensor([1.3, 1.3, 1.3]), 32)
    ijk = np.argwhere(np.ones(grid.shape, bool))
    x = grid.centres(torch.from_numpy(ijk)).double().numpy().reshape(*grid.shape, 3)
    carved = ((x[..., 0] > 0) & (x[..., 0] < 1) & (x[..., 1] > 0) & (x[..., 1] < 1) & (x[..., 2] < 1))
    kept = within_support(grid, torch.from_numpy(pts).float(), carved, pad_voxels=0.5)
    box = carved & (x[..., 2] > 0)
    assert kept[box].all()
    assert not kept[carved & (x[..., 2] < -0.5 * grid.voxel_size - 1e-9)].any()


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), skip=st.integers(0, 12), chunk=st.sampled_from([7, 64, 1 << 16]),
       ellipsoids=st.booleans())
def test_support_heights_skip_is_the_kth_largest_by_sorting(seed, skip, chunk, ellipsoids):
    """h(u) with ``skip`` = the (skip + 1)-th largest support value of the Gaussians along u (all but one when there
    are fewer), whatever the chunking: against a sort of the per-Gaussian values computed from the covariances."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 40))
    mu = rng.normal(size=(n, 3))
    s = rng.uniform(0.01, 0.3, size=(n, 3))
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    d = support_directions(20)
    kw = {"scales": torch.from_numpy(s), "quats": torch.from_numpy(q)} if ellipsoids else {}
    got = support_heights(torch.from_numpy(mu), d, chunk=chunk, skip=skip, **kw).numpy()
    vals = mu @ d.numpy().T  # [n, D]
    if ellipsoids:
        R = quat_to_rotmat(torch.from_numpy(q)).numpy()
        cov = np.einsum("nij,nj,nkj->nik", R, s**2, R)
        vals = vals + np.sqrt(np.einsum("di,nij,dj->nd", d.numpy(), cov, d.numpy()))
    want = -np.sort(-vals, axis=0)[min(skip, n - 1)]
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)


def test_within_support_skip_ignores_a_few_strays_under_the_object():
    """Five stray means 0.2 under a box's bottom face: with every Gaussian counted the carved slab under the box is
    kept down to them; with the five skipped it is cut at the face, and the box is kept either way."""
    rng = np.random.default_rng(1)
    u = rng.uniform(size=(2000, 2))
    pts = np.concatenate([np.insert(u, axis, v, axis=1) for axis in range(3) for v in (0.0, 1.0)])
    strays = np.column_stack([rng.uniform(0.2, 0.8, 5), rng.uniform(0.2, 0.8, 5), np.full(5, -0.2)])
    pts = torch.from_numpy(np.concatenate([pts, strays])).float()
    grid = VoxelGrid.from_bounds(torch.tensor([-0.3, -0.3, -0.3]), torch.tensor([1.3, 1.3, 1.3]), 32)
    ijk = np.argwhere(np.ones(grid.shape, bool))
    x = grid.centres(torch.from_numpy(ijk)).double().numpy().reshape(*grid.shape, 3)
    carved = ((x[..., 0] > 0) & (x[..., 0] < 1) & (x[..., 1] > 0) & (x[..., 1] < 1) & (x[..., 2] < 1))
    box = carved & (x[..., 2] > 0)
    slab = carved & (x[..., 2] < -0.5 * grid.voxel_size - 1e-9) & (x[..., 2] > -0.15)
    every = within_support(grid, pts, carved, pad_voxels=0.5)
    robust = within_support(grid, pts, carved, pad_voxels=0.5, skip=5)
    assert every[box].all() and robust[box].all()
    assert every[slab].mean() > 0.5
    assert not robust[slab].any()


def _cup(n: int, r_out: float, r_in: float, h: float, bottom: float) -> tuple[VoxelGrid, np.ndarray, np.ndarray]:
    grid = VoxelGrid.from_bounds(torch.tensor([-1.0, -1.0, -0.2]), torch.tensor([1.0, 1.0, 1.8]), n)
    ijk = np.argwhere(np.ones(grid.shape, bool))
    x = grid.centres(torch.from_numpy(ijk)).double().numpy().reshape(*grid.shape, 3)
    rho = np.hypot(x[..., 0], x[..., 1])
    hull = (rho <= r_out) & (x[..., 2] >= 0) & (x[..., 2] <= h)  # the silhouettes cannot carve the inside
    inside = (rho < r_in) & (x[..., 2] > bottom)
    return grid, hull, hull & ~inside


@pytest.mark.parametrize("wall", [0.1, 0.2])
def test_concavity_rule_counts_a_thick_cup_wall_once(wall):
    """A cup carved with a wall several voxels thick (a low-resolution carving of a thin wall): every face in
    full counts the wall's inner and outer faces; with the concavity rule the inner faces drop and the area is
    the outer side and the bottom, analytic."""
    r, h = 0.8, 1.5
    grid, hull, solid = _cup(64, r, r - wall, h, wall)
    parts = np.where(solid, 0, -1)
    outer = 2 * math.pi * r * h + math.pi * r**2
    inner = 2 * math.pi * (r - wall) * (h - wall) + math.pi * (r - wall) ** 2
    rim = math.pi * (r**2 - (r - wall) ** 2)
    plain = part_areas(grid, solid, parts, 1, sheet_voxels=1.0).area[0]
    assert plain == pytest.approx(outer + inner + rim, rel=0.06)
    conc = concavities(hull, solid, 2.0)
    assert conc.any() and not (conc & solid).any() and not (conc & ~hull).any()
    ruled = part_areas(grid, solid, parts, 1, sheet_voxels=1.0, concave=conc).area[0]
    # the inner faces within 2 voxels of the rim still count: allow that strip
    strip = 2 * math.pi * (r - wall) * 3 * grid.voxel_size
    assert outer + rim - 0.05 * outer <= ruled <= outer + rim + strip + 0.05 * outer


def _boxes(solid_box: tuple[slice, ...], hull_box: tuple[slice, ...]) -> None:
    """The solid and the hull are boxes on a 40^3 grid: no voxel is a concavity and the area is unchanged."""
    grid = VoxelGrid.from_bounds(torch.tensor([0.0] * 3), torch.tensor([1.0] * 3), 40)
    solid = np.zeros(grid.shape, bool)
    solid[solid_box] = True
    hull = np.zeros(grid.shape, bool)
    hull[hull_box] = True
    parts = np.where(solid, 0, -1)
    conc = concavities(hull, solid, 2.0)
    assert not conc.any()
    a0 = part_areas(grid, solid, parts, 1).area[0]
    assert part_areas(grid, solid, parts, 1, concave=conc).area[0] == pytest.approx(a0)


def test_concavity_rule_leaves_a_closed_box_and_the_blur_layer_alone():
    """A filled box whose hull is the box grown by 2 voxels (the masks' blur)."""
    _boxes(np.s_[8:32, 8:32, 8:32], np.s_[6:34, 6:34, 6:34])


def test_concavity_rule_leaves_a_face_carved_below_the_hull_alone():
    """A closed box whose top depth carved 4 voxels below the hull (the hull is the true box, the solid lower):
    the empty layer over the top is deep in the hull but lies against the solid on one side only, so it is no
    concavity and the top face counts."""
    _boxes(np.s_[8:32, 8:32, 8:28], np.s_[8:32, 8:32, 8:32])


@pytest.mark.parametrize("radius", [2.0, 2.5, 3.0, 4.2])
def test_concavities_deep_layer_matches_erosion_by_a_ball(radius: float) -> None:
    """The hull's deep layer (by the exact distance transform) against scipy's erosion by a ball of that radius with
    outside-the-grid as outside, on random blobby hulls with a solid that surrounds pockets."""
    from scipy import ndimage

    rng = np.random.default_rng(int(radius * 10))
    hull = ndimage.binary_dilation(rng.random((26, 28, 24)) < 0.02, iterations=int(radius) + 2)
    solid = hull & (rng.random(hull.shape) < 0.7)
    r = int(np.floor(radius))
    o = np.arange(-r, r + 1)
    ball = (o[:, None, None] ** 2 + o[None, :, None] ** 2 + o[None, None, :] ** 2) <= radius**2
    deep = ndimage.binary_erosion(hull, structure=ball, border_value=0) & ~solid
    enclosed = np.zeros_like(deep)
    for axis in range(3):
        before = np.maximum.accumulate(solid, axis=axis)
        after = np.flip(np.maximum.accumulate(np.flip(solid, axis), axis=axis), axis)
        enclosed |= before & after
    want = deep & enclosed
    assert want.any()
    np.testing.assert_array_equal(concavities(hull, solid, radius), want)
