"""Exports of a PhysGS property field: PLY point cloud, voxel grid, property maps, mass report.

The object's geometry lives in :mod:`physgs_nerfstudio.geometry`, the mass in :mod:`physgs_nerfstudio.mass`;
this package writes files and reports. Heavy dependencies (nerfstudio, matplotlib, skimage) are imported by
the functions that need them.
"""

from .field import PropertyField
from .scale import SceneScale, resolve_scale

__all__ = ["PropertyField", "SceneScale", "resolve_scale"]
