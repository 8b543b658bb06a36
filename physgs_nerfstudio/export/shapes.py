"""Analytic Gaussian clouds of known shapes with known mass: for tests, benchmarks and sanity checks.

``solid_box`` / ``solid_cylinder``: isotropic Gaussians on a cubic lattice of spacing ``s`` filling the
shape (one Gaussian per lattice cell whose centre is inside), scale ``s`` (smooth, ripple-free field).
``shell_sphere``: flat Gaussians tangent to a sphere (Fibonacci points), the 3DGS-like surface case.
``field_from`` wraps positions into a :class:`PropertyField` with one or more materials whose NIG posteriors
are centred on known densities.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from ..bayes import NIG
from .field import PropertyField

__all__ = ["field_from", "material_nig", "random_cloud", "shell_sphere", "solid_box", "solid_cylinder"]

KEYS = ("density", "kinetic_friction", "shore_hardness", "youngs_modulus")
LOG_SPACE = (True, False, False, True)


def _lattice(lo: Sequence[float], hi: Sequence[float], spacing: float) -> torch.Tensor:
    axes = [torch.arange(a + spacing / 2, b, spacing, dtype=torch.float64) for a, b in zip(lo, hi)]
    g = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    return g


def solid_box(size: Sequence[float], spacing: float, centre: Sequence[float] = (0, 0, 0)):
    """(means, scales, quats) of a lattice filling the box ``size`` centred at ``centre``; volume = prod(size)
    exactly when every size is a multiple of ``spacing``."""
    c = torch.as_tensor(centre, dtype=torch.float64)
    half = torch.as_tensor(size, dtype=torch.float64) / 2
    means = _lattice((c - half).tolist(), (c + half - 1e-12).tolist(), spacing).float()
    n = means.shape[0]
    return means, torch.full((n, 3), spacing), _identity(n)


def solid_cylinder(radius: float, height: float, spacing: float):
    """Lattice filling the z-axis cylinder (centred at the origin); one Gaussian per cell centre inside."""
    pts = _lattice((-radius, -radius, -height / 2), (radius, radius, height / 2 - 1e-12), spacing)
    pts = pts[(pts[:, 0] ** 2 + pts[:, 1] ** 2) <= radius**2].float()
    n = pts.shape[0]
    return pts, torch.full((n, 3), spacing), _identity(n)


def shell_sphere(radius: float, spacing: float, normal_scale: float = 1e-4):
    """Flat Gaussians tangent to a sphere: ~area/spacing^2 Fibonacci points, in-plane scale ``spacing``,
    normal scale ``normal_scale`` (3DGS surfaces are thinner than any voxel)."""
    n = max(16, int(round(4 * math.pi * radius**2 / spacing**2)))
    i = torch.arange(n, dtype=torch.float64) + 0.5
    z = 1 - 2 * i / n
    phi = math.pi * (3 - math.sqrt(5)) * i
    r = torch.sqrt(1 - z * z)
    normal = torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1)
    means = (radius * normal).float()
    # rotation taking local z to the normal: quaternion from (0,0,1) to n
    axis = torch.cross(torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand_as(normal), normal, dim=-1)
    w = 1 + normal[:, 2]
    q = torch.cat([w.unsqueeze(1), axis], -1)
    south = w < 1e-9
    q[south] = torch.tensor([0.0, 1.0, 0.0, 0.0], dtype=torch.float64)
    q = (q / q.norm(dim=-1, keepdim=True)).float()
    scales = torch.tensor([spacing, spacing, normal_scale]).expand(n, 3).clone()
    return means, scales, q


def random_cloud(n: int, seed: int = 0, extent: float = 1.0, k: int = 4):
    """N random anisotropic Gaussians in a ball (benchmarks): means, scales, quats, opacities, alpha."""
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g)
    means = means / means.norm(dim=-1, keepdim=True).clamp_min(1e-9) * extent * torch.rand(n, 1, generator=g) ** (1 / 3)
    spacing = extent * (4.19 / n) ** (1 / 3)
    scales = spacing * torch.exp(0.3 * torch.randn(n, 3, generator=g))
    quats = torch.randn(n, 4, generator=g)
    opac = 0.2 + 0.8 * torch.rand(n, generator=g)
    alpha = 1 + 5 * torch.rand(n, k, generator=g)
    return means, scales, quats, opac, alpha


def _identity(n: int) -> torch.Tensor:
    q = torch.zeros(n, 4)
    q[:, 0] = 1
    return q


def material_nig(densities: Sequence[float], *, kappa: float = 1e4, a: float = 1e4, rel_sd: float = 0.01) -> NIG:
    """[K, P] NIG posteriors centred on the given densities (log space), other properties nominal.

    ``rel_sd`` is the predictive relative spread of the density (log-space sd); ``kappa`` and ``a`` set how
    much evidence there is (large = tight)."""
    K = len(densities)
    tau = torch.tensor([[math.log(d), 0.5, 50.0, math.log(1e9)] for d in densities], dtype=torch.float64)
    var = torch.tensor([rel_sd**2, 0.01, 25.0, 0.04], dtype=torch.float64).expand(K, 4)
    kap = torch.full((K, 4), float(kappa), dtype=torch.float64)
    aa = torch.full((K, 4), float(a), dtype=torch.float64)
    b = var * (aa - 1)  # E[sigma^2] = var
    return NIG(tau, kap, aa, b)


def field_from(
    means: torch.Tensor,
    scales: torch.Tensor,
    quats: torch.Tensor,
    *,
    densities: Sequence[float] = (1000.0,),
    labels: torch.Tensor | None = None,
    thickness_m: Sequence[float | None] | None = None,
    nig: NIG | None = None,
    opacity: float = 0.9,
    confidence: float = 200.0,
    metres_per_unit: float = 1.0,
    names: Sequence[str] | None = None,
) -> PropertyField:
    """PropertyField over the given Gaussians: material ``labels[g]`` (default 0) gets Dirichlet evidence
    ``confidence``, the others 1 (alpha0)."""
    n, K = means.shape[0], len(densities)
    labels = torch.zeros(n, dtype=torch.long) if labels is None else labels
    alpha = torch.ones(n, K)
    alpha[torch.arange(n), labels] += confidence
    names = list(names) if names is not None else [f"material_{i}" for i in range(K)]
    colors = [(int(40 + 200 * i / max(K - 1, 1)), 120, int(240 - 200 * i / max(K - 1, 1))) for i in range(K)]
    return PropertyField(
        means=means.float(), quats=quats.float(), scales=scales.float(), opacities=torch.full((n,), opacity),
        alpha=alpha, nig=nig if nig is not None else material_nig(densities), material_names=names,
        material_colors=colors, log_space=LOG_SPACE,
        thickness_m=list(thickness_m) if thickness_m is not None else [None] * K,
        metres_per_unit=metres_per_unit, sh_dc=torch.zeros(n, 3), property_keys=KEYS,
    )  # fmt: skip
