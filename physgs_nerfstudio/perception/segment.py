"""Part masks at three granularities (paper sec. 3.4 "Semantic Segmentation").

One protocol, :class:`Segmenter`: ``segment(image: uint8 [H, W, 3]) -> list[Mask]``. This module holds the
protocol, the mask type, the shared mask operations and mask persistence; the two implementations live in
their own modules and are built by their configs' ``setup()`` (the one segmenter factory):

* ``sam`` (:class:`.segment_sam.SamSegmenter`): segment-anything's automatic mask generator from a local checkpoint
  (optional extra: ``pip install -e ".[sam]"``). SAM's own predicted IoU and stability scores filter the
  masks; levels come from the containment hierarchy (a mask inside no other mask is "whole", a mask inside
  a mask that is itself contained is "subpart", the rest "part").
* ``builtin`` (:class:`.segment_builtin.BuiltinSegmenter`): no weights. SLIC superpixels merged on their region adjacency
  graph by mean colour (scikit-image) at a coarse, a medium and a fine threshold give the "whole", "part"
  and "subpart" levels; regions dominating the image border are treated as background. Its ``predicted_iou`` and ``stability`` are HEURISTICS with
  the same meaning of "higher is better" but not SAM's learned quantities (see the class docstring).
  It is much weaker than SAM on real photographs (textured parts split, low-contrast parts merge); it
  exists so the pipeline runs anywhere, and it is adequate for generated scenes with flat-coloured parts.

Both deduplicate masks by IoU (greedy, best score first) and drop masks below a minimum area.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Protocol

import numpy as np

logger = logging.getLogger(__name__)

Level = Literal["whole", "part", "subpart"]
LEVELS: tuple[str, ...] = ("whole", "part", "subpart")

SAM_INSTALL_HINT = (
    'The "sam" segmenter needs the optional package segment-anything: pip install -e ".[sam]" '
    "(or pip install segment-anything), then choose segmenter:sam --segmenter.checkpoint PATH to a SAM "
    "checkpoint (e.g. sam_vit_h_4b8939.pth) and --segmenter.model-type vit_h|vit_l|vit_b. "
    "Use segmenter:builtin (the default) to run without SAM."
)


@dataclass
class Mask:
    """One region of an image."""

    segmentation: np.ndarray
    """bool [H, W]."""
    area: int
    predicted_iou: float
    """SAM's predicted IoU, or the builtin segmenter's boundary-contrast heuristic; in [0, 1]."""
    stability: float
    """SAM's stability score, or the builtin segmenter's IoU under a perturbed scale; in [0, 1]."""
    level: str
    """"whole" | "part" | "subpart"."""

    @property
    def score(self) -> float:
        return float(self.predicted_iou) * float(self.stability)

    def bbox(self) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1), exclusive upper bounds; (0, 0, 0, 0) for an empty mask."""
        ys = np.flatnonzero(self.segmentation.any(axis=1))
        xs = np.flatnonzero(self.segmentation.any(axis=0))
        if len(ys) == 0:
            return (0, 0, 0, 0)
        return (int(xs[0]), int(ys[0]), int(xs[-1]) + 1, int(ys[-1]) + 1)


class Segmenter(Protocol):
    name: str

    def segment(self, image: np.ndarray) -> list[Mask]:
        """image: uint8 [H, W, 3] RGB -> masks (deduplicated, filtered, sorted by level then area)."""
        ...

    def fingerprint(self) -> str:
        """A string identifying the configuration (masks change when it changes)."""
        ...


# ---------------------------------------------------------------------------------------------------------
# shared helpers
# ---------------------------------------------------------------------------------------------------------


def check_image(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=-1)
    if image.ndim != 3 or image.shape[-1] not in (3, 4):
        raise ValueError(f"expected an RGB image [H, W, 3], got shape {image.shape}")
    if image.dtype != np.uint8:
        raise ValueError(
            f"expected a uint8 image, got {image.dtype}; convert with (img * 255).astype(np.uint8)"
        )
    return np.ascontiguousarray(image[..., :3])


def mask_iou_matrix(a: np.ndarray, b: np.ndarray | None = None) -> np.ndarray:
    """Pairwise IoU of stacked bool masks a [N, H, W] and b [M, H, W] (default b = a) -> [N, M]."""
    fa = a.reshape(len(a), -1).astype(np.float32)
    fb = fa if b is None else b.reshape(len(b), -1).astype(np.float32)
    inter = fa @ fb.T
    union = fa.sum(1)[:, None] + fb.sum(1)[None, :] - inter
    return np.where(union > 0, inter / np.maximum(union, 1), 0.0)


