"""The object's contact with what it stands on, from perception's names: a stand, a plinth, a table top, the floor.

The support plane (:mod:`.support`) is the floor or table that the splat shows as a wide level plane around the
object. A stand, a plinth or a coaster is no such plane: it is a solid narrower than what stands on it, which
geometry alone cannot tell from the object's own foot (a lamp's base, a bowl's foot ring), and the views keep it
with the object because the two touch. Perception can: it names the whole object of every part it is shown
(``object`` in observations.jsonl: "stand" for the stand, "bowl" for the bowl on it).

1. **Names per pixel** (:func:`object_labels`): each view's pixels take the name of the finest mask holding them
   (subpart over part over whole).
2. **Names per surface voxel** (:func:`surface_names`): a voxel on the boundary of the kept space takes, in each
   view that sees it on its rendered surface (its centre within :data:`SURFACE_BAND` voxels of the whole splat's
   surface depth at its pixel), that pixel's name; its name is the one most of those views give.
3. **The contact** (:func:`contact_cut`): an object rests on its support, so the cut is the level along the views'
   up direction that best separates the surface named for the object, above it, from the surface named for
   anything else, below it (the threshold that puts the most surface voxels on their name's side). The object's
   name is the one most of the top :data:`TOP_SHARE` of the surface has: what stands on a support is above it, and a
   stand can have more surface than the mug on it. The cut is made only when it puts at least :data:`MIN_GAIN` of the
   surface on its side beyond what no cut does: a wrong name here and there (a real model's slips, mixed masks at
   the contact) never pays for a cut, a stand's whole surface does.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from jaxtyping import Bool, Float, Int
from torch import Tensor

from .capture import CaptureView, MaskObservation
from .grid import VoxelGrid
from .support import SupportPlane

__all__ = ["MIN_GAIN", "SURFACE_BAND", "TOP_SHARE", "Contact", "ObjectLabels", "contact_cut", "object_labels", "surface_names"]

SURFACE_BAND = 1.5
"""a voxel is on a view's rendered surface when its centre lies within this many voxels of the surface depth at its
pixel: half a voxel's diagonal (0.87) plus the surface depth's own scatter of about half a voxel"""

MIN_GAIN = 0.05
"""the least share of the named surface voxels that a cut must put on their name's side beyond no cut. On the
development families' CPU runs a stand gains 0.25-0.35 and an object standing on a floor or a table 0-0.01 (the
simulated model names another object in 10% of its answers, at random)"""

TOP_SHARE = 0.25
"""the object's name is the one most of this share of the named surface, the highest, has: on the development
families' stands the stand held up to 60% of the kept surface, never the top quarter"""

_LEVEL_ORDER = {"whole": 0, "part": 1, "subpart": 2}


@dataclass
class ObjectLabels:
    names: list[str]
    """the object names the answers gave, in order of first appearance"""
    maps: list[Int[Tensor, "H W"] | None]
    """per view (in the views' order): each pixel's name index (-1: none) at the view's size; None: no named mask"""


@dataclass
class Contact:
    """Where the object stands on another named object (:func:`contact_cut`)."""

    plane: SupportPlane
    """the cut: the object is what lies above it"""
    object_name: str
    """the name most of the top of the surface has"""
    below: str
    """the name most of the surface below the cut has"""
    gain: float
    """the share of the named surface voxels that the cut puts on their side beyond no cut"""


def object_labels(views: Sequence[CaptureView], observations: Sequence[MaskObservation]) -> ObjectLabels:
    """Step 1 of the module doc: each view's pixels labelled with the object named for the finest mask holding them
    (observations whose view is not among ``views``, or that name no object, are skipped)."""
    names: list[str] = []
    index: dict[str, int] = {}
    by_view: dict[str, dict[int, MaskObservation]] = {}
    for ob in observations:
        if ob.object is None:
            continue
        if ob.object not in index:
            index[ob.object] = len(names)
            names.append(ob.object)
        by_view.setdefault(ob.view, {}).setdefault(ob.mask_id if ob.mask_id is not None else id(ob.mask), ob)
    maps: list[Tensor | None] = []
    for v in views:
        obs = sorted(by_view.get(v.name, {}).values(), key=lambda o: _LEVEL_ORDER.get(o.level, 1))
        if not obs:
            maps.append(None)
            continue
        lab = torch.full(obs[0].mask.shape, -1, dtype=torch.long)
        for ob in obs:  # coarse first: the finer masks paint over
            lab[torch.as_tensor(np.array(ob.mask, dtype=bool))] = index[ob.object]  # type: ignore[index]
        if tuple(lab.shape) != (v.height, v.width):
            lab = torch.nn.functional.interpolate(lab[None, None].float(), size=(v.height, v.width),
                                                  mode="nearest")[0, 0].long()  # fmt: skip
        maps.append(lab)
    return ObjectLabels(names, maps)


