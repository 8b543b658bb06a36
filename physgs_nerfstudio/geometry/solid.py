"""The object's solid: the carving of the views' free space on a voxel grid fitted to the selection, in every
variant that the mass interval samples (:func:`carving_variants`), then the cuts that end it where no view saw: the
seen Gaussians' polytope (:mod:`.gaussians`), the support plane and the contact with a named object under it
(:mod:`.support`, :mod:`.contact`), and the hidden open space (:mod:`.hidden`). One entry: :func:`carve_object`,
called by :func:`.reconstruct.reconstruct_object`."""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from .capture import CaptureView
from .carve import CarveConfig, carve_votes_many, mask_hull, solid_from_votes
from .config import GeometryConfig
from .contact import Contact, ObjectLabels, contact_cut
from .free_space import free_space_depths, seeded_components
from .gaussians import Subset, ViewRender, support_excess, surface_excess, surface_views
from .grid import GeometryError, VoxelGrid
from .hidden import (
    HIDDEN_PASSES,
    MIN_OPEN_FRACTION,
    SKIN_SIGMAS,
    gaussian_samples,
    hidden_boundary,
    skin_centred,
    without_hidden_space_many,
)
from .select import ObjectSelection
from .support import SupportPlane, align_to_plane, views_up

logger = logging.getLogger(__name__)

__all__ = ["Carving", "carve_object", "carving_variants", "unseen_face_share"]


def _domain(g: Any, selected: torch.Tensor, cfg: GeometryConfig) -> VoxelGrid:
    m = g.means[selected].double()
    lo = torch.quantile(m[: 1 << 20], 0.001, dim=0) if len(m) > 1000 else m.amin(0)
    hi = torch.quantile(m[: 1 << 20], 0.999, dim=0) if len(m) > 1000 else m.amax(0)
    r = 3 * g.scales[selected].double().amax(-1)
    pad = float((hi - lo).max()) * cfg.pad_fraction + float(torch.quantile(r[: 1 << 20], 0.9)) if len(r) else 0.0
    return VoxelGrid.from_bounds((lo - pad).cpu(), (hi + pad).cpu(), cfg.resolution)


