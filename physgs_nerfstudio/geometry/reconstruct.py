"""The object's geometry from a splat and its views: selection (:mod:`.select`) -> the solid, carved from the views'
free space in several variants and cut where no view saw (:mod:`.solid`) -> parts and their materials -> per-part
volume, wall area and structure. One public entry: :func:`reconstruct_object`.

Geometric uncertainty: the carving is redone under perturbed settings (``variants``: a looser and a tighter
vote, a smaller and a larger depth margin). The mass's Monte Carlo draws one
variant per sample, so the interval carries the geometry's uncertainty alongside the materials', densities',
structure and thickness (:mod:`physgs_nerfstudio.mass`). Parts are defined once, on the union of the variants'
solids, so a part keeps its identity across variants.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from ..bayes.mixture import material_mixture_weights
from .capture import CaptureView, MaskObservation
from .config import GeometryConfig
from .contact import object_labels
from .gaussians import Subset, ViewRender, render_depth
from .grid import GeometryError, VoxelGrid
from .part_evidence import absorb_unobserved, fuse_part_materials, merge_same_material, observation_shares
from .partial import BOUNDARY_SUBSAMPLES, boundary_fill, part_volumes
from .parts import (
    material_quantiles,
    part_labels,
    pooled_part_alpha,
    sum_rows,
    voxel_mixture,
)
from .select import ObjectSelection, drop_outside_hull, select_object, support_under
from .solid import Carving, carve_object, unseen_face_share
from .structure import PartStructure, fuse_structure
from .support import views_up
from .walls import PartGeometry, concavities, part_areas, seam_areas

logger = logging.getLogger(__name__)

__all__ = ["GeometryConfig", "ObjectGeometry", "reconstruct_object"]


@dataclass
class ObjectGeometry:
    grid: VoxelGrid
    solid: np.ndarray
    """bool [X, Y, Z]: the nominal carved solid"""
    parts: np.ndarray
    """int [X, Y, Z]: part id on the union of the variants' solids, -1 elsewhere"""
    part_mixture: np.ndarray
    """[P, K]: volume-weighted material mixture of each part (nominal solid)"""
    mixture: np.ndarray
    """[X, Y, Z, K] per-voxel material mixture (zeros outside the union solid)"""
    variant_names: list[str]
    volumes: np.ndarray
    """[G, P] volume per variant and part, scene units^3"""
    areas: np.ndarray
    """[G, P] wall area per variant and part, scene units^2"""
    sheet_share: np.ndarray
    """[P] share of each part's wall faces on sheets (nominal)"""
    structure: PartStructure
    selection: ObjectSelection
    views_used: int
    mask_sources: dict[str, int]
    """views per mask source (:func:`.capture.load_capture`: labels, whole masks or both)"""
    surface_areas: np.ndarray
    """[G, P] whole surface area per variant and part, scene units^2 (every face once: the mass's surface
    offset)"""
    material_levels: np.ndarray | None = None
    """[P, J, K]: per part and quantile level, the volume share per material
    (:func:`physgs_nerfstudio.geometry.parts.material_quantiles`); None = each part one material"""
    pixel_voxels: float = 1.0
    """the views' median pixel footprint at the grid's centre, in voxels (the masks' resolution)"""
    full_areas: np.ndarray | None = None
    """[G, P] area of the fully counted wall faces per variant and part, scene units^2 (the rest of ``areas`` is
    sheet faces at half weight)"""
    curvatures: np.ndarray | None = None
    """[G, P] integrated mean curvature of those faces, scene units (:mod:`physgs_nerfstudio.geometry.walls`,
    "Wall curvature"); None: walls of area x thickness"""
    seam_areas: np.ndarray | None = None
    """[P, P] area between each two parts inside the nominal solid, scene units^2
    (:func:`physgs_nerfstudio.geometry.walls.seam_areas`); None: no seams (the mass moves none)"""
    unseen_surface_share: float = 0.0
    """the share of the nominal solid's voxel faces that no view placed: faces onto space the views kept (no
    view saw past it) that the support plane's cut, the Gaussians' polytope or the hidden open space rule
    removed (an unseen underside; :func:`unseen_face_share`)"""
    extent_gaussians: int = 0
    """the Gaussians whose polytope ends the solid (those some view sees)"""
    stands_on: str | None = None
    """the object perception names under the contact cut (a stand, a table; :mod:`.contact`); None: no cut"""
    contact_gain: float = 0.0
    """the share of the named surface that the contact cut put on its name's side (:data:`.contact.MIN_GAIN`)"""
    hidden_removed: dict[str, int] | None = None
    """the nominal solid's voxels removed as hidden open space (:mod:`.hidden`), by the rule that removed them:
    "majority", "open_half"; None = the rule is off"""
    hidden_boundary: np.ndarray | None = None
    """[G, P] volume per variant and part of the kept voxels on the boundary with the hidden open space, whole
    voxels, scene units^3 (:func:`.hidden.hidden_boundary`); ``volumes`` counts them at ``hidden_boundary_fill``,
    and the mass draws their occupancy uniformly in [0, 1]. None = none (the rule off, or no such voxel)"""
    hidden_edge: np.ndarray | None = None
    """bool [X, Y, Z]: the nominal solid's voxels on that boundary (None with ``hidden_boundary``)"""
    occupancy: np.ndarray | None = None
    """float32 [X, Y, Z]: the share of each voxel that the nominal volume counts, before the hidden boundary's half
    (:mod:`.partial`: 1 inside the solid, the sub-points' share on its boundary and on the voxels just outside it
    that the vote carved, 0 elsewhere); None = whole voxels (``solid``)"""

    @property
    def hidden_boundary_fill(self) -> float:
        """The share of a boundary voxel that ``volumes`` counts: 0.5, or 1 where there is no boundary."""
        return 0.5 if self.hidden_boundary is not None else 1.0

    def fill(self) -> np.ndarray:
        """float32 [X, Y, Z]: the share of each voxel that the nominal volume counts: its ``occupancy`` (1 inside the
        solid, a share around its surface, 0 elsewhere), times ``hidden_boundary_fill`` on the boundary with hidden
        open space."""
        out = self.occupancy.copy() if self.occupancy is not None else self.solid.astype(np.float32)
        if self.hidden_edge is not None:  # a subset of the nominal solid
            out[self.hidden_edge] *= self.hidden_boundary_fill
        return out

    @property
    def num_parts(self) -> int:
        return int(self.volumes.shape[1])

    def summary(self) -> dict[str, Any]:
        return {"grid": self.grid.to_dict(), "solid_voxels": int(self.solid.sum()), "num_parts": self.num_parts,
                "variants": self.variant_names, "views_used": self.views_used, "mask_sources": self.mask_sources,
                "selected_gaussians": self.selection.num_selected,
                "object_centre_scene": [float(x) for x in self.selection.centre],
                "rests_on_plane": self.selection.plane is not None,
                "support_plane_in_masks": self.selection.plane_in_masks,
                "support_found": self.selection.support_found,
                "on_support_gaussians": self.selection.on_support, "clusters": self.selection.num_clusters,
                "split_from_gaussians": self.selection.split_from,
                "hidden_open_voxels": self.hidden_removed, "pixel_footprint_voxels": self.pixel_voxels,
                "hidden_boundary_voxels": (int(self.hidden_edge.sum()) if self.hidden_edge is not None else None),
                "unseen_surface_share": self.unseen_surface_share,
                "extent_gaussians": self.extent_gaussians, "stands_on": self.stands_on,
                "contact_gain": self.contact_gain}  # fmt: skip


