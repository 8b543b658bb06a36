"""Pure-torch, differentiable 3D Gaussian rasterizer with the call shape of `gsplat.rasterization` (1.4.0).

Covers what nerfstudio 1.1.5's splatfacto and gsplat's DefaultStrategy use: pinhole cameras, N-D colours
or SH coefficients, backgrounds, render modes RGB / D / ED / RGB+D / RGB+ED, classic or antialiased
opacity compensation, packed or unpacked meta, and `absgrad`. Runs on any device (meant for CPU).
"""

from __future__ import annotations

import math
from typing import Any, Literal

import torch
from jaxtyping import Float
from torch import Tensor

from .composite import composite_image, crossing_depth_image
from .projection import covariance_3d, project_gaussians, quat_to_rotmat
from .sh import eval_sh_colors

RENDER_MODES = ("RGB", "D", "ED", "RGB+D", "RGB+ED")


def _check_inputs(
    means, quats, scales, opacities, colors, viewmats, Ks, covars, sh_degree
) -> tuple[int, int]:
    N, C = means.shape[0], viewmats.shape[0]
    if means.shape != (N, 3):
        raise ValueError(f"means must be [N, 3], got {tuple(means.shape)}")
    if covars is None:
        if quats is None or quats.shape != (N, 4):
            raise ValueError(
                f"quats must be [N={N}, 4] (wxyz), got {None if quats is None else tuple(quats.shape)}"
            )
        if scales is None or scales.shape != (N, 3):
            raise ValueError(
                f"scales must be [N={N}, 3], got {None if scales is None else tuple(scales.shape)}"
            )
    elif covars.shape != (N, 3, 3):
        raise ValueError(f"covars must be [N={N}, 3, 3], got {tuple(covars.shape)}")
    if opacities.shape != (N,):
        raise ValueError(f"opacities must be [N={N}], got {tuple(opacities.shape)}")
    if viewmats.shape != (C, 4, 4) or Ks.shape != (C, 3, 3):
        raise ValueError(
            f"viewmats must be [C, 4, 4] and Ks [C, 3, 3], got {tuple(viewmats.shape)}, {tuple(Ks.shape)}"
        )
    if sh_degree is None:
        ok = (colors.dim() == 2 and colors.shape[0] == N) or (
            colors.dim() == 3 and colors.shape[:2] == (C, N)
        )
        if not ok:
            raise ValueError(
                f"colors must be [N, D] or [C, N, D] without sh_degree, got {tuple(colors.shape)}"
            )
    else:
        ok = (colors.dim() == 3 and colors.shape[0] == N and colors.shape[2] == 3) or (
            colors.dim() == 4 and colors.shape[:2] == (C, N) and colors.shape[3] == 3
        )
        if not ok:
            raise ValueError(f"SH colors must be [N, K, 3] or [C, N, K, 3], got {tuple(colors.shape)}")
        if (sh_degree + 1) ** 2 > colors.shape[-2]:
            raise ValueError(f"sh_degree={sh_degree} needs {(sh_degree + 1) ** 2} SH coefficients, "
                             f"got {colors.shape[-2]}")  # fmt: skip
    return N, C


