"""The contact cut (geometry/contact.py): an object on a stand perception names, separated at their contact.

Oracles: a brute-force scan of every threshold for the cut's search; for the whole rule, views ray-cast
analytically onto two boxes (an object on a wider stand, or on its own foot), whose pixels carry the names of the
box the ray meets first."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from helpers.shapes import look_at_w2c
from hypothesis import given, settings
from hypothesis import strategies as st

from physgs_nerfstudio.geometry.capture import CaptureView, MaskObservation
from physgs_nerfstudio.geometry.contact import MIN_GAIN, ObjectLabels, _best_cut, contact_cut, object_labels
from physgs_nerfstudio.geometry.free_space import SEES_THROUGH
from physgs_nerfstudio.geometry.grid import VoxelGrid


def _brute_cut(height: np.ndarray, name: np.ndarray, k: int) -> float:
    """The best share right over every threshold between and around the points (the gain's oracle)."""
    u = np.unique(height)
    levels = np.concatenate([[-np.inf], (u[:-1] + u[1:]) / 2, [u[-1] + 1]])
    right = [((height >= t) & (name == k)).sum() + ((height < t) & (name != k)).sum() for t in levels]
    return (max(right) - right[0]) / len(height)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 12), st.integers(0, 2)), min_size=1, max_size=60), st.integers(0, 2))
def test_best_cut_matches_a_scan_of_every_threshold(points, k):
    height = np.array([p[0] / 4 for p in points])  # on a lattice: ties, as voxel centres have
    name = np.array([p[1] for p in points])
    level, gain = _best_cut(height, name, k)
    assert gain == pytest.approx(_brute_cut(height, name, k), abs=1e-12)
    right = ((height >= level) & (name == k)).sum() + ((height < level) & (name != k)).sum()
    assert right - (name == k).sum() == pytest.approx(gain * len(height), abs=1e-9)  # the level achieves it


def test_best_cut_separates_a_stand_and_ignores_scattered_slips():
    rng = np.random.default_rng(0)
    h = rng.uniform(0, 1, 2000)
    name = np.where(h < 0.3, 1, 0)
    level, gain = _best_cut(h, name, 0)
    assert 0.29 < level < 0.31 and gain == pytest.approx((h < 0.3).mean())
    slips = np.where(rng.random(2000) < 0.1, rng.integers(1, 3, 2000), 0)  # no stand: 10% wrong names anywhere
    assert _best_cut(h, slips, 0)[1] < MIN_GAIN


# ------------------------------------------------------------------ two boxes, seen by ray-cast views

def _hit(o: np.ndarray, d: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Ray parameter of the first hit of rays o + t d on the box [lo, hi] (inf: none), the slab method."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = (lo - o) / d, (hi - o) / d
    near = np.nanmax(np.minimum(t0, t1), axis=-1)
    far = np.nanmin(np.maximum(t0, t1), axis=-1)
    return np.where((far >= near) & (far > 0), np.maximum(near, 0), np.inf)


def _views(boxes: list[tuple[np.ndarray, np.ndarray, int]], n: int = 12, size: int = 48):
    """Views on an orbit around the boxes: the depth of the first box each pixel's ray meets, and its name index."""
    views, depths, maps = [], [], []
    W = H = size
    K = torch.tensor([[40.0, 0, W / 2], [0, 40.0, H / 2], [0, 0, 1]])
    target = np.array([0.0, 0.0, 0.25])
    for i in range(n):
        a, el = 2 * math.pi * i / n, (0.25 if i % 2 else 0.6)
        eye = target + 1.6 * np.array([math.cos(a) * math.cos(el), math.sin(a) * math.cos(el), math.sin(el)])
        vm = look_at_w2c(eye, target)
        R = vm[:3, :3].double().numpy()
        u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
        cam = np.stack([(u - W / 2) / 40.0, (v - H / 2) / 40.0, np.ones_like(u)], -1)
        dirs = cam @ R  # world directions (camera z = 1 per unit of depth)
        ts = np.stack([_hit(eye, dirs, lo, hi) for lo, hi, _ in boxes])
        first = ts.argmin(0)
        t = ts.min(0)
        depth = np.where(np.isfinite(t), t, SEES_THROUGH)  # camera z, since dirs have z = 1
        names = np.where(np.isfinite(t), np.array([b[2] for b in boxes])[first], -1)
        mask = torch.from_numpy(np.isfinite(t))
        views.append(CaptureView(vm, K, W, H, mask, name=f"v{i}"))
        depths.append(torch.from_numpy(depth).float())
        maps.append(torch.from_numpy(names).long())
    return views, depths, maps


def _solid(grid: VoxelGrid, boxes) -> np.ndarray:
    ax = [grid.origin[i] + (np.arange(grid.shape[i]) + 0.5) * grid.voxel_size for i in range(3)]
    X, Y, Z = np.meshgrid(*ax, indexing="ij")
    p = np.stack([X, Y, Z], -1)
    return np.logical_or.reduce([((p >= lo) & (p <= hi)).all(-1) for lo, hi, _ in boxes])


@pytest.mark.parametrize("stand_name", [1, 0])  # a stand perception names, or the object's own foot
def test_contact_cut_separates_a_named_stand_at_its_top(stand_name):
    stand = (np.array([-0.12, -0.12, 0.0]), np.array([0.12, 0.12, 0.1]), stand_name)
    mug = (np.array([-0.08, -0.08, 0.1]), np.array([0.08, 0.08, 0.3]), 0)
    grid = VoxelGrid.from_bounds(torch.tensor([-0.2, -0.2, 0.0]), torch.tensor([0.2, 0.2, 0.4]), 40)
    views, depths, maps = _views([stand, mug])
    solid = _solid(grid, [stand, mug])
    contact = contact_cut(grid, solid, views, depths, ObjectLabels(["mug", "stand"], maps), np.array([0, 0, 1.0]))
    if not stand_name:
        assert contact is None  # one name all over: nothing to cut
        return
    assert contact is not None and contact.object_name == "mug" and contact.below == "stand"
    assert abs(contact.plane.offset - 0.1) <= 1.5 * grid.voxel_size  # at the contact, to about a voxel
    assert contact.gain > MIN_GAIN


def test_object_labels_paint_the_finest_mask_over_the_coarser():
    view = CaptureView(torch.eye(4), torch.eye(3), 4, 2, torch.ones(2, 4, dtype=torch.bool), name="v")
    whole = np.ones((2, 4), bool)
    part = np.zeros((2, 4), bool)
    part[:, :1] = True
    obs = [MaskObservation("v", part, "abs", 1.0, None, "part", mask_id=1, object="stand"),
           MaskObservation("v", whole, "steel", 1.0, None, "whole", mask_id=0, object="mug"),
           MaskObservation("v", whole, "abs", 1.0, None, "whole", mask_id=2, object=None)]  # fmt: skip
    labels = object_labels([view, CaptureView(torch.eye(4), torch.eye(3), 4, 2, torch.ones(2, 4, dtype=torch.bool),
                                              name="other")], obs)  # fmt: skip
    assert labels.names == ["stand", "mug"] and labels.maps[1] is None
    assert labels.maps[0].tolist() == [[0, 1, 1, 1], [0, 1, 1, 1]]