def _object_views(g: Any, selection: ObjectSelection, views: Sequence[CaptureView], cfg: GeometryConfig
                  ) -> tuple[list[CaptureView], list[ViewRender]]:  # fmt: skip
    """The object's own depth and alpha (its Gaussians rendered alone: which of them lie on its seen surface,
    :func:`.gaussians.surface_excess`), and the foreground masks cut down to this object (foreground AND the dilated
    silhouette of its Gaussians, less the support plane's pixels outside its own silhouette), for the masks' visual
    hull (the concavities; the masks do not carve, :mod:`.free_space`)."""
    import cv2

    renders = render_depth(Subset(g, selection.selected), views, backend=cfg.backend)
    k = 2 * cfg.object_mask_dilate_px + 1
    kernel = np.ones((k, k), np.uint8)
    ground: list[np.ndarray | None] = [None] * len(views)
    if selection.support is not None and bool(selection.support.any()):
        # the support plane took the masks with it (select.py, step 2): its pixels around the object are not the
        # object's, though the dilated silhouette reaches them
        plane = render_depth(Subset(g, selection.support), views, backend=cfg.backend, surface=False)
        ground = [p.alpha.cpu().numpy() > 0.5 for p in plane]
    out = []
    for v, r, on_plane in zip(views, renders, ground):
        core = r.alpha.cpu().numpy() > 0.5
        fg = v.mask.cpu().numpy() & cv2.dilate(core.astype(np.uint8), kernel).astype(bool)
        if on_plane is not None:
            fg &= core | ~on_plane
        out.append(replace(v, mask=torch.from_numpy(fg)))
    return out, renders


