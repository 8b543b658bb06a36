"""The carving rule's settings: :class:`CarveConfig` (the rule itself is described in :mod:`.carve`'s module doc;
each view's votes are computed in :mod:`.carve_views`). Its own module so that both can read it without an import
circle."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

__all__ = ["EXPECTED_DEPTH_EXTENT", "CarveConfig"]

EXPECTED_DEPTH_EXTENT = 2.0
"""the default ``front_extent`` where the expected depth carves (gsplat): the module doc's k"""


@dataclass
class CarveConfig:
    """The carving rule (module doc). The defaults are the nominal geometry; :mod:`.variants` perturbs them."""

    min_votes: int = 2
    """a voxel is empty when at least this many views see past it ..."""
    min_vote_fraction: float = 0.15
    """... and at least this fraction of the views that see it"""
    mask_margin_px: float = 0.0
    """+: dilate the object masks by this many pixels before carving; -: erode"""
    depth_margin_voxels: float = 0.0
    depth_margin_rel: float = 0.0
    """a voxel is in front of the surface when nearer than depth - (margin_voxels * voxel + margin_rel * depth)"""
    depth_lookup: Literal["bilinear", "nearest"] = "bilinear"
    """how the rendered depth is read at a voxel's projection: interpolated between the opaque pixels around it,
    or the depth of the pixel that holds it"""
    depth_slope_margin: float = 1.0
    """... plus this times the lookup's error bound at that pixel (:func:`depth_slack`: 0 on a plane with the
    bilinear lookup; half a pixel's depth change with the nearest); 0 = off"""
    min_alpha: float = 0.5
    """pixels less opaque than this do not carve by depth"""
    depth_render: Literal["auto", "expected", "median", "first"] = "auto"
    """the rendered depth that carves (module doc, "First surface"): "expected", the blending-weighted mean of the
    Gaussians' depths; "median", the depth where the transmittance crosses 1/2; "first", the expected depth
    except where it lies more than ``mixed_depth_voxels`` behind the median (the pixel mixes surfaces), the
    median there; "auto" (:func:`resolve_depth_render`): the median where the depth is rendered by the reference
    rasterizer (CPU), the expected depth with gsplat (CUDA)"""
    mixed_depth_voxels: float = 1.0
    """"first": a pixel mixes surfaces when its expected depth lies this many voxels behind its median depth"""
    front_spread: float = 0.0
    """carve by depth only in front of depth - this times the pixel's depth spread about a plane
    (:func:`.gaussians.depth_spread`): a front-surface estimate where a pixel mixes surfaces (module doc,
    "First surface"); 0 = the expected depth"""
    max_spread_voxels: float = float("inf")
    """pixels whose depth spread exceeds this many voxels do not carve by depth (their depth is no surface)"""
    front_extent: float | None = None
    """carve with the rendered depth moved this many of its pixel's blended along-ray extents
    (:func:`.gaussians.ray_extent`) towards the camera (module doc, "The Gaussians' depth"); 0 = the depth as
    rendered; None (default): :data:`EXPECTED_DEPTH_EXTENT` (2) with the expected depth, 0 with the median and
    "first" depths, which already lie in front of the centres (:meth:`extent_multiple`)"""
    min_direct_fraction: float = 2.0
    """... or at least this fraction of the views that see it directly see past it by depth (module doc);
    > 1 (the default) switches the direct rule off: over the generated suite it carved the space under objects
    but also thin bottoms that only a few poorly reconstructed low views see (a higher median APE with 0.5 than
    without). 0.5 is the setting to try for a capture with views from below"""
    depth_consensus: float = 0.5
    """a voxel that the silhouette votes alone do not carve is carved only when its depth votes are at least this
    fraction of the views that see it near or in front of their rendered surface (within ``near_band_voxels``
    behind it: module doc, "Depth consensus"); 0 = off (the vote alone decides); documented range 0.35-0.65"""
    near_band_voxels: float = 1.0
    """... a view sees a voxel *near* its surface when the voxel lies at most this many voxels (plus the depth
    margin) behind the rendered depth, where that depth is sharp (the lookup's slack, :func:`depth_slack`, no wider
    than the band) ..."""
    near_inset_px: float = 1.0
    """... and the voxel projects at least this many pixels inside the view's mask: a view that has the voxel on its
    silhouette's edge pixels, whose depth is the edge's, has no say"""
    use_depth: bool = True
    min_seen_fraction: float = 0.5
    """a voxel that fewer than this fraction of the views have in their image is empty: an object-centric capture
    frames its object in every view, so space out of frame in most views is not the object (left solid, as unseen
    space inside the object is, it filled a domain that outliers of the selection had stretched); lower it for a
    capture whose views each show only part of the object"""
    min_component: float = 0.02
    """drop solid components smaller than this fraction of the largest one"""
    fill_cavities: bool = True
    """fill empty pockets that the solid encloses completely (module doc)"""

    def __post_init__(self) -> None:
        if self.min_votes < 1:
            raise ValueError(f"CarveConfig.min_votes must be >= 1, got {self.min_votes}.")
        if not 0 <= self.min_vote_fraction <= 1:
            raise ValueError(f"CarveConfig.min_vote_fraction must be in [0, 1], got {self.min_vote_fraction}.")
        if self.front_extent is not None and not self.front_extent >= 0:
            raise ValueError(f"CarveConfig.front_extent must be >= 0 (or None: by the depth), got {self.front_extent}.")
        if self.depth_margin_voxels < -1 or self.depth_margin_rel < 0:
            raise ValueError(f"CarveConfig: depth_margin_voxels must be >= -1 and depth_margin_rel >= 0, got "
                             f"{self.depth_margin_voxels} and {self.depth_margin_rel}.")

    def extent_multiple(self) -> float:
        """``front_extent`` resolved: as set, or (None) :data:`EXPECTED_DEPTH_EXTENT` where the depth that
        carves is the expected depth, else 0 (an unresolved ``depth_render="auto"`` carves with the median
        where the render has one)."""
        if self.front_extent is not None:
            return float(self.front_extent)
        return EXPECTED_DEPTH_EXTENT if self.depth_render == "expected" else 0.0
