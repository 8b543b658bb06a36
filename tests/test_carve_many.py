"""One carving pass under several settings gives, per setting, the votes of the carving rule, checked voxel by
voxel against a direct loop (an independent oracle of carve.py's module rule)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from physgs_nerfstudio.geometry.capture import CaptureView
from physgs_nerfstudio.geometry.carve import CarveConfig, carve_votes, carve_votes_many, signed_mask_distance
from physgs_nerfstudio.geometry.gaussians import ViewRender
from physgs_nerfstudio.geometry.grid import VoxelGrid


def _look_at(eye: np.ndarray) -> torch.Tensor:
    """World-to-camera (OpenCV axes) looking at the origin."""
    f = -eye / np.linalg.norm(eye)
    r = np.cross(f, [0.0, 0.0, 1.0])
    r /= np.linalg.norm(r)
    d = np.cross(f, r)
    R = np.stack([r, d, f])
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = R, -R @ eye
    return torch.tensor(out, dtype=torch.float32)


def _scene(seed: int):
    g = torch.Generator().manual_seed(seed)
    views, renders = [], []
    for i in range(4):
        a = 2 * math.pi * i / 4 + 0.3
        W, H = 20, 16
        K = torch.tensor([[18.0, 0, W / 2], [0, 18.0, H / 2], [0, 0, 1]])
        mask = torch.rand(H, W, generator=g) > 0.4
        views.append(CaptureView(_look_at(np.array([2.5 * math.cos(a), 2.5 * math.sin(a), 0.7])), K, W, H, mask,
                                 name=f"v{i}"))  # fmt: skip
        renders.append(ViewRender(depth=2.0 + torch.rand(H, W, generator=g), alpha=torch.rand(H, W, generator=g)))
    grid = VoxelGrid.from_bounds(np.array([-0.6, -0.5, -0.4]), np.array([0.6, 0.5, 0.4]), 12)
    return grid, views, renders


def _bilinear(img: np.ndarray, u: float, v: float) -> float:
    H, W = img.shape
    x, y = min(max(u - 0.5, 0), W - 1), min(max(v - 0.5, 0), H - 1)
    x0, y0 = math.floor(x), math.floor(y)
    x1, y1 = min(x0 + 1, W - 1), min(y0 + 1, H - 1)
    fx, fy = x - x0, y - y0
    top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    bot = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return top * (1 - fy) + bot * fy


def _opaque_bilinear(r, u: float, v: float) -> float:
    """Bilinear depth from the opaque ones (alpha >= 0.5) of the four pixels around (u, v), weights renormalised."""
    H, W = r.depth.shape
    x, y = min(max(u - 0.5, 0), W - 1), min(max(v - 0.5, 0), H - 1)
    x0, y0 = math.floor(x), math.floor(y)
    fx, fy = x - x0, y - y0
    num = den = 0.0
    for yy, xx, wt in ((y0, x0, (1 - fx) * (1 - fy)), (y0, min(x0 + 1, W - 1), fx * (1 - fy)),
                       (min(y0 + 1, H - 1), x0, (1 - fx) * fy), (min(y0 + 1, H - 1), min(x0 + 1, W - 1), fx * fy)):
        if float(r.alpha[yy, xx]) >= 0.5:
            num += wt * float(r.depth[yy, xx])
            den += wt
    return num / den if den > 0 else math.inf


def _slack(r, i: int, j: int, lookup: str) -> float:
    """The lookup's error bound at pixel (i, j), one pixel at a time (as in carve_views.depth_slack)."""
    H, W = r.depth.shape
    op = lambda a, b: 0 <= a < H and 0 <= b < W and float(r.alpha[a, b]) >= 0.5
    if not op(i, j):
        return 0.0
    d = lambda a, b: float(r.depth[a, b])
    total = 0.0
    for di, dj in ((1, 0), (0, 1)):
        p, n = (i - di, j - dj), (i + di, j + dj)
        if lookup == "bilinear" and op(*p) and op(*n):
            total += abs(d(*p) - 2 * d(i, j) + d(*n)) / 8
        else:
            total += 0.5 * max(abs(d(i, j) - d(*p)) if op(*p) else 0.0, abs(d(*n) - d(i, j)) if op(*n) else 0.0)
    return total


