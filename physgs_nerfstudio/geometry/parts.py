"""The carved solid's material mixture per voxel, its 3-D parts and each part's material.

* **Material per voxel.** The object's Gaussians are binned into the voxels that hold their centres (weights:
  opacity x observed share x mixture weights ``pi``, the field's material weights). The observed share is the
  part of a Gaussian's blending weight that fell on labelled pixels (``PropertyField.labelled``): a Gaussian
  that no labelled view saw (the underside of a box, the inside of a cavity) holds only its prior and gives
  no material. A voxel *has evidence* when its summed opacity x observed share reaches ``min_evidence`` (half
  an opaque, fully observed Gaussian by default). A solid voxel without evidence (the inside of a 3DGS object:
  Gaussians sit on surfaces; or a surface no view labelled) takes the mixture of the nearest voxel that has
  it (distance transform), i.e. it takes the nearest observed surface evidence. "Nearest" counts a vertical
  distance ``up_weight`` times (``GeometryConfig.interior_up_weight``): an object at rest is built in layers,
  and the seam between two parts inside it continues the one seen on its sides. A sole under an upper as wide as
  it is seen only along its edge; by plain distance half of its inside is nearer the upper, and at a weight of 3
  the Gaussians of the sole's top face, seen through a short training's semi-transparent upper, still reach 3 times
  as deep as its edge; at 10 the edge reaches across its whole thickness.
* **Parts.** Connected components (26-connectivity) of solid voxels sharing a dominant (argmax) material;
  parts below ``min_part_fraction`` of the object's volume are pooled into one residual part.
* **A part's material** (:func:`pooled_part_alpha`, for a part that no view's answer reaches; the others fuse the
  views' answers per part, :mod:`.part_evidence`). A part is one piece of one material; its Dirichlet is the
  weighted mean of its Gaussians' posteriors, ``alpha0 + mean(lambda * e_g)`` (weights: opacity x observed share):
  the mean, not the sum, since a part's Gaussians see the same pixels. Averaging the Gaussians' *weights* instead
  keeps every weakly observed Gaussian's spread over 10-28 candidates, and a metal tail can double a wooden part's
  mean density. The whole part switches material together in the mass's Monte Carlo.
* **Material draws within a part** (:func:`material_quantiles`, without the Gaussians' posteriors). The mass's Monte
  Carlo draws one level ``u ~ U(0, 1)`` per part and sample; each voxel of the part then takes the material where
  its own mixture's cumulative sum (materials in the order of the part's mean mixture) first reaches ``u``. Where the voxels are
  equally unsure (oak or walnut everywhere) the whole part switches together, which keeps the ambiguity in the
  interval; where they are sure but differ (a leg voxel steel, a top voxel oak), each keeps its own material,
  so a 5% steel share of a part's volume stays 5% of its volume instead of becoming a 5% chance that the whole
  part is steel. The draw is tabulated at ``levels`` quantiles as the part's volume share per material.

Each part's wall area and curvature: :mod:`.walls`.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from .carve import bounding_box
from .grid import VoxelGrid

__all__ = [
    "material_quantiles",
    "part_labels",
    "pooled_part_alpha",
    "sum_rows",
    "voxel_mixture",
]

def sum_rows(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """float64 [n, K]: the rows of ``values`` [M, K] summed per ``index`` [M] (in 0..n-1), added in their order, as
    ``np.add.at`` adds them (bit for bit), by one ``np.bincount`` per column (``np.add.at`` is slow on many rows)."""
    values = np.asarray(values, dtype=np.float64)
    out = np.zeros((n, values.shape[1]))
    for k in range(values.shape[1]):  # columns, not rows
        out[:, k] = np.bincount(index, values[:, k], minlength=n)
    return out


def voxel_mixture(grid: VoxelGrid, solid: np.ndarray, means: Tensor, opacities: Tensor, pi: Tensor,
                  observed: Tensor | None = None, *, min_evidence: float = 0.5,
                  up_weight: float = 1.0) -> np.ndarray:  # fmt: skip
    """float64 [X, Y, Z, K] mixture on the solid's voxels (zeros elsewhere); module doc. ``observed``: per
    Gaussian observed share in [0, 1] (None: every Gaussian counts as observed). ``up_weight``: distances along
    the grid's z (up) count this many times in "nearest" (module doc)."""
    from scipy import ndimage  # lazily: a PLY-only export needs no SciPy
    K = pi.shape[1]
    idx = grid.index_of(means.float())
    ok = ((idx >= 0) & (idx < torch.as_tensor(grid.shape, device=idx.device))).all(1)
    _, Y, Z = grid.shape
    flat = ((idx[:, 0] * Y + idx[:, 1]) * Z + idx[:, 2])[ok].cpu().numpy()  # the voxels, flat (C order)
    conf = opacities.double().reshape(-1)
    if observed is not None:
        conf = conf * observed.double().reshape(-1).clamp(0.0, 1.0)
    wk = (conf[:, None] * pi.double())[ok].cpu().numpy()
    # sums per occupied voxel, in the Gaussians' order, as np.add.at adds them (bincount over the voxels' rows: the
    # same sums, bit for bit, as over the whole grid, without K columns of the grid's size: at 128^3 and 17
    # materials those were 280 MB written and copied per export)
    occ, row = np.unique(flat, return_inverse=True)  # the occupied voxels (sorted) and each Gaussian's row
    acc = sum_rows(row, wk, len(occ))  # [V, K] (float64 also when there is no Gaussian)
    strength = np.bincount(row, conf[ok].cpu().numpy(), minlength=len(occ))
    rows_with = occ[strength >= min_evidence]
    if not len(rows_with):  # nothing reached the bar: every voxel with any evidence counts
        rows_with = occ[acc.sum(-1) > 0]
    out = np.zeros((*grid.shape, K))
    if not len(rows_with):
        out[solid] = 1.0 / K
        return out
    has = np.zeros(grid.num_voxels, bool)
    has[rows_with] = True
    has = has.reshape(grid.shape)
    # the nearest voxel with evidence, found on the box of those voxels and the solid's: the features are all inside,
    # so the transform gives there what it gives on the whole grid (tests/test_geometry_fast_paths.py)
    lo, hi = bounding_box(has | solid)
    box = tuple(slice(a, b) for a, b in zip(lo, hi))
    near = ndimage.distance_transform_edt(~has[box], sampling=(1.0, 1.0, up_weight), return_distances=False,
                                          return_indices=True)  # fmt: skip
    inside = solid[box]
    src = np.ravel_multi_index(tuple(n[inside] + a for n, a in zip(near, lo)), grid.shape)
    mix = acc[np.searchsorted(occ, src)]  # each source has evidence, so it is occupied: its row
    out[solid] = mix / mix.sum(-1, keepdims=True)
    return out


