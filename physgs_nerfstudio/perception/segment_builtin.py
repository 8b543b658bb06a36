"""Built-in weight-free segmenter: superpixels merged hierarchically by colour (scikit-image).

The superpixels are SLIC's, split along Felzenszwalb-Huttenlocher's graph segmentation by default
(``oversegment="slic+graph"``). SLIC's superpixels are compact, about ``sqrt(h w / n_segments)`` pixels across (21 px
at 512 px): a part thinner than that (a table's steel legs, a chair's aluminium legs) shares its superpixels with the
background or its neighbours, and the merging can never take it apart again. Each superpixel is split where the
graph segmentation's regions, which follow the pixels' colour edges at any width, cross it. At 512 px this raised the
share of each material that a mask of that majority material covers from 0.78 to 0.90 on twelve generated objects
(not the stool's footrest: its arcs stay too small to keep), at 96 px (the CPU demo, 4 px superpixels) from 0.645 to
0.656, for about 0.9 s more per 512 px image on one core (benchmarks/README.md, "Thin parts in the built-in
segmenter"; ``benchmarks/segment_coverage.py``).

Thin fragments (``thin_chroma``, 4 by default; None turns it off). A thin curved part (a stool's 14 mm footrest at 512 px, 5-8 px
wide) still falls apart at the part level: the legs in front cut it, and its shading around the curve and the
highlight along it split it lengthwise, so its fragments are smaller than ``min_area_frac`` or fail the sliver test
and are dropped. With ``thin_chroma`` set, the dropped fragments that are mostly foreground are joined where two touch
and their mean chromaticities (CIE a*, b*) differ by less than ``thin_chroma``; lightness is left out, since shading
and a white highlight change it along one material, and chromaticity is what tells steel from pine. A group that
passes the area, sliver, contrast and stability tests (stability: the best IoU with the groups at ``perturb`` times
the threshold) is a part mask. At 512 px on the twelve generated objects (8 views; ``thin_chroma`` 4) the share of
each material that a mask of that majority covers goes 0.895 -> 0.921 (lowest 0.33 -> 0.57: a stool's steel
footrest 0.33 -> 0.73), the share painted by a mask of another majority stays about 0.025, and the masks per view
(the VLM's calls) rise 6.6 -> 7.0; the demo's time does not change (``benchmarks/segment_coverage.py``).

The whole object. The cameras of a capture orbit the object and frame it whole, while the support it stands on (a
floor, a table top) and the backdrop run past every image's border. So the background is every region of the
whole-level merge (``thresholds[0]``, Delta E 6: the part level's) that touches the image border, and a whole mask is
a connected component of the rest, whatever its contrast or stability scores (a glossy or low-contrast object, which
the perturbed threshold merges into the floor, is exactly what this level must keep; the scores still rank it).
Two kinds of support pixels are not reached from the border that way: the floor seen through the object (between a
table's legs, a chair's) and the object's cast shadow. Both are the support in less light: a shadow scales the
irradiance, not the surface's reflectance spectrum, so their chromaticity (r, g over r + g + b) stays the support's
while they are no brighter. A region off the border whose mean chromaticity is within ``support_chroma`` (0.5
percent) of a border region's and whose mean brightness is at most ``SUPPORT_BRIGHT_TOL`` (10%: the render noise and
the floor's light falloff) above it is background too. Chromaticity only tells a coloured support: on a neutral
grey one every achromatic object (steel, aluminium, white or grey plastic) would match, so only border regions more
than ``support_chroma`` from neutral grey are compared, and no achromatic object is ever taken for the support.
A whole mask also survives the deduplication against a part mask that repeats it (a one-region object), since the
geometry reads the whole level. On the path-traced development families of ``benchmarks/mass_suite.py`` (16 families
at two seeds, 16 views at 96 px; ``mass_suite.py --masks``) the union of the whole masks against the object's label
maps: median IoU 0.26 -> 0.65 (mean 0.37 -> 0.62), the masks' median share on the support 0.31 -> 0.17 and the views
without a whole mask 173 -> 27 of 512 (the regions holding 15% of the border at Delta E 9, the whole masks'
contrast and stability filters and the deduplication by score -> this). Without the support rule: median IoU 0.62
(mean 0.59), share on the support 0.25. Comparing grey supports too: share 0.14 at the same median IoU, but a grey
object darker than a grey backdrop then vanishes. The chromaticity tolerance was the best of 0.5, 0.7 (without the 10%
margin), 1 and 2, compared with whole masks deduplicated by score and grey supports included (wider ones trim more of
the objects: median IoU 0.40 at 1 against 0.58 at 0.5); at 1 without the brightness test (a tolerance of 10x) median IoU falls to 0.21. An object
with the support's chromaticity and no brighter than it gets no whole mask in some views: the perception run then
says in how many, and that SAM's masks are the remedy (``pipeline.no_object_message``).

Built by ``BuiltinSegmenterConfig.setup()``; the protocol, the mask type and the shared mask operations are in
:mod:`.segment`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np

from ..advanced import Advanced
from .segment import LEVELS, Mask, check_image, deduplicate, mask_iou_matrix, sort_masks

SUPPORT_BRIGHT_TOL = 0.1
"""A region is the support in less light (module doc, "The whole object") when its mean brightness is at most this
much above the border region's: the path tracer's noise and the floor's light falloff between the image border and
the object."""

# ---------------------------------------------------------------------------------------------------------
# builtin (no weights)
# ---------------------------------------------------------------------------------------------------------


@dataclass
class BuiltinSegmenterConfig:
    """SLIC superpixels split along a graph segmentation, merged hierarchically by mean Lab colour (scikit-image);
    no learned weights."""

    name: ClassVar[str] = "builtin"

    work_size: Advanced[int] = 512
    """Images are segmented at this long side (downscaled, never upscaled); masks are upsampled back."""
    n_segments: Advanced[int] = 600
    """SLIC superpixels per image (the finest possible granularity)."""
    compactness: Advanced[float] = 10.0
    """SLIC compactness (higher: squarer superpixels, lower: follow colour edges more)."""
    oversegment: Advanced[Literal["slic", "slic+graph"]] = "slic+graph"
    """The superpixels: SLIC's alone, or SLIC's split along Felzenszwalb-Huttenlocher's graph segmentation (module
    doc: keeps parts thinner than a SLIC superpixel apart)."""
    graph_scale: Advanced[float] = 50.0
    """The graph segmentation's scale (larger: larger regions)."""
    graph_sigma: Advanced[float] = 0.5
    """The graph segmentation's Gaussian pre-smoothing, in pixels."""
    graph_min_size: Advanced[int] = 10
    """The graph segmentation's smallest region, in pixels."""
    thresholds: Advanced[tuple[float, float, float]] = (6.0, 6.0, 3.0)
    """Dissimilarity (CIE Lab Delta E, see ``colour_weight``) up to which adjacent regions are merged, for
    the whole (background: the regions touching the border, module doc "The whole object") / part / subpart
    levels."""
    colour_weight: Advanced[float] = 0.0
    """Region dissimilarity = colour_weight * mean-colour distance + (1 - colour_weight) * mean colour
    step across the shared boundary (0: boundary strength only, which keeps shaded objects apart from a
    similar background)."""
    perturb: Advanced[float] = 1.5
    """Stability = best IoU of a region with the regions merged at ``threshold * perturb`` (a heuristic
    stand-in for SAM's stability score: how much the region survives a change of threshold)."""
    min_area_frac: Advanced[float] = 0.002
    """Masks smaller than this fraction of the image are dropped."""
    min_area_px: Advanced[int] = 32
    """... and smaller than this many pixels."""
    min_solidity: Advanced[float] = 0.25
    """Drop slivers: masks keeping less than this fraction of their area after a 3x3 erosion."""
    max_background_frac: Advanced[float] = 0.5
    """Masks with more than this fraction of background pixels are dropped."""
    min_predicted_iou: Advanced[float] = 0.2
    """Drop masks whose boundary-contrast heuristic is below this."""
    min_stability: Advanced[float] = 0.3
    """Drop masks whose perturbed-threshold IoU is below this."""
    dedup_iou: Advanced[float] = 0.85
    """Masks overlapping a better mask by more than this IoU are dropped."""
    thin_chroma: Advanced[float | None] = 4.0
    """Thin parts (module doc, "Thin fragments"): part-level regions that the area or sliver test drops are grouped
    with adjacent such regions whose mean chromaticity (CIE a*, b*) differs by less than this (Delta E), and a
    group that passes the tests is a part mask. None = off."""
    support_chroma: Advanced[float | None] = 0.5
    """The support seen through the object or in its shadow (module doc, "The whole object"): a region off the
    border whose mean chromaticity is within this (r, g over r + g + b, in percent) of a border region's, and no
    brighter, is background. None = off."""
    max_masks_per_level: Advanced[tuple[int, int, int]] = (4, 16, 24)
    """Cap per level (best score x area first); bounds the VLM calls per view."""
    levels: Advanced[tuple[str, ...]] = LEVELS
    """Levels to produce."""
    seed: Advanced[int] = 0
    """(SLIC is deterministic; kept for future randomised variants.)"""

    def setup(self) -> BuiltinSegmenter:
        """The segmenter of this config."""
        return BuiltinSegmenter(self)


