"""Which Gaussians are the object.

1. Every Gaussian gets a Beta posterior of "belongs to a foreground object" from the foreground masks of every
   view that sees it (:func:`.gaussians.lift_masks`: per view, the share of its blending weight on mask pixels):
   ``P(object) = (a0 + inside) / (a0 + b0 + inside + outside)``. The floor, walls and background are outside
   the masks in the views that see them, so they come out near 0.
2. The *support plane* (a floor or table top that the masks took in with the objects standing on it, :mod:`.support`)
   is found among the foreground Gaussians and its Gaussians are dropped, when there is one. The other
   foreground Gaussians (probability >= ``min_prob``, opacity >= ``min_opacity``) are grouped into 3-D clusters
   (26-connected occupied cells of a coarse grid, ``cluster_cells`` along the longest side but no finer than
   1.5 x the Gaussians' median nearest-neighbour spacing, cells dilated by ``bridge_cells`` so that an
   object's parts a few millimetres apart stay one cluster). Over a support plane, two more rules (session 28): the
   clusters are cut above a *contact band* one reach above the plane and grown back into it (``contact_band``: near
   a floor, its clutter, contact shadows and reflections bridge the objects standing on it), and the chosen cluster
   is split again at its own resolution (``split_on_plane``, :func:`_split_close`: the cells are a share of the floor,
   and a chair 15 cm from a table shared its cluster). On the GPU's `indoor_room` at two fresh seeds the selected
   volume fell from 5.14x the table's to 1.73x and 1.69x, the chair, the crate and the lamp left out.
3. The object is the cluster nearest the *capture centre*: the point closest, in least squares, to every
   camera's optical axis (an object-centric capture looks at its object). A user's ``point`` (e.g. a click in
   the viewer, scene units) replaces the capture centre, and a ``bbox`` (viewer crop box, scene units)
   restricts the candidates first.
4. **Inside the masks' hull** (:func:`outside_mask_hull`, applied by :func:`.reconstruct.reconstruct_object`). A
   selected Gaussian is dropped when its centre projects outside the views' foreground masks (by more than
   ``hull_margin_px``) in at least ``hull_min_votes`` views and ``hull_vote_fraction`` (a majority) of the views
   whose frame holds it, or when fewer than ``hull_min_framed_fraction`` of the views frame it at all (the
   carving's rule for space out of frame). It counts every view that frames the centre, seen or hidden, whereas
   the probability of step 1 counts only the views that see a Gaussian: floaters and background that few views
   see, over masks that bled, can get a high probability and join the object's cluster. On a 60-view 512 px GPU
   run of the generated chair 81% of the selected Gaussians were such (benchmarks/README.md); kept, they
   stretched the voxel domain and made the selection's silhouette disagree with every view's mask, so that no
   view's failed mask could be replaced by it (:func:`.reconstruct._object_views`). The vote is a majority, not
   the carving's 15%: the built-in segmenter's masks miss a part of the object in a quarter of the views or more
   (the chair's seat at 512 px), and the carving's replacement of those masks needs the object's Gaussians kept.
   Each view's vote is weighed by its mask's *recall* (:func:`hull_view_weights`): the share of the centres that
   the views' majority holds inside the masks which this view holds inside too. A plain count trusts every mask
   alike, and when a third of the views lost the table's top (60-view 512 px GPU run, seed 3434), a vote fraction
   of 0.35 dropped the top: the mass fell to 0.49x. Weighed, a view that lost a part says little about it, while
   the floaters, outside the masks of the views that see the object well, still go.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from torch import Tensor

from .capture import CaptureView
from .carve import mask_view_votes, signed_mask_distances
from .errors import GeometryError
from .gaussians import lift_masks
from .support import SupportConfig, SupportPlane, support_plane_or_reason, views_up

logger = logging.getLogger(__name__)

_MAX_CELLS = 1e9  # the coarse clusters' grid (bool cells, int32 labels): about 6 GB at most; the GPU rooms needed 180-200M

__all__ = ["ObjectSelection", "SelectConfig", "capture_centre", "hull_view_weights", "select_object"]


@dataclass
class SelectConfig:
    """How the object's Gaussians are chosen (module doc)."""

    prior: tuple[float, float] = (1.0, 1.0)
    """Beta prior (a0, b0) of a Gaussian belonging to the object"""
    min_prob: float = 0.5
    min_opacity: float = 0.05
    cluster_cells: int = 48
    """cells along the longest side of the foreground's extent, for the 3-D clusters"""
    bridge_cells: int = 1
    """dilation of occupied cells before labelling clusters"""
    hull_vote_fraction: float = 0.5
    """a selected Gaussian is outside the masks' hull when its centre projects outside the views' masks in at least
    this fraction of the views that frame it (module doc, step 4: a majority; documented range 0.35-0.65); > 1
    switches the test off"""
    hull_weigh_views: bool = True
    """each view's hull vote is weighed by its mask's recall of the selection (:func:`hull_view_weights`, module doc,
    step 4); False: every view votes 1"""
    hull_min_votes: int = 2
    """... and in at least this many views (the carving's ``min_votes``)"""
    hull_min_framed_fraction: float = 0.5
    """a selected Gaussian whose centre fewer than this fraction of the views frame is dropped as well (the carving's
    ``min_seen_fraction``: an object-centric capture frames its object in every view)"""
    hull_margin_px: float = 2.0
    """a centre within this many pixels of a mask counts as inside it (the object's silhouette dilation)"""
    point: tuple[float, float, float] | None = None
    """pick the cluster nearest this point (scene units) instead of the capture centre"""
    bbox: tuple[float, float, float, float, float, float] | None = None
    """only Gaussians inside (xmin ymin zmin xmax ymax zmax), scene units (the viewer's crop box)"""
    contact_band: float | None = 1.0
    """where a support plane is found: the clusters are cut only among the candidates higher above it than its
    tolerance plus this many of the clusters' *reach* (the distance across which they join: a cell times
    ``bridge_cells`` + 1), and the candidates in that band then join the cluster whose points they reach, a reach per
    round, for as many rounds as cross the band's height (:func:`_grow_into_band`); band candidates that no cluster
    reaches form clusters of their own (an object lying flat on the floor). Objects stand on a floor, and near it
    their contact shadows, clutter and the floor's reflections bridge them: on the GPU's `indoor_room` the chair, the
    crate and the lamp joined the table's cluster through Gaussians a few centimetres up. At the clusters' own
    resolution whatever lies within one reach of the plane touches it, so it is no evidence that two objects touch.
    None: every candidate above the plane's tolerance is clustered (before session 28)"""
    split_on_plane: bool = True
    """where a support plane is found: the chosen cluster is split again at its own resolution (:func:`_split_close`:
    its Gaussians linked within the clusters' reach, two cells of ``cluster_cells`` along the longest side of its
    5-95% core or of 1.5 x the 90th percentile of their spacing, by exact distance), keeping the part nearest the
    centre, until it stops shrinking. The clusters' cells
    are a share of the floor's size, not of the object's, and objects on a floor stand close: on the GPU's
    `indoor_room` the chair stands 15 cm from the table and stayed in its cluster (2.5-2.8x the table's volume at three
    seeds, session 28). False: the coarse clusters alone"""
    support: SupportConfig = field(default_factory=SupportConfig)
    """the floor or table the object stands on, dropped before the clusters (module doc, step 2;
    :mod:`.support`)"""

    def __post_init__(self) -> None:
        if not 0 < self.min_prob < 1:
            raise ValueError(f"SelectConfig.min_prob must be in (0, 1), got {self.min_prob}.")
        if min(self.prior) <= 0:
            raise ValueError(f"SelectConfig.prior must be two positive numbers, got {self.prior}.")
        if self.contact_band is not None and not self.contact_band >= 0:
            raise ValueError(f"SelectConfig.contact_band must be >= 0 (the clusters' reach) or None, got "
                             f"{self.contact_band}.")
        if self.cluster_cells < 4:
            raise ValueError(f"SelectConfig.cluster_cells must be >= 4, got {self.cluster_cells}.")
        if self.bbox is not None:
            b = tuple(float(v) for v in self.bbox)
            if len(b) != 6 or not all(b[i] < b[i + 3] for i in range(3)):
                raise ValueError(f"bbox must be (xmin, ymin, zmin, xmax, ymax, zmax) with min < max, got {self.bbox}.")
            self.bbox = b  # type: ignore[assignment]


