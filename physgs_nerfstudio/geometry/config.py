"""How the object's geometry is recovered: :class:`GeometryConfig`, the options of
:func:`.reconstruct.reconstruct_object` (selection, carving, hidden space, parts, structure and the variants that
sample the geometry in the mass interval). Their documented ranges and what each was measured on:
docs/architecture.md, "Mass geometry"."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from .carve import CarveConfig
from .select import SelectConfig
from .structure import StructureConfig

__all__ = ["GeometryConfig"]


@dataclass
class GeometryConfig:
    """How the object's volume is recovered (docs/architecture.md, "Mass geometry")."""

    resolution: int = 128
    """voxels along the longest side of the object's box"""
    select: SelectConfig = field(default_factory=SelectConfig)
    carve: CarveConfig = field(default_factory=CarveConfig)
    structure: StructureConfig = field(default_factory=StructureConfig)
    variants: bool = True
    """sample the geometry in the mass interval (module doc); False: the nominal carving only"""
    mask_margin_variants_px: tuple[float, ...] = (-0.5, 0.5)
    vote_variants: tuple[tuple[int, float], ...] = ((1, 0.1), (3, 0.25))
    """(min_votes, min_vote_fraction) pairs"""
    depth_margin_variants: tuple[float, ...] = (-0.5, 1.0)
    """depth margins in voxels (negative: also carve up to that much behind the rendered surface)"""
    pad_fraction: float = 0.1
    """domain padding around the object's Gaussians, as a fraction of their extent"""
    refit_fraction: float = 0.5
    """when the carved solid's longest side is below this fraction of the domain's, carve again on a grid fitted to
    the solid (outliers of the selection stretched the domain and coarsened the voxels)"""
    extent_pad_voxels: float | None = 0.0
    """the solid is cut to the support polytope of the object's Gaussians grown by this many voxels
    (:mod:`physgs_nerfstudio.geometry.extent`: the space under an object that no view sees past is not the
    object); None = no cut. 0: the outermost Gaussian means already lie on or, by their scatter, beyond the surface
    (the lamp's lowest of 13,686 was 3 mm below its base), and a voxel counts when its centre is inside"""
    extent_of: Literal["ellipsoids", "means"] = "ellipsoids"
    """the polytope supports the Gaussians' one-sigma ellipsoids (each Gaussian's mean plus its standard deviation
    along each direction: a flat Gaussian on a face adds nothing across it, and on a curved surface sampled by a
    few Gaussians their extent spans the gaps between them) or only their means (inscribed in a curved surface
    between the means: a 4 cm rod at 8 mm voxels kept 0.81 of its volume)"""
    extent_seen: bool = True
    """the polytope supports only the object's Gaussians that some view sees on its rendered surface
    (:func:`.gaussians.surface_excess`, within a voxel behind it; all of them where fewer than 50 are):
    Gaussians under an unseen underside, which no view sees, do not place where the solid ends there; the seen
    faces around it do. False: every selected Gaussian (the GPU lamp's steel base kept a layer of false solid
    under its bottom, and the lamp came out 1.14-1.17x at 3 of 5 seeds; benchmarks/README.md)"""
    extent_outlier_fraction: float = 0.001
    """the polytope of all but this fraction of the object's Gaussians along each of its directions (the outermost
    ones, :func:`.extent.support_heights`): a few strays under an object's unseen bottom face otherwise set where its
    solid ends (on a GPU splat of a lamp the lowest of some 20,000 Gaussians near it lay 10 mm under its base, the
    20th 4.4 mm, the 50th 2.5 mm). 0 = every Gaussian counts; documented range 0-0.003"""
    extent_variant_voxels: float | None = 1.0
    """the mass interval also samples the nominal carving cut to the polytope grown by this many more voxels: where
    the polytope ends the solid (an underside no view sees past), the surface is placed by the scatter of a few
    Gaussians, to about a voxel; None = no such variant"""
    extent_shrink_voxels: float | None = None
    """the mass interval also samples the nominal carving without the voxels that lie within this many voxels inside
    the polytope where the polytope ends the solid (next to carved space more than a voxel past the polytope: no view
    saw past it): the other side of ``extent_variant_voxels``, since the few Gaussians' scatter places such a face
    either way (a voxel layer of false solid under a flat unseen base). Seen faces, where the
    views end the solid, keep their voxels. None (default) = no such variant: at 1.0 it widened the suite's
    intervals and covered no more objects"""
    hidden_skin_voxels: int | None = 2
    """the solid loses its *hidden open space* (:mod:`.hidden`): voxels that no view could carve (under a table top
    shot from above, under a chair's seat) and that, in most directions, no seen surface encloses. The seen surface
    (the *skin*) is sampled by the Gaussians that some view sees on its rendered surface; this is how far, in voxels,
    the skin closes the gaps between their samples (``hidden_skin``). None = keep all the space no view sees past
    (the carving alone); documented range 2-3"""
    hidden_skin: Literal["centred", "grown"] = "centred"
    """how the skin closes its gaps (:mod:`.hidden`, "The skin"): "centred", a voxel is skin when the samples within
    ``hidden_skin_voxels`` of it each way are centred on it, to ``hidden_skin_tolerance`` (gaps close, edges and faces
    do not grow); "grown", the samples' voxels grown by ``hidden_skin_voxels`` 6-connected steps (faces
    grow too, and the skin under a seen top encloses that many layers of hidden space)"""
    hidden_skin_tolerance: float = 1.5
    """"centred" skin: the largest distance, in voxels, between a voxel's centre and the centroid of the samples
    around it (half the skin's thickness across a surface); documented range 1.25-2"""
    hidden_skin_sigmas: float = 1.0
    """the skin's samples are the surface Gaussians' means and the ends of their axes at this many standard
    deviations (:func:`.hidden.gaussian_samples`: a few large Gaussians cover a surface their means alone leave
    gappy); 0 = the means only"""
    hidden_skin_seen: float | None = 1.0
    """the skin's samples at the ends of the Gaussians' axes count only where some view sees them on its
    rendered surface (:func:`.gaussians.surface_views`), at most this many voxels plus their Gaussian's
    own thickness (its smallest standard deviation, at ``hidden_skin_sigmas``) behind it, as the Gaussians'
    means are seen: an axis end that pokes through the seen surface into space no view sees (a long thin
    Gaussian tilted across a table top, under its unseen underside) is no sample of that surface
    (:mod:`.hidden`, "Seen samples"). None = every axis end counts; documented range 0.5-2"""
    hidden_skin_band: float | None = 0.5
    """the skin's Gaussians are those whose centre some view sees at most this many voxels behind its rendered depth
    (:func:`.gaussians.surface_excess`; :mod:`.hidden`, "The skin's band"); None: ``evidence_surface_voxels``'s
    band (1 voxel), the set whose labels count as material evidence. Documented range 0.5-1"""
    hidden_min_open_fraction: float = 0.5
    """a voxel is hidden open space when the rays from it leave the solid without meeting the seen surface in more
    than this share of the 26 lattice directions (a majority; :mod:`.hidden`)"""
    hidden_min_open_half: int | None = 9
    """a voxel is also hidden open space when the rays leave in at least this many of the 9 directions of one half
    (those with a positive, or a negative, step along one of the grid's axes) and in one across it (:mod:`.hidden`,
    "The open half"): the layer under a seen top that the Gaussians of its partly seen underside enclose sideways;
    None = the majority alone; documented range 8-9"""
    hidden_passes: int = 8
    """the rules run again on what they leave, at most this many times in all, until a pass removes nothing: the
    space a pass removed is open to the rays of the next (:mod:`.hidden`, "Passes"); 1 = one pass;
    documented range 1-8"""
    hidden_boundary: Literal["half", "whole"] = "half"
    """how a kept voxel on the boundary with the hidden open space counts in the volume (:mod:`.hidden`, "The
    boundary with hidden open space"): "half", half a voxel, and the mass's Monte Carlo draws its occupancy in
    [0, 1] (the object's unseen surface lies somewhere in it); "whole", a whole voxel"""
    boundary_subsamples: int = 2
    """partial volume (:mod:`.partial`): a voxel on the solid's boundary counts the share of its n x n x n
    sub-points that the vote keeps at the rendered surface (the depth margin a tolerance, not volume); 1 = whole
    voxels by their centres; documented range 2-3"""
    sheet_voxels: float | None = None
    """a face is one side of a sheet where the solid's inscribed half-thickness is at most this many voxels;
    None = the nominal depth margin + 2 (the surface depth keeps both surfaces of a wall, in front of the
    Gaussians' centres on each, so a wall comes out about a voxel thicker than its Gaussians' layers)"""
    min_plate: float = 0.25
    """a sheet face counts half only where the thin solid around it is a plate, not a rod: the second-largest
    spread of its voxels within twice the widest sheet's thickness is at least this times the largest
    (:func:`physgs_nerfstudio.geometry.parts.part_areas`): a rod of a shell's material (a closed tube leg, filled
    because no view sees its inside) is as thin as a two-sided wall but its faces are its one outer side;
    0 = every sheet face counts half"""
    concavity_px: float | None = 3.0
    """a wall face that is no sheet and faces a concavity (empty space that only depth carved, this many pixels of
    the views, and at least 2 voxels, inside the visual hull: a cup's or a pan's inside, the unseen fill's top
    under a cup's rim) is not counted in a hollow part's area: its wall's outer face is
    (:func:`physgs_nerfstudio.geometry.parts.part_areas`). In pixels because the hull is wider than the solid by
    the masks' blur, a few pixels (at 96 px on 2 cores, 5 voxels around the mug); None = every face counts"""
    min_part_fraction: float = 2e-3
    part_materials: Literal["observations", "pooled", "voxels"] = "observations"
    """a part's material mixture: "observations", the Dirichlet fusion of the views' answers about the part, each
    view's answer counted once per part (:mod:`physgs_nerfstudio.geometry.part_evidence`; a part no observation
    reaches falls back to "pooled"); "pooled", from the mean of its Gaussians' Dirichlet posteriors (one piece of
    one material); "voxels", the volume-weighted mean of its voxels' mixtures, each voxel drawing its own material
    (:mod:`physgs_nerfstudio.geometry.parts`, "A part's material")"""
    min_part_observation: float = 0.5
    """``part_materials="observations"``: a part takes its material from the observations when their summed weight
    (level weight x confidence x share of the mask, over views and candidates) reaches this, about half a view's
    answer; else from its Gaussians (``"pooled"``)"""
    absorb_unobserved: bool = True
    """``part_materials="observations"``: a part below ``min_part_observation`` joins the observed part nearest each of
    its voxels (:func:`physgs_nerfstudio.geometry.part_evidence.absorb_unobserved`); False: it keeps its own
    material (pooled from its Gaussians) and structure (the prior)"""
    min_voxel_evidence: float = 0.5
    """a voxel gives its own material mixture when its Gaussians' summed opacity x observed share reaches this
    (:func:`physgs_nerfstudio.geometry.parts.voxel_mixture`); other solid voxels take the nearest such voxel's"""
    evidence_surface_voxels: float | None = 1.0
    """a Gaussian gives its voxel material evidence (``min_voxel_evidence``) only where at least one view sees its
    centre on the rendered surface, at most this many voxels behind the object's rendered depth
    (:func:`.gaussians.surface_excess`). Gaussians under the surface carry the labels that a sliver of blending
    weight through the surface in front of them gave them in the lifting (each view that sees a Gaussian at all
    counts as one observation, :mod:`physgs_nerfstudio.nerfstudio.pipeline`): the GPU shoe's rubber sole, under
    its leather upper, held leather evidence 5-8 mm below the seam, and 22% of its voxels were weighed as the
    upper's hollow inside. None = every labelled Gaussian counts; documented range 0.5-2"""
    interior_up_weight: float = 10.0
    """in the nearest-evidence rule of the solid's inside (:func:`.parts.voxel_mixture`), a vertical distance counts
    this many times a horizontal one, so that an inside voxel takes the material of the observed surface nearest at
    its own height: an object at rest is built in layers (a sole under an upper, a base under a pole, a top on its
    legs), and the boundary between two parts inside it continues the seam seen on its sides. 1: plain Euclidean
    distance. Used only where the views' up direction is within 25 degrees of the grid's z (a capture oriented by
    nerfstudio's dataparser is); elsewhere 1"""
    occluder_min_prob: float | None = None
    """None (the default): the depth and alpha that carve (and the silhouette that cuts the masks) are rendered from
    the selected Gaussians alone. A number: from those plus the others in the selection's box whose object probability
    (:mod:`.select`, step 1) is at least this (opacity at least ``select.min_opacity``, not on the support plane).
    Why: an object's boundary Gaussians carry labels mixed with the background's and fall below the selection's 0.5;
    rendered without them the boundary is see-through, and the depth carves it although the masks keep it (a
    table can lose a rim of a few centimetres of its top). A Gaussian rendered but not selected only withholds depth
    votes. Measured at 0.2 over the CPU suite: the tables' tops are kept and
    coverage rises, but the median volume error rises (more false solid, and the tables' missing legs
    are then made up by excess top), so it is off until measured on the GPU"""
    object_mask_dilate_px: int = 2
    """the object's own silhouette (its Gaussians rendered alone) is dilated by this before it cuts the
    foreground masks, so that other objects in the views do not count as this one"""
    complete_masks: bool = True
    """a view's mask gets back the pieces of the object's rendered silhouette that it misses: the silhouette is the
    consensus of every view's masks, so a part that this view's segmentation dropped is not carved away by it"""
    complete_min_share: float = 0.02
    """... a missed piece counts when its area is at least this share of the silhouette's (smaller ones are the
    silhouette's blur at the boundary, or thin parts the consensus is no surer of than the mask); documented range
    0.01-0.05"""
    min_mask_agreement: float = 0.5
    """IoU between a view's object mask and the object's rendered silhouette below which the view carves with
    the silhouette (:func:`_object_views`)"""
    max_views: int | None = None
    """use at most this many views (evenly spaced); None = all"""
    backend: str = "auto"

    def __post_init__(self) -> None:
        if self.resolution < 8:
            raise ValueError(f"GeometryConfig.resolution must be >= 8, got {self.resolution}.")
        if not 1 <= self.boundary_subsamples <= 8:
            raise ValueError("GeometryConfig.boundary_subsamples must be in 1-8 (1: whole voxels), got "
                             f"{self.boundary_subsamples}.")
        if not 0.0 <= self.extent_outlier_fraction < 0.5:
            raise ValueError("GeometryConfig.extent_outlier_fraction must be in [0, 0.5), got "
                             f"{self.extent_outlier_fraction}.")
        if self.hidden_skin_band is not None and not self.hidden_skin_band >= 0:
            raise ValueError("GeometryConfig.hidden_skin_band must be >= 0 voxels (or None), got "
                             f"{self.hidden_skin_band}.")
        if self.hidden_skin_voxels is not None and self.hidden_skin_voxels < 0:
            raise ValueError("GeometryConfig.hidden_skin_voxels must be >= 0 (or None: keep the hidden space), got "
                             f"{self.hidden_skin_voxels}.")
        if self.occluder_min_prob is not None and not 0 < self.occluder_min_prob <= 1:
            raise ValueError("GeometryConfig.occluder_min_prob must be in (0, 1] (or None: the selected Gaussians "
                             f"alone), got {self.occluder_min_prob}.")
        if self.hidden_skin not in ("centred", "grown"):
            raise ValueError(f"GeometryConfig.hidden_skin must be 'centred' or 'grown', got {self.hidden_skin!r}.")
        if not self.hidden_skin_tolerance > 0 or not self.hidden_skin_sigmas >= 0:
            raise ValueError("GeometryConfig.hidden_skin_tolerance must be > 0 and hidden_skin_sigmas >= 0, got "
                             f"{self.hidden_skin_tolerance} and {self.hidden_skin_sigmas}.")
        if self.hidden_skin_seen is not None and not self.hidden_skin_seen >= 0:
            raise ValueError("GeometryConfig.hidden_skin_seen must be >= 0 (voxels) or None, got "
                             f"{self.hidden_skin_seen}.")
        if not 0.0 <= self.hidden_min_open_fraction < 1.0:
            raise ValueError("GeometryConfig.hidden_min_open_fraction must be in [0, 1), got "
                             f"{self.hidden_min_open_fraction}.")
        if self.extent_shrink_voxels is not None and not (math.isfinite(self.extent_shrink_voxels)
                                                          and self.extent_shrink_voxels > 0):  # fmt: skip
            raise ValueError("GeometryConfig.extent_shrink_voxels must be finite and > 0 (or None: no such variant), "
                             f"got {self.extent_shrink_voxels}.")
        if self.hidden_boundary not in ("half", "whole"):
            raise ValueError("GeometryConfig.hidden_boundary must be 'half' or 'whole', got "
                             f"{self.hidden_boundary!r}.")
        if self.hidden_passes < 1:
            raise ValueError(f"GeometryConfig.hidden_passes must be >= 1, got {self.hidden_passes}.")
        if self.hidden_min_open_half is not None and not 1 <= self.hidden_min_open_half <= 9:
            raise ValueError("GeometryConfig.hidden_min_open_half must be in 1-9 (or None: the majority alone), got "
                             f"{self.hidden_min_open_half}.")
        if self.evidence_surface_voxels is not None and not self.evidence_surface_voxels >= 0:
            raise ValueError("GeometryConfig.evidence_surface_voxels must be >= 0 (or None: every labelled Gaussian "
                             f"counts), got {self.evidence_surface_voxels}.")
