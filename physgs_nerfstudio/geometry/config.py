"""How the object's geometry is recovered: :class:`GeometryConfig`, the options of
:func:`.reconstruct.reconstruct_object` (selection, carving, hidden space, parts, structure and the variants that
sample the geometry in the mass interval). What each rule does: docs/architecture.md, "Mass geometry"; the
measurements that chose the defaults: CHANGELOG.md and benchmarks/results/mass_stability_cpu.json."""

from __future__ import annotations

from dataclasses import dataclass, field

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
    vote_variants: tuple[tuple[int, float], ...] = ((1, 0.1), (3, 0.25))
    """(min_votes, min_vote_fraction) pairs"""
    depth_margin_variants: tuple[float, ...] = (-0.5, 1.0)
    """depth margins in voxels (negative: also carve up to that much behind the rendered surface)"""
    pad_fraction: float = 0.1
    """domain padding around the object's Gaussians, as a fraction of their extent"""
    refit_fraction: float = 0.5
    """when the carved solid's longest side is below this fraction of the domain's, carve again on a grid fitted to
    the solid (outliers of the selection stretched the domain and coarsened the voxels)"""
    extent_pad_voxels: float = 0.0
    """the solid is cut to the support polytope of the object's seen Gaussians grown by this many voxels
    (the object's extent, :mod:`.gaussians`: space under an object that no view sees past is not the object).
    0: the outermost Gaussians lie on or, by their scatter, beyond the surface, and a voxel counts when its centre
    is in"""
    extent_outlier_fraction: float = 0.001
    """along each direction the polytope skips this share of the outermost Gaussians
    (:func:`.gaussians.support_heights`), so that a few strays under an unseen bottom face do not set where the solid ends; documented range 0-0.003"""
    extent_variant_voxels: float = 1.0
    """the interval also samples the nominal carving cut to the polytope grown by this many voxels (where the
    polytope ends the solid, a few Gaussians' scatter places the surface to about a voxel)"""
    hidden_skin_voxels: int = 2
    """the solid loses its *hidden open space* (:mod:`.hidden`: space no view could carve that no seen surface
    encloses, such as under a table top); the skin closes the gaps between its samples over this many voxels each
    way; documented range 2-3"""
    hidden_skin_tolerance: float = 1.5
    """a voxel is skin when the samples around it have their centroid within this many voxels of its centre (half
    the skin's thickness across a surface); documented range 1.25-2"""
    hidden_skin_seen: float = 1.0
    """an axis end samples the skin only where some view sees it on its rendered surface, within this many voxels
    plus its Gaussian's own thickness (:mod:`.hidden`, "Seen samples"); documented range 0.5-2"""
    hidden_skin_band: float = 0.5
    """the skin's Gaussians: those whose centre some view sees at most this many voxels behind its rendered depth
    (:mod:`.hidden`, "The skin's band"); documented range 0.5-1"""
    hidden_min_open_half: int = 9
    """... or in at least this many of the 9 directions of one half and one across it (:mod:`.hidden`, "The open
    half"); documented range 8-9"""
    concavity_px: float = 3.0
    """a wall face that is no sheet and faces a concavity (empty space that only depth carved, this many pixels and
    at least 2 voxels inside the visual hull: a cup's inside) is not counted in a hollow part's area (its outer face
    is; :func:`.walls.part_areas`); in pixels because the hull is wider than the solid by the masks' blur"""
    min_part_fraction: float = 2e-3
    """parts smaller than this share of the solid are pooled into one last part (:func:`.parts.part_labels`)"""
    min_part_observation: float = 0.5
    """a part takes its material from the observations when their summed weight (level x confidence x share of the
    mask) reaches this, about half a view's answer; below it, it joins the observed part nearest each voxel"""
    min_voxel_evidence: float = 0.5
    """a voxel gives its own material mixture when its Gaussians' summed opacity x observed share reaches this
    (:func:`.parts.voxel_mixture`); other solid voxels take the nearest such voxel's"""
    evidence_surface_voxels: float = 1.0
    """a Gaussian's labels count as material evidence only where some view sees its centre at most this many voxels
    behind the rendered surface (:func:`.gaussians.surface_excess`): one under the surface took the labels of the
    surface in front of it through a sliver of blending weight; documented range 0.5-2"""
    interior_up_weight: float = 10.0
    """inside the solid a voxel takes the material of the nearest observed voxel, a vertical distance counting this
    many times a horizontal one (an object at rest is built in layers, so the seam inside it continues the one seen
    on its sides); used where the views' up is within 25 degrees of the grid's z; 1 = Euclidean"""
    object_mask_dilate_px: int = 2
    """the object's own silhouette (its Gaussians rendered alone) is dilated by this many pixels before it cuts the
    foreground masks, so that other objects in the views do not count as this one"""
    backend: str = "auto"

    def __post_init__(self) -> None:
        if self.resolution < 8:
            raise ValueError(f"GeometryConfig.resolution must be >= 8, got {self.resolution}.")
        if not 0.0 <= self.extent_outlier_fraction < 0.5:
            raise ValueError("GeometryConfig.extent_outlier_fraction must be in [0, 0.5), got "
                             f"{self.extent_outlier_fraction}.")
        if not self.hidden_skin_band >= 0:
            raise ValueError("GeometryConfig.hidden_skin_band must be >= 0 voxels, got "
                             f"{self.hidden_skin_band}.")
        if self.hidden_skin_voxels < 0:
            raise ValueError(f"GeometryConfig.hidden_skin_voxels must be >= 0, got {self.hidden_skin_voxels}.")
        if not self.hidden_skin_tolerance > 0:
            raise ValueError(f"GeometryConfig.hidden_skin_tolerance must be > 0, got {self.hidden_skin_tolerance}.")
        if not self.hidden_skin_seen >= 0:
            raise ValueError(f"GeometryConfig.hidden_skin_seen must be >= 0 voxels, got {self.hidden_skin_seen}.")
        if not 1 <= self.hidden_min_open_half <= 9:
            raise ValueError("GeometryConfig.hidden_min_open_half must be in 1-9, got "
                             f"{self.hidden_min_open_half}.")
        if not self.min_voxel_evidence > 0:  # a voxel with none would divide its mixture by zero
            raise ValueError(f"GeometryConfig.min_voxel_evidence must be > 0, got {self.min_voxel_evidence}.")
        if not self.evidence_surface_voxels >= 0:
            raise ValueError(f"GeometryConfig.evidence_surface_voxels must be >= 0, got {self.evidence_surface_voxels}.")
