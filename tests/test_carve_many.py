"""One carving pass under several settings gives, per setting, the votes of the free-space rule, and the masks' hull
the silhouette vote's, each checked voxel by voxel against a direct loop (independent oracles of carve.py's module
rules)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from helpers.shapes import look_at_w2c

from physgs_nerfstudio.geometry.capture import CaptureView
from physgs_nerfstudio.geometry.carve import CarveConfig, carve_votes_many, mask_hull, signed_mask_distance
from physgs_nerfstudio.geometry.free_space import SEES_THROUGH
from physgs_nerfstudio.geometry.grid import VoxelGrid


def _scene(seed: int):
    """Four views around a grid, with random masks and random surface depths, some pixels seeing through."""
    g = torch.Generator().manual_seed(seed)
    views, depths = [], []
    for i in range(4):
        a = 2 * math.pi * i / 4 + 0.3
        W, H = 20, 16
        K = torch.tensor([[18.0, 0, W / 2], [0, 18.0, H / 2], [0, 0, 1]])
        mask = torch.rand(H, W, generator=g) > 0.4
        views.append(CaptureView(look_at_w2c(np.array([2.5 * math.cos(a), 2.5 * math.sin(a), 0.7])), K, W, H, mask,
                                 name=f"v{i}"))  # fmt: skip
        depth = 2.0 + torch.rand(H, W, generator=g)
        depth[torch.rand(H, W, generator=g) < 0.1] = SEES_THROUGH
        depths.append(depth)
    grid = VoxelGrid.from_bounds(np.array([-0.6, -0.5, -0.4]), np.array([0.6, 0.5, 0.4]), 12)
    return grid, views, depths


def _bilinear(img: np.ndarray, u: float, v: float) -> float:
    """Bilinear sample at continuous pixel coordinates (pixel i covers [i, i+1)), clamped to the image."""
    H, W = img.shape
    x, y = min(max(u - 0.5, 0), W - 1), min(max(v - 0.5, 0), H - 1)
    x0, y0 = math.floor(x), math.floor(y)
    x1, y1 = min(x0 + 1, W - 1), min(y0 + 1, H - 1)
    fx, fy = x - x0, y - y0
    top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    bot = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return top * (1 - fy) + bot * fy


def _slack(depth: np.ndarray, i: int, j: int) -> float:
    """The bilinear lookup's error bound at pixel (i, j), one pixel at a time (as in carve_views.depth_slack)."""
    H, W = depth.shape
    inside = lambda a, b: 0 <= a < H and 0 <= b < W
    total = 0.0
    for di, dj in ((1, 0), (0, 1)):
        p, n = (i - di, j - dj), (i + di, j + dj)
        if inside(*p) and inside(*n):
            total += abs(depth[p] - 2 * depth[i, j] + depth[n]) / 8
        else:
            total += 0.5 * max(abs(depth[i, j] - depth[p]) if inside(*p) else 0.0,
                               abs(depth[n] - depth[i, j]) if inside(*n) else 0.0)  # fmt: skip
    return total


def _project(grid, views):
    """Per voxel (flattened C order) and view: None outside the image, else (camera depth, u, v), in float64."""
    _, Y, Z = grid.shape
    for flat in range(grid.num_voxels):
        i, j, k = flat // (Y * Z), (flat // Z) % Y, flat % Z
        c = np.asarray(grid.origin) + (np.array([i, j, k]) + 0.5) * grid.voxel_size
        row = []
        for v in views:
            pc = v.viewmat[:3, :3].double().numpy() @ c + v.viewmat[:3, 3].double().numpy()
            K = v.K.double().numpy()
            u, w = K[0, 0] * pc[0] / pc[2] + K[0, 2], K[1, 1] * pc[1] / pc[2] + K[1, 2]
            row.append((pc[2], u, w) if pc[2] > 1e-6 and 0 <= u < v.width and 0 <= w < v.height else None)
        yield flat, row


def _free_oracle(grid, views, depths, cfg):
    """The free-space vote (carve.py's module doc), voxel by voxel and view by view."""
    free, seen, near = (np.zeros(grid.num_voxels, int) for _ in range(3))
    images = [d.double().numpy() for d in depths]
    for flat, row in _project(grid, views):
        for at, img in zip(row, images):
            if at is None:
                continue
            z, u, w = at
            seen[flat] += 1
            d = _bilinear(img, u, w)
            margin = cfg.depth_margin_voxels * grid.voxel_size + cfg.depth_slope_margin * _slack(img, int(w), int(u))
            band = cfg.near_band_voxels * grid.voxel_size
            free[flat] += int(z < d - margin)
            near[flat] += int(z <= d + margin + band and margin <= band)
    return free, seen, near


