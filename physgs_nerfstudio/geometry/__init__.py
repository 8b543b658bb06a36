"""The object's geometry for mass: which Gaussians are the object (from the views' masks), its volume carved from
the views' free space (the whole splat's depth), its parts, their wall areas and whether each is solid or hollow
(docs/architecture.md, "Mass geometry"). Pure geometry on tensors and arrays: no nerfstudio imports."""

from .capture import CaptureView, MaskObservation, load_capture, load_observations
from .carve import CarveConfig
from .grid import GeometryError, VoxelGrid
from .reconstruct import GeometryConfig, ObjectGeometry, reconstruct_object
from .select import SelectConfig
from .structure import StructureConfig

__all__ = [
           "CaptureView",
           "CarveConfig",
           "GeometryConfig",
           "GeometryError",
           "MaskObservation",
           "ObjectGeometry",
           "SelectConfig",
           "StructureConfig",
           "VoxelGrid",
           "load_capture",
           "load_observations",
           "reconstruct_object",
]