def containment_matrix(masks: np.ndarray) -> np.ndarray:
    """C[i, j] = |m_i & m_j| / |m_i|: the fraction of mask i inside mask j ([N, N], diagonal 1)."""
    f = masks.reshape(len(masks), -1).astype(np.float32)
    inter = f @ f.T
    return inter / np.maximum(f.sum(1)[:, None], 1)


def deduplicate(masks: Sequence[Mask], iou_threshold: float) -> list[Mask]:
    """Greedy non-maximum suppression on mask IoU: best score first, drop any mask whose IoU with a kept
    mask exceeds ``iou_threshold``. Ties prefer the coarser level (whole < part < subpart)."""
    if not masks:
        return []
    order = sorted(
        range(len(masks)), key=lambda i: (-masks[i].score, LEVELS.index(masks[i].level), -masks[i].area)
    )
    stack = np.stack([masks[i].segmentation for i in order])
    iou = mask_iou_matrix(stack)
    keep: list[int] = []
    for r in range(len(order)):
        if all(iou[r, k] <= iou_threshold for k in keep):
            keep.append(r)
    return [masks[order[r]] for r in keep]


def sort_masks(masks: Sequence[Mask]) -> list[Mask]:
    """Deterministic order: level (whole, part, subpart), then area descending, then top-left pixel."""

    def key(m: Mask):
        flat = np.flatnonzero(m.segmentation.reshape(-1))
        return (LEVELS.index(m.level), -m.area, int(flat[0]) if len(flat) else 0)

    return sorted(masks, key=key)


def assign_levels_by_containment(stack: np.ndarray, contain: float = 0.9) -> list[str]:
    """Hierarchy depth from containment: depth 0 -> whole, 1 -> part, >= 2 -> subpart.

    Mask i is inside mask j when >= ``contain`` of i lies in j and j is larger than i.
    """
    if len(stack) == 0:
        return []
    c = containment_matrix(stack)
    areas = stack.reshape(len(stack), -1).sum(1)
    inside = (c >= contain) & (areas[None, :] > areas[:, None])
    np.fill_diagonal(inside, False)
    depth = np.zeros(len(stack), dtype=int)
    # Longest chain of containing masks; areas strictly increase along a chain, so process by area.
    for i in np.argsort(-areas, kind="stable"):
        parents = np.flatnonzero(inside[i])
        if len(parents):
            depth[i] = depth[parents].max() + 1
    return [LEVELS[min(d, 2)] for d in depth]


# ---------------------------------------------------------------------------------------------------------
# implementations (in segment_builtin.py / segment_sam.py; re-exported lazily here to avoid an import cycle,
# since those modules import the shared helpers above)
# ---------------------------------------------------------------------------------------------------------

# ---------------------------------------------------------------------------------------------------------
# persistence (so fusion and resumed runs use exactly the masks the VLM saw)
# ---------------------------------------------------------------------------------------------------------


def save_masks(path: Path, masks: Sequence[Mask], shape: tuple[int, int], fingerprint: str) -> None:
    """Packed-bit npz; atomic (written to a temporary file, then renamed)."""
    import os

    path.parent.mkdir(parents=True, exist_ok=True)
    h, w = shape
    stack = np.stack([m.segmentation for m in masks]) if masks else np.zeros((0, h, w), bool)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez_compressed(
        tmp,
        bits=np.packbits(stack.reshape(len(stack), h * w), axis=1),  # explicit h*w: -1 fails for 0 masks
        shape=np.array([len(stack), h, w]),
        predicted_iou=np.array([m.predicted_iou for m in masks], np.float64),
        stability=np.array([m.stability for m in masks], np.float64),
        level=np.array([LEVELS.index(m.level) for m in masks], np.int64),
        fingerprint=np.array(fingerprint),
    )
    os.replace(tmp, path)


def load_masks(path: Path, fingerprint: str | None = None) -> list[Mask] | None:
    """Masks saved by :func:`save_masks`; None when missing, unreadable or made with another fingerprint."""
    if not path.is_file():
        return None
    try:
        with np.load(path) as z:
            if fingerprint is not None and str(z["fingerprint"]) != fingerprint:
                return None
            n, h, w = (int(v) for v in z["shape"])
            stack = (
                np.unpackbits(z["bits"], axis=1, count=h * w).reshape(n, h, w).astype(bool)
                if n
                else np.zeros((0, h, w), bool)
            )
            return [
                Mask(
                    stack[i],
                    int(stack[i].sum()),
                    float(z["predicted_iou"][i]),
                    float(z["stability"][i]),
                    LEVELS[int(z["level"][i])],
                )
                for i in range(n)
            ]
    except Exception as err:  # a corrupt file is recomputed, never fatal
        logger.warning("ignoring unreadable mask file %s (%s)", path, err)
        return None