def reference_rasterization(
    means: Float[Tensor, "N 3"],
    quats: Float[Tensor, "N 4"] | None,
    scales: Float[Tensor, "N 3"] | None,
    opacities: Float[Tensor, " N"],
    colors: Tensor,  # [(C,) N, D] or [(C,) N, K, 3]
    viewmats: Float[Tensor, "C 4 4"],
    Ks: Float[Tensor, "C 3 3"],
    width: int,
    height: int,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    radius_clip: float = 0.0,
    eps2d: float = 0.3,
    sh_degree: int | None = None,
    packed: bool = True,
    tile_size: int = 16,
    backgrounds: Float[Tensor, "C D"] | None = None,
    render_mode: Literal["RGB", "D", "ED", "RGB+D", "RGB+ED"] = "RGB",
    sparse_grad: bool = False,
    absgrad: bool = False,
    rasterize_mode: Literal["classic", " antialiased"] = "classic",
    channel_chunk: int = 32,
    distributed: bool = False,
    camera_model: Literal["pinhole", "ortho", " fisheye"] = "pinhole",
    covars: Float[Tensor, "N 3 3"] | None = None,
    *,
    max_pairs: int = 1 << 21,
) -> tuple[Float[Tensor, "C H W X"], Float[Tensor, "C H W 1"], dict[str, Any]]:
    """Same arguments and return as `gsplat.rasterization`; see gsplat's documentation.

    `sparse_grad` and `channel_chunk` are accepted and ignored (memory is bounded by `max_pairs`, the
    number of candidate (Gaussian, pixel) pairs processed at once; beyond it, depth chunks are
    gradient-checkpointed). `distributed` and camera models other than "pinhole" raise.
    """
    if camera_model != "pinhole":
        raise NotImplementedError(
            f"reference rasterizer supports camera_model='pinhole' only, got {camera_model!r}"
        )
    if distributed:
        raise NotImplementedError("reference rasterizer does not support distributed=True")
    if render_mode not in RENDER_MODES:
        raise ValueError(f"render_mode must be one of {RENDER_MODES}, got {render_mode!r}")
    if rasterize_mode not in ("classic", "antialiased"):
        raise ValueError(f"rasterize_mode must be 'classic' or 'antialiased', got {rasterize_mode!r}")
    N, C = _check_inputs(means, quats, scales, opacities, colors, viewmats, Ks, covars, sh_degree)

    cov3d = covariance_3d(quats, scales) if covars is None else covars
    proj = project_gaussians(
        means, cov3d, viewmats, Ks, width, height, eps2d=eps2d, near_plane=near_plane, far_plane=far_plane,
        radius_clip=radius_clip, calc_compensations=rasterize_mode == "antialiased",
    )  # fmt: skip
    radii = proj.radii
    opac = opacities[None].expand(C, N)
    if proj.compensations is not None:
        opac = opac * proj.compensations

    # Per-camera colours [C, N, D].
    if render_mode in ("D", "ED"):
        feats = proj.depths[..., None]
    else:
        if sh_degree is None:
            feats = colors if colors.dim() == 3 else colors[None].expand(C, -1, -1)
        else:
            campos = torch.linalg.inv(viewmats)[:, :3, 3]
            dirs = means[None] - campos[:, None]
            shs = colors if colors.dim() == 4 else colors[None].expand(C, -1, -1, -1)
            feats = torch.clamp_min(eval_sh_colors(sh_degree, dirs, shs) + 0.5, 0.0)
            feats = torch.where((radii > 0)[..., None], feats, torch.zeros_like(feats) + 0.5)
        if render_mode in ("RGB+D", "RGB+ED"):
            feats = torch.cat([feats, proj.depths[..., None].to(feats.dtype)], dim=-1)
    if backgrounds is not None:
        if render_mode in ("D", "ED"):
            backgrounds = torch.zeros(C, 1, dtype=feats.dtype, device=feats.device)
        elif render_mode in ("RGB+D", "RGB+ED"):
            backgrounds = torch.cat([backgrounds, torch.zeros_like(backgrounds[:, :1])], dim=-1)
        if backgrounds.shape != (C, feats.shape[-1]):
            raise ValueError(
                f"backgrounds must be [C={C}, D={feats.shape[-1]}], got {tuple(backgrounds.shape)}"
            )

    # Flat per-(camera, Gaussian) tensors: [C*N] unpacked, [nnz] packed.
    means2d, depths, conics = proj.means2d, proj.depths, proj.conics
    camera_ids = gaussian_ids = None
    if packed:
        camera_ids, gaussian_ids = torch.nonzero(radii > 0, as_tuple=True)
        means2d = means2d[camera_ids, gaussian_ids]
        flat = {"means2d": means2d, "conics": conics[camera_ids, gaussian_ids], "opac": opac[camera_ids, gaussian_ids],
                    "feats": feats[camera_ids, gaussian_ids], "depths": depths[camera_ids, gaussian_ids],
                    "radii": radii[camera_ids, gaussian_ids], "cov2d": proj.covars2d[camera_ids, gaussian_ids]}  # fmt: skip
        radii, depths, conics, opac = flat["radii"], flat["depths"], flat["conics"], flat["opac"]
        cam_of = camera_ids
    else:
        flat = {"means2d": means2d.reshape(C * N, 2), "conics": conics.reshape(C * N, 3), "opac": opac.reshape(C * N),
                    "feats": feats.reshape(C * N, -1), "depths": depths.reshape(C * N), "radii": radii.reshape(C * N),
                    "cov2d": proj.covars2d.reshape(C * N, 3)}  # fmt: skip
        cam_of = torch.arange(C, device=means.device).repeat_interleave(N)

    hook = None
    if absgrad and means2d.requires_grad:
        means2d.absgrad = torch.zeros_like(means2d)
        absgrad_flat = means2d.absgrad.view(-1, 2)

        def hook(
            abs_grads: Tensor, ids: Tensor
        ) -> None:  # per-pair |d loss / d means2d|, summed per Gaussian
            absgrad_flat.index_add_(0, ids, abs_grads.to(absgrad_flat.dtype))

    images, alphas = [], []
    for cam in range(C):
        sel = torch.nonzero(cam_of == cam).squeeze(-1)
        cam_hook = None if hook is None else (lambda ag, ids, sel=sel: hook(ag, sel[ids]))
        img, alpha = composite_image(
            flat["means2d"][sel], flat["conics"][sel], flat["opac"][sel], flat["feats"][sel], flat["depths"][sel],
            flat["radii"][sel], flat["cov2d"][sel], width, height, tile_size=tile_size, max_pairs=max_pairs,
            absgrad_hook=cam_hook,
        )  # fmt: skip
        if backgrounds is not None:
            img = img + (1.0 - alpha) * backgrounds[cam]
        images.append(img)
        alphas.append(alpha)
    render_colors = torch.stack(images)
    render_alphas = torch.stack(alphas)
    if render_mode in ("ED", "RGB+ED"):
        render_colors = torch.cat(
            [render_colors[..., :-1], render_colors[..., -1:] / render_alphas.clamp(min=1e-10)], dim=-1
        )

    tile_width, tile_height = math.ceil(width / tile_size), math.ceil(height / tile_size)
    meta = {
        "camera_ids": camera_ids,
        "gaussian_ids": gaussian_ids,
        "radii": radii,
        "means2d": means2d,
        "depths": depths,
        "conics": conics,
        "opacities": opac,
        "tile_width": tile_width,
        "tile_height": tile_height,
        "tiles_per_gauss": None,
        "isect_ids": None,
        "flatten_ids": None,
        "isect_offsets": None,
        "width": width,
        "height": height,
        "tile_size": tile_size,
        "n_cameras": C,
        "backend": "reference",
    }
    return render_colors, render_alphas, meta