def _carve_variants(grid: VoxelGrid, views: list[CaptureView], depths: list[torch.Tensor], hull: np.ndarray,
                    variants: list[tuple[str, CarveConfig]], device: Any, means: torch.Tensor, pad_voxels: float,
                    wider_voxels: float | None, scales: torch.Tensor, quats: torch.Tensor, extent_skip: int = 0,
                    ) -> tuple[list[np.ndarray], np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The solid of every variant, from one free-space voting pass (:func:`.carve.carve_votes_many`), cut to the
    support polytope of ``means`` grown by ``pad_voxels`` (:mod:`.gaussians`; the polytope of the Gaussians'
    one-sigma ellipsoids of ``scales`` and ``quats``, :func:`.gaussians.support_heights`), then (unless
    ``wider_voxels`` is None) the first variant's solid cut to the polytope grown by that much more, as one more
    variant; the masks' visual ``hull`` cut the same way; the voxels that the views kept (in a solid or the hull)
    and the polytope cut; and the first variant's solid before the cut."""
    votes = carve_votes_many(grid, views, depths, [cc for _, cc in variants], device=device)
    solids = [solid_from_votes(v, grid, cc) for v, (_, cc) in zip(votes, variants)]
    candidates = np.logical_or.reduce(solids) | hull
    # how far beyond the polytope each candidate lies, once for both pads
    idx = tuple(np.argwhere(candidates).T)
    excess = (support_excess(grid, means, candidates, scales=scales, quats=quats, skip=extent_skip)
              if len(means) and len(idx[0])
              else np.full(len(idx[0]), -np.inf))  # fmt: skip
    inside = np.zeros_like(candidates)
    inside[idx] = excess <= pad_voxels
    cut = [s & inside for s in solids]
    if wider_voxels is not None:  # the nominal carving within a wider extent (GeometryConfig)
        wider = np.zeros_like(candidates)
        wider[idx] = excess <= pad_voxels + wider_voxels
        cut.append(solids[0] & wider)
    return cut, hull & inside, candidates & ~inside, solids[0]


def _beyond_kept(raw: np.ndarray, beyond: np.ndarray) -> np.ndarray:
    """The space that the views kept (``raw``: the nominal carving before any cut) beyond the polytope, less
    its slivers: on a seen face the carving keeps up to a voxel past the Gaussians (a morphological opening
    removes that), while under an unseen underside the views keep a wedge of space many voxels deep."""
    from scipy import ndimage  # lazily: a PLY-only export needs no SciPy

    return ndimage.binary_opening(raw & beyond)


def unseen_face_share(solid: np.ndarray, unseen: np.ndarray) -> float:
    """The share of ``solid``'s voxel faces (between a solid voxel and a 6-neighbour outside it, the grid's
    border counted as outside) whose outside voxel is in ``unseen`` (bool, the grid's shape)."""
    total = hidden = 0
    padded_s = np.pad(solid, 1)
    padded_u = np.pad(unseen & ~solid, 1)
    inner = (slice(1, -1),) * 3
    for axis in range(3):
        for step in (-1, 1):
            nb = tuple(slice(1 + step, padded_s.shape[a] - 1 + step) if a == axis else inner[a]
                       for a in range(3))
            total += int((solid & ~padded_s[nb]).sum())
            hidden += int((solid & padded_u[nb]).sum())
    return hidden / total if total else 0.0


def _cut_below(grid: VoxelGrid, solids: list[np.ndarray], hull: np.ndarray, plane: SupportPlane | None
               ) -> tuple[list[np.ndarray], np.ndarray]:  # fmt: skip
    """The solids and the hull without the voxels whose centres lie below ``plane`` (None: unchanged)."""
    if plane is None:
        return solids, hull
    above = plane.above_voxels(grid)
    return [s & above for s in solids], hull & above


def _without_hidden(g: Any, selection: ObjectSelection, views: list[CaptureView], renders: list[ViewRender],
                    excess: torch.Tensor, grid: VoxelGrid, solids: list[np.ndarray], beyond: np.ndarray,
                    plane: SupportPlane | None, cfg: GeometryConfig
                    ) -> tuple[list[np.ndarray], dict[str, int], list[np.ndarray]]:  # fmt: skip
    """Every variant's solid without its hidden open space (:mod:`.hidden`): the skin is sampled by the selected
    Gaussians whose centres some view sees within ``hidden_skin_band`` behind its surface (``excess``: their depth
    behind the nearest rendered surface), their axis ends only where a view sees them too (``hidden_skin_seen``);
    rays that leave the solid below ``plane`` (the support's or the contact's) or into space that the views kept and the Gaussians' polytope
    cut (``beyond``) are enclosed (the object's unseen underside). Also returns the nominal solid's voxels that each
    rule removed, and each variant's kept voxels on the boundary with the space removed
    (:func:`.hidden.hidden_boundary`)."""
    on_skin = excess <= cfg.hidden_skin_band * grid.voxel_size
    surface = Subset(g, torch.nonzero(selection.selected).squeeze(1)[on_skin])
    samples = gaussian_samples(surface.means.double(), surface.scales, surface.quats, SKIN_SIGMAS)
    n = len(surface.means)
    if len(samples) > n:
        # the means are seen; the axis ends that some view sees too, within the band plus their Gaussian's own
        # thickness (its smallest standard deviation): a thick Gaussian's shortest axis ends that far behind
        ends = samples[n:]
        thick = (SKIN_SIGMAS * surface.scales.min(1).values).repeat_interleave(6)
        seen = surface_views(ends, views, renders, cfg.hidden_skin_seen * grid.voxel_size + thick)
        samples = torch.cat([samples[:n], ends[seen > 0]])
    skin = skin_centred(samples, np.asarray(grid.origin), grid.voxel_size, grid.shape,
                        cfg.hidden_skin_voxels, cfg.hidden_skin_tolerance)  # fmt: skip
    dev = surface.means.device
    closed = beyond.copy()
    if plane is not None:
        closed |= ~plane.above_voxels(grid)
    closed_t = torch.from_numpy(closed).to(dev)
    before = torch.from_numpy(np.stack(solids)).to(dev)
    kept, counts = without_hidden_space_many(before, skin, closed_t, MIN_OPEN_FRACTION,
                                             cfg.hidden_min_open_half, HIDDEN_PASSES)  # fmt: skip
    out = list(kept.cpu().numpy())
    edges = list(hidden_boundary(kept, before & ~kept).cpu().numpy())
    removed = counts[0]  # the nominal solid's
    if removed["majority"] or removed["open_half"]:
        logger.info("hidden open space: %d of %d solid voxels that no seen surface encloses removed (%d by the open "
                    "half)", removed["majority"] + removed["open_half"], int(solids[0].sum()), removed["open_half"])
    return out, removed, edges


def _solid_bounds(grid: VoxelGrid, solid: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Scene-unit bounds of the solid voxels (None when there are none)."""
    if not solid.any():
        return None, None
    idx = np.argwhere(solid)
    origin = np.asarray(grid.origin, dtype=np.float64)
    return origin + idx.min(0) * grid.voxel_size, origin + (idx.max(0) + 1) * grid.voxel_size


def carving_variants(cfg: GeometryConfig) -> list[tuple[str, CarveConfig]]:
    base = cfg.carve
    out = [("nominal", base)]
    if not cfg.variants:
        return out
    out += [(f"vote{k}/{q:g}", replace(base, min_votes=k, min_vote_fraction=q)) for k, q in cfg.vote_variants]
    out += [(f"depth{d:g}vox", replace(base, depth_margin_voxels=d)) for d in cfg.depth_margin_variants]
    return out


@dataclass
class Carving:
    """The carved object (:func:`carve_object`): its grid, the variants' names and carving settings, their solids
    (the nominal first) after every cut, the nominal visual hull, the views and their surface depths that carved
    (:func:`.free_space.free_space_depths`), each selected Gaussian's depth behind the rendered surface nearest it
    (``excess``, :func:`.gaussians.surface_excess`), the space no view placed (:func:`unseen_face_share`), the hidden
    open space removed and each variant's boundary with it (:mod:`.hidden`), and how many Gaussians the extent
    used."""

    grid: VoxelGrid
    names: list[str]
    cfgs: list[CarveConfig]
    solids: list[np.ndarray]
    hull: np.ndarray
    views: list[CaptureView]
    depths: list[torch.Tensor]
    excess: torch.Tensor
    unseen: np.ndarray
    extent_gaussians: int
    hidden_removed: dict[str, int]
    edges: list[np.ndarray]
    contact: Contact | None = None


def _refit(grid: VoxelGrid, solids: list[np.ndarray], cfg: GeometryConfig) -> VoxelGrid | None:
    """A grid fitted to the carved solids when they span less than ``refit_fraction`` of ``grid`` (outliers of the
    selection stretched the domain and coarsened the voxels), at full resolution; None otherwise."""
    lo, hi = _solid_bounds(grid, np.logical_or.reduce(solids))
    side = float(np.max(grid.shape)) * grid.voxel_size
    if lo is None or float((hi - lo).max()) >= cfg.refit_fraction * side:
        return None
    pad = float((hi - lo).max()) * (cfg.pad_fraction + 2.0 / cfg.resolution)  # + 2 new voxels
    logger.info("the carved object spans %.0f%% of the selection's box: carved again on a grid fitted to it",
                100 * float((hi - lo).max()) / side)  # fmt: skip
    return VoxelGrid.from_bounds(torch.from_numpy(lo - pad), torch.from_numpy(hi + pad), cfg.resolution)


def carve_object(g: Any, selection: ObjectSelection, views: list[CaptureView], renders: list[ViewRender],
                  labels: ObjectLabels, cfg: GeometryConfig) -> Carving:  # fmt: skip
    """Every variant's solid: carved on the selection's domain (again on a fitted grid, :func:`_refit`), cut to the
    seen Gaussians' polytope (:mod:`.gaussians`), above the support plane and above the contact with another named
    object under it (:mod:`.contact`), less the hidden open space. ``views``: the object masks (their visual hull),
    ``renders``: the object's Gaussians' own render (which lie on its surface), ``labels``: the views' names."""
    grid = align_to_plane(_domain(g, selection.selected, cfg), selection.plane)
    depths = free_space_depths(g, views, cfg.backend)
    variants = carving_variants(cfg)
    wider = cfg.extent_variant_voxels if cfg.variants else None
    ext_idx = torch.nonzero(selection.selected).squeeze(1)
    # each selected Gaussian's smallest depth behind a view's rendered surface: the extent's, the material evidence's
    # and the skin's sets are those within their bands of it (one pass over the views)
    excess = surface_excess(g.means[ext_idx], views, renders)
    seen = excess <= grid.voxel_size
    if int(seen.sum()) >= 50:
        logger.info("object extent: %d of %d selected Gaussians are seen by a view; the unseen ones "
                    "do not set where the solid ends", int(seen.sum()), len(ext_idx))  # fmt: skip
        ext_idx = ext_idx[seen]
    # the outlier count of the whole selection: the seen Gaussians' polytope is never wider than all of theirs
    ext = {"scales": g.scales[ext_idx], "quats": g.quats[ext_idx],
           "extent_skip": int(cfg.extent_outlier_fraction * selection.num_selected)}  # fmt: skip

    def carve(on: VoxelGrid) -> tuple[list[np.ndarray], np.ndarray, np.ndarray, np.ndarray]:
        # the masks' visual hull: the empty space inside it, outside the solid, is the object's concavities
        hull = mask_hull(on, views, variants[0][1], device=g.means.device)
        return _carve_variants(on, views, depths, hull, variants, g.means.device, g.means[ext_idx],
                               cfg.extent_pad_voxels, wider, **ext)  # fmt: skip

    solids, hull, beyond, raw_nominal = carve(grid)
    fitted = _refit(grid, solids, cfg)
    if fitted is not None:
        grid = align_to_plane(fitted, selection.plane)
        solids, hull, beyond, raw_nominal = carve(grid)
    before_cuts = solids[0]
    solids, hull = _cut_below(grid, solids, hull, selection.plane)
    seeds = g.means[selection.selected]
    solids = [seeded_components(grid, s, seeds) for s in solids]
    up = selection.plane.normal if selection.plane is not None else views_up(views)
    contact = contact_cut(grid, solids[0], views, depths, labels, up)
    plane = selection.plane
    if contact is not None:
        logger.info("contact: the object (%r) stands on %r: cut at the level that separates their named surfaces "
                    "(%.0f%% of the surface)", contact.object_name, contact.below, 100 * contact.gain)  # fmt: skip
        plane = contact.plane
        solids, hull = _cut_below(grid, solids, hull, plane)
        solids = [seeded_components(grid, s, seeds) for s in solids]
    solids, removed, edges = _without_hidden(g, selection, views, renders, excess, grid, solids, beyond, plane, cfg)
    if not solids[0].any():
        raise GeometryError("carving left no solid voxel: the object masks and the views disagree (check poses and "
                            "masks, or raise --mass.geometry.carve.min-vote-fraction).")  # fmt: skip
    unseen = before_cuts & ~solids[0]  # kept by the views, removed by the plane's cut or as hidden open space
    unseen = unseen | _beyond_kept(raw_nominal, beyond)
    names = [n for n, _ in variants] + ([f"extent+{wider:g}vox"] if wider is not None else [])
    cfgs = [cc for _, cc in variants] + [variants[0][1]] * (len(solids) - len(variants))  # the extent variant's
    return Carving(grid, names, cfgs, solids, hull, views, depths, excess, unseen, len(ext_idx), removed, edges,
                    contact)