def _lab(image: np.ndarray) -> np.ndarray:
    from skimage.color import rgb2lab

    return rgb2lab(image).astype(np.float64)


def _relabel(labels: np.ndarray) -> np.ndarray:
    """Labels renumbered 0..n-1 in their sorted order (``np.unique``'s inverse; a lookup table where the labels are
    small non-negative integers, which is faster than the sort)."""
    flat = labels.reshape(-1)
    if flat.size and flat.min() >= 0 and flat.max() < 8 * flat.size:
        rank = np.cumsum(np.bincount(flat) > 0) - 1
        return rank[labels].astype(np.int32)
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
        bs, bc = self.edges[u][v]
        step = bs / max(bc, 1.0)
        if self.colour_weight == 0.0:  # the default: the boundary step alone (no colour distance to compute)
            return step
        colour = math.dist((self.sum[u] / self.count[u]).tolist(), (self.sum[v] / self.count[v]).tolist())
        return self.colour_weight * colour + (1.0 - self.colour_weight) * step

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


def _superpixels(image: np.ndarray, cfg: BuiltinSegmenterConfig) -> np.ndarray:
    """The initial regions [H, W] (labels 0..n-1): SLIC's superpixels, split where the graph segmentation's
    regions cross them (``cfg.oversegment``, module doc)."""
    from skimage.segmentation import felzenszwalb, slic

    labels = slic(image, n_segments=cfg.n_segments, compactness=cfg.compactness, start_label=0, convert2lab=True)
    if cfg.oversegment == "slic+graph":
        graph = felzenszwalb(image, scale=cfg.graph_scale, sigma=cfg.graph_sigma, min_size=cfg.graph_min_size)
        labels = labels.astype(np.int64) * (int(graph.max()) + 1) + graph
    return _relabel(labels)


