"""Part masks at three granularities (paper sec. 3.4 "Semantic Segmentation").

One protocol, :class:`Segmenter`: ``segment(image: uint8 [H, W, 3]) -> list[Mask]``. Two implementations:

* ``sam`` (:class:`SamSegmenter`): segment-anything's automatic mask generator from a local checkpoint
  (optional extra: ``pip install -e ".[sam]"``). SAM's own predicted IoU and stability scores filter the
  masks; levels come from the containment hierarchy (a mask inside no other mask is "whole", a mask inside
  a mask that is itself contained is "subpart", the rest "part").
* ``builtin`` (:class:`BuiltinSegmenter`): no weights. SLIC superpixels merged on their region adjacency
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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Protocol

import numpy as np

logger = logging.getLogger(__name__)

Level = Literal["whole", "part", "subpart"]
LEVELS: tuple[str, ...] = ("whole", "part", "subpart")

SAM_INSTALL_HINT = (
    'The "sam" segmenter needs the optional package segment-anything: pip install -e ".[sam]" '
    "(or pip install segment-anything), then pass --sam-checkpoint PATH to a SAM checkpoint "
    "(e.g. sam_vit_h_4b8939.pth) and --sam-model-type vit_h|vit_l|vit_b. "
    "Use --segmenter builtin to run without SAM."
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
# builtin (no weights)
# ---------------------------------------------------------------------------------------------------------


@dataclass
class BuiltinSegmenterConfig:
    """SLIC superpixels merged hierarchically by mean Lab colour (scikit-image), no learned weights."""

    work_size: int = 512
    """Images are segmented at this long side (downscaled, never upscaled); masks are upsampled back."""
    n_segments: int = 600
    """SLIC superpixels per image (the finest possible granularity)."""
    compactness: float = 10.0
    """SLIC compactness (higher: squarer superpixels, lower: follow colour edges more)."""
    thresholds: tuple[float, float, float] = (9.0, 6.0, 3.0)
    """Dissimilarity (CIE Lab Delta E, see ``colour_weight``) up to which adjacent regions are merged, for
    the whole (background detection) / part / subpart levels."""
    colour_weight: float = 0.0
    """Region dissimilarity = colour_weight * mean-colour distance + (1 - colour_weight) * mean colour
    step across the shared boundary (0: boundary strength only, which keeps shaded objects apart from a
    similar background)."""
    perturb: float = 1.5
    """Stability = best IoU of a region with the regions merged at ``threshold * perturb`` (a heuristic
    stand-in for SAM's stability score: how much the region survives a change of threshold)."""
    min_area_frac: float = 0.002
    """Masks smaller than this fraction of the image are dropped."""
    min_area_px: int = 32
    """... and smaller than this many pixels."""
    min_solidity: float = 0.25
    """Drop slivers: masks keeping less than this fraction of their area after a 3x3 erosion."""
    border_frac: float = 0.15
    """A coarse region holding at least this fraction of the image's border pixels is background."""
    max_background_frac: float = 0.5
    """Masks with more than this fraction of background pixels are dropped."""
    min_predicted_iou: float = 0.2
    """Drop masks whose boundary-contrast heuristic is below this."""
    min_stability: float = 0.3
    """Drop masks whose perturbed-threshold IoU is below this."""
    dedup_iou: float = 0.85
    """Masks overlapping a better mask by more than this IoU are dropped."""
    max_masks_per_level: tuple[int, int, int] = (4, 16, 24)
    """Cap per level (best score x area first); bounds the VLM calls per view."""
    levels: tuple[str, ...] = LEVELS
    """Levels to produce."""
    seed: int = 0
    """(SLIC is deterministic; kept for future randomised variants.)"""


def _lab(image: np.ndarray) -> np.ndarray:
    from skimage.color import rgb2lab

    return rgb2lab(image).astype(np.float64)


def _relabel(labels: np.ndarray) -> np.ndarray:
    _, inv = np.unique(labels, return_inverse=True)
    return inv.reshape(labels.shape).astype(np.int32)


class _RegionMerger:
    """Hierarchical region merging on a region adjacency graph (vectorised graph construction, heap-based
    greedy merging: always merge the most similar adjacent pair next).

    Dissimilarity of adjacent regions u, v (CIE Lab Delta E units):
    ``colour_weight * |mean(u) - mean(v)| + (1 - colour_weight) * mean step across their shared boundary``,
    where the step is the colour difference of the two pixels on either side of each boundary edge. The
    boundary term keeps an object apart from a similar-coloured background when a visible edge separates
    them; the mean-colour term merges smooth shading gradients.

    ``merge(thresh)`` continues merging until no adjacent pair is closer than ``thresh``; ``labels()`` maps
    the initial regions to the current ones; ``copy()`` forks the state."""

    def __init__(self, labels: np.ndarray, features: np.ndarray, colour_weight: float = 0.5):
        import heapq

        n = int(labels.max()) + 1
        flat = labels.reshape(-1)
        self.base = labels
        self.colour_weight = float(colour_weight)
        self.count = np.bincount(flat, minlength=n).astype(np.float64)
        self.sum = np.stack(
            [
                np.bincount(flat, weights=features[..., c].reshape(-1), minlength=n)
                for c in range(features.shape[-1])
            ],
            1,
        )
        a = np.concatenate([labels[:, :-1].reshape(-1), labels[:-1, :].reshape(-1)])
        b = np.concatenate([labels[:, 1:].reshape(-1), labels[1:, :].reshape(-1)])
        step = np.concatenate(
            [
                np.linalg.norm(features[:, :-1] - features[:, 1:], axis=-1).reshape(-1),
                np.linalg.norm(features[:-1, :] - features[1:, :], axis=-1).reshape(-1),
            ]
        )
        sel = a != b
        lo, hi, step = np.minimum(a[sel], b[sel]), np.maximum(a[sel], b[sel]), step[sel]
        keys, inv = np.unique(lo.astype(np.int64) * n + hi, return_inverse=True)
        bsum = np.bincount(inv, weights=step, minlength=len(keys))
        bcnt = np.bincount(inv, minlength=len(keys)).astype(np.float64)
        self.edges: list[dict[int, list[float]]] = [{} for _ in range(n)]
        for key, s_, c_ in zip(keys.tolist(), bsum.tolist(), bcnt.tolist()):
            u, v = divmod(key, n)
            stats = [s_, c_]
            self.edges[u][v] = stats
            self.edges[v][u] = stats
        self.parent = np.arange(n)
        self.alive = self.count > 0
        self.version = np.zeros(n, dtype=np.int64)
        self.heap: list[tuple[float, int, int, int, int]] = []
        for u in range(n):
            for v in self.edges[u]:
                if u < v:
                    self.heap.append((self._dist(u, v), u, v, 0, 0))
        heapq.heapify(self.heap)

    def copy(self) -> _RegionMerger:
        other = object.__new__(_RegionMerger)
        other.base = self.base
        other.colour_weight = self.colour_weight
        other.count = self.count.copy()
        other.sum = self.sum.copy()
        other.edges = [{} for _ in self.edges]
        for u, nb in enumerate(self.edges):
            for v, stats in nb.items():
                if u < v:
                    st = list(stats)
                    other.edges[u][v] = st
                    other.edges[v][u] = st
        other.parent = self.parent.copy()
        other.alive = self.alive.copy()
        other.version = self.version.copy()
        other.heap = list(self.heap)
        return other

    def _dist(self, u: int, v: int) -> float:
        colour = float(np.linalg.norm(self.sum[u] / self.count[u] - self.sum[v] / self.count[v]))
        bs, bc = self.edges[u][v]
        return self.colour_weight * colour + (1.0 - self.colour_weight) * (bs / max(bc, 1.0))

    def merge(self, thresh: float) -> _RegionMerger:
        import heapq

        heap = self.heap
        while heap:
            w, u, v, vu, vv = heap[0]
            if not (self.alive[u] and self.alive[v]) or self.version[u] != vu or self.version[v] != vv:
                heapq.heappop(heap)
                continue
            if w >= thresh:
                break
            heapq.heappop(heap)
            # merge v into u
            self.sum[u] += self.sum[v]
            self.count[u] += self.count[v]
            self.alive[v] = False
            self.parent[v] = u
            self.version[u] += 1
            del self.edges[u][v]
            for x, stats in self.edges[v].items():
                if x == u:
                    continue
                del self.edges[x][v]
                if x in self.edges[u]:
                    shared = self.edges[u][x]
                    shared[0] += stats[0]
                    shared[1] += stats[1]
                else:
                    self.edges[u][x] = stats
                    self.edges[x][u] = stats
            self.edges[v] = {}
            for x in self.edges[u]:
                a, b = (u, x) if u < x else (x, u)
                heapq.heappush(heap, (self._dist(a, b), a, b, int(self.version[a]), int(self.version[b])))
        return self

    def labels(self) -> np.ndarray:
        root = self.parent.copy()
        while True:  # path compression, vectorised
            nxt = root[root]
            if np.array_equal(nxt, root):
                break
            root = nxt
        return _relabel(root[self.base])


def _border_pixels(labels: np.ndarray) -> np.ndarray:
    return np.concatenate([labels[0], labels[-1], labels[1:-1, 0], labels[1:-1, -1]])


def _background(labels: np.ndarray, border_frac: float) -> np.ndarray:
    """bool [H, W]: union of the regions that hold >= border_frac of the border pixels."""
    border = _border_pixels(labels)
    counts = np.bincount(border, minlength=int(labels.max()) + 1)
    bg_ids = np.flatnonzero(counts >= border_frac * len(border))
    return np.isin(labels, bg_ids)


def _contrast_score(mask: np.ndarray, lab: np.ndarray, ring: int) -> float:
    """Boundary-contrast heuristic in [0, 1]: contrast / (contrast + spread), where contrast is the Lab
    distance between the mask's mean colour and the mean colour of a ring just outside it, and spread the
    mean Lab distance of the mask's pixels from their mean. A flat region on a different background
    scores near 1; a region cut out of a uniform area scores near 0."""
    import cv2

    kernel = np.ones((2 * ring + 1, 2 * ring + 1), np.uint8)
    dil = cv2.dilate(mask.astype(np.uint8), kernel).astype(bool)
    outside = dil & ~mask
    inside_px = lab[mask]
    mu = inside_px.mean(0)
    spread = float(np.linalg.norm(inside_px - mu, axis=1).mean())
    if not outside.any():  # the mask is the whole image
        return 0.5
    contrast = float(np.linalg.norm(lab[outside].mean(0) - mu))
    return contrast / (contrast + spread + 1e-6)


def _best_iou_with_labels(mask: np.ndarray, labels: np.ndarray, area: int) -> float:
    ids = labels[mask]
    inter = np.bincount(ids, minlength=int(labels.max()) + 1).astype(np.float64)
    sizes = np.bincount(labels.reshape(-1), minlength=len(inter)).astype(np.float64)
    cand = np.flatnonzero(inter)
    iou = inter[cand] / (area + sizes[cand] - inter[cand])
    return float(iou.max()) if len(iou) else 0.0


def _solidity(mask: np.ndarray) -> float:
    import cv2

    eroded = cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE)
    return float(eroded.sum()) / max(1, int(mask.sum()))