@torch.no_grad()
def reference_surface_depth(
    means: Float[Tensor, "N 3"],
    quats: Float[Tensor, "N 4"],
    scales: Float[Tensor, "N 3"],
    opacities: Float[Tensor, " N"],
    viewmat: Float[Tensor, "4 4"],
    K: Float[Tensor, "3 3"],
    width: int,
    height: int,
    *,
    transmittance: float,
    near_plane: float = 0.01,
    eps2d: float = 0.3,
) -> Float[Tensor, "H W"]:
    """Per pixel the depth (camera z) at which the ray's transmittance first drops to ``transmittance`` or below, with
    the projection and compositing of :func:`reference_rasterization` (classic mode): the depth of the densest
    point along the pixel's ray of the Gaussian at which it does (:func:`.composite.crossing_depth_image` finds
    that Gaussian; :func:`ray_peak_depth`); +inf where it never does, i.e. where the pixel's alpha stays under
    ``1 - transmittance``. 0.5 is the *median depth* of 3-D Gaussian surface reconstruction. Why the ray's point,
    not the Gaussian's centre: a pixel takes its light from Gaussians whose centres lie beside its ray, and on a face
    seen at an angle the centres nearer the camera lie in front of the face where the ray meets it; the lower the
    transmittance's level, the more it is set by such a Gaussian's fringe. Runs on any device; gsplat has no such
    render mode."""
    if not 0 < transmittance < 1:
        raise ValueError(f"reference_surface_depth: transmittance must be in (0, 1), got {transmittance}")
    cov = covariance_3d(quats, scales)
    proj = project_gaussians(means, cov, viewmat[None], K[None], width, height, eps2d=eps2d,
                             near_plane=near_plane, far_plane=1e10, radius_clip=0.0, calc_compensations=False)  # fmt: skip
    index = torch.arange(len(means), dtype=torch.float64, device=means.device)
    hit = crossing_depth_image(proj.means2d[0], proj.conics[0], opacities, proj.depths[0], proj.radii[0],
                               proj.covars2d[0], width, height, level=transmittance, values=index)  # fmt: skip
    out = torch.full((height, width), float("inf"), dtype=means.dtype, device=means.device)
    rows, cols = torch.nonzero(torch.isfinite(hit), as_tuple=True)
    if len(rows):
        gid = hit[rows, cols].long()
        out[rows, cols] = ray_peak_depth(means[gid], quats[gid], scales[gid], viewmat, K, cols, rows).to(out.dtype)
    return out