def _border_pixels(labels: np.ndarray) -> np.ndarray:
    return np.concatenate([labels[0], labels[-1], labels[1:-1, 0], labels[1:-1, -1]])


def _background(labels: np.ndarray) -> np.ndarray:
    """bool [H, W]: union of the regions that touch the image border (module doc, "The whole object")."""
    return np.isin(labels, np.unique(_border_pixels(labels)))


def _support_like(labels: np.ndarray, image: np.ndarray, background: np.ndarray, min_area: int, chroma_tol: float,
                  bright_tol: float) -> np.ndarray:
    """bool [H, W]: the regions off ``background`` that look like a border-touching region of at least ``min_area``
    pixels seen in less light (module doc, "The whole object"): their mean chromaticity (r, g over r + g + b, in
    percent) within ``chroma_tol`` of that region's and their mean brightness at most ``1 + bright_tol`` times
    its. Only border regions more than ``chroma_tol`` from neutral grey count, so that no achromatic object is ever
    taken for the support."""
    n = int(labels.max()) + 1
    flat = labels.reshape(-1)
    rgb = image.reshape(-1, 3).astype(np.float64) + 1.0
    bright = rgb.sum(1)
    size = np.bincount(flat, minlength=n).astype(np.float64)
    chroma = np.stack([np.bincount(flat, 100 * rgb[:, c] / bright, n) for c in (0, 1)], 1) / np.maximum(size, 1)[:, None]
    mean_bright = np.bincount(flat, bright, n) / np.maximum(size, 1)
    border = np.unique(_border_pixels(labels))
    grey = np.linalg.norm(chroma[border] - 100 / 3, axis=1)  # the chromaticity's distance from neutral grey
    ref = border[(size[border] >= min_area) & (grey > chroma_tol)]  # only a coloured support tells its shadow
    is_bg = np.bincount(flat, background.reshape(-1), n) > 0
    cand = np.flatnonzero(~is_bg & (size > 0))
    if not len(ref) or not len(cand):
        return np.zeros(labels.shape, bool)
    near = np.linalg.norm(chroma[cand, None] - chroma[None, ref], axis=-1) < chroma_tol
    darker = mean_bright[cand, None] <= (1 + bright_tol) * mean_bright[None, ref]
    return np.isin(labels, cand[(near & darker).any(1)])


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


