"""benchmarks/depth_truth.py's surface angle on analytic depth maps."""

from __future__ import annotations

import math

import numpy as np
import pytest
from bench_modules import load_benchmark


@pytest.fixture(scope="module")
def dt():
    return load_benchmark("depth_truth.py", "physgs_bench_depth_truth")


@pytest.mark.parametrize("tilt_deg", [0.0, 30.0, 50.0])
def test_plane_incidence_matches_the_ray_normal_angle(dt, tilt_deg):
    """A plane through (0, 0, 2) with normal (sin t, 0, -cos t) in camera coordinates: each pixel's z-depth from the
    ray-plane intersection, and |cos| between its ray and that normal computed independently."""
    H = W = 64
    K = np.array([[50.0, 0, 32], [0, 50.0, 32], [0, 0, 1]])
    t = math.radians(tilt_deg)
    n = np.array([math.sin(t), 0.0, -math.cos(t)])
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    ray = np.stack([(u + 0.5 - 32) / 50, (v + 0.5 - 32) / 50, np.ones_like(u)], -1)
    z = (n @ np.array([0, 0, 2.0])) / (ray @ n)  # z-depth: the ray's z component is 1
    want = np.abs(ray @ n) / np.linalg.norm(ray, axis=-1)
    got = dt.true_normals_cos(z, K)
    inner = np.isfinite(got)
    assert inner[2:-2, 2:-2].all() and not inner[0].any() and not inner[:, 0].any()
    np.testing.assert_allclose(got[inner], want[inner], atol=1e-9)
    normal, _ = dt.true_normals(z, K)
    np.testing.assert_allclose(normal[inner], np.broadcast_to(n, normal[inner].shape), atol=1e-9)  # faces the camera


def test_faces_by_the_world_normal(dt):
    n = np.array([[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0], [0.6, 0, 0.8], [0.8, 0, -0.6]])
    assert dt.face_of(n).tolist() == ["up", "down", "side", "up", "side"]


def test_background_neighbours_give_no_angle(dt):
    z = np.full((16, 16), 3.0)
    z[:, 8:] = 0.0  # background
    c = dt.true_normals_cos(z, np.array([[20.0, 0, 8], [0, 20.0, 8], [0, 0, 1]]))
    assert np.isnan(c[:, 7:]).all() and np.isfinite(c[2:-2, 2:6]).all()
