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
   object's parts a few millimetres apart stay one cluster).
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
    contact_band: float | None = None
    """where a support plane is found: the clusters are cut among the candidates more than this many of the plane's
    tolerances above it, and the chosen cluster grows back into the band (a band candidate joins within the cells'
    bridge of one already in, for as many rounds as cross the band's height: :func:`_join_band`). Objects stand on a
    floor; near it, its clutter and reflections bridge them (the GPU's
    `indoor_room`: the chair, the crate and the lamp joined the table's cluster through Gaussians a few centimetres
    up). None (the default): every candidate above the plane's tolerance is clustered; measured offline only
    (benchmarks/README.md, session 27)"""
    support: SupportConfig = field(default_factory=SupportConfig)
    """the floor or table the object stands on, dropped before the clusters (module doc, step 2;
    :mod:`.support`)"""

    def __post_init__(self) -> None:
        if not 0 < self.min_prob < 1:
            raise ValueError(f"SelectConfig.min_prob must be in (0, 1), got {self.min_prob}.")
        if min(self.prior) <= 0:
            raise ValueError(f"SelectConfig.prior must be two positive numbers, got {self.prior}.")
        if self.contact_band is not None and not self.contact_band >= 1:
            raise ValueError(f"SelectConfig.contact_band must be >= 1 (plane tolerances) or None, got {self.contact_band}.")
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


def _clusters(means: Tensor | np.ndarray, cfg: SelectConfig, extent: float | None = None
              ) -> tuple[Tensor, np.ndarray, float, np.ndarray]:  # fmt: skip
    """Cluster label of each point (0: none; a tensor on the points' device), the cell grid's origin and size, and
    the cluster ids. ``extent``: the size the ``cluster_cells`` divide (default: the points' own, 0.2-99.8%
    quantiles). The points' cells are found where the points are (a GPU); only the coarse grid is labelled on the
    host."""
    from scipy import ndimage  # lazily: a PLY-only export needs no SciPy
    from scipy.spatial import cKDTree

    m = torch.as_tensor(means).double()
    lo_hi = _quantiles(m, (0.002, 0.998))  # (one partition for both)
    lo = lo_hi[0].cpu().numpy()
    span = float((lo_hi[1] - lo_hi[0]).max()) if extent is None else extent
    sub = m[:: max(1, len(m) // 100_000)].cpu().numpy()
    # the median nearest-neighbour spacing, estimated from the neighbours of 20,000 of the points (each found among
    # all of them): the query of every point cost 0.9 s at 150k points, and the median moved by < 0.1%
    probe = sub[:: max(1, len(sub) // 20_000)]
    nn = cKDTree(sub).query(probe, k=2)[0][:, 1] if len(sub) > 1 else np.zeros(1)
    # cells no finer than the Gaussians' own spacing, so a sparse splat stays one cluster
    cell = max(span / cfg.cluster_cells, 1.5 * float(np.median(nn)), 1e-9)
    lo = lo - 2 * cell
    idx = torch.floor((m - torch.as_tensor(lo, device=m.device)) / cell).long()
    shape = np.maximum(idx.amax(0).cpu().numpy() + 1, 1) if len(idx) else np.ones(3, np.int64)
    inside = (idx >= 0).all(1)
    flat = (idx[:, 0] * int(shape[1]) + idx[:, 1]) * int(shape[2]) + idx[:, 2]
    occ = np.zeros(int(np.prod(shape)), bool)
    occ[flat[inside].cpu().numpy()] = True
    occ = occ.reshape(*shape)
    grown = ndimage.binary_dilation(occ, iterations=cfg.bridge_cells) if cfg.bridge_cells > 0 else occ
    labels, n = ndimage.label(grown, structure=np.ones((3, 3, 3), bool))
    lab = torch.zeros(len(m), dtype=torch.long, device=m.device)
    lab[inside] = torch.from_numpy(labels.reshape(-1)).to(m.device).long()[flat[inside]]
    return lab, lo, cell, np.arange(1, n + 1)


def _join_band(means: Tensor, band: Tensor, chosen_core: Tensor, reach: float, rounds: int) -> Tensor:
    """bool [N] over ``means``: the chosen cluster of the points outside the ``band`` (``chosen_core``, over those
    points in order), grown into the band: a band point joins when it lies within ``reach`` of a point already in,
    for ``rounds`` rounds (enough to cross the band's height, not to walk along it to the next object's feet)."""
    from scipy.spatial import cKDTree

    member = torch.zeros(len(means), dtype=torch.bool)
    member[~band.cpu()] = chosen_core.cpu()
    pts = means.cpu().numpy()
    low = torch.nonzero(band.cpu()).squeeze(1).numpy()
    for _ in range(max(1, rounds)):
        todo = low[~member.numpy()[low]]
        if not len(todo) or not bool(member.any()):
            break
        dist, _ = cKDTree(pts[member.numpy()]).query(pts[todo], distance_upper_bound=reach)
        new = todo[np.isfinite(dist)]
        if not len(new):
            break
        member[torch.from_numpy(new)] = True
    return member.to(means.device)


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
    band = None  # the kept candidates within the contact band above the support plane (``contact_band``)
    plane, why_not = support_plane_or_reason(means, np.stack([v.centre.double().cpu().numpy() for v in views]),
                                             views_up(views), cfg.support, views)  # fmt: skip
    if plane is None:
        logger.info("object: no support plane among the foreground (%s)", why_not)
    else:
        height = plane.height(means)
        keep = height > plane.tol  # (SupportPlane.drops)
        if keep.any():
            on_support = int((~keep).sum())
            logger.info("object: %d foreground Gaussians on or under the support plane (a floor or table holding "
                        "%.0f%% of the foreground) dropped", on_support, 100 * plane.share)  # fmt: skip
            flat = torch.from_numpy(np.abs(height) <= plane.tol).to(idx.device)
            support = torch.zeros_like(cand)
            support[idx[flat]] = True
            kept = torch.from_numpy(keep).to(idx.device)
            idx, m_dev = idx[kept], m_dev[kept]
            extent = plane.size  # the scene the plane holds, not the floaters and background around it
            if cfg.contact_band is not None:
                band = torch.from_numpy(height[keep] <= cfg.contact_band * plane.tol).to(idx.device)
                band = None if bool(band.all()) else band
    core = m_dev if band is None else m_dev[~band]
    lab, _, cell, ids = _clusters(core, cfg, extent)
    valid = lab > 0
    if not bool(valid.any()):
        chosen = torch.ones(len(lab), dtype=torch.bool, device=lab.device)
    else:
        # distance of each cluster to the centre: its nearest Gaussian
        d = (core - torch.as_tensor(centre, dtype=torch.float64, device=core.device)).norm(dim=1)
        dmin = torch.full((int(lab.max()) + 1,), float("inf"), dtype=torch.float64, device=d.device)
        dmin = dmin.scatter_reduce(0, lab[valid], d[valid], reduce="amin")
        dmin[0] = float("inf")
        chosen = lab == int(torch.argmin(dmin))
    if band is not None:
        reach = cell * (cfg.bridge_cells + 1)
        chosen = _join_band(m_dev, band, chosen, reach, math.ceil(cfg.contact_band * plane.tol / reach) + 1)
    selected = torch.zeros_like(cand)
    selected[idx[chosen.to(idx.device)]] = True
    logger.info("object: %d of %d Gaussians (%d clusters on the foreground)", int(selected.sum()),
                g.means.shape[0], len(ids))  # fmt: skip
    return ObjectSelection(prob, selected, centre, len(ids), on_support=on_support, support=support,
                           plane=plane if support is not None else None)