@dataclass
class ObjectSelection:
    prob: Tensor
    """float [N]: posterior probability that each Gaussian belongs to a foreground object"""
    selected: Tensor
    """bool [N]: the object's Gaussians"""
    centre: np.ndarray
    """the point the object was chosen by (capture centre or the user's point), scene units"""
    num_clusters: int
    outside_hull: int = 0
    """selected Gaussians dropped by the hull test (module doc, step 4)"""
    on_support: int = 0
    """foreground Gaussians dropped as the support plane's (module doc, step 2)"""
    support: Tensor | None = None
    """bool [N]: the support plane's Gaussians (within its tolerance of it), None when there is none"""
    plane: SupportPlane | None = None
    """the plane the object stands on: the support plane found among the foreground (step 2), or the resting plane
    found among all the Gaussians (:func:`.support.find_resting_plane`, set by the reconstruction); None: none"""
    split_from: int = 0
    """the chosen cluster's Gaussians before ``split_on_plane`` split it (0: not split; module doc, step 2)"""

    @property
    def num_selected(self) -> int:
        return int(self.selected.sum())


def capture_centre(views: Sequence[CaptureView]) -> np.ndarray:
    """Least-squares point nearest to every camera's optical axis (scene units)."""
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for v in views:
        d = v.axis.double().numpy()
        d = d / max(np.linalg.norm(d), 1e-12)
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ v.centre.double().numpy()
    if np.linalg.matrix_rank(A) < 3:  # parallel axes (e.g. one view): a point on the first axis
        v = views[0]
        return v.centre.double().numpy() + v.axis.double().numpy()
    return np.linalg.solve(A, b)