def _oracle(grid, views, renders, cfg):
    empty, seen, by_depth, near = (np.zeros(grid.num_voxels, int) for _ in range(4))
    _, Y, Z = grid.shape
    for flat in range(grid.num_voxels):
        i, j, k = flat // (Y * Z), (flat // Z) % Y, flat % Z
        c = np.asarray(grid.origin) + (np.array([i, j, k]) + 0.5) * grid.voxel_size
        for v, r in zip(views, renders):
            pc = v.viewmat[:3, :3].double().numpy() @ c + v.viewmat[:3, 3].double().numpy()
            K = v.K.double().numpy()
            u, w = K[0, 0] * pc[0] / pc[2] + K[0, 2], K[1, 1] * pc[1] / pc[2] + K[1, 2]
            if not (pc[2] > 1e-6 and 0 <= u < v.width and 0 <= w < v.height):
                continue
            seen[flat] += 1
            dist = _bilinear(signed_mask_distance(v.mask).numpy().astype(np.float64), u, w)
            a = float(r.alpha[int(w), int(u)])
            d = _opaque_bilinear(r, u, w) if cfg.depth_lookup == "bilinear" else float(r.depth[int(w), int(u)])
            margin = cfg.depth_margin_voxels * grid.voxel_size + cfg.depth_margin_rel * d
            margin += cfg.depth_slope_margin * _slack(r, int(w), int(u), cfg.depth_lookup)
            inside = cfg.use_depth and dist <= cfg.mask_margin_px and a >= cfg.min_alpha
            by_depth[flat] += int(inside and pc[2] < d - margin)
            band = cfg.near_band_voxels * grid.voxel_size
            near[flat] += int(inside and dist <= cfg.mask_margin_px - cfg.near_inset_px and pc[2] <= d + margin + band
                              and margin <= band)
            empty[flat] += int(dist > cfg.mask_margin_px or (inside and pc[2] < d - margin))
    return empty, seen, by_depth, near


def test_many_settings_in_one_pass_match_the_rule_and_single_calls() -> None:
    grid, views, renders = _scene(0)
    cfgs = [CarveConfig(), CarveConfig(mask_margin_px=-0.5), CarveConfig(mask_margin_px=0.5),
            CarveConfig(depth_margin_voxels=2.0), CarveConfig(use_depth=False, min_alpha=0.2),
            CarveConfig(depth_slope_margin=0.0), CarveConfig(depth_margin_voxels=-0.5),
            CarveConfig(near_band_voxels=2.5, depth_consensus=0.5), CarveConfig(depth_consensus=0.5),
            CarveConfig(depth_consensus=0.5, near_inset_px=0.0), CarveConfig(depth_consensus=0.0)]  # fmt: skip
    many = carve_votes_many(grid, views, renders, cfgs, chunk=300)
    for cfg, got in zip(cfgs, many):
        # float32 vs float64 projection: a voxel exactly on a threshold may flip; none does in this scene
        for name, want in zip(("empty", "seen", "depth_empty", "near"), _oracle(grid, views, renders, cfg)):
            if name == "near" and not cfg.depth_consensus:
                assert got.near is None  # not counted when no setting asks for it
                continue
            assert np.array_equal(getattr(got, name).numpy(), want), (name, cfg)
        one = carve_votes(grid, views, renders, cfg)
        for name in ("empty", "seen", "depth_empty"):
            assert torch.equal(getattr(one, name), getattr(got, name)), name
    assert len({tuple(v.empty.tolist()) for v in many[:7]}) == 7  # the settings really differ here
    assert not torch.equal(many[8].near, many[7].near)  # (the band: only what counts as near)
    assert not torch.equal(many[8].near, many[9].near)  # (the inset: views with the voxel on their mask's edge)
    nearest = [CarveConfig(depth_lookup="nearest"), CarveConfig(depth_lookup="nearest", depth_margin_voxels=1.0)]
    for cfg, got in zip(nearest, carve_votes_many(grid, views, renders, nearest, chunk=300)):
        for name, want in zip(("empty", "seen", "depth_empty"), _oracle(grid, views, renders, cfg)):
            assert np.array_equal(getattr(got, name).numpy(), want), (name, cfg)


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
    """The rule of solid_from_votes on hand-made counts (60 views frame every voxel): silhouette votes alone carve
    at the vote's 15%; depth votes carve only when they are also half of the views near the surface."""
    from physgs_nerfstudio.geometry.carve import CarveVotes, solid_from_votes

    grid = VoxelGrid((0.0, 0.0, 0.0), 1.0, (1, 1, 5))
    t = lambda *v: torch.tensor(v, dtype=torch.int32)
    # voxel: 0 depth 10/40 near (a few views render the face too deep), 1 depth 30/35, 2 masks 10, 3 none,
    # 4 masks 5 + depth 5 of 40 near
    votes = CarveVotes(empty=t(10, 30, 10, 0, 10), seen=t(60, 60, 60, 60, 60), depth_empty=t(10, 30, 0, 0, 5),
                       num_views=60, near=t(40, 35, 0, 30, 40))  # fmt: skip
    cfg = CarveConfig(depth_consensus=0.5, min_component=0.0, fill_cavities=False)
    keep = solid_from_votes(votes, grid, cfg).ravel()
    assert keep.tolist() == [True, False, False, True, True]
    off = solid_from_votes(votes, grid, CarveConfig(depth_consensus=0.0, min_component=0.0, fill_cavities=False))
    assert off.ravel().tolist() == [False, False, False, True, False]
