"""benchmarks/carve_diag.py: its rules resolve "auto" as the export does, and its per-view account names the view
whose depth votes emptied a part."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from bench_modules import load_benchmark

from physgs_nerfstudio.geometry.capture import CaptureView
from physgs_nerfstudio.geometry.carve import signed_mask_distance
from physgs_nerfstudio.geometry.gaussians import ViewRender
from physgs_nerfstudio.geometry.grid import VoxelGrid


@pytest.fixture(scope="module")
def cd():
    pytest.importorskip("nerfstudio")  # carve_diag loads runs through the export's loader
    return load_benchmark("carve_diag.py", "physgs_bench_carve_diag")


def test_auto_resolves_per_rasterizer(cd):
    assert cd.rule_config({}, "reference").depth_render == "median"
    assert cd.rule_config({}, "gsplat").depth_render == "expected"
    assert cd.rule_config({}, "gsplat").extent_multiple() == 2.0  # the GPU rule: expected - 2 extents
    assert cd.rule_config({"depth_render": "median"}, "gsplat").depth_render == "median"
    assert cd.rule_config({"depth_margin_voxels": 1.0}, "reference").depth_margin_voxels == 1.0


def _view(eye: np.ndarray, size: int = 32, f: float = 40.0) -> CaptureView:
    """A pinhole camera at ``eye`` looking at the origin (OpenCV axes), its mask the whole image."""
    fwd = -eye / np.linalg.norm(eye)
    up = np.array([0.0, 0.0, 1.0]) if abs(fwd[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    R = np.stack([right, down, fwd])
    vm = np.eye(4)
    vm[:3, :3], vm[:3, 3] = R, -R @ eye
    K = np.array([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1.0]])
    return CaptureView(torch.tensor(vm, dtype=torch.float32), torch.tensor(K, dtype=torch.float32), size, size,
                       torch.ones(size, size, dtype=torch.bool))  # fmt: skip


def test_account_names_the_view_that_sees_past_the_part(cd):
    """Three views render the depth of a plane through the origin exactly (facing them); one renders it 0.5 too deep.
    Every voxel of a thin slab just under the plane is in front of that view's depth only, so its account holds all the
    slab's depth votes and the others none; its angle from the world's down is that of its axis."""
    grid = VoxelGrid((-0.2, -0.2, -0.05), 0.05, (8, 8, 2))
    eyes = [np.array([0.0, 0.0, 3.0]), np.array([0.1, 0.0, 3.0]), np.array([0.0, 0.1, 3.0]),
            np.array([2.0, 0.0, 2.0])]  # fmt: skip
    views = [_view(e) for e in eyes]
    renders = []
    for j, v in enumerate(views):
        H, W = v.height, v.width
        ys, xs = np.mgrid[0:H, 0:W] + 0.5
        K, vm = v.K.double().numpy(), v.viewmat.double().numpy()
        rays = np.stack([(xs - K[0, 2]) / K[0, 0], (ys - K[1, 2]) / K[1, 1], np.ones_like(xs)], -1)
        n_cam = vm[:3, :3] @ np.array([0.0, 0.0, 1.0])  # the plane z = 0 in camera axes: n.x = n.t ... through origin
        z = (n_cam @ vm[:3, 3]) / (rays @ n_cam)  # z-depth where the ray meets the plane
        z = z + (0.5 if j == 0 else 0.0)
        renders.append(ViewRender(torch.tensor(z, dtype=torch.float32), torch.ones(H, W)))
    sdf = [signed_mask_distance(v.mask) for v in views]
    cc = cd.rule_config({"depth_render": "expected", "front_extent": 0.0, "depth_consensus": 0.5}, "gsplat")
    part = np.zeros(grid.shape, bool)
    part[2:6, 2:6, 0] = True  # voxel centres at z = -0.025: half a voxel behind the plane, in front of view 0's depth
    solid = np.zeros(grid.shape, bool)
    acc = cd.view_account({"T": np.eye(3, 4)}, grid, views, renders, sdf, cc, solid, part, "cpu")
    by_view = {r["view"]: r for r in acc["views"]}
    assert acc["lost"] == 16 and acc["kept"] == 0
    assert by_view[0]["lost_depth"] == 16 and by_view[0]["lost_mask"] == 0
    assert all(by_view[j]["lost_depth"] == 0 for j in (1, 2, 3))
    assert by_view[0]["from_down_deg"] == pytest.approx(0.0, abs=0.1)
    assert by_view[3]["from_down_deg"] == pytest.approx(45.0, abs=0.1)
    assert acc["views"][0]["view"] == 0  # sorted: most depth votes first
    assert acc["median_depth_votes"] == 1.0