def _region_solidity(lbl: np.ndarray) -> np.ndarray:
    """Per label of ``lbl``, :func:`_solidity` of its region (the share left after a 3x3 erosion, the image's edge
    replicated): a pixel stays when its eight neighbours carry its label."""
    pad = np.pad(lbl, 1, mode="edge")
    h, w = lbl.shape
    inner = np.ones(lbl.shape, bool)
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            inner &= pad[dy : dy + h, dx : dx + w] == lbl
    n = int(lbl.max()) + 1
    return np.bincount(lbl[inner], minlength=n) / np.maximum(np.bincount(lbl.reshape(-1), minlength=n), 1)


def _thin_groups(
    lbl: np.ndarray, lab: np.ndarray, background: np.ndarray, min_area: int, min_solidity: float,
    max_background_frac: float, thresholds: Sequence[float],
) -> list[np.ndarray]:
    """Per threshold, [H, W] group ids (0: no group) of the regions of ``lbl`` that are mostly foreground but fail
    the area or the sliver test, joined where two of them touch (4-connected) and their mean chromaticities (a*, b*)
    differ by less than that threshold (single linkage; the fragments and their distances are found once). Lightness is left out: along a thin curved part it changes with the shading
    and the highlight, which split the part into fragments in the first place; chromaticity changes with the
    material."""
    n = int(lbl.max()) + 1
    flat = lbl.reshape(-1)
    size = np.bincount(flat, minlength=n).astype(np.float64)
    fg = np.bincount(flat, weights=(~background).reshape(-1).astype(np.float64), minlength=n)
    cand = (fg >= (1 - max_background_frac) * size) & ((size < min_area) | (_region_solidity(lbl) < min_solidity))
    cand &= size > 0
    chroma = np.stack([np.bincount(flat, weights=lab[..., c].reshape(-1), minlength=n) for c in (1, 2)], 1)
    chroma /= np.maximum(size, 1)[:, None]
    a = np.concatenate([lbl[:, :-1].reshape(-1), lbl[:-1, :].reshape(-1)])
    b = np.concatenate([lbl[:, 1:].reshape(-1), lbl[1:, :].reshape(-1)])
    sel = (a != b) & cand[a] & cand[b]
    pairs = np.unique(np.stack([np.minimum(a[sel], b[sel]), np.maximum(a[sel], b[sel])], 1), axis=0)
    dist = np.linalg.norm(chroma[pairs[:, 0]] - chroma[pairs[:, 1]], axis=1) if len(pairs) else np.zeros(0)
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    out = []
    for thresh in thresholds:
        near = pairs[dist < thresh]
        graph = coo_matrix((np.ones(len(near)), (near[:, 0], near[:, 1])), shape=(n, n))
        _, comp = connected_components(graph, directed=False)  # single linkage over the adjacent pairs
        root = np.full(int(comp.max()) + 1, n)
        np.minimum.at(root, comp, np.arange(n))  # each fragment's group named by its smallest member
        root = root[comp]
        groups = np.where(cand, root + 1, 0)[lbl]
        uniq, inv = np.unique(groups, return_inverse=True)
        out.append(inv.reshape(lbl.shape) + (0 if uniq[0] == 0 else 1))  # 1..k, 0 where no group
    return out


