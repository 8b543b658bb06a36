"""Rasterizer dispatch: gsplat's CUDA rasterizer for CUDA tensors, the pure-torch reference elsewhere."""

from __future__ import annotations

from typing import Any, Literal

import torch
from torch import Tensor

from .reference import reference_rasterization

Backend = Literal["auto", "gsplat", "reference"]
BACKENDS = ("auto", "gsplat", "reference")


def resolve_backend(backend: Backend, device: torch.device) -> Literal["gsplat", "reference"]:
    """The backend that `rasterize` will use for tensors on `device`."""
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if backend == "auto":
        return "gsplat" if device.type == "cuda" else "reference"
    if backend == "gsplat" and device.type != "cuda":
        raise RuntimeError(
            f"backend='gsplat' needs CUDA tensors (got device {device}); gsplat's rasterizer is CUDA-only. "
            "Use backend='reference' (or 'auto') to rasterize on the CPU."
        )
    return backend


def rasterize(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    colors: Tensor,
    viewmats: Tensor,
    Ks: Tensor,
    width: int,
    height: int,
    *args: Any,
    backend: Backend = "auto",
    **kwargs: Any,
) -> tuple[Tensor, Tensor, dict[str, Any]]:
    """`gsplat.rasterization` (same arguments and return) on the chosen backend.

    "auto": gsplat for CUDA tensors, the reference rasterizer otherwise. gsplat is imported lazily.
    Reference-only keyword arguments (e.g. `max_pairs`) are dropped when gsplat runs.
    """
    which = resolve_backend(backend, means.device)
    if which == "gsplat":
        from gsplat import rasterization  # lazy: importing is cheap but keeps CPU paths gsplat-free

        from .gsplat_build import prepare_gsplat, record_gsplat_build

        prepare_gsplat()  # an earlier build of the same sources loads without ninja (gsplat_build.py)
        kwargs.pop("max_pairs", None)
        out = rasterization(means, quats, scales, opacities, colors, viewmats, Ks, width, height, *args, **kwargs)
        record_gsplat_build()
        return out
    return reference_rasterization(means, quats, scales, opacities, colors, viewmats, Ks, width, height,
                                   *args, **kwargs)  # fmt: skip
