"""Analytic shapes as Gaussian splats and the cameras that see them, for the geometry tests: flat Gaussians on a
box's faces, a ring of cameras whose masks are the rendered silhouettes, a box or any object on a tile floor."""

from __future__ import annotations

import math

import numpy as np
import torch

from physgs_nerfstudio.export.shapes import field_from
from physgs_nerfstudio.geometry import CaptureView, GeometryConfig, reconstruct_object
from physgs_nerfstudio.geometry.capture import viewmat_from_c2w
from physgs_nerfstudio.geometry.gaussians import render_depth
from physgs_nerfstudio.synth.render import look_at

RES = 96


def look_at_w2c(eye: np.ndarray, target: np.ndarray | None = None) -> torch.Tensor:
    """World-to-camera [4, 4] (OpenCV axes, float32) of a camera at ``eye`` looking at ``target`` (the origin), its
    image x axis level (world z up): the generator's camera (:func:`physgs_nerfstudio.synth.render.look_at`) as the
    geometry reads it (:func:`physgs_nerfstudio.geometry.capture.viewmat_from_c2w`)."""
    return viewmat_from_c2w(torch.from_numpy(look_at(eye, np.zeros(3) if target is None else target)[:3]))


def flat_gaussians(points: torch.Tensor, normals: torch.Tensor, spacing: float):
    """Flat Gaussians tangent to a surface: in-plane scale ``spacing``, thin along the normal."""
    z = torch.tensor([0.0, 0.0, 1.0], dtype=points.dtype)
    n = normals / normals.norm(dim=1, keepdim=True)
    axis = torch.cross(z.expand_as(n), n, dim=1)
    s = axis.norm(dim=1, keepdim=True).clamp(max=1.0)
    c = (n * z).sum(1, keepdim=True)
    ang = torch.atan2(s, c)
    axis = torch.where(s > 1e-9, axis / s.clamp_min(1e-12), torch.tensor([1.0, 0.0, 0.0], dtype=points.dtype))
    quats = torch.cat([torch.cos(ang / 2), axis * torch.sin(ang / 2)], 1)
    scales = torch.tensor([spacing, spacing, 1e-4], dtype=points.dtype).expand(len(points), 3).clone()
    return points.float(), scales.float(), quats.float()


def box_surface(size, spacing, centre=(0.0, 0.0, 0.0)):
    pts, nrm = [], []
    half = torch.tensor(size, dtype=torch.float64) / 2
    for ax in range(3):
        a, b = [i for i in range(3) if i != ax]
        na, nb = max(2, round(size[a] / spacing)), max(2, round(size[b] / spacing))
        ga = (torch.arange(na, dtype=torch.float64) + 0.5) / na * size[a] - half[a]
        gb = (torch.arange(nb, dtype=torch.float64) + 0.5) / nb * size[b] - half[b]
        A, B = torch.meshgrid(ga, gb, indexing="ij")
        for sign in (-1.0, 1.0):
            p = torch.zeros(A.numel(), 3, dtype=torch.float64)
            p[:, a], p[:, b], p[:, ax] = A.reshape(-1), B.reshape(-1), sign * half[ax]
            n = torch.zeros_like(p)
            n[:, ax] = sign
            pts.append(p)
            nrm.append(n)
    p = torch.cat(pts) + torch.tensor(centre, dtype=torch.float64)
    return flat_gaussians(p, torch.cat(nrm), spacing * 0.5)


def ring_views(
    pf, centre, radius, n=20, elevations=(-20.0, 20.0, 55.0), size=RES, fov_deg=40.0, mask_pf=None
):
    """Cameras on rings looking at ``centre``; masks = rendered silhouettes of ``mask_pf`` (default: pf)."""
    f = size / (2 * math.tan(math.radians(fov_deg) / 2))
    K = torch.tensor([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1.0]])
    views = []
    c = torch.tensor(centre, dtype=torch.float64)
    per = max(1, n // len(elevations))
    for e_i, elev in enumerate(elevations):
        for i in range(per):
            az = 2 * math.pi * (i + 0.5 * e_i) / per
            el = math.radians(elev)
            pos = c + radius * torch.tensor([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)],
                                            dtype=torch.float64)  # fmt: skip
            fwd = (c - pos) / (c - pos).norm()
            right = torch.cross(fwd, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), dim=0)
            right /= right.norm()
            up = torch.cross(right, fwd, dim=0)
            c2w = torch.stack([right, up, -fwd, pos], 1).float()  # OpenGL axes
            views.append(CaptureView(viewmat_from_c2w(c2w), K, size, size, torch.zeros(size, size, dtype=torch.bool),
                                     name=f"v{len(views)}"))  # fmt: skip
    src = mask_pf if mask_pf is not None else pf
    for v, r in zip(views, render_depth(src, views, backend="reference")):
        v.mask = r.alpha > 0.5
    return views


