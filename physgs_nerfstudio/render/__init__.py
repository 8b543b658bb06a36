"""Gaussian rasterization: gsplat on CUDA, a pure-torch reference rasterizer on CPU (same call shape)."""

from .backend import BACKENDS, Backend, rasterize, resolve_backend
from .reference import reference_rasterization, reference_surface_depth
from .sh import eval_sh_colors

__all__ = ["BACKENDS", "Backend", "eval_sh_colors", "rasterize", "reference_rasterization", "reference_surface_depth",
           "resolve_backend"]