class BuiltinSegmenter:
    """Weight-free three-level segmenter (see module docstring; weaker than SAM).

    SLIC superpixels are merged hierarchically while adjacent regions' mean CIE Lab colours differ by less
    than a threshold; the fine / medium / coarse thresholds give the subpart / part / whole levels:

    * whole: connected components of the foreground, where background = coarse regions holding a large
      share of the image border (``border_frac``);
    * part / subpart: regions at the medium / fine threshold that are mostly foreground.

    Scores (heuristics, documented honestly): ``predicted_iou`` = boundary contrast ratio
    (:func:`_contrast_score`); ``stability`` = best IoU of the region with the regions merged at
    ``perturb`` times the threshold. Colour-based merging splits strongly textured or shaded parts and
    merges neighbouring parts of similar colour, which SAM handles far better.
    """

    name = "builtin"

    def __init__(self, config: BuiltinSegmenterConfig | None = None):
        self.config = config or BuiltinSegmenterConfig()
        for level in self.config.levels:
            if level not in LEVELS:
                raise ValueError(f"unknown level {level!r}; choose from {LEVELS}")

    def fingerprint(self) -> str:
        return f"builtin-slic-rag:{self.config!r}"

    def segment(self, image: np.ndarray) -> list[Mask]:
        from skimage.measure import label as cc_label
        from skimage.segmentation import slic

        cfg = self.config
        image = check_image(image)
        full_h, full_w = image.shape[:2]
        scale = cfg.work_size / max(full_h, full_w)
        if scale < 1:
            import cv2

            image = cv2.resize(
                image,
                (max(1, round(full_w * scale)), max(1, round(full_h * scale))),
                interpolation=cv2.INTER_AREA,
            )
        h, w = image.shape[:2]
        min_area = max(cfg.min_area_px, int(cfg.min_area_frac * h * w))
        lab = _lab(image)
        ring = max(2, int(round(3 * max(h, w) / 512)))

        superpixels = _relabel(
            slic(
                image, n_segments=cfg.n_segments, compactness=cfg.compactness, start_label=0, convert2lab=True
            )
        )
        # fine -> coarse, each level merged further from the previous one (a monotone hierarchy)
        t_whole, t_part, t_sub = cfg.thresholds
        merger = _RegionMerger(superpixels, lab, cfg.colour_weight)
        by_level: dict[str, np.ndarray] = {}
        perturbed: dict[str, np.ndarray] = {}
        merger.merge(t_sub)
        by_level["subpart"] = merger.labels()
        perturbed["subpart"] = merger.copy().merge(t_sub * cfg.perturb).labels()
        merger.merge(t_part)
        by_level["part"] = merger.labels()
        perturbed["part"] = merger.copy().merge(t_part * cfg.perturb).labels()
        merger.merge(t_whole)
        coarse = merger.labels()
        coarse_perturbed = merger.merge(t_whole * cfg.perturb).labels()
        background = _background(coarse, cfg.border_frac)
        by_level["whole"] = cc_label(~background, connectivity=1).astype(np.int32)
        perturbed["whole"] = cc_label(~_background(coarse_perturbed, cfg.border_frac), connectivity=1).astype(
            np.int32
        )

        raw: list[Mask] = []
        for li, level in enumerate(LEVELS):
            if level not in cfg.levels:
                continue
            lbl = by_level[level]
            sizes = np.bincount(lbl.reshape(-1))
            bg_counts = np.bincount(lbl[background], minlength=len(sizes))
            first = 1 if level == "whole" else 0  # whole: label 0 is the background
            ids = [
                i
                for i in range(first, len(sizes))
                if sizes[i] >= min_area and bg_counts[i] <= cfg.max_background_frac * sizes[i]
            ]
            level_masks = []
            for i in ids:
                m = lbl == i
                area = int(sizes[i])
                if _solidity(m) < cfg.min_solidity:
                    continue
                piou = _contrast_score(m, lab, ring)
                stab = _best_iou_with_labels(m, perturbed[level], area)
                if piou < cfg.min_predicted_iou or stab < cfg.min_stability:
                    continue
                level_masks.append(Mask(m, area, piou, stab, level))
            level_masks.sort(key=lambda m: -m.score * m.area)
            raw.extend(level_masks[: cfg.max_masks_per_level[li]])
        masks = deduplicate(raw, cfg.dedup_iou)
        if (h, w) != (full_h, full_w):
            import cv2

            up = []
            for m in masks:
                seg = cv2.resize(
                    m.segmentation.astype(np.uint8), (full_w, full_h), interpolation=cv2.INTER_NEAREST
                ).astype(bool)
                up.append(Mask(seg, int(seg.sum()), m.predicted_iou, m.stability, m.level))
            masks = up
        return sort_masks(masks)


