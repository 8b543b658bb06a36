"""3-D clusters of the foreground Gaussians' means, for the object selection (:mod:`.select`, module doc, step 2).

* :func:`cluster_labels`: 26-connected occupied cells of a coarse grid, dilated by ``bridge_cells`` (parts of one
  object a few millimetres apart stay one cluster); the grid is coarsened, with a warning, where it would exceed
  :data:`MAX_CELLS` cells (a small plane's cell over strays metres apart can ask for tens of GB of labels).
* :func:`band_labels`: over a support plane, the clusters cut above a contact band and grown back into it
  (:func:`grow_into_band`).
* :func:`split_close`: a chosen cluster split again at its own resolution, by exact distances.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from typing import Protocol

import numpy as np
import torch
from torch import Tensor


class ClusterSettings(Protocol):
    """What the clusters read of :class:`.select.SelectConfig` (its docs)."""

    cluster_cells: int
    bridge_cells: int
    contact_band: float

logger = logging.getLogger(__name__)

MAX_CELLS = 1e9
"""the coarse clusters' grid (bool cells, int32 labels): about 6 GB at most; the GPU rooms' grids hold 180-200M"""

__all__ = ["MAX_CELLS", "ClusterSettings", "band_labels", "cell_size", "cluster_labels", "column_quantiles",
           "grow_into_band", "split_close"]


def cluster_labels(means: Tensor | np.ndarray, cfg: ClusterSettings, extent: float | None = None,
                   cell: float | None = None) -> tuple[Tensor, np.ndarray, float, np.ndarray]:  # fmt: skip
    """Cluster label of each point (0: none; a tensor on the points' device), the cell grid's origin and size, and
    the cluster ids. ``extent``: the size the ``cluster_cells`` divide (default: the points' own, 0.2-99.8%
    quantiles); ``cell``: the cell size, when the caller has it (:func:`cell_size`). The points' cells are found
    where the points are (a GPU); only the coarse grid is labelled on the host."""
    from scipy import ndimage  # lazily: a PLY-only export needs no SciPy

    m = torch.as_tensor(means).double()
    lo_hi = column_quantiles(m, (0.002, 0.998))  # (one partition for both)
    lo = lo_hi[0].cpu().numpy()
    if cell is None:
        cell = cell_size(m, cfg, extent, lo_hi)
    spread = lo_hi[1].cpu().numpy() - lo
    if float(np.prod(spread / cell + 5)) > MAX_CELLS:
        # a cell far finer than the points' spread (a support plane's size divided, under far strays): coarsened
        # until the grid fits (uncoarsened, such a grid can take tens of GB of labels)
        fine = cell
        while float(np.prod(spread / cell + 5)) > MAX_CELLS:
            cell *= 1.25
        logger.warning("object: the clusters' cell %.3g coarsened to %.3g to fit a spread of %.3g scene units",
                       fine, cell, float(spread.max()))  # fmt: skip
    lo = lo - 2 * cell
    idx = torch.floor((m - torch.as_tensor(lo, device=m.device)) / cell).long()
    top = np.floor(spread / cell).astype(np.int64) + 5  # 2 cells past the 99.8% quantiles, as before the 0.2% ones
    shape = np.maximum(idx.amax(0).cpu().numpy() + 1, 1) if len(idx) else np.ones(3, np.int64)
    inside = (idx >= 0).all(1)
    if float(np.prod(shape.astype(np.float64))) > MAX_CELLS:  # far strays: what lies past the box is no cluster
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


def cell_size(m: Tensor, cfg: ClusterSettings, extent: float | None = None, lo_hi: Tensor | None = None) -> float:
    """The clusters' cell: ``extent`` (default: the points' 0.2-99.8% quantiles' largest side; ``lo_hi``: those
    quantiles, when the caller has them) over ``cluster_cells``, but no finer than 1.5 x the points' median
    nearest-neighbour spacing, so that a sparse splat stays one cluster."""
    from scipy.spatial import cKDTree

    if extent is None:
        lo_hi = column_quantiles(m, (0.002, 0.998)) if lo_hi is None else lo_hi
        extent = float((lo_hi[1] - lo_hi[0]).max())
    sub = m[:: max(1, len(m) // 100_000)].cpu().numpy()
    return max(extent / cfg.cluster_cells, 1.5 * float(np.median(_nn_spacings(cKDTree(sub), sub))), 1e-9)


def _nn_spacings(tree, points: np.ndarray) -> np.ndarray:
    """The nearest-neighbour distances of 20,000 of ``points`` (each found among all of them, in ``tree``: a cKDTree
    of ``points``): the query of every point cost 0.9 s at 150k points, and the median moved by < 0.1%."""
    if len(points) < 2:
        return np.zeros(1)
    return tree.query(points[:: max(1, len(points) // 20_000)], k=2)[0][:, 1]


def grow_into_band(means: Tensor, band: Tensor, core_labels: Tensor, reach: float, rounds: int,
                   cfg: ClusterSettings, cell: float) -> Tensor:  # fmt: skip
    """long [N]: cluster labels of all ``means`` from those of the points outside the ``band`` (``core_labels``, over
    those points in order; 0: none). Every cluster grows into the band at once: a band point takes the label of the
    nearest labelled point within ``reach``, for ``rounds`` rounds (enough to cross the band's height, so an object's
    feet join it, and each foot goes to the nearest object, not along the floor to the next one). Band points that no
    cluster reaches are clustered among themselves (:func:`cluster_labels`, the same ``cell``), with labels after the
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
        sub, _, _, _ = cluster_labels(means[torch.from_numpy(left).to(means.device)], cfg, cell=cell)
        sub = sub.cpu().numpy()
        lab[left] = np.where(sub > 0, sub + lab.max(), 0)
    return torch.from_numpy(lab).to(means.device)