def test_many_settings_in_one_pass_match_the_free_space_rule_and_single_calls() -> None:
    grid, views, depths = _scene(0)
    cfgs = [CarveConfig(), CarveConfig(depth_margin_voxels=2.0), CarveConfig(depth_slope_margin=0.0),
            CarveConfig(depth_margin_voxels=-0.5), CarveConfig(near_band_voxels=2.5),
            CarveConfig(depth_consensus=0.0, min_votes=3)]  # fmt: skip
    many = carve_votes_many(grid, views, depths, cfgs, chunk=300)
    for cfg, got in zip(cfgs, many):
        # float32 vs float64 projection: a voxel exactly on a threshold may flip; none does in this scene
        for name, want in zip(("free", "seen", "near"), _free_oracle(grid, views, depths, cfg)):
            assert np.array_equal(getattr(got, name).numpy(), want), (name, cfg)
        one = carve_votes_many(grid, views, depths, [cfg])[0]
        for name in ("free", "seen", "near"):
            assert torch.equal(getattr(one, name), getattr(got, name)), name
    assert len({tuple(v.free.tolist()) for v in many[:4]}) == 4  # the settings really differ here
    assert not torch.equal(many[4].near, many[0].near)  # (the band: only what counts as near)
    assert int(many[0].free.sum()) > 0 and int(many[0].near.sum()) > 0


def test_the_masks_hull_is_the_silhouette_vote() -> None:
    """mask_hull against the silhouette vote (carve.py's module doc) counted voxel by voxel: a view votes a voxel
    empty when it projects outside the view's mask (its signed distance, bilinear, positive)."""
    grid, views, _ = _scene(1)
    sdf = [signed_mask_distance(v.mask).numpy().astype(np.float64) for v in views]
    outside, seen = np.zeros(grid.num_voxels, int), np.zeros(grid.num_voxels, int)
    for flat, row in _project(grid, views):
        for at, sd in zip(row, sdf):
            if at is not None:
                seen[flat] += 1
                outside[flat] += int(_bilinear(sd, at[1], at[2]) > 0)
    for cfg in (CarveConfig(), CarveConfig(min_votes=1, min_vote_fraction=0.5, min_seen_fraction=0.8)):
        carved = (outside >= cfg.min_votes) & (outside >= cfg.min_vote_fraction * seen)
        carved |= seen < cfg.min_seen_fraction * len(views)
        want = ~carved.reshape(grid.shape)
        assert 0 < int(want.sum()) < grid.num_voxels
        for chunk, points in ((1 << 20, None), (300, 1), (300, 1 << 20)):
            assert np.array_equal(mask_hull(grid, views, cfg, chunk=chunk, batch_points=points), want), (cfg, chunk)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_signed_mask_distance_matches_scipy_edt(seed):
    """The OpenCV transform gives SciPy's exact Euclidean distances (the independent oracle), with the half-pixel
    offset, for blobs, holes and masks touching the border; many views at once give the same maps."""
    from scipy import ndimage

    from physgs_nerfstudio.geometry.carve import signed_mask_distances

    rng = np.random.default_rng(seed)
    masks = []
    for _ in range(5):
        m = ndimage.gaussian_filter(rng.random((61, 83)), 3) > 0.5
        m[rng.integers(0, 61), :] = True  # a thin line to the border
        masks.append(m)
    masks += [np.zeros((9, 7), bool), np.ones((9, 7), bool)]
    for m, d in zip(masks, signed_mask_distances(masks, workers=3)):
        if m.any() and not m.all():
            want = np.where(m, 0.5 - ndimage.distance_transform_edt(m), ndimage.distance_transform_edt(~m) - 0.5)
            np.testing.assert_allclose(d.numpy(), want, atol=1e-4)
        else:
            assert torch.all(d > 1e5) if not m.any() else torch.all(d < -1e5)
        np.testing.assert_allclose(d.numpy(), signed_mask_distance(m).numpy(), atol=1e-5)


def test_depth_consensus_needs_a_majority_of_the_views_near_the_surface() -> None:
    """The rule of solid_from_votes on hand-made counts (60 views frame every voxel): free votes carve at the vote's
    15% only when they are also half of the views near the surface."""
    from physgs_nerfstudio.geometry.carve import CarveVotes, solid_from_votes

    grid = VoxelGrid((0.0, 0.0, 0.0), 1.0, (1, 1, 5))
    t = lambda *v: torch.tensor(v, dtype=torch.int32)
    # voxel: 0 free 10 of 40 near (a few views render the face too deep), 1 free 30 of 35 near, 2 none,
    # 3 free 10 of 15 near, 4 free 1 (below min_votes)
    votes = CarveVotes(free=t(10, 30, 0, 10, 1), seen=t(60, 60, 60, 60, 60), near=t(40, 35, 30, 15, 1), num_views=60)
    cfg = CarveConfig(depth_consensus=0.5, min_component=0.0, fill_cavities=False)
    assert solid_from_votes(votes, grid, cfg).ravel().tolist() == [True, False, True, False, True]
    off = solid_from_votes(votes, grid, CarveConfig(depth_consensus=0.0, min_component=0.0, fill_cavities=False))
    assert off.ravel().tolist() == [False, False, True, False, True]
    few = CarveVotes(free=t(0, 0, 0, 0, 0), seen=t(29, 30, 60, 0, 60), near=t(0, 0, 0, 0, 0), num_views=60)
    assert solid_from_votes(few, grid, cfg).ravel().tolist() == [False, True, True, False, True]  # min_seen_fraction