def _up_weight(views: Sequence[CaptureView], weight: float) -> float:
    """``weight`` when the views' up direction is within 25 degrees of the grid's z axis, else 1."""
    return weight if abs(float(views_up(views)[2])) >= math.cos(math.radians(25.0)) else 1.0


def _pixel_voxels(views: Sequence[CaptureView], grid: VoxelGrid) -> float:
    """The median over views of a pixel's footprint at the grid's centre, in voxels."""
    centre = torch.as_tensor(grid.origin, dtype=torch.float64) + 0.5 * grid.voxel_size * torch.tensor(grid.shape)
    fp = [float((v.centre.double().cpu() - centre).norm()) / float(v.K[0, 0]) for v in views]
    return float(np.median(fp)) / grid.voxel_size


@dataclass
class _Parts:
    """The object's parts and their materials (:func:`_part_materials`): per-voxel ``mixture`` [X, Y, Z, K],
    ``parts`` on the union of the solids, ``pm`` [P, K] per part, the coupled quantile draw ``levels`` (None: one
    material per part), the observations' shares of each part (the structure's evidence) and the material names."""

    mixture: np.ndarray
    parts: np.ndarray
    pm: np.ndarray
    levels: np.ndarray | None
    shares: list[tuple[int, np.ndarray]]
    names: list[str]

    @property
    def count(self) -> int:
        return int(self.parts.max()) + 1


def _merged_parts(parts: np.ndarray, cv: Carving, views: Sequence[CaptureView],
                  observations: Sequence[MaskObservation], names: list[str], prior: tuple[float, float],
                  cfg: GeometryConfig, device: Any) -> tuple[np.ndarray, list[tuple[int, np.ndarray]]]:  # fmt: skip
    """``parts`` after the observations: a part they do not reach joins the observed part nearest each of its
    voxels (:func:`.part_evidence.absorb_unobserved`), and touching parts they name the same material merge; and
    each observation's shares of the parts (:func:`.part_evidence.observation_shares`)."""
    a0, lam = prior

    def shares_of(p: np.ndarray) -> list[tuple[int, np.ndarray]]:
        return observation_shares(cv.grid, np.where(cv.solids[0], p, -1), int(p.max()) + 1, views, observations,
                                  device)  # fmt: skip

    shares = shares_of(parts)
    if not shares:
        return parts, shares
    seen = fuse_part_materials(shares, observations, names, int(parts.max()) + 1, a0, lam)[1]
    merged = absorb_unobserved(parts, seen >= cfg.min_part_observation)
    if merged is not parts:
        parts = merged
        shares = shares_of(parts)
    # touching parts whose views name the same material are one piece of it (the absorbed voxels that separated them
    # now join them)
    P = int(parts.max()) + 1
    fused, seen = fuse_part_materials(shares, observations, names, P, a0, lam)
    dom = np.where(seen >= cfg.min_part_observation, np.argmax(fused, 1), -1 - np.arange(P))
    parts, old_to_new = merge_same_material(parts, dom)
    merged_p = int(parts.max()) + 1  # the shares re-binned once, not recomputed per observation
    if merged_p < P:
        shares = [(i, np.bincount(old_to_new, sh, minlength=merged_p)) for i, sh in shares]
    return parts, shares


def _part_mixture(parts: np.ndarray, mixture: np.ndarray, cv: Carving) -> np.ndarray:
    """[P, K]: each part's volume-weighted voxel mixture over the nominal solid (over the union for a part only in
    other variants)."""
    P = int(parts.max()) + 1
    nominal, union = cv.solids[0], np.logical_or.reduce(cv.solids)
    pm = sum_rows(np.where(nominal, parts, -1)[nominal], mixture[nominal], P)
    empty = pm.sum(1) == 0
    if empty.any():
        pm += sum_rows(parts[union], mixture[union] * empty[parts[union]][:, None], P)
    return pm / pm.sum(1, keepdims=True)