@torch.no_grad()
def surface_names(x: Float[Tensor, "N 3"], views: Sequence[CaptureView], depths: Sequence[Tensor],
                  labels: ObjectLabels, band: float) -> Float[Tensor, "N K"]:  # fmt: skip
    """Step 2 of the module doc: per point, how many views see it on their rendered surface (within ``band``, scene
    units, of ``depths``: each view's surface depth) on a pixel of each name."""
    k = len(labels.names)
    votes = torch.zeros(len(x), k, dtype=torch.float32)
    for v, depth, lab in zip(views, depths, labels.maps):
        if lab is None or not len(x):
            continue
        c = x.float() @ v.viewmat[:3, :3].T.float() + v.viewmat[:3, 3].float()
        z = c[:, 2]
        zs = z.clamp_min(1e-9)
        u = v.K[0, 0] * c[:, 0] / zs + v.K[0, 2]
        w = v.K[1, 1] * c[:, 1] / zs + v.K[1, 2]
        ok = (z > 0) & (u >= 0) & (u < v.width) & (w >= 0) & (w < v.height)
        ui, vi = u.floor().long().clamp(0, v.width - 1), w.floor().long().clamp(0, v.height - 1)
        name = lab[vi, ui]
        ok &= (name >= 0) & ((z - depth.cpu()[vi, ui].float()).abs() <= band)
        votes.index_put_((torch.nonzero(ok).squeeze(1), name[ok]), torch.ones(int(ok.sum())), accumulate=True)
    return votes


def _best_cut(height: np.ndarray, name: np.ndarray, k: int) -> tuple[float, float]:
    """(level, gain): the threshold on ``height`` that puts the most points named ``k`` above it and the most others
    below it, and the share of points it puts right beyond no cut (-inf and 0: no cut does best)."""
    order = np.argsort(height, kind="stable")
    h, own = height[order], name[order] == k
    right = np.concatenate([[0], np.cumsum(~own)]) + np.concatenate([np.cumsum(own[::-1])[::-1], [0]])
    right[1:-1][h[1:] == h[:-1]] = -1  # points of one height stay on one side
    i = int(right.argmax())  # the cut between sorted points i - 1 and i
    if i == 0:
        return -np.inf, 0.0
    level = np.nextafter(h[-1], np.inf) if i == len(h) else 0.5 * (h[i - 1] + h[i])
    return float(level), float(right[i] - right[0]) / len(h)


def contact_cut(grid: VoxelGrid, solid: Bool[np.ndarray, "X Y Z"], views: Sequence[CaptureView],
                depths: Sequence[Tensor], labels: ObjectLabels, up: np.ndarray) -> Contact | None:  # fmt: skip
    """Step 3 of the module doc: the level above which ``solid`` is the object (None: no other object under it, or
    perception named none)."""
    from scipy import ndimage  # lazily: a PLY-only export needs no SciPy

    if len(labels.names) < 2 or not solid.any():
        return None
    shell = solid & ~ndimage.binary_erosion(solid, structure=np.ones((3, 3, 3), bool))
    idx = np.argwhere(shell)
    x = torch.from_numpy(np.asarray(grid.origin, dtype=np.float64) + (idx + 0.5) * grid.voxel_size)
    votes = surface_names(x, views, depths, labels, SURFACE_BAND * grid.voxel_size)
    named = votes.sum(1) > 0
    if int(named.sum()) == 0:
        return None
    name = votes[named].argmax(1).numpy()
    height = x[named].numpy() @ np.asarray(up, dtype=np.float64)
    top = height >= np.quantile(height, 1.0 - TOP_SHARE)
    k = int(np.bincount(name[top], minlength=len(labels.names)).argmax())
    level, gain = _best_cut(height, name, k)
    if gain < MIN_GAIN:
        return None
    below = name[height < level]
    other = np.bincount(below[below != k], minlength=len(labels.names)).argmax()
    plane = SupportPlane(np.asarray(up, dtype=np.float64), level, grid.voxel_size, gain)
    return Contact(plane, labels.names[k], labels.names[int(other)], gain)
