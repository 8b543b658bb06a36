"""Which Gaussians the views see on their rendered surface (geometry.gaussians.surface_views): against a per-point
loop over random depth maps, and on a solid box of lattice Gaussians rendered by the reference rasterizer, whose
outer layer is seen and whose inside is not."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from helpers.shapes import ring_views
from hypothesis import given, settings
from hypothesis import strategies as st

from physgs_nerfstudio.export.shapes import field_from, solid_box
from physgs_nerfstudio.geometry.capture import CaptureView
from physgs_nerfstudio.geometry.gaussians import ViewRender, render_depth, surface_excess, surface_views


def _loop(means: np.ndarray, views: list[CaptureView], renders: list[ViewRender], band: float) -> np.ndarray:
    out = np.zeros(len(means))
    for v, r in zip(views, renders):
        vm, K = v.viewmat.double().numpy(), v.K.double().numpy()
        depth, alpha = r.depth.double().numpy(), r.alpha.double().numpy()
        for i, m in enumerate(means):
            c = vm[:3, :3] @ m + vm[:3, 3]
            if c[2] <= 0:
                continue
            u, w = K[0, 0] * c[0] / c[2] + K[0, 2], K[1, 1] * c[1] / c[2] + K[1, 2]
            if not (0 <= u < v.width and 0 <= w < v.height):
                continue
            px, py = int(math.floor(u)), int(math.floor(w))
            if alpha[py, px] >= 0.5 and c[2] <= depth[py, px] + band:
                out[i] += 1
    return out


def _random_views(rng: np.random.Generator) -> tuple[list[CaptureView], list[ViewRender]]:
    views, renders = [], []
    for _ in range(3):
        a = rng.uniform(0, 2 * math.pi)
        R = np.array([[math.cos(a), 0, -math.sin(a)], [0, 1, 0], [math.sin(a), 0, math.cos(a)]])
        vm = np.eye(4)
        vm[:3, :3], vm[:3, 3] = R, [rng.normal(0, 0.1), rng.normal(0, 0.1), 3.0]
        H, W = int(rng.integers(8, 20)), int(rng.integers(8, 20))
        K = torch.tensor([[10.0, 0, W / 2], [0, 10.0, H / 2], [0, 0, 1]])
        views.append(CaptureView(torch.from_numpy(vm).float(), K, W, H, torch.ones(H, W, dtype=torch.bool)))
        depth = torch.from_numpy(rng.uniform(2.0, 4.0, (H, W))).float()
        alpha = torch.from_numpy(rng.uniform(0, 1, (H, W))).float()
        renders.append(ViewRender(depth=torch.where(alpha > 0, depth, torch.full_like(depth, float("inf"))),
                                  alpha=alpha))
    return views, renders


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), band=st.sampled_from([0.0, 0.05, 0.3]))
def test_surface_views_matches_a_loop_over_points_and_views(seed, band):
    rng = np.random.default_rng(seed)
    views, renders = _random_views(rng)
    means = rng.normal(0, 1.0, (60, 3))
    got = surface_views(torch.from_numpy(means).float(), views, renders, band).numpy()
    np.testing.assert_array_equal(got, _loop(means.astype(np.float32).astype(np.float64), views, renders, band))


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_one_pass_of_surface_excess_gives_the_seen_set_at_every_band(seed):
    """The reconstruction reads the extent's, the material evidence's and the skin's sets off one pass: within a
    band of the smallest excess is seen by some view at that band (the loop's count > 0); no view: +inf."""
    rng = np.random.default_rng(seed)
    views, renders = _random_views(rng)
    means = rng.normal(0, 1.0, (60, 3))
    excess = surface_excess(torch.from_numpy(means).float(), views, renders).numpy()
    for band in (0.0, 0.05, 0.3, 1.0):
        want = _loop(means.astype(np.float32).astype(np.float64), views, renders, band) > 0
        np.testing.assert_array_equal(excess <= band, want)
    far = surface_excess(torch.tensor([[0.0, 1000.0, 0.0]]), views, renders)  # outside every image
    assert torch.isinf(far).all() and (far > 0).all()


def test_surface_views_sees_a_solid_boxs_outer_layer_and_not_its_inside():
    """A 0.6 m box filled with 0.1 m lattice Gaussians, seen from rings of views well above, level with and well below
    it: every Gaussian of the outer layer is on some view's surface, none of the layers inside it is."""
    means, scales, quats = solid_box((0.6, 0.6, 0.6), 0.1)
    pf = field_from(means, scales * 0.6, quats, opacity=0.99)
    views = ring_views(pf, (0.0, 0.0, 0.0), 3.0, n=12, elevations=(-60.0, 0.0, 60.0), size=64)
    renders = render_depth(pf, views, backend="reference")
    seen = surface_views(pf.means, views, renders, band=0.1)  # one lattice spacing
    depth_in = 0.3 - means.abs().amax(1)  # distance inside the box's faces: 0.05 on the outer layer
    assert bool((seen[depth_in < 0.06] >= 1).all())
    assert bool((depth_in > 0.14).sum() == 64) and not bool((seen[depth_in > 0.14] > 0).any())


def test_geometry_config_rejects_out_of_range_stray_fraction_and_surface_band():

    from physgs_nerfstudio.geometry import GeometryConfig

    for bad in (-0.1, 0.5, 1.0):
        with pytest.raises(ValueError, match="extent_outlier_fraction"):
            GeometryConfig(extent_outlier_fraction=bad)
    with pytest.raises(ValueError, match="evidence_surface_voxels"):
        GeometryConfig(evidence_surface_voxels=-1.0)
