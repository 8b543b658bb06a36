"""Partial volume of the carving's boundary voxels (physgs_nerfstudio.geometry.partial): a boundary voxel's share is
the carving of a grid n times finer (an independent path: the grid's own voxel centres), and the depth margin, a
tolerance, no longer adds a layer of volume on the faces that only the depth places (a tray's inside)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch
from helpers.shapes import box_surface, flat_gaussians, geometry_of, ring_views

from physgs_nerfstudio.export.shapes import field_from
from physgs_nerfstudio.geometry import CarveConfig, VoxelGrid
from physgs_nerfstudio.geometry.carve import carve_votes_many, carved_by_votes
from physgs_nerfstudio.geometry.free_space import free_space_depths
from physgs_nerfstudio.geometry.partial import (
    boundary_fill,
    boundary_layers,
    boundary_voxels,
    outer_rim,
    part_volumes,
    rim_labels,
    sub_offsets,
    surface_config,
)


def test_sub_offsets_are_the_sub_cells_centres():
    assert torch.equal(sub_offsets(1), torch.zeros(1, 3))
    off = sub_offsets(3)
    assert off.shape == (27, 3)
    assert torch.allclose(off.mean(0), torch.zeros(3), atol=1e-7)
    assert sorted({round(float(v), 6) for v in off.reshape(-1)}) == [round(-1 / 3, 6), 0.0, round(1 / 3, 6)]


def test_boundary_voxels_have_a_face_neighbour_outside():
    rng = np.random.default_rng(3)
    solid = rng.random((7, 6, 5)) < 0.6
    padded = np.pad(solid, 1)
    brute = np.zeros_like(solid)
    for i, j, k in np.argwhere(solid):
        a, b, c = i + 1, j + 1, k + 1
        nbrs = [padded[a - 1, b, c], padded[a + 1, b, c], padded[a, b - 1, c], padded[a, b + 1, c],
                padded[a, b, c - 1], padded[a, b, c + 1]]  # fmt: skip
        brute[i, j, k] = not all(nbrs)
    assert np.array_equal(boundary_voxels(solid), brute)


def test_rim_labels_and_part_volumes_give_a_share_outside_the_solid_to_a_neighbouring_part():
    labels = -np.ones((5, 4, 3), np.int64)
    labels[1:3, 1:3, 1] = 0
    labels[3, 1:3, 1] = 1
    lab = rim_labels(labels)
    assert lab[0, 1, 1] == 0 and lab[4, 1, 1] == 1 and lab[1, 1, 0] == 0 and lab[3, 1, 2] == 1
    assert lab[0, 0, 0] == -1  # no face neighbour in the solid
    fill = (labels >= 0).astype(np.float32)
    fill[0, 1, 1], fill[4, 2, 1], fill[0, 0, 0] = 0.25, 0.5, 0.75  # the last has no part: not counted
    assert np.allclose(part_volumes(fill, labels, 2, 0.1), np.array([4.25, 2.5]) * 1e-3)


def test_settings_that_vote_alike_share_their_counts_and_the_others_do_not(box_render):
    """The votes of settings that differ only in their counts (min_votes, the fraction, the consensus) are one
    count; those that differ in the margin, the slope margin or the band each get their own, equal to a pass of
    their own (the per-voxel oracle of the vote: tests/test_carve_many.py)."""
    _, views, depths = box_render
    grid = VoxelGrid((-0.27, -0.21, -0.15), 0.03, (18, 14, 10))
    base = CarveConfig()
    cfgs = [base, replace(base, min_votes=3, min_vote_fraction=0.25, depth_consensus=0.0),
            replace(base, depth_margin_voxels=1.0), replace(base, depth_slope_margin=0.0),
            replace(base, near_band_voxels=3.0)]  # fmt: skip
    many = carve_votes_many(grid, views, depths, cfgs)
    assert torch.equal(many[0].free, many[1].free) and torch.equal(many[0].near, many[1].near)
    for i, cfg in enumerate(cfgs[2:], 2):
        alone = carve_votes_many(grid, views, depths, [cfg])[0]
        assert torch.equal(alone.free, many[i].free) and torch.equal(alone.near, many[i].near)
        assert not (torch.equal(many[i].free, many[0].free) and torch.equal(many[i].near, many[0].near)), cfg


def test_a_margin_reaches_as_many_layers_as_it_keeps():
    assert boundary_layers(CarveConfig(depth_margin_voxels=1.5)) == 3  # 1.5 voxels kept in front: 2 more layers
    assert boundary_layers(CarveConfig(depth_margin_voxels=1.0)) == 2
    assert boundary_layers(CarveConfig(depth_margin_voxels=-0.5)) == 1


def test_surface_config_keeps_a_negative_margin_and_drops_a_tolerance():
    assert surface_config(CarveConfig(depth_margin_voxels=1.0)).depth_margin_voxels == 0.0
    assert surface_config(CarveConfig(depth_margin_voxels=-0.5)).depth_margin_voxels == -0.5
    assert surface_config(CarveConfig(depth_margin_voxels=0.5, min_votes=3)).min_votes == 3


@pytest.fixture(scope="module")
def box_render():
    means, scales, quats = box_surface((0.4, 0.3, 0.2), 0.02)
    pf = field_from(means, scales, quats, densities=[700.0], names=["oak"], thickness_m=[None])
    views = ring_views(pf, (0, 0, 0), 1.5)
    return pf, views, free_space_depths(pf, views, backend="reference")


@pytest.mark.parametrize("margin", [0.0, 1.0, -0.5])
def test_a_boundary_voxels_share_is_the_carving_of_a_finer_grid(box_render, margin):
    """The share of each boundary voxel (its n^3 sub-points voted on as points) against the carving of the grid n
    times finer, whose voxel centres are those sub-points (the grid's path of ``carve_votes_many``), at the
    surface's setting."""
    _, views, depths = box_render
    n, h = 2, 0.03
    grid = VoxelGrid((-0.27, -0.21, -0.15), h, (18, 14, 10))
    fine = VoxelGrid(grid.origin, h / n, tuple(s * n for s in grid.shape))
    cfg = CarveConfig(depth_margin_voxels=margin)
    votes = carve_votes_many(grid, views, depths, [cfg])[0]
    solid = (~carved_by_votes(votes, cfg)).reshape(grid.shape).numpy()
    fill = boundary_fill(grid, [solid], [cfg], views, depths, subsamples=n)[0]
    surf = surface_config(cfg)
    # (the settings in voxels are the coarse grid's: the sub-points vote in coarse voxels)
    fine_votes = carve_votes_many(fine, views, depths, [in_finer_voxels(surf, n)])[0]
    kept = (~carved_by_votes(fine_votes, surf)).reshape(fine.shape).numpy()
    share = kept.reshape(grid.shape[0], n, grid.shape[1], n, grid.shape[2], n).mean((1, 3, 5))
    edge = boundary_voxels(solid, boundary_layers(cfg))
    rim = outer_rim(solid)  # every voxel outside this solid is carved by the vote
    assert edge.sum() > 100 and rim.sum() > 100
    for where in (edge, rim):
        diff = np.abs(fill[where] - share[where])
        assert np.mean(diff > 1e-6) < 0.01  # a sub-point exactly on a surface may round either way
    assert np.array_equal(fill[solid & ~edge], np.ones(int((solid & ~edge).sum()), np.float32))
    assert not fill[~solid & ~rim].any()
    if margin <= 0:  # the surface cuts voxels whose centres lie in front of it (beyond a tolerance: none)
        assert fill[rim].sum() > 0
    if margin > 0:  # voxels that the tolerance alone keeps count less than whole
        assert fill[edge].mean() < 1.0


def in_finer_voxels(cfg: CarveConfig, n: int) -> CarveConfig:
    """``cfg`` with its lengths in the finer grid's voxels (n of them to a coarse voxel)."""
    from dataclasses import replace

    return replace(cfg, depth_margin_voxels=cfg.depth_margin_voxels * n, near_band_voxels=cfg.near_band_voxels * n)


def tray_surface(outer=(0.4, 0.4, 0.2), inner=(0.28, 0.28, 0.12), spacing=0.012):
    """A tray: a solid block with an open box-shaped well in its top. The well's floor and walls are faces that no
    silhouette places, only the depth. Its true volume: outer - inner."""
    ox, oy, oz = (v / 2 for v in outer)
    ix, iy = inner[0] / 2, inner[1] / 2
    floor_z = outer[2] / 2 - inner[2]

    def rect(ax: int, sign: float, at: float, lo_a, hi_a, lo_b, hi_b, keep=None):
        a, b = [i for i in range(3) if i != ax]
        na, nb = max(2, round((hi_a - lo_a) / spacing)), max(2, round((hi_b - lo_b) / spacing))
        ga = lo_a + (torch.arange(na, dtype=torch.float64) + 0.5) / na * (hi_a - lo_a)
        gb = lo_b + (torch.arange(nb, dtype=torch.float64) + 0.5) / nb * (hi_b - lo_b)
        A, B = torch.meshgrid(ga, gb, indexing="ij")
        p = torch.zeros(A.numel(), 3, dtype=torch.float64)
        p[:, a], p[:, b], p[:, ax] = A.reshape(-1), B.reshape(-1), at
        if keep is not None:
            p = p[keep(p)]
        nrm = torch.zeros_like(p)
        nrm[:, ax] = sign
        return p, nrm

    parts = [rect(ax, s, s * h, -w[0], w[0], -w[1], w[1])
             for ax, h, w in ((0, ox, (oy, oz)), (1, oy, (ox, oz))) for s in (-1.0, 1.0)]  # fmt: skip
    parts.append(rect(2, -1.0, -oz, -ox, ox, -oy, oy))  # the bottom
    parts.append(rect(2, 1.0, oz, -ox, ox, -oy, oy,
                      keep=lambda p: (p[:, 0].abs() > ix) | (p[:, 1].abs() > iy)))  # the rim  # fmt: skip
    parts.append(rect(2, 1.0, floor_z, -ix, ix, -iy, iy))  # the well's floor
    parts += [rect(0, -s, s * ix, -iy, iy, floor_z, oz) for s in (-1.0, 1.0)]  # its walls, facing in
    parts += [rect(1, -s, s * iy, -ix, ix, floor_z, oz) for s in (-1.0, 1.0)]
    p = torch.cat([q for q, _ in parts])
    n = torch.cat([m for _, m in parts])
    volume = outer[0] * outer[1] * outer[2] - inner[0] * inner[1] * inner[2]
    return flat_gaussians(p, n, spacing * 0.5), volume


@pytest.fixture(scope="module")
def tray():
    (means, scales, quats), volume = tray_surface()
    pf = field_from(means, scales, quats, densities=[700.0], names=["oak"], thickness_m=[None])
    views = ring_views(pf, (0, 0, 0), 1.5, n=24, elevations=(20.0, 50.0, 75.0))
    return pf, views, volume


def _depth_variants(pf, views, monkeypatch, sub):
    from physgs_nerfstudio.geometry import reconstruct

    monkeypatch.setattr(reconstruct, "BOUNDARY_SUBSAMPLES", sub)  # 1: whole voxels, to compare against
    # with the Gaussians' polytope grown out of the way (it cuts each variant's solid on its own): the margin's layer
    # is the depth's alone
    geo = geometry_of(pf, views, resolution=48, extent_pad_voxels=1e6, depth_margin_variants=(-0.5, 1.0))
    vol = dict(zip(geo.variant_names, geo.volumes.sum(1)))
    return vol["nominal"], vol["depth1vox"], geo


def test_the_depth_margin_no_longer_adds_a_layer_on_the_faces_only_the_depth_places(tray, monkeypatch):
    pf, views, truth = tray
    whole, whole_plus, _ = _depth_variants(pf, views, monkeypatch, 1)
    part, part_plus, geo = _depth_variants(pf, views, monkeypatch, 2)
    # whole voxels: the +1 voxel margin adds a layer on the faces that only the depth places (12.5% at 48 voxels)
    assert whole_plus / whole - 1 > 0.02
    # partial volume: the tolerance keeps those voxels, but they lie in front of the surface (+0.05%)
    assert abs(part_plus / part - 1) < 0.3 * (whole_plus / whole - 1)
    # (both about 9% over: the depth carves the well's inside only where few views see down into it)
    assert abs(part / truth - 1) < 0.12 and abs(part / truth - 1) < abs(whole / truth - 1) + 0.01
    occ = geo.occupancy
    assert occ is not None and occ.dtype == np.float32
    assert np.all((occ >= 0) & (occ <= 1)) and np.all(occ[~geo.solid & ~outer_rim(geo.solid)] == 0)
    assert geo.fill().sum() * geo.grid.voxel_size**3 == pytest.approx(geo.volumes[0].sum(), rel=1e-5)


def test_one_subsample_is_whole_voxels(tray, monkeypatch):
    from helpers.shapes import whole_voxel_volume

    from physgs_nerfstudio.geometry import reconstruct

    pf, views, _ = tray
    monkeypatch.setattr(reconstruct, "BOUNDARY_SUBSAMPLES", 1)
    geo = geometry_of(pf, views, resolution=32)
    assert np.array_equal(geo.occupancy, geo.solid.astype(np.float32))
    assert geo.volumes[0].sum() == pytest.approx(whole_voxel_volume(geo))
