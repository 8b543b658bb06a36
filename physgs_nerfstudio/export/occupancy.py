"""Object occupancy from Gaussians: opacity field on a voxel grid -> threshold -> fill -> select the object.

Steps (all vectorised; scipy.ndimage on the boolean grid):

0. Gaussians: those with opacity >= ``min_opacity``; with ``select="labelled"`` (the default ``auto`` when the
   field carries the lifting's labelled fractions) only those the material maps label: labelled fraction
   >= ``min_labelled`` and total lifted evidence >= ``min_evidence``. So the object is what perception
   labelled, not the environment around it (the far background, a floor or table, floaters), which
   geometry alone cannot tell from the object. Without labelled fractions ``auto`` is ``largest`` (logged).
1. Domain: the user's bounding box (scene units), else the extent of the Gaussians (``extent_quantile``
   trims far floaters) padded by their 3-sigma radius; ``resolution`` voxels along the longest side. Without a bbox, steps 2-5 are
   redone on the selected object's box (``refine_passes``), so the resolution is the object's, not the
   floaters'.
2. Opacity field ``F`` (:func:`.grid.splat`, anti-aliased by ``filter_voxels`` voxels).
3. Threshold ``F >= level``. ``relative`` (default): ``level = threshold * Q`` with ``Q`` the
   ``reference_quantile`` of F over the voxels the Gaussians reach (F > 1% of its max), i.e. a fraction of
   the field's plateau. At 0.5 the boundary of a solid block of Gaussians lands on the block's true faces (a
   step blurred by any symmetric kernel crosses half its height at the step), and a thin surface becomes its
   half-maximum layer. ``absolute``: ``level = threshold``.
4. Fill the interior (3DGS puts Gaussians on surfaces): ``3d`` = :func:`scipy.ndimage.binary_fill_holes`
   (closed surfaces only), ``slices`` = fill each 2-D slice along x, y and z and keep voxels filled in at
   least ``slice_votes`` of the three (closes surfaces with an unobserved side, e.g. a bottom on a table,
   but also fills open cavities such as a cup's inside), ``none``.
5. Select the object: the largest connected component (26-connectivity) of the filled set (``largest``),
   every component with at least ``min_component`` of the largest one's voxels (``labelled``), or every
   component (``all``).

Results are cropped to the object (plus ``pad_voxels``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import torch
from scipy import ndimage

from .field import PropertyField
from .grid import VoxelGrid, gaussian_boxes, inverse_covariance6, splat

__all__ = ["MaterialGrid", "Occupancy", "OccupancyConfig", "compute_occupancy", "select_gaussians", "volume_weights",
           "voxel_materials"]

logger = logging.getLogger(__name__)

SELECT_MODES = ("auto", "labelled", "largest", "all")


@dataclass
class OccupancyConfig:
    """How the object's volume is recovered from the Gaussians (module doc)."""

    resolution: int = 128
    """voxels along the longest side of the domain"""
    threshold: float = 0.5
    """occupancy threshold: a fraction of the field's plateau (relative) or an opacity-field value (absolute)"""
    threshold_mode: Literal["relative", "absolute"] = "relative"
    reference_quantile: float = 0.95
    """quantile of the reached voxels' field used as the plateau in relative mode"""
    fill: Literal["3d", "slices", "none"] = "3d"
    slice_votes: int = 2
    """with fill=slices: axes (of 3) whose 2-D slice fill must agree"""
    select: Literal["auto", "labelled", "largest", "all"] = "auto"
    """labelled: Gaussians the material maps label, then their largest component; largest: the largest
    component of all Gaussians; all: every component; auto: labelled when the field has labelled fractions,
    else largest"""
    min_labelled: float = 0.5
    """select=labelled: minimum share of a Gaussian's blending weight on labelled pixels"""
    min_evidence: float = 0.05
    """select=labelled: minimum total lifted evidence (confidence-weighted views; one view at full confidence
    counts 1)"""
    min_component: float = 0.05
    """select=labelled: keep every connected component with at least this fraction of the largest one's voxels
    (an object's parts need not touch at the grid's resolution, e.g. a chair's back and seat); the labelled
    selection has already removed the unlabelled clutter that `largest` exists to drop"""
    bbox: tuple[float, float, float, float, float, float] | None = None
    """(xmin, ymin, zmin, xmax, ymax, zmax) in scene units (the viewer's crop box frame); None = all Gaussians"""
    min_opacity: float = 0.01
    """Gaussians below this opacity are ignored"""
    extent_quantile: float = 0.0
    """without bbox: trim this quantile of Gaussian centres per side when sizing the domain (floaters)"""
    filter_voxels: float = 0.5
    """anti-aliasing filter sigma, in voxels"""
    cutoff_sigma: float = 3.0
    pad_voxels: int = 2
    refine_passes: int = 3
    """without bbox: rebuild the grid on the selected object's box at most this many times (compute_occupancy)"""
    refine_below: float = 0.8
    """rebuild while the object's box (with padding) is shorter than this fraction of the domain's longest side"""
    pair_budget: int = 1 << 21
    sheet_correction: bool = True
    """count layer voxels that separate a filled cavity from the outside as half inside (see volume_weights)"""
    sheet_max_voxels: float = 6.0
    """a layer voxel is part of such a sheet if (distance to cavity + distance to outside) <= this, in voxels"""
    support_eps: float = 1e-3
    """a voxel whose kernel weight sum is below this takes its material mixture from the nearest voxel above"""
    progress: bool = True

    def __post_init__(self) -> None:
        if self.resolution < 4:
            raise ValueError(f"OccupancyConfig.resolution must be >= 4, got {self.resolution}.")
        if self.threshold <= 0:
            raise ValueError(f"OccupancyConfig.threshold must be > 0, got {self.threshold}.")
        if not 0 < self.reference_quantile <= 1:
            raise ValueError("OccupancyConfig.reference_quantile must be in (0, 1].")
        if self.threshold_mode not in ("relative", "absolute"):
            raise ValueError(f"threshold_mode must be relative|absolute, got {self.threshold_mode!r}.")
        if self.fill not in ("3d", "slices", "none"):
            raise ValueError(f"fill must be 3d|slices|none, got {self.fill!r}.")
        if self.select not in SELECT_MODES:
            raise ValueError(f"select must be one of {'|'.join(SELECT_MODES)}, got {self.select!r}.")
        if not 0 <= self.min_labelled <= 1:
            raise ValueError(f"OccupancyConfig.min_labelled must be in [0, 1], got {self.min_labelled}.")
        if self.refine_passes < 0 or not 0 < self.refine_below <= 1:
            raise ValueError("OccupancyConfig: refine_passes must be >= 0 and refine_below in (0, 1].")
        if self.min_evidence < 0:
            raise ValueError(f"OccupancyConfig.min_evidence must be >= 0, got {self.min_evidence}.")
        if self.bbox is not None:
            b = tuple(float(v) for v in self.bbox)
            if len(b) != 6 or not all(b[i] < b[i + 3] for i in range(3)):
                raise ValueError(f"bbox must be (xmin, ymin, zmin, xmax, ymax, zmax) with min < max, got {self.bbox}.")
            self.bbox = b  # type: ignore[assignment]