def column_quantiles(x: Tensor, qs: Sequence[float]) -> Tensor:
    """float64 [len(qs), D]: the column quantiles of ``x`` [N, D] (linear interpolation, NumPy's default): NumPy's on
    the CPU, a sort on a GPU (``torch.quantile`` refuses inputs of more than 16M elements)."""
    if x.device.type == "cpu":
        return torch.from_numpy(np.quantile(x.double().numpy(), qs, axis=0))
    return _sorted_quantiles(x, qs)


def _sorted_quantiles(x: Tensor, qs: Sequence[float]) -> Tensor:
    """:func:`column_quantiles` by a sort along the rows, on ``x``'s device."""
    s = torch.sort(x.double(), dim=0).values
    pos = torch.tensor(qs, dtype=torch.float64) * (len(s) - 1)
    i0 = pos.floor().long().clamp(0, len(s) - 1)
    i1 = (i0 + 1).clamp(max=len(s) - 1)
    t = (pos - i0).to(s.device)[:, None]
    a, b = s[i0.to(s.device)], s[i1.to(s.device)]
    return a + (b - a) * t


def split_close(m: Tensor, chosen: Tensor, centre: np.ndarray, cfg: ClusterSettings, rounds: int = 8,
                min_share: float = 0.01, spacing_quantile: float = 0.9, height: np.ndarray | None = None,
                tol: float = 0.0) -> Tensor:  # fmt: skip
    """bool [N] over ``m``: the ``chosen`` points split into parts that lie farther apart than the clusters' reach at
    the chosen points' own resolution (``bridge_cells`` + 1 cells of their 5-95% extent's longest side over
    ``cluster_cells``, a cell no finer than 1.5 x the ``spacing_quantile`` of their nearest-neighbour spacings: a
    sparse splat's Gaussians come in clumps, and with the median a CPU demo's table fell into 93 pieces), and the
    part nearest ``centre`` kept; again on that part until it stops shrinking (a neighbour's points stretched the
    extent, and so the reach, of the first round). The parts are the connected components of each point's 16 nearest
    neighbours within the reach (SciPy), exact distances rather than the coarse clusters' dilated cells, which join
    points up to 4-7 cells apart. Only parts of at least ``min_share`` of the points (and 16) are split off: smaller
    ones are gaps in the sampling of one surface or stray floaters, and each joins the part nearest it.

    ``height`` [N] (the points' heights above the support plane, ``tol`` its tolerance) with ``cfg.contact_band``:
    the contact band of :func:`band_labels` at the split's own reach. The parts are linked only through the points
    higher than ``tol`` + ``contact_band`` reaches above the plane, and each point in the band joins the part of the
    linked point nearest it. Near a floor, what lies within a reach of it touches it, so it is no evidence that two
    objects touch: faint Gaussians a few centimetres above a floor, on no object, can link a table to a chair or a
    lamp tens of centimetres away at a split's reach of 10 cm."""
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
        spacing = float(np.quantile(_nn_spacings(tree, p), spacing_quantile))
        reach = (cfg.bridge_cells + 1) * max(float((q[1] - q[0]).max()) / cfg.cluster_cells, 1.5 * spacing)
        linked = np.ones(len(p), bool)
        if height is not None:
            linked = np.asarray(height)[cur] > tol + cfg.contact_band * reach
            if linked.sum() < 16:
                linked[:] = True
        pl = p[linked]
        dist, j = (tree if linked.all() else cKDTree(pl)).query(pl, k=16, distance_upper_bound=reach)
        ok = np.isfinite(dist)
        rows = np.broadcast_to(np.arange(len(pl))[:, None], j.shape)[ok]
        graph = coo_matrix((np.ones(int(ok.sum()), np.int8), (rows, j[ok])), shape=(len(pl), len(pl)))
        n, comp_linked = connected_components(graph, directed=False)
        size = np.bincount(comp_linked, minlength=n)
        big = size >= max(16, min_share * len(pl))
        if big.sum() <= 1:
            break
        # crumbs (gaps in the sampling of one surface, stray floaters) are no objects, and the contact band links
        # nothing: each of their points joins the part of the nearest point in a part
        comp = np.zeros(len(p), np.int64)
        comp[linked] = comp_linked
        crumb = ~linked
        crumb[linked] = ~big[comp_linked]
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


def band_labels(m: Tensor, cfg: ClusterSettings, extent: float | None, height: np.ndarray | None, tol: float
                ) -> tuple[Tensor, np.ndarray]:  # fmt: skip
    """Cluster label of each candidate (0: none) and the cluster ids: :func:`cluster_labels`, or, above a support plane
    (``height``: the candidates' heights above it, ``tol``: its tolerance) with ``cfg.contact_band``, clusters cut
    above the band and grown back into it (:func:`grow_into_band`)."""
    if height is None:
        lab, _, _, ids = cluster_labels(m, cfg, extent)
        return lab, ids
    cell = cell_size(m, cfg, extent)
    reach = cell * (cfg.bridge_cells + 1)
    top = tol + cfg.contact_band * reach
    band = torch.from_numpy(height <= top).to(m.device)
    if bool(band.all()) or not bool(band.any()):
        lab, _, _, ids = cluster_labels(m, cfg, extent, cell=cell)
        return lab, ids
    core, _, _, _ = cluster_labels(m[~band], cfg, cell=cell)
    lab = grow_into_band(m, band, core, reach, math.ceil(top / reach) + 1, cfg, cell)
    ids = torch.unique(lab[lab > 0]).cpu().numpy()
    return lab, ids
