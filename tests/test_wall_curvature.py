"""The wall's volume inside a curved face: the mesh's integrated mean curvature and the wall-volume model.

Oracles: exact dihedral sums of a regular octahedron; Steiner's values of voxelised cylinders and spheres; the
closed-form shell volumes of a sphere and of a closed tube."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage
from skimage.measure import marching_cubes

from physgs_nerfstudio.geometry.grid import VoxelGrid
from physgs_nerfstudio.geometry.walls import face_mean_curvature, part_areas
from physgs_nerfstudio.mass.integrate import wall_volume


def _signed_volume(verts: np.ndarray, faces: np.ndarray) -> float:
    t = verts[faces]
    return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6)


def _mesh(solid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The smoothed marching-cubes mesh that :func:`part_areas` builds."""
    padded = ndimage.gaussian_filter(np.pad(solid, 2).astype(np.float32), 0.5)
    verts, faces, _, _ = marching_cubes(padded, 0.5)
    return verts, faces


def _centred(n: int) -> tuple[np.ndarray, ...]:
    o = np.arange(n) - (n - 1) / 2
    return np.meshgrid(o, o, o, indexing="ij")


def test_marching_cubes_winds_its_faces_inwards():
    """face_mean_curvature relies on scikit-image's winding around a field that is larger inside."""
    x, y, z = _centred(24)
    v, f = _mesh(x**2 + y**2 + z**2 <= 8**2)
    assert _signed_volume(v, f) < 0


@pytest.mark.parametrize("edge", [1.0, 2.5])
def test_octahedron_gives_its_exact_dihedral_sum(edge):
    """M = sum |e| theta / 2 over the 12 edges, theta = pi - acos(-1/3) (exact); wound as marching cubes winds."""
    r = edge / math.sqrt(2)
    v = np.array([[r, 0, 0], [-r, 0, 0], [0, r, 0], [0, -r, 0], [0, 0, r], [0, 0, -r]])
    faces = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    if _signed_volume(v, faces) > 0:
        faces = faces[:, ::-1]
    c = face_mean_curvature(v, faces)
    theta = math.pi - math.acos(-1 / 3)
    assert c.sum() == pytest.approx(12 * edge * theta / 2, rel=1e-12)
    np.testing.assert_allclose(c, c[0])  # each face takes an equal share by symmetry
    # turned inside out (the faces wound the other way) the same surface is concave everywhere
    assert face_mean_curvature(v, faces[:, ::-1]).sum() == pytest.approx(-c.sum(), rel=1e-12)


@pytest.mark.parametrize("R,h", [(3, 40), (6, 40), (12, 40)])
def test_voxelised_cylinder_against_steiner(R, h):
    """Lateral pi h plus the two rims' pi/2 edges, 2 pi R x pi/2 / 2 each: pi h + pi^2 R."""
    x, y, z = _centred(max(2 * R, h) + 8)
    v, f = _mesh((x**2 + y**2 <= R**2) & (np.abs(z) <= h / 2))
    assert face_mean_curvature(v, f).sum() == pytest.approx(math.pi * h + math.pi**2 * R, rel=0.02)


@pytest.mark.parametrize("R", [5, 10, 20])
def test_voxelised_sphere_curvature_over_area(R):
    """M / A = 1 / R for a sphere (the wall model's radius)."""
    x, y, z = _centred(2 * R + 8)
    v, f = _mesh(x**2 + y**2 + z**2 <= R**2)
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    assert face_mean_curvature(v, f).sum() / area == pytest.approx(1 / R, rel=0.04)


def test_a_concave_face_has_negative_curvature():
    """The inside of a spherical cavity: the surface bends away from the solid."""
    x, y, z = _centred(40)
    r2 = x**2 + y**2 + z**2
    v, f = _mesh((r2 <= 17**2) & (r2 > 10**2))
    tri = v[f]
    centroid_r = np.linalg.norm(tri.mean(1) - (np.array([40, 40, 40]) + 3) / 2, axis=1)
    c = face_mean_curvature(v, f)
    assert c[centroid_r < 13].sum() < 0 < c[centroid_r > 14].sum()


@pytest.mark.parametrize("t_over_R", [0.01, 0.1, 0.5, 0.99])
def test_wall_volume_is_exact_for_a_sphere(t_over_R):
    R = 0.2
    t = t_over_R * R
    A, M = 4 * math.pi * R**2, 4 * math.pi * R
    exact = 4 / 3 * math.pi * (R**3 - (R - t) ** 3)
    assert float(wall_volume(A, A, M, t)) == pytest.approx(exact, rel=1e-12)
    assert float(wall_volume(A, A, M, 2 * R)) == pytest.approx(4 / 3 * math.pi * R**3, rel=1e-12)


def test_wall_volume_without_full_faces_is_area_times_thickness():
    area = np.array([0.3, 0.5])
    np.testing.assert_allclose(wall_volume(area, 0.0, 7.0, 0.004), area * 0.004, rtol=1e-15)


def test_wall_volume_of_a_long_tube_is_first_order_exact():
    """Lateral wall of a tube (A = 2 pi R h, M = pi h): exact pi h (2 R t - t^2) to O(t^3)."""
    R, h = 0.02, 0.5
    A, M = 2 * math.pi * R * h, math.pi * h
    for t in (0.001, 0.002, 0.004):
        exact = math.pi * h * (2 * R * t - t * t)
        assert float(wall_volume(A, A, M, t)) == pytest.approx(exact, rel=(t / R) ** 2 / 6 + 1e-12)


@settings(max_examples=60, deadline=None)
@given(st.floats(1e-4, 1.0), st.floats(0.0, 1.0), st.floats(-50.0, 200.0), st.floats(1e-5, 0.05),
       st.floats(1e-5, 0.05))
def test_wall_volume_grows_with_thickness_and_stays_positive(area, full_share, mean_h, t1, t2):
    full = area * full_share
    M = mean_h * full
    lo, hi = sorted((t1, t2))
    w_lo, w_hi = (float(wall_volume(area, full, M, t)) for t in (lo, hi))
    assert 0 < w_lo <= w_hi * (1 + 1e-12)
    if M >= 0:
        assert w_hi <= area * hi * (1 + 1e-12)
    else:
        assert w_hi >= area * hi * (1 - 1e-12)


def test_part_areas_wall_of_a_closed_tube():
    """A closed tube carved solid (no view sees inside): its wall t inside the outer surface. The mass's model
    from part_areas' full area and curvature lands within 3% of the true shell volume; area x t is 8% high."""
    R, h, t = 20.0, 60.0, 3.0
    x, y, z = _centred(80)
    solid = (x**2 + y**2 <= R**2) & (np.abs(z) <= h / 2)
    grid = VoxelGrid.from_bounds(np.zeros(3), np.full(3, 80.0), 80)
    parts = np.where(solid, 0, -1)
    geo = part_areas(grid, solid, parts, 1)
    h_vox = grid.voxel_size
    Rm, hm, tm = (v * h_vox for v in (R + 0.5, h + 1.0, t))  # the voxels' outer faces
    exact = math.pi * Rm**2 * hm - math.pi * (Rm - tm) ** 2 * (hm - 2 * tm)
    assert geo.full_area[0] == pytest.approx(geo.area[0])
    model = float(wall_volume(geo.area[0], geo.full_area[0], geo.curvature[0], tm))
    assert model == pytest.approx(exact, rel=0.03)
    assert geo.area[0] * tm > 1.05 * exact
