"""Fusion of VLM observations: per-material NIG property posteriors (properties.py), per-view
per-pixel Dirichlet material maps (maps.py) and writing them into a nerfstudio dataset (writer.py)."""

from .maps import MapFusionConfig, ViewMaps, fuse_view
from .properties import PropertyPosteriors, fuse_properties, legend_names, posterior_means
from .writer import materials_document, update_transforms, write_materials_json, write_view_maps

__all__ = [
    "MapFusionConfig",
    "PropertyPosteriors",
    "ViewMaps",
    "fuse_properties",
    "fuse_view",
    "legend_names",
    "materials_document",
    "posterior_means",
    "update_transforms",
    "write_materials_json",
    "write_view_maps",
]
