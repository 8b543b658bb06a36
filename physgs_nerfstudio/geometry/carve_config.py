"""The carving rule's settings: :class:`CarveConfig` (the rule itself is described in :mod:`.carve`'s module doc;
each view's votes are computed in :mod:`.carve_views`). Its own module so that both can read it without an import
circle."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["CarveConfig"]


@dataclass
class CarveConfig:
    """The carving rule (module doc). The defaults are the nominal geometry; :mod:`.variants` perturbs them."""

    min_votes: int = 2
    """a voxel is empty when at least this many views see through it ..."""
    min_vote_fraction: float = 0.15
    """... and at least this fraction of the views that see it"""
    depth_margin_voxels: float = 0.0
    """a view sees through a voxel when the voxel is nearer than its surface depth less this many voxels ..."""
    depth_slope_margin: float = 1.0
    """... and less this times the depth lookup's error bound there (:func:`.carve_views.depth_slack`: 0 on a
    plane); 0 = off"""
    depth_consensus: float = 0.5
    """a voxel is carved only when its free votes are also at least this fraction of the views that see it near or
    in front of their surface (within ``near_band_voxels`` behind it: module doc, "Depth consensus"); 0 = off (the
    vote alone decides); documented range 0.35-0.65"""
    near_band_voxels: float = 1.0
    """... a view sees a voxel *near* its surface when the voxel lies at most this many voxels (plus the depth
    margin) behind the surface depth, where that depth is sharp (the lookup's slack no wider than the band)"""
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
        if self.depth_margin_voxels < -1:
            raise ValueError(f"CarveConfig.depth_margin_voxels must be >= -1, got {self.depth_margin_voxels}.")