@torch.no_grad()
def outside_mask_hull(means: Tensor, views: Sequence[CaptureView], cfg: SelectConfig, *,
                      chunk: int = 1 << 20) -> Tensor:  # fmt: skip
    """bool [N]: centres that project outside the views' masks in enough of the views that frame them (module doc,
    step 4), each view's vote weighed by its mask's recall (:func:`hull_view_weights`) unless
    ``cfg.hull_weigh_views`` is False. Out-of-frame views and views behind which a centre lies do not vote.
    ``chunk``: centres looked up at a time."""
    dev = means.device
    n = means.shape[0]
    sdf = [d.to(dev) for d in signed_mask_distances([v.mask for v in views])]
    framed = torch.zeros(len(views), n, dtype=torch.bool, device=dev)
    outside = torch.zeros_like(framed)
    for s0 in range(0, n, chunk):
        framed[:, s0 : s0 + chunk], outside[:, s0 : s0 + chunk] = mask_view_votes(
            means[s0 : s0 + chunk].float(), views, sdf, cfg.hull_margin_px)
    n_framed, n_outside = framed.sum(0), outside.sum(0)
    if cfg.hull_weigh_views:
        w = hull_view_weights(framed, outside, (n_framed, n_outside)).to(torch.float32)
        w_framed, w_outside = w @ framed.to(w.dtype), w @ outside.to(w.dtype)
        by_vote = (w_outside >= cfg.hull_vote_fraction * w_framed) & (w_framed > 0)
    else:
        by_vote = n_outside >= cfg.hull_vote_fraction * n_framed
    return ((n_outside >= cfg.hull_min_votes) & by_vote) | (n_framed < cfg.hull_min_framed_fraction * len(views))