# ---------------------------------------------------------------------------------------------------------
# SAM (optional extra)
# ---------------------------------------------------------------------------------------------------------


@dataclass
class SamSegmenterConfig:
    """segment-anything automatic mask generation from a local checkpoint."""

    checkpoint: Path | None = None
    """Path to a SAM checkpoint (.pth). Required for --segmenter sam."""
    model_type: str = "vit_h"
    """vit_h | vit_l | vit_b (must match the checkpoint)."""
    device: str = "auto"
    """auto (cuda if available) | cpu | cuda."""
    points_per_side: int = 32
    min_predicted_iou: float = 0.86
    """Drop masks with SAM predicted IoU below this (SAM's pred_iou_thresh)."""
    min_stability: float = 0.92
    """Drop masks with SAM stability score below this (SAM's stability_score_thresh)."""
    dedup_iou: float = 0.85
    min_area_frac: float = 0.002
    min_area_px: int = 64
    containment: float = 0.9
    """A mask is inside another when at least this fraction of it is covered (level assignment)."""
    max_masks_per_level: tuple[int, int, int] = (4, 16, 24)
    levels: tuple[str, ...] = LEVELS
    generator_kwargs: dict = field(default_factory=dict)
    """Extra keyword arguments for SamAutomaticMaskGenerator (e.g. crop_n_layers)."""


