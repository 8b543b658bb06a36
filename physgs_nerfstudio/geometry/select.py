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
   object's parts a few millimetres apart stay one cluster). Over a support plane, two more rules: the
   clusters are cut above a *contact band* one reach above the plane and grown back into it (``contact_band``: near
   a floor, its clutter, contact shadows and reflections bridge the objects standing on it), and the chosen cluster
   is split again at its own resolution (:func:`.clusters.split_close`: the cells are a share of the floor, and a
   chair 15 cm from a table would share its cluster), linked above the contact band only (faint Gaussians
   just over a floor, on no object, would link neighbours). In `indoor_room` they keep the chair, the crate and the
   lamp out of the table's selection.
3. The object is the cluster nearest the *capture centre*: the point closest, in least squares, to every
   camera's optical axis (an object-centric capture looks at its object). A user's ``point`` (e.g. a click in
   the viewer, scene units) replaces the capture centre, and a ``bbox`` (viewer crop box, scene units)
   restricts the candidates first.
4. **Inside the masks' hull** (:func:`outside_mask_hull`, applied by :func:`drop_outside_hull`). A
   selected Gaussian is dropped when its centre projects outside the views' foreground masks (by more than
   ``hull_margin_px``) in at least ``hull_min_votes`` views and ``hull_vote_fraction`` (a majority) of the views
   whose frame holds it, or when fewer than ``hull_min_framed_fraction`` of the views frame it at all (the
   carving's rule for space out of frame). It counts every view that frames the centre, seen or hidden, whereas
   the probability of step 1 counts only the views that see a Gaussian: floaters and background that few views
   see, over masks that bled, can get a high probability and join the object's cluster. On a 60-view 512 px GPU
   run of the generated chair 81% of the selected Gaussians can be such; kept, they stretch the voxel domain and
   the seen Gaussians' polytope (:mod:`.solid`). The vote is a majority, not the carving's 15%: the built-in
   segmenter's masks miss a part of the object in a quarter of the views or more (the chair's seat at 512 px).
   Each view's vote is weighed by its mask's *recall* (:func:`hull_view_weights`): the share of the centres that
   the views' majority holds inside the masks which this view holds inside too. A plain count trusts every mask
   alike, and when a third of the views lose a table's top, a vote fraction of 0.35 drops the top (half the
   mass gone). Weighed, a view that lost a part says little about it, while
   the floaters, outside the masks of the views that see the object well, still go.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from torch import Tensor

from .capture import CaptureView
from .carve import mask_view_votes, signed_mask_distances
from .clusters import band_labels, split_close
from .gaussians import lift_masks
from .grid import GeometryError
from .support import (
    SupportConfig,
    SupportPlane,
    find_support,
    support_gaussians,
    support_plane_or_reason,
    views_up,
)

logger = logging.getLogger(__name__)