def pooled_part_alpha(grid: VoxelGrid, parts: np.ndarray, num_parts: int, means: Tensor, opacities: Tensor,
                      alpha: Tensor, observed: Tensor | None = None) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """float64 [P, K] pooled Dirichlet per part (module doc, "A part's material") and float64 [P] the summed
    weight behind it (0: no Gaussian of the part carries evidence; its row is then undefined). A Gaussian
    belongs to the part of the voxel that holds its centre."""
    idx = grid.index_of(means.float())
    _, Y, Z = grid.shape
    w = opacities.double().reshape(-1)
    if observed is not None:
        w = w * observed.double().reshape(-1).clamp(0.0, 1.0)
    # the rows that can count, chosen where the Gaussians are (a GPU): only those cross to the host
    rows = ((idx >= 0) & (idx < torch.as_tensor(grid.shape, device=idx.device))).all(1) & (w > 0)
    at = idx[rows]
    pid = parts.reshape(-1)[((at[:, 0] * Y + at[:, 1]) * Z + at[:, 2]).cpu().numpy()]
    keep = pid >= 0
    pid = pid[keep]
    w_k = w[rows].cpu().numpy()[keep]
    acc = sum_rows(pid, w_k[:, None] * alpha[rows].double().cpu().numpy()[keep], num_parts)
    tot = np.bincount(pid, weights=w_k, minlength=num_parts).astype(np.float64)
    pooled = np.divide(acc, tot[:, None], out=np.ones_like(acc), where=tot[:, None] > 0)
    return pooled, tot


def label_by_value(values: np.ndarray, inside: np.ndarray) -> tuple[np.ndarray, int]:
    """``(labels, n)``: the 26-connected components of the voxels ``inside`` that share one value of ``values``,
    numbered 0..n-1 (value by value in ascending order, each value's components in raster order), -1 outside."""
    from scipy import ndimage  # lazily: a PLY-only export needs no SciPy

    out = np.full(inside.shape, -1, np.int64)
    offset = 0
    st = np.ones((3, 3, 3), bool)
    for k in np.unique(values[inside]):  # values present, not voxels
        lab, n = ndimage.label(inside & (values == k), structure=st)
        sel = lab > 0
        out[sel] = lab[sel] - 1 + offset
        offset += n
    return out, offset


def part_labels(solid: np.ndarray, mixture: np.ndarray, min_part_fraction: float = 2e-3) -> np.ndarray:
    """int [X, Y, Z]: part id (0..P-1) per solid voxel, -1 elsewhere (module doc)."""
    out = np.full(solid.shape, -1, np.int64)
    if not solid.any():
        return out
    # on the solid's bounding box: the same components, numbered in the same (raster) order as on the whole grid
    lo, hi = bounding_box(solid)
    box = tuple(slice(a, b) for a, b in zip(lo, hi))
    inner = solid[box]
    part, offset = label_by_value(np.argmax(mixture[box], -1), inner)
    out[box] = part
    sizes = np.bincount(out[solid], minlength=offset)
    small = sizes < min_part_fraction * sizes.sum()
    if small.any() and (~small).any():
        remap = np.cumsum(~small) - 1
        remap[small] = int((~small).sum())
        out[solid] = remap[out[solid]]
    elif small.all():
        out[solid] = 0
    return out


def material_quantiles(parts: np.ndarray, mixture: np.ndarray, num_parts: int, part_mixture: np.ndarray,
                       levels: int = 32) -> np.ndarray:  # fmt: skip
    """float64 [P, levels, K]: per part and quantile level ``u_j = (j + 1/2) / levels``, the share of the part's
    voxels that take each material (module doc, "Material draws within a part"); rows sum to 1 (a part without
    voxels: its ``part_mixture``)."""
    K = mixture.shape[-1]
    sel = parts >= 0
    pid = parts[sel]
    mix = mixture[sel]
    order = np.argsort(-part_mixture, axis=1, kind="stable")  # [P, K]
    cum = np.cumsum(np.take_along_axis(mix, order[pid], 1), 1)  # [N, K]
    out = np.zeros((num_parts, levels, K))
    for j in range(levels):  # quantile levels, not voxels
        rank = np.minimum((cum < (j + 0.5) / levels).sum(1), K - 1)
        mat = order[pid, rank]
        out[:, j, :] = np.bincount(pid * K + mat, minlength=num_parts * K).reshape(num_parts, K)
    tot = out.sum(-1, keepdims=True)
    return np.where(tot > 0, out / np.maximum(tot, 1e-300), part_mixture[:, None, :])