@dataclass
class Occupancy:
    """The selected object on a grid cropped around it (arrays indexed [x, y, z], scene units)."""

    grid: VoxelGrid
    field: np.ndarray
    """opacity field F (float32)"""
    level: float
    """threshold applied to F"""
    layer: np.ndarray
    """F >= level within the object (unfilled: for 3DGS, the surface layer)"""
    solid: np.ndarray
    """filled object volume (superset of ``layer``)"""
    filter_sigma: float
    config: OccupancyConfig = field(repr=False, default_factory=OccupancyConfig)
    select: str = "largest"
    """the selection actually applied (``auto`` resolved, fallbacks included)"""
    gaussians: torch.Tensor | None = field(default=None, repr=False)
    """bool [N]: the Gaussians the object was built from (None = all with opacity >= min_opacity)"""

    @property
    def num_selected(self) -> int:
        return int(self.gaussians.sum()) if self.gaussians is not None else -1

    @property
    def voxel_volume(self) -> float:
        return self.grid.voxel_size**3


def _domain(pf: PropertyField, keep: torch.Tensor, cfg: OccupancyConfig) -> VoxelGrid:
    if cfg.bbox is not None:
        b = np.asarray(cfg.bbox, dtype=np.float64)
        return VoxelGrid.from_bounds(b[:3], b[3:], cfg.resolution)
    means = pf.means[keep].double()
    if means.shape[0] == 0:
        raise ValueError(
            f"no Gaussian has opacity >= min_opacity={cfg.min_opacity}; nothing to integrate (lower min_opacity)."
        )
    _, cov_diag = inverse_covariance6(pf.quats[keep], pf.scales[keep], 0.0)
    radius = cfg.cutoff_sigma * torch.sqrt(cov_diag.double())
    q = cfg.extent_quantile
    if q > 0:
        sub = means[torch.randperm(means.shape[0], device=means.device)[: 1 << 20]]  # torch.quantile size limit
        lo = torch.quantile(sub, q, dim=0)
        hi = torch.quantile(sub, 1 - q, dim=0)
        pad = torch.quantile(radius.amax(-1)[: 1 << 20], 0.99)
        lo, hi = lo - pad, hi + pad
    else:
        lo = (means - radius).amin(0)
        hi = (means + radius).amax(0)
    ext = float((hi - lo).max())
    pad_extra = cfg.pad_voxels * ext / cfg.resolution
    return VoxelGrid.from_bounds((lo - pad_extra).cpu(), (hi + pad_extra).cpu(), cfg.resolution)


