"""The geometry's one error: the object could not be reconstructed from this run's views (a property of the data,
not a bug), so a caller can still write what does not need the geometry."""

from __future__ import annotations

from ..errors import PhysGSError

__all__ = ["GeometryError"]


class GeometryError(PhysGSError, ValueError):
    """No object to measure: no Gaussian on the masks, no training view, or carving left no solid voxel."""