def _part_materials(g: Any, pi: Any, selection: ObjectSelection, views: Sequence[CaptureView],
                    observations: Sequence[MaskObservation], cv: Carving, cfg: GeometryConfig,
                    material_names: Sequence[str] | None, alpha: torch.Tensor | None, material_weights: str,
                    dirichlet_prior: tuple[float, float] | None) -> _Parts:  # fmt: skip
    """Per-voxel material mixture, the parts (components of one dominant material) and each part's material: the
    Dirichlet fusion of the views' answers about it (:mod:`.part_evidence`); a part no observation reaches keeps its
    Gaussians' pooled posterior (:func:`.parts.pooled_part_alpha`), and without ``alpha`` each voxel keeps its own
    mixture (:func:`.parts.material_quantiles`). :func:`reconstruct_object`'s arguments."""
    sel, device = selection.selected, g.means.device
    labelled = getattr(g, "labelled", None)
    pi_sel = pi(sel) if callable(pi) else pi[sel]
    observed = labelled[sel] if labelled is not None else None
    near = cv.excess <= cfg.evidence_surface_voxels * cv.grid.voxel_size  # their labels are material evidence
    observed = near.to(g.means.dtype) * (observed.reshape(-1) if observed is not None else 1.0)
    union = np.logical_or.reduce(cv.solids)
    mixture = voxel_mixture(cv.grid, union, g.means[sel], g.opacities[sel], pi_sel, observed,
                            min_evidence=cfg.min_voxel_evidence, up_weight=_up_weight(views, cfg.interior_up_weight))
    parts = part_labels(union, mixture, cfg.min_part_fraction)
    names = list(material_names) if material_names is not None else [str(k) for k in range(pi_sel.shape[1])]
    prior = dirichlet_prior if dirichlet_prior is not None else (1.0, 4.0)
    by_views = alpha is not None and bool(observations)
    shares: list[tuple[int, np.ndarray]] = []
    if by_views:
        parts, shares = _merged_parts(parts, cv, views, observations, names, prior, cfg, device)
    P = int(parts.max()) + 1
    pm = _part_mixture(parts, mixture, cv)
    if observations and not by_views:  # the structure's evidence
        shares = observation_shares(cv.grid, np.where(cv.solids[0], parts, -1), P, views, observations, device)
    if alpha is None:
        return _Parts(mixture, parts, pm, material_quantiles(parts, mixture, P, pm), shares, names)
    pooled, support = pooled_part_alpha(cv.grid, parts, P, g.means[sel], g.opacities[sel], alpha[sel], observed)
    has = support > 0
    if by_views and shares:
        fused, seen = fuse_part_materials(shares, observations, names, P, *prior)
        obs = seen >= cfg.min_part_observation
        pooled[obs] = fused[obs]
        has = has | obs
    if has.any():
        w = material_mixture_weights(torch.from_numpy(pooled[has]), material_weights)  # type: ignore[arg-type]
        pm[has] = w.double().numpy()
    return _Parts(mixture, parts, pm, None, shares, names)


def _surfaces(cv: Carving, pp: _Parts, cfg: GeometryConfig, pixel_voxels: float, device: Any
              ) -> list[PartGeometry]:  # fmt: skip
    """Every variant's per-part wall areas, surfaces and curvatures (:func:`.walls.part_areas`)."""
    # a face is one side of a sheet where the solid's inscribed half-thickness is at most the nominal depth margin
    # + 2 voxels (the surface depth keeps both surfaces of a wall, in front of their Gaussians)
    sheet = cfg.carve.depth_margin_voxels + 2.0
    concave = concavities(cv.hull, cv.solids[0], max(2.0, cfg.concavity_px * pixel_voxels))

    def areas(s: np.ndarray) -> PartGeometry:
        return part_areas(cv.grid, s, np.where(s, pp.parts, -1), pp.count, sheet_voxels=sheet, concave=concave,
                          device=device)  # fmt: skip

    # the variants' surfaces on a thread pool: each is independent, and NumPy's and SciPy's loops release the GIL
    # for much of the work (the same numbers as one at a time)
    with ThreadPoolExecutor(max_workers=max(1, min(len(cv.solids), os.cpu_count() or 1))) as pool:
        return list(pool.map(areas, cv.solids))


def _volumes(cv: Carving, pp: _Parts, fills: list[np.ndarray]
             ) -> tuple[np.ndarray, np.ndarray | None]:  # fmt: skip
    """[G, P] volume per variant and part (partial volume's shares, or whole voxels), less half of each voxel on the
    boundary with hidden open space; and that boundary's whole volume [G, P] (None: no such voxel)."""
    P, h3 = pp.count, cv.grid.voxel_size**3
    volumes = np.stack([part_volumes(f, np.where(s, pp.parts, -1), P, cv.grid.voxel_size)
                        for f, s in zip(fills, cv.solids)])  # fmt: skip
    if not any(e.any() for e in cv.edges):
        return volumes, None
    on = pp.parts >= 0  # the kept voxels on the boundary with the hidden open space: half a voxel each
    boundary = np.stack([np.bincount(pp.parts[e & on], f[e & on], minlength=P)[:P]
                         for e, f in zip(cv.edges, fills)]) * h3  # fmt: skip
    return volumes - 0.5 * boundary, boundary


