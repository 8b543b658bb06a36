"""Voxel grids and splatting of anisotropic 3D Gaussians onto them (vectorised, chunked).

The opacity field of N Gaussians at point x is

    F(x) = sum_g o_g exp(-1/2 (x - mu_g)^T Sigma_g'^{-1} (x - mu_g)),   Sigma_g' = R_g (S_g^2 + f^2 I) R_g^T,

where ``f`` is an isotropic anti-aliasing filter (a fraction of the voxel size): 3DGS surfaces are made of
flat Gaussians far thinner than a voxel, which point sampling at voxel centres would miss. The filter keeps
the peak (``o_g``), so a thin opaque layer stays opaque (it becomes about one voxel thick).

Each Gaussian only touches the voxels inside its ``cutoff``-sigma axis-aligned box (exact extent
``cutoff * sqrt(Sigma'_aa)`` per axis), so the work is sum_g |box_g| (never N x V). The (Gaussian, voxel)
pairs of a chunk of Gaussians are enumerated with ``repeat_interleave``, evaluated at once and scattered
with ``index_add_``; chunks hold at most ``pair_budget`` pairs, so memory is bounded for any N.
Works on whatever device the inputs are on (CPU or CUDA).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor
from tqdm.auto import tqdm

from ..errors import PhysGSError

__all__ = ["GeometryError", "VoxelGrid", "gaussian_boxes", "inverse_covariance6", "splat"]


@dataclass(frozen=True)
class VoxelGrid:
    """Axis-aligned grid; voxel (i, j, k) covers ``origin + [i, i+1) * voxel_size`` along x (j: y, k: z),
    its centre is ``origin + (index + 0.5) * voxel_size``. Arrays over the grid are indexed [i, j, k] = [x, y, z]
    and flattened in C order (``(i * Y + j) * Z + k``). Units: scene units."""

    origin: tuple[float, float, float]
    voxel_size: float
    shape: tuple[int, int, int]

    def __post_init__(self) -> None:
        if not (self.voxel_size > 0 and math.isfinite(self.voxel_size)):
            raise ValueError(f"VoxelGrid: voxel_size must be > 0, got {self.voxel_size}.")
        if len(self.shape) != 3 or min(self.shape) < 1:
            raise ValueError(f"VoxelGrid: shape must be 3 positive ints, got {self.shape}.")

    @property
    def num_voxels(self) -> int:
        return int(np.prod(self.shape))

    @classmethod
    def from_bounds(cls, lo: Tensor | np.ndarray, hi: Tensor | np.ndarray, resolution: int) -> VoxelGrid:
        """``resolution`` voxels along the longest side of the box [lo, hi] (cubic voxels)."""
        lo = np.asarray(torch.as_tensor(lo).detach().cpu(), dtype=np.float64)
        hi = np.asarray(torch.as_tensor(hi).detach().cpu(), dtype=np.float64)
        if resolution < 2:
            raise ValueError(f"resolution must be >= 2 voxels, got {resolution}.")
        ext = hi - lo
        if not np.all(np.isfinite(ext)) or ext.max() <= 0:
            raise ValueError(f"VoxelGrid.from_bounds: empty or invalid box lo={lo}, hi={hi}.")
        h = float(ext.max()) / resolution
        shape = tuple(int(max(1, math.ceil(e / h - 1e-9))) for e in ext)
        centre = (lo + hi) / 2
        origin = centre - np.asarray(shape) * h / 2
        return cls(tuple(float(v) for v in origin), h, shape)  # type: ignore[arg-type]

    def crop(self, lo_idx: np.ndarray, hi_idx: np.ndarray) -> VoxelGrid:
        """Sub-grid of voxels lo_idx .. hi_idx - 1 (per axis)."""
        lo_idx = np.asarray(lo_idx, dtype=np.int64)
        hi_idx = np.asarray(hi_idx, dtype=np.int64)
        origin = np.asarray(self.origin) + lo_idx * self.voxel_size
        return VoxelGrid(tuple(float(v) for v in origin), self.voxel_size,
                         tuple(int(v) for v in hi_idx - lo_idx))  # type: ignore[arg-type]

    def centres(self, index: Tensor) -> Tensor:
        """Centres of voxels given as integer [..., 3] indices (float32, same device)."""
        origin = torch.as_tensor(self.origin, dtype=torch.float32, device=index.device)
        return origin + (index.float() + 0.5) * self.voxel_size

    def index_of(self, points: Tensor) -> Tensor:
        """Integer [..., 3] index of the voxel containing each point (not clamped)."""
        origin = torch.as_tensor(self.origin, dtype=points.dtype, device=points.device)
        return torch.floor((points - origin) / self.voxel_size).long()

    def to_dict(self) -> dict:
        return {"origin": list(self.origin), "voxel_size": self.voxel_size, "shape": list(self.shape)}


def _rotmats(quats: Tensor) -> Tensor:
    q = quats / quats.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(*q.shape[:-1], 3, 3)  # fmt: skip


def inverse_covariance6(
    quats: Float[Tensor, "n 4"], scales: Float[Tensor, "n 3"], filter_sigma: float = 0.0
) -> tuple[Float[Tensor, "n 6"], Float[Tensor, "n 3"]]:
    """Unique entries (xx, yy, zz, xy, xz, yz) of ``Sigma'^{-1}`` and the diagonal of ``Sigma'``
    (``Sigma' = R (S^2 + f^2 I) R^T``)."""
    R = _rotmats(quats.float())
    var = scales.float() ** 2 + float(filter_sigma) ** 2  # [N, 3]
    inv = (R * (1.0 / var).unsqueeze(-2)) @ R.transpose(-1, -2)  # R diag(1/var) R^T
    cov_diag = (R * R * var.unsqueeze(-2)).sum(-1)  # sum_j R_aj^2 var_j
    inv6 = torch.stack([inv[:, 0, 0], inv[:, 1, 1], inv[:, 2, 2], inv[:, 0, 1], inv[:, 0, 2], inv[:, 1, 2]], -1)
    return inv6, cov_diag


def gaussian_boxes(
    grid: VoxelGrid, means: Tensor, cov_diag: Tensor, cutoff: float
) -> tuple[Tensor, Tensor, Tensor]:
    """Per Gaussian the voxel index range [lo, hi] (inclusive, clipped to the grid) whose centres lie within
    ``cutoff * sqrt(Sigma'_aa)`` of the mean per axis, and its voxel count (0 if outside the grid)."""
    origin = torch.as_tensor(grid.origin, dtype=torch.float64, device=means.device)
    h = grid.voxel_size
    radius = cutoff * torch.sqrt(cov_diag.double())
    m = means.double()
    lo = torch.ceil((m - radius - origin) / h - 0.5).long()
    hi = torch.floor((m + radius - origin) / h - 0.5).long()
    upper = torch.as_tensor(grid.shape, device=means.device) - 1
    lo = torch.maximum(lo, torch.zeros_like(lo))
    hi = torch.minimum(hi, upper)
    dims = (hi - lo + 1).clamp_min(0)
    return lo, hi, dims.prod(-1)


def splat(
    grid: VoxelGrid,
    means: Float[Tensor, "n 3"],
    quats: Float[Tensor, "n 4"],
    scales: Float[Tensor, "n 3"],
    opacities: Float[Tensor, " n"],
    values: Float[Tensor, "n c"] | None = None,
    *,
    filter_sigma: float = 0.0,
    cutoff: float = 3.0,
    lut: Tensor | None = None,
    num_rows: int | None = None,
    pair_budget: int = 1 << 21,
    small_box: int = 12,
    desc: str | None = None,
) -> tuple[Tensor, Tensor | None]:
    """Kernel sums on the grid: ``weight[v] = sum_g w_gv`` and ``weighted[v] = sum_g w_gv values_g`` with
    ``w_gv = o_g exp(-m_gv / 2)`` (module doc), pairs beyond ``cutoff`` sigma dropped.

    Args:
        lut: optional int64 [V] map from flat voxel index to an output row (-1: skip the voxel), so that only
            a sparse set of voxels is accumulated (outputs then have ``num_rows`` rows).
        pair_budget: max (Gaussian, voxel) pairs evaluated at once (memory ~ 150 bytes per pair).
        small_box: Gaussians whose box is at most this many voxels along every axis take the offset-loop
            path (:func:`_splat_small`); larger ones the pair-enumeration path (:func:`_splat_pairs`).
        desc: progress bar label (None: no bar).

    Returns:
        ``weight`` [V] (or [num_rows]) float32 and ``weighted`` [V, C] (or None if ``values`` is None).
    """
    device = means.device
    n = means.shape[0]
    if values is not None and (values.dim() != 2 or values.shape[0] != n):
        raise ValueError(f"splat: values must be [N, C] with N={n}, got {tuple(values.shape)}.")
    rows = grid.num_voxels if lut is None else int(num_rows if num_rows is not None else int(lut.max()) + 1)
    weight = torch.zeros(rows, dtype=torch.float32, device=device)
    weighted = None if values is None else torch.zeros(rows, values.shape[1], dtype=torch.float32, device=device)
    if n == 0:
        return weight, weighted
    inv6, cov_diag = inverse_covariance6(quats, scales, filter_sigma)
    lo, hi, counts = gaussian_boxes(grid, means, cov_diag, cutoff)
    keep = counts > 0
    if not bool(keep.all()):
        idx = torch.nonzero(keep).squeeze(1)
        means, inv6, lo, hi, counts = means[idx], inv6[idx], lo[idx], hi[idx], counts[idx]
        opacities = opacities[idx]
        values = None if values is None else values[idx]
    if counts.numel() == 0:
        return weight, weighted
    dims = hi - lo + 1
    big = dims.amax(-1) > small_box
    dmax = dims.amax(-1)
    lower = 0
    for upper in sorted({b for b in (2, 3, 4, 6, 8, small_box) if b <= small_box}):  # buckets of similar boxes
        in_bucket = (dmax > lower) & (dmax <= upper)
        lower = upper
        if not bool(in_bucket.any()):
            continue
        sel = torch.nonzero(in_bucket).squeeze(1)
        _splat_small(grid, means[sel], inv6[sel], opacities[sel], None if values is None else values[sel],
                     lo[sel], dims[sel], cutoff, lut, weight, weighted, chunk=pair_budget // 4, desc=desc)
    if bool(big.any()):
        sel = torch.nonzero(big).squeeze(1)
        _splat_pairs(grid, means[sel], inv6[sel], opacities[sel], None if values is None else values[sel],
                     lo[sel], dims[sel], counts[sel], cutoff, lut, weight, weighted, pair_budget=pair_budget,
                     desc=desc)
    return weight, weighted


def _splat_pairs(grid, means, inv6, opacities, values, lo, dims, counts, cutoff, lut, weight, weighted, *,
                 pair_budget, desc) -> None:  # fmt: skip
    """Large boxes: enumerate every (Gaussian, voxel) pair of a chunk of Gaussians with repeat_interleave."""
    device = means.device
    cum = torch.cumsum(counts, 0)
    total = int(cum[-1])
    # chunk boundaries: each chunk holds about pair_budget pairs (one oversized Gaussian = its own chunk)
    marks = torch.arange(pair_budget, total, pair_budget, device=device) if total > pair_budget else cum[:0]
    cuts = torch.searchsorted(cum, marks, right=True)
    bounds = torch.unique(torch.cat([torch.zeros(1, dtype=torch.long, device=device), cuts,
                                     torch.tensor([counts.numel()], device=device)])).tolist()  # fmt: skip
    origin = torch.as_tensor(grid.origin, dtype=torch.float32, device=device)
    h = float(grid.voxel_size)
    X, Y, Z = grid.shape
    means32 = means.float()
    op = opacities.float()
    cut2 = float(cutoff) ** 2
    starts = list(zip(bounds[:-1], bounds[1:]))
    bar = tqdm(starts, desc=desc, unit="chunk", leave=False, disable=desc is None)
    for g0, g1 in bar:
        if g1 <= g0:
            continue
        c = counts[g0:g1]
        gid = torch.repeat_interleave(torch.arange(g1 - g0, device=device), c)
        first = torch.cumsum(c, 0) - c
        local = torch.arange(gid.numel(), device=device) - first[gid]
        d = dims[g0:g1][gid]
        dyz = d[:, 1] * d[:, 2]
        di = local // dyz
        rem = local - di * dyz
        dj = rem // d[:, 2]
        dk = rem - dj * d[:, 2]
        l0 = lo[g0:g1][gid]
        ix, iy, iz = l0[:, 0] + di, l0[:, 1] + dj, l0[:, 2] + dk
        flat = (ix * Y + iy) * Z + iz
        g = gid + g0
        if lut is not None:
            row = lut[flat]
            sel = row >= 0
            if not bool(sel.any()):
                continue
            row, g, ix, iy, iz = row[sel], g[sel], ix[sel], iy[sel], iz[sel]
        else:
            row = flat
        centre = torch.stack([ix, iy, iz], -1).float().mul_(h).add_(origin + 0.5 * h)
        dx = centre - means32[g]
        q = inv6[g]
        m = (q[:, 0] * dx[:, 0] ** 2 + q[:, 1] * dx[:, 1] ** 2 + q[:, 2] * dx[:, 2] ** 2
             + 2 * (q[:, 3] * dx[:, 0] * dx[:, 1] + q[:, 4] * dx[:, 0] * dx[:, 2] + q[:, 5] * dx[:, 1] * dx[:, 2]))
        w = op[g] * torch.exp(-0.5 * m)
        w = torch.where(m <= cut2, w, torch.zeros_like(w))
        weight.index_add_(0, row, w)
        if weighted is not None:
            weighted.index_add_(0, row, w.unsqueeze(1) * values[g].float())  # type: ignore[index]


def _splat_small(grid, means, inv6, opacities, values, lo, dims, cutoff, lut, weight, weighted, *, chunk,
                 desc) -> None:  # fmt: skip
    """Small boxes: loop over the voxel offsets (i, j, k) of the largest box, vectorised over Gaussians.

    With c0 = centre(lo) - mu and offset o (voxels), d = c0 + h o and
    m = c0^T A c0 + 2 h o^T A c0 + h^2 o^T A o: per Gaussian three precomputed terms, per offset a few
    multiply-adds on contiguous [N] tensors (no gathers, no integer division). Offsets beyond a Gaussian's
    own box get zero weight.
    """
    device = means.device
    h = float(grid.voxel_size)
    X, Y, Z = grid.shape
    origin = torch.as_tensor(grid.origin, dtype=torch.float32, device=device)
    cut2 = float(cutoff) ** 2
    n = means.shape[0]
    starts = list(range(0, n, max(1, chunk)))
    D = [int(v) for v in dims.amax(0).tolist()]
    bar = tqdm(total=len(starts) * D[0] * D[1] * D[2], desc=desc, unit="offset", leave=False,
               disable=desc is None)  # fmt: skip
    for s in starts:
        e = min(n, s + chunk)
        q = inv6[s:e]
        a00, a11, a22, a01, a02, a12 = q.unbind(-1)
        l0 = lo[s:e]
        c0 = l0.float().mul(h).add(origin + 0.5 * h) - means[s:e].float()  # [n, 3]
        Ac0 = torch.stack([a00 * c0[:, 0] + a01 * c0[:, 1] + a02 * c0[:, 2],
                           a01 * c0[:, 0] + a11 * c0[:, 1] + a12 * c0[:, 2],
                           a02 * c0[:, 0] + a12 * c0[:, 1] + a22 * c0[:, 2]], -1)  # fmt: skip
        base = (c0 * Ac0).sum(-1)
        g = 2 * h * Ac0
        h2 = h * h
        op = opacities[s:e].float()
        val = None if values is None else values[s:e].float()
        dm = dims[s:e]
        flat0 = (l0[:, 0] * Y + l0[:, 1]) * Z + l0[:, 2]
        for oi in range(D[0]):
            vi = dm[:, 0] > oi
            mi = base + g[:, 0] * oi + h2 * a00 * (oi * oi)
            for oj in range(D[1]):
                vij = vi & (dm[:, 1] > oj)
                mij = mi + g[:, 1] * oj + h2 * (a11 * (oj * oj) + 2 * a01 * (oi * oj))
                for ok in range(D[2]):
                    bar.update(1)
                    valid = vij & (dm[:, 2] > ok)
                    m = mij + g[:, 2] * ok + h2 * (a22 * (ok * ok) + 2 * (a02 * (oi * ok) + a12 * (oj * ok)))
                    valid = valid & (m <= cut2)
                    if not bool(valid.any()):
                        continue
                    idx = torch.nonzero(valid).squeeze(1)
                    w = op[idx] * torch.exp(-0.5 * m[idx])
                    flat = flat0[idx] + (oi * Y + oj) * Z + ok
                    if lut is not None:
                        row = lut[flat]
                        keep = row >= 0
                        row, w, idx = row[keep], w[keep], idx[keep]
                    else:
                        row = flat
                    weight.index_add_(0, row, w)
                    if weighted is not None:
                        weighted.index_add_(0, row, w.unsqueeze(1) * val[idx])  # type: ignore[index]
    bar.close()


class GeometryError(PhysGSError, ValueError):
    """No object to measure: no Gaussian on the masks, no training view, or carving left no solid voxel."""