def _fill(occ: np.ndarray, cfg: OccupancyConfig) -> np.ndarray:
    if cfg.fill == "none":
        return occ.copy()
    if cfg.fill == "3d":
        return ndimage.binary_fill_holes(occ)
    votes = np.zeros(occ.shape, dtype=np.uint8)
    for axis in range(3):
        st = np.zeros((3, 3, 3), dtype=bool)
        sl = [slice(None)] * 3
        sl[axis] = 1  # type: ignore[call-overload]
        st[tuple(sl)] = ndimage.generate_binary_structure(2, 1)  # 4-connected background inside each slice
        votes += ndimage.binary_fill_holes(occ, structure=st).astype(np.uint8)
    return occ | (votes >= cfg.slice_votes)


def select_gaussians(pf: PropertyField, cfg: OccupancyConfig) -> tuple[torch.Tensor, str]:
    """(bool [N] mask of the Gaussians the object is built from, the select mode applied) (module doc, step 0)."""
    keep = pf.opacities >= cfg.min_opacity
    mode = cfg.select
    if mode == "auto":
        mode = "labelled" if pf.labelled is not None else "largest"
        if pf.labelled is None:
            logger.info("object selection: the field has no labelled fractions (no lifting): using the largest "
                        "component of all Gaussians")  # fmt: skip
    if mode != "labelled":
        return keep, mode
    if pf.labelled is None:
        raise ValueError("select='labelled' needs the lifting's labelled fractions (PropertyField.labelled); "
                         "export a lifted PhysGS run or use select='largest' / a bbox.")  # fmt: skip
    lab = keep & (pf.labelled.to(keep.device) >= cfg.min_labelled)
    if pf.evidence is not None:
        lab &= pf.evidence.to(keep.device) >= cfg.min_evidence
    if not bool(lab.any()):
        logger.warning("object selection: no Gaussian has labelled fraction >= %.3g and evidence >= %.3g; using "
                       "the largest component of all Gaussians", cfg.min_labelled, cfg.min_evidence)  # fmt: skip
        return keep, "largest"
    logger.info("object selection: %d of %d Gaussians labelled by the material maps", int(lab.sum()),
                int(keep.sum()))  # fmt: skip
    return lab, "labelled"


