"""The surface depth that carves (geometry.gaussians.SURFACE_TRANSMITTANCE) on a solid drawn as a soft layer of
Gaussians, against the analytic volume: a trained splat draws a surface as semi-transparent Gaussians at the surface
and more of them behind it (the splat fills in behind a surface it cannot make opaque with one layer), so the depth
where the ray has lost half its light lies a layer behind the surface, and every view carves that layer off."""

from __future__ import annotations

import math

import pytest
import torch
from helpers.shapes import flat_gaussians, geometry_of, pixel_rays, ring_views, whole_voxel_volume

from physgs_nerfstudio.export.shapes import field_from
from physgs_nerfstudio.geometry import CarveConfig
from physgs_nerfstudio.geometry import gaussians as gaussians_mod

RADIUS = 0.1
LAYERS = 4
LAYER_STEP = 0.01  # 10 mm between the layers: about 2 voxels at 48 voxels across the domain
SPACING = 0.008


def soft_sphere(opacity: float = 0.12):
    """A solid sphere of radius RADIUS drawn as LAYERS concentric shells of flat Gaussians, the outermost on the true
    surface and the others LAYER_STEP apart inside it, each Gaussian ``opacity`` opaque (0.12: a shell stops about
    30% of a ray, the eight crossings of a ray through the centre 94%),
    and the sphere's exact silhouettes as the masks (independent of the Gaussians)."""
    pts, nrm = [], []
    for k in range(LAYERS):
        r = RADIUS - k * LAYER_STEP
        n = max(8, round(4 * math.pi * r**2 / SPACING**2))
        i = torch.arange(n, dtype=torch.float64) + 0.5
        z = 1 - 2 * i / n
        phi = math.pi * (3 - math.sqrt(5)) * i
        ring = torch.sqrt(1 - z * z)
        dirs = torch.stack([ring * torch.cos(phi), ring * torch.sin(phi), z], -1)
        pts.append(r * dirs)
        nrm.append(dirs)
    means, scales, quats = flat_gaussians(torch.cat(pts), torch.cat(nrm), SPACING * 0.5)
    pf = field_from(means, scales, quats, densities=[1000.0], names=["c"], thickness_m=[None], opacity=opacity)
    views = ring_views(pf, (0, 0, 0), 0.9, n=8, elevations=(-30.0, 10.0, 45.0))
    for v in views:  # pixel-centre rays that pass within RADIUS of the centre
        c, d = pixel_rays(v)
        s = (d @ -c).clamp_min(0)
        v.mask = (c + s[..., None] * d).norm(dim=-1) <= RADIUS
    return pf, views


@pytest.fixture(scope="module")
def sphere():
    return soft_sphere()


def _volume_ratio(pf, views) -> float:
    # whole voxels: the depth rule's carving alone, without partial volume's shares
    geo = geometry_of(pf, views, resolution=48, variants=False, carve=CarveConfig())
    return whole_voxel_volume(geo) / (4 / 3 * math.pi * RADIUS**3)


def test_the_surface_depth_keeps_a_soft_layers_solid(sphere):
    """At SURFACE_TRANSMITTANCE the ray crosses on the outermost layer, on the true surface: 1.005x of the analytic
    volume (whole voxels by their centres at 48 voxels)."""
    assert gaussians_mod.SURFACE_TRANSMITTANCE == 0.8
    assert abs(_volume_ratio(*sphere) - 1) < 0.05


def test_the_median_depth_carves_a_soft_layer_off(sphere, monkeypatch):
    """The same sphere carved at the median depth (transmittance 1/2): the ray crosses on the second layer, a layer
    behind the true surface, and every view carves that layer off: 0.815x."""
    monkeypatch.setattr(gaussians_mod, "SURFACE_TRANSMITTANCE", 0.5)
    assert _volume_ratio(*sphere) < 0.9