@torch.no_grad()
def reconstruct_object(
    g: Any,
    pi: torch.Tensor | Callable[[torch.Tensor], torch.Tensor],
    views: Sequence[CaptureView],
    observations: Sequence[MaskObservation] = (),
    library_thickness: Sequence[float | None] | None = None,
    cfg: GeometryConfig | None = None,
    *,
    material_names: Sequence[str] | None = None,
    alpha: torch.Tensor | None = None,
    material_weights: str = "dominant",
    dirichlet_prior: tuple[float, float] | None = None,
    progress: Any = None,
) -> ObjectGeometry:
    """Select, carve, split into parts and measure the object (module doc). ``g``: the Gaussians (activated
    ``means``, ``quats``, ``scales``, ``opacities``), ``pi``: their material mixture weights [N, K]
    (or a function of a bool row mask giving those rows' weights, so that only the object's are computed),
    ``library_thickness[k]``: material k's typical wall thickness in the library (None: solid),
    ``material_names[k]``: the names observations use; ``alpha``: their Dirichlet posteriors [N, K] and
    ``material_weights`` the field's weighting, for the parts' materials (None: each voxel its own,
    :func:`.parts.material_quantiles`); ``dirichlet_prior``: the model's (alpha0, lambda) for the fusion of the
    observations (None: (1, 4), the fusion's defaults). ``progress(stage: str)`` is called as stages start."""
    cfg = cfg or GeometryConfig()
    step = progress or (lambda _s: None)
    views = list(views)
    if not views:
        raise GeometryError("no views to carve the object from: the run has no training cameras.")
    step("selecting the object")
    selection = select_object(g, views, cfg.select, backend=cfg.backend)
    drop_outside_hull(g, selection, views, cfg.select)
    support_under(g, selection, views, cfg.select)
    step("rendering depth")
    obj_views, renders = _object_views(g, selection, views, cfg)
    step("carving")
    cv = carve_object(g, selection, obj_views, renders, object_labels(obj_views, observations), cfg)
    step("materials and parts")
    pp = _part_materials(g, pi, selection, views, observations, cv, cfg, material_names, alpha, material_weights,
                         dirichlet_prior)  # fmt: skip
    pixel_voxels = _pixel_voxels(obj_views, cv.grid) if obj_views else 1.0
    step("partial volume")
    fills = boundary_fill(cv.grid, cv.solids, cv.cfgs, cv.views, cv.depths, subsamples=BOUNDARY_SUBSAMPLES,
                          device=g.means.device)
    geos = _surfaces(cv, pp, cfg, pixel_voxels, g.means.device)
    step("structure")
    lib = library_thickness if library_thickness is not None else [None] * pp.pm.shape[1]
    nominal_parts = np.where(cv.solids[0], pp.parts, -1)
    structure = fuse_structure(cv.grid, nominal_parts, pp.count, views, observations,
                               [lib[k] for k in np.argmax(pp.pm, 1)], pp.pm, pp.names, cfg.structure,
                               shares=pp.shares)  # fmt: skip
    volumes, boundary = _volumes(cv, pp, fills)
    sources: dict[str, int] = {}
    for v in obj_views:
        sources[v.mask_source] = sources.get(v.mask_source, 0) + 1
    return ObjectGeometry(
        grid=cv.grid, solid=cv.solids[0], parts=pp.parts, part_mixture=pp.pm, mixture=pp.mixture,
        variant_names=cv.names, volumes=volumes, areas=np.stack([gm.area for gm in geos]),
        sheet_share=geos[0].sheet_share, structure=structure, selection=selection, views_used=len(views),
        mask_sources=sources, material_levels=pp.levels, surface_areas=np.stack([gm.surface for gm in geos]),
        pixel_voxels=pixel_voxels, full_areas=np.stack([gm.full_area for gm in geos]),
        curvatures=np.stack([gm.curvature for gm in geos]),
        seam_areas=seam_areas(nominal_parts, pp.count, cv.grid.voxel_size), hidden_removed=cv.hidden_removed,
        unseen_surface_share=unseen_face_share(cv.solids[0], cv.unseen), hidden_boundary=boundary,
        hidden_edge=cv.edges[0] if boundary is not None else None,
        stands_on=cv.contact.below if cv.contact else None, contact_gain=cv.contact.gain if cv.contact else 0.0,
        extent_gaussians=cv.extent_gaussians, occupancy=fills[0],
    )  # fmt: skip
