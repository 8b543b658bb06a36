"""Which object perception says each pixel belongs to, and the selected Gaussians that belong to another.

The VLM names the whole object of every part it is shown (``object`` in observations.jsonl: "table" for a table's
leg, "mug" for the mug standing on the table; the simulated VLM from the generated scene's truth, with
``p_object_error``). The segmenter's masks cannot separate objects that touch in the images: a mug on a table is
one connected region of the foreground, and in 3-D the mug stands on the top, one cluster with it. Its part masks
do isolate it, and the answers about them name it.

1. Label maps (:func:`object_labels`): in each view, each pixel takes the object named for the finest mask that
   holds it (``subpart`` over ``part`` over ``whole``: a ``whole`` mask of the table and the mug is named "table"
   after its largest part, its ``part`` mask of the mug "mug"). Pixels no named mask holds have no label.
2. Lifting (:func:`.gaussians.lift_masks_and_labels`, in the rasterizer calls of the foreground's lifting): per
   Gaussian and name, the share of its blending weight on that name's pixels, summed over the views that see it.
3. The object's name is the one with the most evidence over the chosen cluster's Gaussians. A selected Gaussian
   belongs to another object when one other name's evidence exceeds the object's name's by more than ``prior``
   views (:func:`other_object`, ``SelectConfig.object_names``): a single wrong answer, or two names split evenly,
   never removes a Gaussian; a mug that most of the views which see it name "mug" goes.

Off by default (``SelectConfig.object_names`` = None): with the built-in segmenter's masks, on three GPU
`indoor_room` captures (60 views, 512 px), the names drop the table's own Gaussians, not the mug's
(:mod:`.select`, step 3b).

A real VLM may name one object two ways ("table", "desk"); both then hold the table's evidence, and its parts that
most views call "desk" would go. The prompt asks for the whole object's name in one or two words, and the answers
are normalised (lower case, no article or punctuation: :func:`..perception.validate.object_name`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from jaxtyping import Bool, Float, Int
from torch import Tensor

from .capture import CaptureView, MaskObservation

__all__ = ["ObjectLabels", "object_labels", "other_object"]

_LEVEL_ORDER = {"whole": 0, "part": 1, "subpart": 2}


@dataclass
class ObjectLabels:
    names: list[str]
    """the object names the answers gave, in order of first appearance"""
    maps: list[Int[Tensor, "H W"] | None]
    """per view (in the views' order): each pixel's name index (-1: none) at the view's size; None: no named mask"""


def object_labels(views: Sequence[CaptureView], observations: Sequence[MaskObservation]) -> ObjectLabels:
    """Step 1 of the module doc: each view's pixels labelled with the object named for the finest mask holding
    them (observations whose view is not among ``views``, or that name no object, are skipped)."""
    names: list[str] = []
    index: dict[str, int] = {}
    by_view: dict[str, dict[int | None, MaskObservation]] = {}
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
            lab[torch.from_numpy(ob.mask)] = index[ob.object]  # type: ignore[index]
        if tuple(lab.shape) != (v.height, v.width):
            lab = torch.nn.functional.interpolate(lab[None, None].float(), size=(v.height, v.width),
                                                  mode="nearest")[0, 0].long()  # fmt: skip
        maps.append(lab)
    return ObjectLabels(names, maps)


def other_object(counts: Float[Tensor, "N K"], selected: Bool[Tensor, " N"], prior: float
                 ) -> tuple[int | None, Bool[Tensor, " N"]]:  # fmt: skip
    """Step 3 of the module doc: the object's name (index into the names; None without evidence) over the
    ``selected`` Gaussians' ``counts`` (per Gaussian and name, views' worth of evidence), and the selected
    Gaussians one other name claims by more than ``prior`` views."""
    none = torch.zeros_like(selected)
    if counts.shape[1] == 0 or not bool(selected.any()):
        return None, none
    total = counts[selected].sum(0)
    if not float(total.max()) > 0:
        return None, none
    k = int(total.argmax())
    if counts.shape[1] == 1:
        return k, none
    others = counts.clone()
    others[:, k] = -1.0
    return k, selected & (others.amax(1) > counts[:, k] + prior)