def ray_peak_depth(means: Float[Tensor, "P 3"], quats: Float[Tensor, "P 4"], scales: Float[Tensor, "P 3"],
                   viewmat: Float[Tensor, "4 4"], K: Float[Tensor, "3 3"], cols: Tensor, rows: Tensor
                   ) -> Float[Tensor, " P"]:  # fmt: skip
    """float64 [P]: the camera z of the densest point of Gaussian p (world ``means``, ``quats``, activated ``scales``)
    along the ray through the centre of pixel (``rows[p]``, ``cols[p]``): with ``d`` the ray's direction scaled to
    z = 1 and ``mu``, ``A`` the mean and inverse covariance in the camera frame, ``z = d^T A mu / d^T A d`` (the
    density restricted to the line is a 1-D Gaussian with that mean), clamped to within 3 standard deviations of the
    centre's depth (a ray that grazes a long Gaussian far from its centre)."""
    R, t = viewmat[:3, :3].double(), viewmat[:3, 3].double()
    mu = means.double() @ R.T + t
    rot = R @ quat_to_rotmat(quats.double())  # the Gaussians' axes in the camera frame
    s = scales.double().clamp_min(1e-12)
    axes = rot / s[:, None, :]
    A = axes @ axes.transpose(-1, -2)  # the inverse covariance
    Kd = K.double()
    d = torch.stack([(cols.double() + 0.5 - Kd[0, 2]) / Kd[0, 0], (rows.double() + 0.5 - Kd[1, 2]) / Kd[1, 1],
                     torch.ones_like(cols, dtype=torch.float64)], -1)  # fmt: skip
    Ad = (A @ d[:, :, None])[..., 0]
    z = (Ad * mu).sum(-1) / (Ad * d).sum(-1).clamp_min(1e-300)
    sd = (rot[:, 2, :] * s).norm(dim=-1)  # the density's standard deviation in camera z
    return torch.minimum(torch.maximum(z, mu[:, 2] - 3 * sd), mu[:, 2] + 3 * sd)
