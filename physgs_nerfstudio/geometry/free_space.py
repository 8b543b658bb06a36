"""The views' free space: what the carving votes on (:mod:`.carve`) and which of the space it leaves is the object.

**Free space.** A view's pixel sees through every point in front of the whole splat's surface depth along its ray
(:func:`.gaussians.render_depth`, where the ray's transmittance first crosses
:data:`.gaussians.SURFACE_TRANSMITTANCE`), and through every point of a ray that never loses that much light (no
surface: the background, the sky). The carving counts those *free* votes per voxel; a voxel that enough views see
through is empty, and every other voxel is occupied (inside the surface the views agree on) or unseen (behind every
view's surface). The object masks do not carve: the built-in segmenter's whole-object masks are precise but
incomplete (on the 16 path-traced development families, one scene each, the families' median precision is 0.91 and
median recall 0.80, and in 11 of them some views hold less than half the object, up to 15 of 16 views), and a part
that a few views' masks miss is carved away by a silhouette vote, while the splat renders it in every view. A floater
blocks only the rays that pass it, and the vote's fraction (:class:`.carve_config.CarveConfig`) keeps the space it
hides from a few views empty.

**Which of it is the object.** The space the views leave holds the object, its support (cut at the support plane,
:mod:`.support`) and whatever else stands in the grid's box. The object is the connected components of it that hold
the selected Gaussians (:mod:`.select`, from the masks: the masks say *which* surface is the object, the free space
says *where* it ends): a component holding at least :data:`MIN_SEED_SHARE` of the selected Gaussians' centres.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch import Tensor

from .capture import CaptureView
from .gaussians import render_depth
from .grid import VoxelGrid

__all__ = ["MIN_SEED_SHARE", "SEES_THROUGH", "free_space_depths", "seeded_components"]

SEES_THROUGH = 1e30
"""the depth given to a pixel whose ray never reaches the surface transmittance: every point along it is free"""

MIN_SEED_SHARE = 0.01
"""a component of the occupied space is the object's when it holds at least this share of the selected Gaussians'
centres: a stray selected Gaussian in another object's component (the support's edge, a neighbour) does not bring that
component in, while an object's separate parts (a lid, a wheel) each hold far more than 1% of them"""


@torch.no_grad()
def free_space_depths(g: Any, views: Sequence[CaptureView], backend: str = "auto") -> list[Tensor]:
    """float [H, W] per view: the whole splat's surface depth as the carving reads it (module doc), where a pixel with
    no surface sees through (at :data:`SEES_THROUGH`, so that every point on its ray is in front of it)."""
    out = []
    for r in render_depth(g, views, backend=backend):
        out.append(torch.where(torch.isfinite(r.depth), r.depth, torch.full_like(r.depth, SEES_THROUGH)))
    return out


def seeded_components(grid: VoxelGrid, solid: np.ndarray, seeds: Tensor) -> np.ndarray:
    """bool [X, Y, Z]: the 26-connected components of ``solid`` that hold at least :data:`MIN_SEED_SHARE` of the
    points ``seeds`` [N, 3] that fall in a solid voxel (module doc); ``solid`` itself when none does."""
    from scipy import ndimage  # lazily: a PLY-only export needs no SciPy

    lab, n = ndimage.label(solid, structure=np.ones((3, 3, 3), bool))
    if n == 0:
        return solid
    idx = grid.index_of(seeds.detach().double()).cpu().numpy()
    inside = ((idx >= 0) & (idx < np.asarray(grid.shape))).all(1)
    hits = lab[tuple(idx[inside].T)]
    counts = np.bincount(hits, minlength=n + 1)
    counts[0] = 0
    if counts.sum() == 0:
        return solid
    keep = counts >= MIN_SEED_SHARE * counts.sum()
    keep[0] = False
    return keep[lab]