def _occupancy_on(pf: PropertyField, keep: torch.Tensor, grid: VoxelGrid, cfg: OccupancyConfig,
                  mode: str) -> Occupancy:  # fmt: skip
    """Steps 2-5 of the module doc on one grid, cropped to the selected object (+ ``pad_voxels``)."""
    filt = cfg.filter_voxels * grid.voxel_size
    idx = torch.nonzero(keep).squeeze(1)
    weight, _ = splat(grid, pf.means[idx], pf.quats[idx], pf.scales[idx], pf.opacities[idx],
                      filter_sigma=filt, cutoff=cfg.cutoff_sigma, pair_budget=cfg.pair_budget,
                      desc="opacity field" if cfg.progress else None)  # fmt: skip
    F = weight.reshape(grid.shape).cpu().numpy()
    fmax = float(F.max())
    if fmax <= 0:
        raise ValueError("the opacity field is empty in the domain: check bbox / min_opacity.")
    if cfg.threshold_mode == "relative":
        reached = F[F > 0.01 * fmax]
        level = cfg.threshold * float(np.quantile(reached, cfg.reference_quantile))
    else:
        level = cfg.threshold
    occ = F >= level
    if not occ.any():
        raise ValueError(f"no voxel reaches the occupancy level {level:.4g} (field max {fmax:.4g}); lower threshold.")
    filled = _fill(occ, cfg)
    labels, n = ndimage.label(filled, structure=np.ones((3, 3, 3), dtype=bool))
    if mode != "all" and n > 1:
        sizes = np.bincount(labels.ravel())
        sizes[0] = 0
        if mode == "labelled":  # clutter is already gone: keep every substantial part of the object
            comp = (sizes >= cfg.min_component * sizes.max())[labels] & (labels > 0)
        else:
            comp = labels == int(np.argmax(sizes))
    else:
        comp = labels > 0
    # crop to the object + padding
    nz = np.nonzero(comp)
    lo = np.maximum(np.array([a.min() for a in nz]) - cfg.pad_voxels, 0)
    hi = np.minimum(np.array([a.max() for a in nz]) + 1 + cfg.pad_voxels, np.asarray(grid.shape))
    sl = tuple(slice(int(a), int(b)) for a, b in zip(lo, hi))
    comp = comp[sl]
    return Occupancy(
        grid=grid.crop(lo, hi), field=np.ascontiguousarray(F[sl]), level=level,
        layer=np.ascontiguousarray(occ[sl] & comp), solid=np.ascontiguousarray(filled[sl] & comp),
        filter_sigma=filt, config=cfg, select=mode, gaussians=keep,
    )  # fmt: skip


def compute_occupancy(pf: PropertyField, cfg: OccupancyConfig | None = None) -> Occupancy:
    """Opacity field, threshold, fill and object selection (module doc).

    Without a ``bbox`` the first domain spans every selected Gaussian, floaters included, so the object may
    cover a small part of it; the grid is then rebuilt on the object's box (at most ``refine_passes`` times,
    while the object's longest side is below ``refine_below`` of the domain's), so that ``resolution``
    counts voxels along the object's longest side."""
    cfg = cfg or OccupancyConfig()
    keep, mode = select_gaussians(pf, cfg)
    grid = _domain(pf, keep, cfg)
    occ = _occupancy_on(pf, keep, grid, cfg, mode)
    passes = 0
    while cfg.bbox is None and passes < cfg.refine_passes:
        og = occ.grid
        lo = np.asarray(og.origin, dtype=np.float64)
        hi = lo + np.asarray(og.shape) * og.voxel_size  # the object + pad_voxels of the current grid
        if (hi - lo).max() >= cfg.refine_below * max(grid.shape) * grid.voxel_size:
            break
        grid = VoxelGrid.from_bounds(lo, hi, cfg.resolution)
        occ = _occupancy_on(pf, keep, grid, cfg, mode)
        passes += 1
    return occ


def volume_weights(occ: Occupancy) -> np.ndarray:
    """Fraction of each voxel inside the object (float32 [X, Y, Z]): 1 on ``solid``, 0 outside, and 0.5 on
    the thin layer voxels that separate a filled cavity from the outside.

    A 3DGS surface splats into a layer about 2 x (half-maximum half-width) thick that straddles the true
    surface, and filling its inside counts the outer half of the layer too (a sphere of radius R comes out
    as R + half a layer). Counting the sheet voxels (distance to the cavity + distance to the outside <=
    ``sheet_max_voxels``) as half inside puts the boundary back on the middle of the layer. Voxels of a
    solid block of Gaussians have no cavity next to them and keep weight 1.
    """
    w = occ.solid.astype(np.float32)
    cfg = occ.config
    cavity = occ.solid & ~occ.layer
    if not cfg.sheet_correction or not cavity.any():
        return w
    d_out = ndimage.distance_transform_edt(occ.solid)  # distance to the nearest voxel outside the object
    d_cav = ndimage.distance_transform_edt(~cavity)
    sheet = occ.layer & (d_out + d_cav <= cfg.sheet_max_voxels)
    w[sheet] = 0.5
    return w


