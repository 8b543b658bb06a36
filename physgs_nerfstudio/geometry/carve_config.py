"""The carving rule's settings: :class:`CarveConfig` (the rule itself is described in :mod:`.carve`'s module doc;
each view's votes are computed in :mod:`.carve_views`). Its own module so that both can read it without an import
circle."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from .gaussians import SURFACE_TRANSMITTANCE

__all__ = ["CarveConfig"]


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
    """pixels less opaque than this do not carve by depth; at least ``1 - SURFACE_TRANSMITTANCE``
    (:data:`.gaussians.SURFACE_TRANSMITTANCE`), under which a pixel has no surface depth"""
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
        if not 1 - SURFACE_TRANSMITTANCE <= self.min_alpha <= 1:
            raise ValueError(f"CarveConfig.min_alpha must be in [{1 - SURFACE_TRANSMITTANCE:g}, 1] (a pixel less "
                             f"opaque has no surface depth), got {self.min_alpha}.")
        if self.depth_margin_voxels < -1 or self.depth_margin_rel < 0:
            raise ValueError(f"CarveConfig: depth_margin_voxels must be >= -1 and depth_margin_rel >= 0, got "
                             f"{self.depth_margin_voxels} and {self.depth_margin_rel}.")