def _deduplicate_whole_first(masks: Sequence[Mask], iou_threshold: float) -> list[Mask]:
    """:func:`.segment.deduplicate` within the whole level and within the others, then the part and subpart masks that
    repeat a whole mask dropped: a one-region object's part mask is its whole mask, and the whole one must stay, since
    the geometry carves the object from the whole level (whatever the two masks' scores)."""
    whole = deduplicate([m for m in masks if m.level == "whole"], iou_threshold)
    rest = deduplicate([m for m in masks if m.level != "whole"], iou_threshold)
    if not whole or not rest:
        return whole + rest
    iou = mask_iou_matrix(np.stack([m.segmentation for m in rest]), np.stack([m.segmentation for m in whole]))
    return whole + [m for m, row in zip(rest, iou) if row.max() <= iou_threshold]


def _downscale(image: np.ndarray, work_size: int) -> np.ndarray:
    """`image` shrunk (area interpolation) so its longer side is at most `work_size`."""
    full_h, full_w = image.shape[:2]
    scale = work_size / max(full_h, full_w)
    if scale >= 1:
        return image
    import cv2

    size = (max(1, round(full_w * scale)), max(1, round(full_h * scale)))
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def _upscale(masks: list[Mask], width: int, height: int) -> list[Mask]:
    """Masks resized (nearest) to the full image, areas recounted."""
    import cv2

    up = []
    for m in masks:
        seg = cv2.resize(m.segmentation.astype(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST)
        up.append(Mask(seg.astype(bool), int(seg.astype(bool).sum()), m.predicted_iou, m.stability, m.level))
    return up


class BuiltinSegmenter:
    """Weight-free three-level segmenter (see module docstring; weaker than SAM).

    Superpixels (SLIC's, split along the graph segmentation's regions: module doc) are merged hierarchically
    while adjacent regions' mean CIE Lab colours differ by less than a threshold; the fine / medium / coarse
    thresholds give the subpart / part / whole levels:

    * whole: connected components of the foreground, where background = the coarse regions touching the image
      border and the regions that look like them in less light (module doc, "The whole object");
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
        if self.config.thin_chroma is not None and not self.config.thin_chroma > 0:
            raise ValueError(f"BuiltinSegmenterConfig.thin_chroma must be > 0 (or None: off), got "
                             f"{self.config.thin_chroma}.")
        if self.config.oversegment not in ("slic", "slic+graph"):
            raise ValueError(f"BuiltinSegmenterConfig.oversegment must be 'slic' or 'slic+graph', got "
                             f"{self.config.oversegment!r}.")

    def fingerprint(self) -> str:
        return f"builtin-slic-rag:{self.config!r}"

    def segment(self, image: np.ndarray) -> list[Mask]:
        cfg = self.config
        image = check_image(image)
        full_h, full_w = image.shape[:2]
        image = _downscale(image, cfg.work_size)
        h, w = image.shape[:2]
        min_area = max(cfg.min_area_px, int(cfg.min_area_frac * h * w))
        lab = _lab(image)
        ring = max(2, int(round(3 * max(h, w) / 512)))
        superpixels = _superpixels(image, cfg)
        by_level, perturbed, background = self._hierarchy(superpixels, lab, image, min_area)
        raw: list[Mask] = []
        for li, level in enumerate(LEVELS):
            if level not in cfg.levels:
                continue
            level_masks = []
            for m, area in self._regions(by_level[level], background, level == "whole", min_area):
                if _solidity(m) < cfg.min_solidity:
                    continue
                piou = _contrast_score(m, lab, ring)
                stab = _best_iou_with_labels(m, perturbed[level], area)
                if level != "whole" and (piou < cfg.min_predicted_iou or stab < cfg.min_stability):
                    continue
                level_masks.append(Mask(m, area, piou, stab, level))
            if level == "part" and cfg.thin_chroma is not None:
                level_masks.extend(self._thin_masks(by_level[level], lab, background, min_area, ring))
            level_masks.sort(key=lambda m: -m.score * m.area)
            raw.extend(level_masks[: cfg.max_masks_per_level[li]])
        masks = _deduplicate_whole_first(raw, cfg.dedup_iou)
        if (h, w) != (full_h, full_w):
            masks = _upscale(masks, full_w, full_h)
        return sort_masks(masks)

    def _hierarchy(
        self, superpixels: np.ndarray, lab: np.ndarray, image: np.ndarray, min_area: int
    ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], np.ndarray]:
        """Label maps per level, fine -> coarse, each merged further from the previous one (a monotone
        hierarchy); the same with perturbed thresholds (for stability); the background of the coarsest."""
        from skimage.measure import label as cc_label

        cfg = self.config
        t_whole, t_part, t_sub = cfg.thresholds
        merger = _RegionMerger(superpixels, lab, cfg.colour_weight)
        by_level: dict[str, np.ndarray] = {}
        perturbed: dict[str, np.ndarray] = {}
        for level, t in (("subpart", t_sub), ("part", t_part)):
            merger.merge(t)
            by_level[level] = merger.labels()
            perturbed[level] = merger.copy().merge(t * cfg.perturb).labels()
        merger.merge(t_whole)
        coarse = merger.labels()
        coarse_perturbed = merger.merge(t_whole * cfg.perturb).labels()
        background = self._whole_background(coarse, image, min_area)
        by_level["whole"] = cc_label(~background, connectivity=1).astype(np.int32)
        perturbed_bg = self._whole_background(coarse_perturbed, image, min_area)
        perturbed["whole"] = cc_label(~perturbed_bg, connectivity=1).astype(np.int32)
        return by_level, perturbed, background

    def _whole_background(self, coarse: np.ndarray, image: np.ndarray, min_area: int) -> np.ndarray:
        """bool [H, W]: the regions of ``coarse`` touching the border, and those like them in less light (module doc,
        "The whole object")."""
        background = _background(coarse)
        if self.config.support_chroma is not None:
            background |= _support_like(coarse, image, background, min_area, self.config.support_chroma,
                                        SUPPORT_BRIGHT_TOL)
        return background

    def _thin_masks(
        self, lbl: np.ndarray, lab: np.ndarray, background: np.ndarray, min_area: int, ring: int
    ) -> list[Mask]:
        """Part masks made of the level's dropped fragments (``thin_chroma``, module doc "Thin fragments"); their
        stability is the best IoU with the groups made at ``perturb`` times the chroma threshold."""
        cfg = self.config
        groups, perturbed = _thin_groups(lbl, lab, background, min_area, cfg.min_solidity, cfg.max_background_frac,
                                         (cfg.thin_chroma, cfg.thin_chroma * cfg.perturb))
        sizes = np.bincount(groups.reshape(-1))
        out = []
        for g in np.flatnonzero(sizes[1:] >= min_area) + 1:
            m = groups == g
            if _solidity(m) < cfg.min_solidity or background[m].mean() > cfg.max_background_frac:
                continue
            piou = _contrast_score(m, lab, ring)
            stab = _best_iou_with_labels(m, perturbed, int(sizes[g]))
            if piou >= cfg.min_predicted_iou and stab >= cfg.min_stability:
                out.append(Mask(m, int(sizes[g]), piou, stab, "part"))
        return out

    def _regions(
        self, lbl: np.ndarray, background: np.ndarray, whole: bool, min_area: int
    ) -> list[tuple[np.ndarray, int]]:
        """(mask, area) of a level's regions at least `min_area` large and mostly off the background (at the
        whole level label 0 is the background itself)."""
        sizes = np.bincount(lbl.reshape(-1))
        bg_counts = np.bincount(lbl[background], minlength=len(sizes))
        limit = self.config.max_background_frac
        return [
            (lbl == i, int(sizes[i]))
            for i in range(1 if whole else 0, len(sizes))
            if sizes[i] >= min_area and bg_counts[i] <= limit * sizes[i]
        ]
