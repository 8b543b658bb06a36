"""Single-image mode (`physgs image`): dense per-pixel material, property and uncertainty maps of one
photograph (the paper's fabric, terrain and outdoor results), from masks at three levels, one cached VLM
query per mask and Bayesian fusion over the image's masks and levels.

``run_single_image(SingleImageConfig(path=...))`` is the entry point; ``ImageCommand`` the subcommand.
"""

from .maps import NPZ_KEYS, ImageMaps, compute_image_maps
from .pipeline import ImageResult, SingleImageConfig, SingleImageResult, run_single_image

__all__ = [
    "NPZ_KEYS",
    "ImageMaps",
    "ImageResult",
    "SingleImageConfig",
    "SingleImageResult",
    "compute_image_maps",
    "run_single_image",
]