def hull_view_weights(framed: Tensor, outside: Tensor, counts: tuple[Tensor, Tensor] | None = None) -> Tensor:
    """float64 [V]: each view's weight in the hull vote, from the views' votes on the selected centres (bool [V, n]
    each, :func:`.carve.mask_view_votes`): the *recall* of its mask, the share of the centres that the views'
    majority holds inside the masks (inside in more than half of the views that frame them) which this view, where
    it frames them, holds inside too. A view whose segmentation lost a part of the object (the built-in segmenter at
    512 px dropped the table's top in a third of the views) keeps few of them, and its "outside" says little: it
    votes with that little weight, so that the views which did see the part decide. A view that frames none of them
    weighs 1. ``counts``: ``(framed.sum(0), outside.sum(0))`` when the caller has them."""
    n_framed, n_outside = counts if counts is not None else (framed.sum(0), outside.sum(0))
    member = (n_framed > 0) & (2 * n_outside < n_framed)
    held = (framed & member).sum(1)
    kept = (framed & ~outside & member).sum(1)
    return torch.where(held > 0, kept.double() / held.clamp_min(1).double(), torch.ones_like(kept, dtype=torch.float64))


def _clusters(means: Tensor | np.ndarray, cfg: SelectConfig, extent: float | None = None, cell: float | None = None
              ) -> tuple[Tensor, np.ndarray, float, np.ndarray]:  # fmt: skip
    """Cluster label of each point (0: none; a tensor on the points' device), the cell grid's origin and size, and
    the cluster ids. ``extent``: the size the ``cluster_cells`` divide (default: the points' own, 0.2-99.8%
    quantiles); ``cell``: the cell size, when the caller has it (:func:`_cell_size`). The points' cells are found
    where the points are (a GPU); only the coarse grid is labelled on the host."""
    from scipy import ndimage  # lazily: a PLY-only export needs no SciPy

    m = torch.as_tensor(means).double()
    lo_hi = _quantiles(m, (0.002, 0.998))  # (one partition for both)
    lo = lo_hi[0].cpu().numpy()
    if cell is None:
        cell = _cell_size(m, cfg, extent, lo_hi)
    spread = lo_hi[1].cpu().numpy() - lo
    if float(np.prod(spread / cell + 5)) > _MAX_CELLS:
        # a cell far finer than the points' spread (a support plane's size divided, under far strays): coarsened
        # until the grid fits (the CPU lamp at seed 9696 asked for 38 GB of labels)
        fine = cell
        while float(np.prod(spread / cell + 5)) > _MAX_CELLS:
            cell *= 1.25
        logger.warning("object: the clusters' cell %.3g coarsened to %.3g to fit a spread of %.3g scene units",
                       fine, cell, float(spread.max()))  # fmt: skip
    lo = lo - 2 * cell
    idx = torch.floor((m - torch.as_tensor(lo, device=m.device)) / cell).long()
    top = np.floor(spread / cell).astype(np.int64) + 5  # 2 cells past the 99.8% quantiles, as before the 0.2% ones
    shape = np.maximum(idx.amax(0).cpu().numpy() + 1, 1) if len(idx) else np.ones(3, np.int64)
    inside = (idx >= 0).all(1)
    if float(np.prod(shape.astype(np.float64))) > _MAX_CELLS:  # far strays: what lies past the box is no cluster
        inside &= (idx < torch.as_tensor(top, device=idx.device)).all(1)
        shape = np.minimum(shape, top)
    flat = (idx[:, 0] * int(shape[1]) + idx[:, 1]) * int(shape[2]) + idx[:, 2]
    occ = np.zeros(int(np.prod(shape)), bool)
    occ[flat[inside].cpu().numpy()] = True
    occ = occ.reshape(*shape)
    grown = ndimage.binary_dilation(occ, iterations=cfg.bridge_cells) if cfg.bridge_cells > 0 else occ
    labels, n = ndimage.label(grown, structure=np.ones((3, 3, 3), bool))
    lab = torch.zeros(len(m), dtype=torch.long, device=m.device)
    lab[inside] = torch.from_numpy(labels.reshape(-1)).to(m.device).long()[flat[inside]]
    return lab, lo, cell, np.arange(1, n + 1)