__all__ = [
    "ObjectSelection",
    "SelectConfig",
    "capture_centre",
    "drop_outside_hull",
    "hull_view_weights",
    "nearest_cluster",
    "select_object",
    "support_under",
]


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
    this fraction of the views that frame it (module doc, step 4: a majority; documented range 0.35-0.65)"""
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
    contact_band: float = 1.0
    """where a support plane is found: the clusters are cut only among the candidates higher above it than its
    tolerance plus this many of the clusters' *reach* (the distance across which they join: a cell times
    ``bridge_cells`` + 1), and the candidates in that band then join the cluster whose points they reach, a reach per
    round, for as many rounds as cross the band's height (:func:`.clusters.grow_into_band`); band candidates that no cluster
    reaches form clusters of their own (an object lying flat on the floor). Objects stand on a floor, and near it
    their contact shadows, clutter and the floor's reflections bridge them: on the GPU's `indoor_room` the chair, the
    crate and the lamp joined the table's cluster through Gaussians a few centimetres up. At the clusters' own
    resolution whatever lies within one reach of the plane touches it, so it is no evidence that two objects touch.
    0: every candidate above the plane's tolerance is clustered"""
    support: SupportConfig = field(default_factory=SupportConfig)
    """the floor or table the object stands on, dropped before the clusters (module doc, step 2;
    :mod:`.support`)"""

    def __post_init__(self) -> None:
        if not 0 < self.min_prob < 1:
            raise ValueError(f"SelectConfig.min_prob must be in (0, 1), got {self.min_prob}.")
        if min(self.prior) <= 0:
            raise ValueError(f"SelectConfig.prior must be two positive numbers, got {self.prior}.")
        if not self.contact_band >= 0:
            raise ValueError(f"SelectConfig.contact_band must be >= 0 (the clusters' reach), got {self.contact_band}.")
        if not 0 <= self.hull_vote_fraction <= 1:
            raise ValueError(f"SelectConfig.hull_vote_fraction must be in [0, 1], got {self.hull_vote_fraction}.")
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
    """bool [N]: the support plane's Gaussians (within its tolerance of it; found around the object, those around
    it, :func:`.support.support_gaussians`), None when there is none"""
    plane: SupportPlane | None = None
    """the plane the object stands on: the support plane found among the foreground (step 2), or the support found
    in the ring around the object's base among all the Gaussians (:func:`.support.find_support`, set by the
    reconstruction); None: none"""
    plane_in_masks: bool = False
    """the plane was found among the foreground (step 2: the masks took it in)"""
    support_found: str = ""
    """how the support under the object was found, or why none was (:func:`.support.find_support`, for the report)"""
    split_from: int = 0
    """the chosen cluster's Gaussians before the split over the support plane (0: not split; module doc, step 2)"""

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
    step 4), each view's vote weighed by its mask's recall (:func:`hull_view_weights`). Out-of-frame views and views
    behind which a centre lies do not vote. ``chunk``: centres looked up at a time."""
    dev = means.device
    n = means.shape[0]
    sdf = [d.to(dev) for d in signed_mask_distances([v.mask for v in views])]
    framed = torch.zeros(len(views), n, dtype=torch.bool, device=dev)
    outside = torch.zeros_like(framed)
    for s0 in range(0, n, chunk):
        framed[:, s0 : s0 + chunk], outside[:, s0 : s0 + chunk] = mask_view_votes(
            means[s0 : s0 + chunk].float(), views, sdf, cfg.hull_margin_px)
    n_framed, n_outside = framed.sum(0), outside.sum(0)
    w = hull_view_weights(framed, outside, (n_framed, n_outside)).to(torch.float32)
    w_framed, w_outside = w @ framed.to(w.dtype), w @ outside.to(w.dtype)
    by_vote = (w_outside >= cfg.hull_vote_fraction * w_framed) & (w_framed > 0)
    return ((n_outside >= cfg.hull_min_votes) & by_vote) | (n_framed < cfg.hull_min_framed_fraction * len(views))


def hull_view_weights(framed: Tensor, outside: Tensor, counts: tuple[Tensor, Tensor] | None = None) -> Tensor:
    """float64 [V]: each view's weight in the hull vote, from the views' votes on the selected centres (bool [V, n]
    each, :func:`.carve_views.mask_view_votes`): the *recall* of its mask, the share of the centres that the
    views' majority holds inside the masks (inside in more than half of the views that frame them) which this
    view, where it frames them, holds inside too. A view whose segmentation lost a part of the object (the
    built-in segmenter at 512 px dropped the table's top in a third of the views) keeps few of them, and its
    "outside" says little: it votes with that little weight, so that the views which did see the part decide.
    A view that frames none of them weighs 1. ``counts``: ``(framed.sum(0), outside.sum(0))`` when the caller
    has them."""
    n_framed, n_outside = counts if counts is not None else (framed.sum(0), outside.sum(0))
    member = (n_framed > 0) & (2 * n_outside < n_framed)
    held = (framed & member).sum(1)
    kept = (framed & ~outside & member).sum(1)
    return torch.where(held > 0, kept.double() / held.clamp_min(1).double(), torch.ones_like(kept, dtype=torch.float64))


def nearest_cluster(m: Tensor, lab: Tensor, centre: np.ndarray) -> Tensor:
    """bool [N]: the points of the cluster (``lab`` > 0) whose nearest point lies nearest ``centre``; every point
    when no point has a cluster."""
    valid = lab > 0
    if not bool(valid.any()):
        return torch.ones(len(lab), dtype=torch.bool, device=lab.device)
    d = (m - torch.as_tensor(centre, dtype=torch.float64, device=m.device)).norm(dim=1)
    dmin = torch.full((int(lab.max()) + 1,), float("inf"), dtype=torch.float64, device=d.device)
    dmin = dmin.scatter_reduce(0, lab[valid], d[valid], reduce="amin")
    dmin[0] = float("inf")
    return lab == int(torch.argmin(dmin))


def _nothing_selected(prob: Tensor, opaque: Tensor, views: Sequence[CaptureView], cfg: SelectConfig) -> str:
    """Why no Gaussian was selected, from what was seen: the masks' coverage and the best foreground probability."""
    cover = [float(v.mask.float().mean()) for v in views]
    masked = sum(c > 0 for c in cover)
    best = float(prob[opaque].max()) if bool(opaque.any()) else float("nan")
    if masked == 0:
        seen = f"none of the {len(views)} views has an object mask: check that perception ran on this dataset"
    else:
        seen = (f"{masked} of {len(views)} views have object masks (covering {100 * max(cover):.1f}% of a view at "
                f"most), but the best foreground probability of an opaque Gaussian is {best:.2f} (needs "
                f">= {cfg.min_prob}): the masks and the trained splat disagree; check the poses and the masks "
                "(perception/masks), or give --bbox")  # fmt: skip
    return f"no Gaussian lies on the object masks of the views: {seen}."


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
        raise GeometryError(_nothing_selected(prob, g.opacities >= cfg.min_opacity, views, cfg))
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
    lab, ids = band_labels(m_dev, cfg, extent, height, plane.tol if plane is not None else 0.0)
    chosen = nearest_cluster(m_dev, lab, centre)
    split_from = 0
    if height is not None:
        before = int(chosen.sum())
        chosen = split_close(m_dev, chosen, centre, cfg, height=height,
                             tol=plane.tol if plane is not None else 0.0)  # fmt: skip
        split_from = before if int(chosen.sum()) < before else 0
        logger.info("object: split at its own resolution over the support plane: %d of %d Gaussians kept",
                    int(chosen.sum()), before)  # fmt: skip
    selected = torch.zeros_like(cand)
    selected[idx[chosen.to(idx.device)]] = True
    logger.info("object: %d of %d Gaussians (%d clusters on the foreground)", int(selected.sum()),
                g.means.shape[0], len(ids))  # fmt: skip
    return ObjectSelection(prob, selected, centre, len(ids), on_support=on_support, support=support,
                           plane=plane if support is not None else None, plane_in_masks=support is not None,
                           split_from=split_from)  # fmt: skip


def drop_outside_hull(g: Any, selection: ObjectSelection, views: Sequence[CaptureView], cfg: SelectConfig) -> None:
    """Drop the selected Gaussians outside the masks' hull (module doc, step 4; :func:`outside_mask_hull`), in place."""
    idx = torch.nonzero(selection.selected).squeeze(1)
    drop = outside_mask_hull(g.means[idx], views, cfg)
    if not bool(drop.any()) or bool(drop.all()):  # all: the masks and the selection disagree; the carving says so
        return
    selection.selected[idx[drop]] = False
    selection.outside_hull = int(drop.sum())
    logger.info("object: %d selected Gaussians outside the masks' hull dropped, %d left", selection.outside_hull,
                selection.num_selected)  # fmt: skip


def support_under(g: Any, selection: ObjectSelection, views: Sequence[CaptureView], cfg: SelectConfig) -> None:
    """Where the selection found no support plane among the foreground, find the support under the object among all
    the Gaussians (:func:`.support.find_support`) and, in place, drop the object's Gaussians on or under it, set
    ``selection.plane`` and ``selection.support`` (its Gaussians around the object, whose pixels the masks lose)."""
    sc = cfg.support
    if selection.plane is not None or not sc.enabled or not bool(selection.selected.any()):
        return
    keep = (g.opacities.reshape(-1) >= cfg.min_opacity) | selection.selected
    idx = torch.nonzero(keep).squeeze(1)
    means = g.means[idx].double().cpu().numpy()
    sel = selection.selected[idx].cpu().numpy()
    cams = np.stack([v.centre.double().cpu().numpy() for v in views])
    plane, why = find_support(means, sel, cams, views_up(views), sc)
    selection.support_found = why
    if plane is None:
        logger.info("object: no support under it (%s)", why)
        return
    drop = sel & plane.drops(means)
    if int(sel.sum() - drop.sum()) < 50:  # nothing of the object would be left above it: no support
        selection.support_found = f"no support: the level layer around its base holds {drop[sel].mean():.0%} of it"
        logger.info("object: %s", selection.support_found)
        return
    dev = selection.selected.device
    selection.selected[idx[torch.from_numpy(drop).to(dev)]] = False
    selection.on_support += int(drop.sum())
    selection.support = torch.zeros_like(selection.selected)
    selection.support[idx[torch.from_numpy(support_gaussians(means, sel & ~drop, plane)).to(dev)]] = True
    selection.plane = plane
    logger.info("object: standing on a support (%s); %d of its Gaussians on or under it dropped", why,
                int(drop.sum()))  # fmt: skip