@dataclass
class MaterialGrid:
    """Per-voxel material mixture pi on the object: opacity-weighted mean of the Gaussians' pi within
    ``cutoff`` sigma (filtered kernel); voxels with no Gaussian support (a 3DGS object's interior) take the
    mixture of the nearest supported voxel (Euclidean distance transform)."""

    rows: np.ndarray
    """int64 [X, Y, Z]: row of the voxel in ``pi`` (-1 outside the tracked region)"""
    pi: np.ndarray
    """float64 [M, K]: mixture per tracked voxel (nearest-supported mixture already substituted)"""
    support: np.ndarray
    """float32 [M]: kernel weight sum (0 where the mixture was propagated)"""

    def at(self, index: np.ndarray) -> np.ndarray:
        """Mixture [T, K] at integer voxel indices [T, 3] (clipped into the grid; nearest tracked voxel)."""
        shape = np.asarray(self.rows.shape)
        ijk = np.clip(index, 0, shape - 1)
        r = self.rows[ijk[:, 0], ijk[:, 1], ijk[:, 2]]
        if (r < 0).any():
            raise ValueError("MaterialGrid.at: index outside the tracked region (dilate more).")
        return self.pi[r]


def voxel_materials(pf: PropertyField, occ: Occupancy, *, dilate: int = 2) -> MaterialGrid:
    """Per-voxel material mixture over ``occ.solid`` dilated by ``dilate`` voxels (covers the surface mesh)."""
    cfg = occ.config
    tracked = ndimage.binary_dilation(occ.solid, iterations=dilate) if dilate > 0 else occ.solid.copy()
    rows = np.full(occ.solid.shape, -1, dtype=np.int64)
    m = int(tracked.sum())
    rows[tracked] = np.arange(m)
    device = pf.device
    lut = torch.from_numpy(rows.ravel()).to(device)
    keep = occ.gaussians if occ.gaussians is not None else pf.opacities >= cfg.min_opacity
    # only the object's Gaussians whose box touches the crop
    inv6, cov_diag = inverse_covariance6(pf.quats, pf.scales, occ.filter_sigma)
    _, _, counts = gaussian_boxes(occ.grid, pf.means, cov_diag, cfg.cutoff_sigma)
    idx = torch.nonzero(keep & (counts > 0)).squeeze(1)
    sub = pf.subset(idx)
    weight, weighted = splat(occ.grid, sub.means, sub.quats, sub.scales, sub.opacities, sub.pi().float(),
                             filter_sigma=occ.filter_sigma, cutoff=cfg.cutoff_sigma, lut=lut, num_rows=m,
                             pair_budget=cfg.pair_budget,
                             desc="material mixture" if cfg.progress else None)  # fmt: skip
    w = weight.cpu().numpy()
    acc = weighted.cpu().numpy().astype(np.float64)  # type: ignore[union-attr]
    supported = w > cfg.support_eps
    if not supported.any():
        raise ValueError("no voxel of the object is supported by a Gaussian; lower support_eps.")
    pi = np.zeros_like(acc)
    pi[supported] = acc[supported] / acc[supported].sum(1, keepdims=True)
    if not supported.all():
        sup_grid = np.zeros(occ.solid.shape, dtype=bool)
        sup_grid[tracked] = supported
        _, near = ndimage.distance_transform_edt(~sup_grid, return_indices=True)
        t_idx = np.nonzero(tracked)
        src = rows[near[0][t_idx], near[1][t_idx], near[2][t_idx]]
        missing = ~supported
        pi[missing] = pi[src[missing]]
    return MaterialGrid(rows=rows, pi=pi, support=np.where(supported, w, 0).astype(np.float32))