def _cell_size(m: Tensor, cfg: SelectConfig, extent: float | None = None, lo_hi: Tensor | None = None) -> float:
    """The clusters' cell: ``extent`` (default: the points' 0.2-99.8% quantiles' largest side; ``lo_hi``: those
    quantiles, when the caller has them) over ``cluster_cells``, but no finer than 1.5 x the points' median
    nearest-neighbour spacing, so that a sparse splat stays one cluster."""
    from scipy.spatial import cKDTree

    if extent is None:
        lo_hi = _quantiles(m, (0.002, 0.998)) if lo_hi is None else lo_hi
        extent = float((lo_hi[1] - lo_hi[0]).max())
    sub = m[:: max(1, len(m) // 100_000)].cpu().numpy()
    # the median nearest-neighbour spacing, estimated from the neighbours of 20,000 of the points (each found among
    # all of them): the query of every point cost 0.9 s at 150k points, and the median moved by < 0.1%
    probe = sub[:: max(1, len(sub) // 20_000)]
    nn = cKDTree(sub).query(probe, k=2)[0][:, 1] if len(sub) > 1 else np.zeros(1)
    return max(extent / cfg.cluster_cells, 1.5 * float(np.median(nn)), 1e-9)


def _grow_into_band(means: Tensor, band: Tensor, core_labels: Tensor, reach: float, rounds: int, cfg: SelectConfig,
                    cell: float) -> Tensor:  # fmt: skip
    """long [N]: cluster labels of all ``means`` from those of the points outside the ``band`` (``core_labels``, over
    those points in order; 0: none). Every cluster grows into the band at once: a band point takes the label of the
    nearest labelled point within ``reach``, for ``rounds`` rounds (enough to cross the band's height, so an object's
    feet join it, and each foot goes to the nearest object, not along the floor to the next one). Band points that no
    cluster reaches are clustered among themselves (:func:`_clusters`, the same ``cell``), with labels after the
    core's."""
    from scipy.spatial import cKDTree

    b = band.cpu().numpy()
    lab = np.zeros(len(b), np.int64)
    lab[~b] = core_labels.cpu().numpy()
    pts = means.cpu().numpy()
    for _ in range(max(1, rounds)):
        todo = np.nonzero(b & (lab == 0))[0]
        have = np.nonzero(lab > 0)[0]
        if not len(todo) or not len(have):
            break
        dist, j = cKDTree(pts[have]).query(pts[todo], distance_upper_bound=reach)
        ok = np.isfinite(dist)
        if not ok.any():
            break
        lab[todo[ok]] = lab[have[j[ok]]]
    left = b & (lab == 0)
    if left.any():
        sub, _, _, _ = _clusters(means[torch.from_numpy(left).to(means.device)], cfg, cell=cell)
        sub = sub.cpu().numpy()
        lab[left] = np.where(sub > 0, sub + lab.max(), 0)
    return torch.from_numpy(lab).to(means.device)


def _quantiles(x: Tensor, qs: Sequence[float]) -> Tensor:
    """float64 [len(qs), D]: the column quantiles of ``x`` [N, D] (linear interpolation, NumPy's default): NumPy's on
    the CPU, a sort on a GPU (``torch.quantile`` refuses inputs of more than 16M elements)."""
    if x.device.type == "cpu":
        return torch.from_numpy(np.quantile(x.double().numpy(), qs, axis=0))
    return _sorted_quantiles(x, qs)


def _sorted_quantiles(x: Tensor, qs: Sequence[float]) -> Tensor:
    """:func:`_quantiles` by a sort along the rows, on ``x``'s device."""
    s = torch.sort(x.double(), dim=0).values
    pos = torch.tensor(qs, dtype=torch.float64) * (len(s) - 1)
    i0 = pos.floor().long().clamp(0, len(s) - 1)
    i1 = (i0 + 1).clamp(max=len(s) - 1)
    t = (pos - i0).to(s.device)[:, None]
    a, b = s[i0.to(s.device)], s[i1.to(s.device)]
    return a + (b - a) * t


def _split_close(m: Tensor, chosen: Tensor, centre: np.ndarray, cfg: SelectConfig, rounds: int = 8,
                 min_share: float = 0.01, spacing_quantile: float = 0.9) -> Tensor:
    """bool [N] over ``m``: the ``chosen`` points split into parts that lie farther apart than the clusters' reach at
    the chosen points' own resolution (``bridge_cells`` + 1 cells of their 5-95% extent's longest side over
    ``cluster_cells``, a cell no finer than 1.5 x the ``spacing_quantile`` of their nearest-neighbour spacings: a
    sparse splat's Gaussians come in clumps, and with the median a CPU demo's table fell into 93 pieces), and the
    part nearest ``centre`` kept; again on that part until it stops shrinking (a neighbour's points stretched the
    extent, and so the reach, of the first round). The parts are the connected components of each point's 16 nearest
    neighbours within the reach (SciPy), exact distances rather than the coarse clusters' dilated cells, which join
    points up to 4-7 cells apart. Only parts of at least ``min_share`` of the points (and 16) are split off: smaller
    ones are gaps in the sampling of one surface or stray floaters, and each joins the part nearest it."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    cur = chosen.cpu().numpy().copy()
    pts = m.cpu().numpy()
    for _ in range(rounds):
        p = pts[cur]
        if len(p) < 16:
            break
        q = np.quantile(p, (0.05, 0.95), axis=0)
        tree = cKDTree(p)
        nn = tree.query(p[:: max(1, len(p) // 20_000)], k=2)[0][:, 1]
        spacing = float(np.quantile(nn, spacing_quantile))
        reach = (cfg.bridge_cells + 1) * max(float((q[1] - q[0]).max()) / cfg.cluster_cells, 1.5 * spacing)
        dist, j = tree.query(p, k=16, distance_upper_bound=reach)
        ok = np.isfinite(dist)
        rows = np.broadcast_to(np.arange(len(p))[:, None], j.shape)[ok]
        graph = coo_matrix((np.ones(int(ok.sum()), np.int8), (rows, j[ok])), shape=(len(p), len(p)))
        n, comp = connected_components(graph, directed=False)
        size = np.bincount(comp, minlength=n)
        big = size >= max(16, min_share * len(p))
        if big.sum() <= 1:
            break
        # crumbs (gaps in the sampling of one surface, stray floaters) are no objects: each joins the nearest part
        crumb = ~big[comp]
        if crumb.any():
            _, k = cKDTree(p[~crumb]).query(p[crumb])
            comp[crumb] = comp[~crumb][k]
        d = np.linalg.norm(p - centre, axis=1)
        near = np.full(n, np.inf)
        np.minimum.at(near, comp, d)
        keep = comp == int(np.argmin(near))
        idx = np.nonzero(cur)[0]
        cur[:] = False
        cur[idx[keep]] = True
    return torch.from_numpy(cur).to(chosen.device)


def _labels(m: Tensor, cfg: SelectConfig, extent: float | None, height: np.ndarray | None, tol: float
            ) -> tuple[Tensor, np.ndarray]:  # fmt: skip
    """Cluster label of each candidate (0: none) and the cluster ids: :func:`_clusters`, or, above a support plane
    (``height``: the candidates' heights above it, ``tol``: its tolerance) with ``cfg.contact_band``, clusters cut
    above the band and grown back into it (:func:`_grow_into_band`)."""
    if height is None or cfg.contact_band is None:
        lab, _, _, ids = _clusters(m, cfg, extent)
        return lab, ids
    cell = _cell_size(m, cfg, extent)
    reach = cell * (cfg.bridge_cells + 1)
    top = tol + cfg.contact_band * reach
    band = torch.from_numpy(height <= top).to(m.device)
    if bool(band.all()) or not bool(band.any()):
        lab, _, _, ids = _clusters(m, cfg, extent, cell=cell)
        return lab, ids
    core, _, _, _ = _clusters(m[~band], cfg, cell=cell)
    lab = _grow_into_band(m, band, core, reach, math.ceil(top / reach) + 1, cfg, cell)
    ids = torch.unique(lab[lab > 0]).cpu().numpy()
    return lab, ids


@torch.no_grad()
def select_object(g: Any, views: Sequence[CaptureView], cfg: SelectConfig | None = None, *,
                  backend: str = "auto") -> ObjectSelection:  # fmt: skip
    """The object's Gaussians (module doc)."""
    cfg = cfg or SelectConfig()
    inside, outside = lift_masks(g, views, backend=backend)
    a0, b0 = cfg.prior
    prob = ((a0 + inside) / (a0 + b0 + inside + outside)).float()
    cand = (prob >= cfg.min_prob) & (g.opacities >= cfg.min_opacity)
    if cfg.bbox is not None:
        b = torch.as_tensor(cfg.bbox, dtype=g.means.dtype, device=g.means.device)
        cand &= ((g.means >= b[:3]) & (g.means <= b[3:])).all(-1)
    centre = np.asarray(cfg.point, dtype=np.float64) if cfg.point is not None else capture_centre(views)
    if not bool(cand.any()):
        raise GeometryError("no Gaussian lies on the object masks of the views (foreground probability >= "
                         f"{cfg.min_prob}): check that perception ran on this dataset, or give a bbox.")  # fmt: skip
    idx = torch.nonzero(cand).squeeze(1)
    m_dev = g.means[idx].double()  # the candidates' means, gathered once
    means = m_dev.cpu().numpy()
    on_support = 0
    extent = None
    support = None
    height = None  # the kept candidates' heights above the support plane, where there is one
    plane, why_not = support_plane_or_reason(means, np.stack([v.centre.double().cpu().numpy() for v in views]),
                                             views_up(views), cfg.support, views)  # fmt: skip
    if plane is None:
        logger.info("object: no support plane among the foreground (%s)", why_not)
    else:
        h = plane.height(means)
        keep = h > plane.tol  # (SupportPlane.drops)
        if keep.any():
            on_support = int((~keep).sum())
            logger.info("object: %d foreground Gaussians on or under the support plane (a floor or table holding "
                        "%.0f%% of the foreground) dropped", on_support, 100 * plane.share)  # fmt: skip
            flat = torch.from_numpy(np.abs(h) <= plane.tol).to(idx.device)
            support = torch.zeros_like(cand)
            support[idx[flat]] = True
            kept = torch.from_numpy(keep).to(idx.device)
            idx, m_dev, height = idx[kept], m_dev[kept], h[keep]
            extent = plane.size  # the scene the plane holds, not the floaters and background around it
    lab, ids = _labels(m_dev, cfg, extent, height, plane.tol if plane is not None else 0.0)
    valid = lab > 0
    if not bool(valid.any()):
        chosen = torch.ones(len(lab), dtype=torch.bool, device=lab.device)
    else:
        # distance of each cluster to the centre: its nearest Gaussian
        d = (m_dev - torch.as_tensor(centre, dtype=torch.float64, device=m_dev.device)).norm(dim=1)
        dmin = torch.full((int(lab.max()) + 1,), float("inf"), dtype=torch.float64, device=d.device)
        dmin = dmin.scatter_reduce(0, lab[valid], d[valid], reduce="amin")
        dmin[0] = float("inf")
        chosen = lab == int(torch.argmin(dmin))
    split_from = 0
    if height is not None and cfg.split_on_plane:
        before = int(chosen.sum())
        chosen = _split_close(m_dev, chosen, centre, cfg)
        split_from = before if int(chosen.sum()) < before else 0
        logger.info("object: split at its own resolution over the support plane: %d of %d Gaussians kept",
                    int(chosen.sum()), before)  # fmt: skip
    selected = torch.zeros_like(cand)
    selected[idx[chosen.to(idx.device)]] = True
    logger.info("object: %d of %d Gaussians (%d clusters on the foreground)", int(selected.sum()),
                g.means.shape[0], len(ids))  # fmt: skip
    return ObjectSelection(prob, selected, centre, len(ids), on_support=on_support, support=support,
                           plane=plane if support is not None else None, split_from=split_from)
