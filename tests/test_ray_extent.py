"""The Gaussians' extent along the ray (geometry.gaussians.ray_extent), its rendered channel, and carving with the
depth moved in front by it (CarveConfig.front_extent): against a numerical integral along the ray, and on a box
whose depth is rendered behind its faces, as a trained splat's surface Gaussians render it."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from helpers.shapes import ring_views

from physgs_nerfstudio.export.shapes import field_from
from physgs_nerfstudio.geometry import CarveConfig
from physgs_nerfstudio.geometry.carve import carve_votes, solid_from_votes
from physgs_nerfstudio.geometry.gaussians import ViewRender, ray_extent, render_depth
from physgs_nerfstudio.geometry.grid import VoxelGrid
from physgs_nerfstudio.render.projection import covariance_3d


def _random_quats(n: int, gen: torch.Generator) -> torch.Tensor:
    q = torch.randn(n, 4, generator=gen, dtype=torch.float64)
    return q / q.norm(dim=1, keepdim=True)


def _look_at(eye: np.ndarray) -> torch.Tensor:
    """A world-to-camera matrix (OpenCV axes: z forward) at ``eye`` looking at the origin."""
    fwd = -eye / np.linalg.norm(eye)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    if np.linalg.norm(right) < 1e-9:  # looking along z
        right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    R = np.stack([right, down, fwd])  # rows: camera axes in world
    vm = np.eye(4)
    vm[:3, :3], vm[:3, 3] = R, -R @ eye
    return torch.from_numpy(vm)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ray_extent_is_the_density_spread_along_the_ray(seed):
    """Oracle: the Gaussian's density sampled along the ray from the camera through its centre (numpy), the
    standard deviation of the ray parameter under it, times the ray's camera-z component."""
    gen = torch.Generator().manual_seed(seed)
    n = 20
    means = torch.randn(n, 3, generator=gen, dtype=torch.float64) * 0.3
    scales = torch.exp(torch.randn(n, 3, generator=gen, dtype=torch.float64)) * 0.02
    quats = _random_quats(n, gen)
    vm = _look_at(np.array([2.0, -1.0, 1.5]))
    got = ray_extent(means, quats, scales, vm).numpy()
    cov = covariance_3d(quats, scales).numpy()
    cam = -vm[:3, :3].numpy().T @ vm[:3, 3].numpy()  # the camera centre in world
    for i in range(n):
        mu = means[i].numpy()
        d = (mu - cam) / np.linalg.norm(mu - cam)
        t = np.linspace(-1.0, 1.0, 200_001)  # around the centre, metres along the ray
        x = mu + t[:, None] * d
        prec = np.linalg.inv(cov[i])
        w = np.exp(-0.5 * np.einsum("ni,ij,nj->n", x - mu, prec, x - mu))
        mean_t = (w * t).sum() / w.sum()
        std_t = math.sqrt((w * (t - mean_t) ** 2).sum() / w.sum())
        dz = (vm[:3, :3].numpy() @ d)[2]
        assert got[i] == pytest.approx(std_t * dz, rel=1e-3)


def test_a_flat_gaussian_seen_at_an_angle_has_its_thickness_over_the_cosine():
    sigma_n = 0.004
    scales = torch.tensor([[0.05, 0.05, sigma_n]], dtype=torch.float64)
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=torch.float64)  # normal: world z
    for deg in (0.0, 30.0, 60.0):
        th = math.radians(deg)
        vm = _look_at(np.array([3 * math.sin(th), 0.0, 3 * math.cos(th)]))
        e = float(ray_extent(torch.zeros(1, 3, dtype=torch.float64), quats, scales, vm)[0])
        # exactly 1 / sqrt(cos^2/sn^2 + sin^2/st^2); about sn / cos when the disc is wide
        assert e == pytest.approx(1 / math.sqrt(math.cos(th) ** 2 / sigma_n**2 + math.sin(th) ** 2 / 0.05**2), rel=1e-9)
        assert e == pytest.approx(sigma_n / math.cos(th), rel=0.06)