def geometry_of(pf, views, **kw):
    """The object's geometry by the reference rasterizer at ``resolution`` (default 56) and the other
    ``GeometryConfig`` fields in ``kw``."""
    cfg = GeometryConfig(resolution=kw.pop("resolution", 56), backend="reference", **kw)
    return reconstruct_object(
        pf, pf.pi(), views, (), [t for t in pf.thickness_m], cfg, material_names=pf.material_names
    )


def box_on_floor():
    """A 0.3 m oak box standing on a 2 m tile floor 1 mm below it: (the field, the box's field alone, the box's
    Gaussians)."""
    obj = box_surface((0.3, 0.3, 0.3), 0.02, centre=(0.0, 0.0, 0.15))
    pf, only_obj = on_tile_floor(obj, 1.0)
    return pf, only_obj, obj


def on_tile_floor(obj, half: float):
    """(an oak object's Gaussians ``obj`` on a tile floor 1 mm below z = 0 spanning [-half, half]^2, the object's
    field alone)."""
    g = torch.arange(-half, half, 0.04) + 0.02
    X, Y = torch.meshgrid(g, g, indexing="ij")
    fp = torch.stack([X, Y, torch.zeros_like(X) - 1e-3], -1).reshape(-1, 3).double()
    floor = flat_gaussians(fp, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand_as(fp), 0.032)
    means, scales, quats = (torch.cat([a, b]) for a, b in zip(obj, floor))
    labels = torch.cat([torch.zeros(len(obj[0])), torch.ones(len(floor[0]))]).long()
    pf = field_from(means, scales, quats, densities=[700.0, 1500.0], labels=labels, names=["oak", "tile"],
                    thickness_m=[None, None])  # fmt: skip
    return pf, field_from(*obj, densities=[700.0], names=["oak"])


def table_on_floor():
    """A 0.8 x 0.5 m table (a 4 cm top at 0.5 m on four 4 cm legs) on a tile floor; the masks hold the table alone.
    (Not square: from the middle of a square table aligned with the grid, the lattice's horizontal diagonals run
    straight into its legs, and they count as enclosing; physgs_nerfstudio.geometry.hidden, limits.)"""
    parts = [box_surface((0.8, 0.5, 0.04), 0.02, centre=(0.0, 0.0, 0.52))]
    parts += [
        box_surface((0.04, 0.04, 0.5), 0.02, centre=(x, y, 0.25))
        for x in (-0.37, 0.37)
        for y in (-0.22, 0.22)
    ]
    return on_tile_floor([torch.cat(t) for t in zip(*parts)], 1.2)


def grown_skin(points, origin, voxel_size: float, shape, steps: int):
    """bool tensor: the voxels (a grid of ``origin`` and ``voxel_size``) holding one of ``points``, grown by
    ``steps`` 6-connected steps: a skin that closes every gap, the simplest input for the hidden-space rules."""
    from scipy import ndimage

    ij = np.floor((np.asarray(points, dtype=np.float64) - np.asarray(origin)) / voxel_size).astype(int)
    ij = ij[np.all((ij >= 0) & (ij < np.asarray(shape)), 1)]
    skin = np.zeros(shape, bool)
    skin[tuple(ij.T)] = True
    if steps > 0 and skin.any():
        skin = ndimage.binary_dilation(skin, ndimage.generate_binary_structure(3, 1), iterations=steps)
    return torch.from_numpy(skin)


def whole_voxel_volume(geo) -> float:
    """The nominal volume in whole voxels (scene units^3): the solid's voxels, those on the boundary with hidden open
    space at half, without partial volume's shares (geometry/partial.py)."""
    edge = 0 if geo.hidden_edge is None else int(geo.hidden_edge.sum())
    return (int(geo.solid.sum()) - 0.5 * edge) * geo.grid.voxel_size**3


def pixel_rays(v):
    """A view's camera centre [3] and the unit directions [H, W, 3] of its pixel-centre rays (float64)."""
    R, t, K = v.viewmat[:3, :3].double(), v.viewmat[:3, 3].double(), v.K.double()
    ys, xs = torch.meshgrid(torch.arange(v.height, dtype=torch.float64) + 0.5,
                            torch.arange(v.width, dtype=torch.float64) + 0.5, indexing="ij")  # fmt: skip
    d = torch.stack([(xs - K[0, 2]) / K[0, 0], (ys - K[1, 2]) / K[1, 1], torch.ones_like(xs)], -1) @ R
    return -R.T @ t, d / d.norm(dim=-1, keepdim=True)