class SamSegmenter:
    """segment-anything's automatic mask generator, three levels by containment (see module docstring)."""

    name = "sam"

    def __init__(self, config: SamSegmenterConfig | None = None):
        self.config = config or SamSegmenterConfig()
        self._generator = None

    def fingerprint(self) -> str:
        cfg = self.config
        ckpt = Path(cfg.checkpoint).name if cfg.checkpoint else None
        return (
            f"sam:{ckpt}:{cfg.model_type}:{cfg.points_per_side}:{cfg.min_predicted_iou}:{cfg.min_stability}:"
            f"{cfg.dedup_iou}:{cfg.min_area_frac}:{cfg.min_area_px}:{cfg.containment}:{cfg.max_masks_per_level}:"
            f"{cfg.levels}:{sorted(cfg.generator_kwargs.items())}"
        )

    def _load(self):
        if self._generator is not None:
            return self._generator
        cfg = self.config
        try:
            import segment_anything  # noqa: F401
            from segment_anything import SamAutomaticMaskGenerator, sam_model_registry
        except ImportError as err:
            raise ImportError(SAM_INSTALL_HINT) from err
        if cfg.checkpoint is None:
            raise FileNotFoundError("no SAM checkpoint given. " + SAM_INSTALL_HINT)
        ckpt = Path(cfg.checkpoint).expanduser()
        if not ckpt.is_file():
            raise FileNotFoundError(f"SAM checkpoint not found: {ckpt}. " + SAM_INSTALL_HINT)
        if cfg.model_type not in sam_model_registry:
            raise ValueError(
                f"unknown SAM model type {cfg.model_type!r}; choose from {sorted(sam_model_registry)}"
            )
        device = cfg.device
        if device == "auto":
            import torch

            device = "cuda" if torch.cuda.is_available() else "cpu"
        model = sam_model_registry[cfg.model_type](checkpoint=str(ckpt))
        model.to(device=device)
        self._generator = SamAutomaticMaskGenerator(
            model,
            points_per_side=cfg.points_per_side,
            pred_iou_thresh=cfg.min_predicted_iou,
            stability_score_thresh=cfg.min_stability,
            output_mode="binary_mask",
            **cfg.generator_kwargs,
        )
        return self._generator

    def segment(self, image: np.ndarray) -> list[Mask]:
        cfg = self.config
        image = check_image(image)
        h, w = image.shape[:2]
        records = self._load().generate(image)
        min_area = max(cfg.min_area_px, int(cfg.min_area_frac * h * w))
        kept = []
        for r in records:
            seg = np.asarray(r["segmentation"], dtype=bool)
            area = int(seg.sum())
            piou = float(r.get("predicted_iou", 0.0))
            stab = float(r.get("stability_score", 0.0))
            if area < min_area or piou < cfg.min_predicted_iou or stab < cfg.min_stability:
                continue
            kept.append(Mask(seg, area, min(max(piou, 0.0), 1.0), min(max(stab, 0.0), 1.0), "part"))
        # dedup first so near-duplicates do not create spurious hierarchy levels
        kept = deduplicate(kept, cfg.dedup_iou)
        if not kept:
            return []
        levels = assign_levels_by_containment(np.stack([m.segmentation for m in kept]), cfg.containment)
        out: list[Mask] = []
        for li, level in enumerate(LEVELS):
            if level not in cfg.levels:
                continue
            ms = [
                Mask(m.segmentation, m.area, m.predicted_iou, m.stability, level)
                for m, lv in zip(kept, levels)
                if lv == level
            ]
            ms.sort(key=lambda m: -m.score * m.area)
            out.extend(ms[: cfg.max_masks_per_level[li]])
        return sort_masks(out)


def make_segmenter(
    kind: str,
    builtin: BuiltinSegmenterConfig | None = None,
    sam: SamSegmenterConfig | None = None,
) -> Segmenter:
    if kind == "builtin":
        return BuiltinSegmenter(builtin)
    if kind == "sam":
        seg = SamSegmenter(sam)
        seg._load()  # fail early with the install/checkpoint hint
        return seg
    raise ValueError(f"unknown segmenter {kind!r}; choose 'builtin' or 'sam'")


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