def test_rendered_extent_is_the_blend_of_the_gaussians_extents():
    gen = torch.Generator().manual_seed(3)
    n = 60
    means = (torch.rand(n, 3, generator=gen) - 0.5) * 0.2
    scales = torch.full((n, 3), 0.03)
    quats = _random_quats(n, gen).float()
    pf = field_from(means, scales, quats, densities=[700.0], names=["oak"], thickness_m=[None])
    views = ring_views(pf, (0, 0, 0), 1.5, n=3, elevations=(20.0,))
    for v, r in zip(views, render_depth(pf, views, backend="reference", extent=True, spread=True)):
        e = ray_extent(pf.means, pf.quats, pf.scales, v.viewmat)
        # isotropic Gaussians: the extent along any ray is the scale times the ray's z component (<= 1)
        hit = r.alpha > 1e-3
        assert hit.sum() > 100
        assert torch.all(r.extent[hit] <= 0.03 + 1e-6) and torch.all(r.extent[hit] >= 0.03 * float(e.min() / 0.03) - 1e-6)
        assert torch.all(r.extent[~hit] == 0)
        assert r.spread is not None and torch.all(r.spread >= 0)  # the moments' channels unchanged by the new one


def test_front_extent_must_not_be_negative():
    with pytest.raises(ValueError, match="front_extent"):
        CarveConfig(front_extent=-1.0)
    assert CarveConfig(depth_render="expected").extent_multiple() == 2.0
    assert CarveConfig(depth_render="median").extent_multiple() == 0.0
    assert CarveConfig(depth_render="expected", front_extent=0.0).extent_multiple() == 0.0


def _box_renders(views, lo, hi, behind, extent):
    """Each view's depth of the box [lo, hi] by ray casting (camera z), rendered ``behind`` too deep, with the
    along-ray extent ``extent`` everywhere on it: as a trained splat's surface Gaussians give it, whose centres lie
    behind the surface they draw."""
    out = []
    for v in views:
        H, W = v.height, v.width
        jj, ii = torch.meshgrid(torch.arange(H, dtype=torch.float64) + 0.5, torch.arange(W, dtype=torch.float64) + 0.5,
                                indexing="ij")  # fmt: skip
        K = v.K.double()
        dc = torch.stack([(ii - K[0, 2]) / K[0, 0], (jj - K[1, 2]) / K[1, 1], torch.ones_like(ii)], -1)  # z = 1
        R, t = v.viewmat[:3, :3].double(), v.viewmat[:3, 3].double()
        origin = -R.T @ t
        dw = dc @ R  # world direction per unit camera z
        with np.errstate(divide="ignore"):
            t0 = (torch.tensor(lo) - origin) / dw
            t1 = (torch.tensor(hi) - origin) / dw
        near = torch.minimum(t0, t1).amax(-1)
        far = torch.maximum(t0, t1).amin(-1)
        hit = (far >= near) & (near > 0)
        depth = torch.where(hit, near + behind, torch.full_like(near, float("inf"))).float()
        out.append(ViewRender(depth, hit.float(), extent=torch.where(hit, extent, 0.0).float()))
        v.mask = hit
    return out


def test_moving_the_depth_by_the_extent_keeps_the_layer_behind_the_surface():
    """A box whose depth is rendered 1 cm behind its faces in every view (the centres' layer) with an along-ray
    extent of 1 cm: the depth votes carve a 1 cm layer off each face that the views see; moved by one extent, the
    depth is the face's and the box is kept whole."""
    lo, hi = (-0.2, -0.15, -0.1), (0.2, 0.15, 0.1)
    truth = 0.4 * 0.3 * 0.2
    one = field_from(torch.zeros(1, 3), torch.full((1, 3), 0.05), torch.tensor([[1.0, 0, 0, 0]]), densities=[700.0],
                     names=["oak"], thickness_m=[None])  # the views' masks are the box's (_box_renders)
    pf_views = ring_views(one, (0, 0, 0), 1.5, n=24, size=128)
    renders = _box_renders(pf_views, lo, hi, behind=0.01, extent=0.01)
    grid = VoxelGrid.from_bounds(torch.tensor([-0.25, -0.2, -0.15]), torch.tensor([0.25, 0.2, 0.15]), 100)

    def volume(k: float) -> float:
        cfg = CarveConfig(depth_render="expected", front_extent=k)
        solid = solid_from_votes(carve_votes(grid, pf_views, renders, cfg), grid, cfg)
        return float(solid.sum()) * grid.voxel_size**3 / truth

    v0, v1 = volume(0.0), volume(1.0)
    assert v0 < 0.9  # the seen faces lost their layer (the bottom, seen by few views, may keep it)
    assert abs(v1 - 1) < 0.04
