"""Exports of a PhysGS property field: PLY point cloud, voxel grid, property maps, mass with uncertainty.

Heavy dependencies (nerfstudio, matplotlib, skimage) are imported by the functions that need them.
"""

from .field import PropertyField
from .mass import MassConfig, MassGeometry, MassReport, MaterialMass, integrate_mass, mass_geometry
from .occupancy import Occupancy, OccupancyConfig, compute_occupancy
from .scale import SceneScale, resolve_scale

__all__ = [
    "MassConfig",
    "MassGeometry",
    "MassReport",
    "MaterialMass",
    "Occupancy",
    "OccupancyConfig",
    "PropertyField",
    "SceneScale",
    "compute_occupancy",
    "integrate_mass",
    "mass_geometry",
    "resolve_scale",
]
