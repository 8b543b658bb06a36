"""The plane the object stands on: a floor or a table top that the foreground masks took in with the objects.

Perception's whole-object masks leave out what touches the image border (walls, a floor that fills the frame), but
a floor or a platform seen whole, as in the generated ``indoor_room``, is a region like any other: its Gaussians
get a high foreground probability and join every object standing on it into one cluster
(:mod:`.select`; before this step, 12,837 of the 17,108 Gaussians selected in ``indoor_room`` at demo settings lay
on the floor and the rug, and the "object" came out 105x the table's volume).

The robotics answer is the tabletop one: find the support plane and drop it, then cluster what stands on it. Here
the plane is searched among the foreground Gaussians' means, and only accepted when it is a support, so that an
object's own flat bottom (a crate's, a shoe's sole) or top (a table's) is never taken for one:

* **level**: its normal is within ``max_tilt_deg`` of the views' up direction (:func:`views_up`; an object-centric capture is
  shot from around and above its object);
* **below everything**: at most ``max_below`` of the foreground near the plane (within half its size of its
  inliers' footprint, in the plane and in height: far floaters and background are other clusters) lies more than
  the plane's tolerance below it, under its footprint (its inliers' 1-99% box), and at least
  ``min_cameras_above`` of the cameras lie above it (a table's top has its legs below it; the views of an
  object-centric capture from below its bottom face are under that face). Where the views are given (the search
  among the foreground), a point under the plane counts only when the views see it *past* the plane, on their
  masks (:func:`seen_under_plane`): a table's legs from the low views. A splat draws a shiny floor's reflections
  with Gaussians under it, seen only through it (the GPU's ``indoor_room`` at 512 px: 27% of the foreground near
  the floor, which was rejected, and the room's whole floor came out as the object);
* **wider than what stands on it**: the plane's inliers reach beyond the 5-95% quantiles (``WIDER_QUANTILE``) of
  the rest of the foreground above it, over and beside its footprint at any height, on all four sides, by
  ``margin`` of that extent (an object's own bottom face *is* its footprint; a lamp's base has its shade overhanging
  it; a few floaters beside a floor do not move the quantiles);
* **substantial**: it holds at least ``min_share`` of the foreground near it.

The plane is fitted by RANSAC with the normal constrained to be level (three points from the lowest third of the
foreground, best inlier count within ``SEARCH_BAND``), refined by least squares on its inliers. The tolerance is the
inliers' own thickness: ``tol_sigmas`` robust standard deviations (1.4826 x MAD) of their distances to the plane, at
least ``min_tol`` of the foreground's extent, so a rug on the floor (8 mm at demo settings, where a pixel covers
3 cm of the floor) counts with it. A plane is a thin layer: when the refinement grows the tolerance past
``MAX_TOL_GROWTH`` times the search's band, it cut through a diffuse cloud (a floor's reflections, the lowest
third of the GPU room's foreground), and the search is made again with the three points drawn from all the
points (``SAMPLE_QUANTILES``). The Gaussians within the tolerance of the plane and below it are not the
object's; those above it are clustered as before.

The support under the object
----------------------------
Where the masks leave the floor out (the usual case: perception's whole masks hold the object, spilling onto the
floor at its base), the search above finds nothing among the foreground, but the floor or table is still in the
splat, all around the object. :func:`find_support` looks for it there, after the object is selected: the plane
whose normal is the views' up direction (:func:`views_up`) through the Gaussians (all of them, the object's and
the background's) in a *ring* around the object's *base* (``BASE_SHARE`` of its height above its lowest part), from
``RING_GAP`` to ``RING_GAP + RING_WIDTH`` of its horizontal size beyond the base's footprint and within
``RING_HEIGHT`` of its size of the base's height. RANSAC with the normal fixed level (every ring point's height a
hypothesis, the band ``RING_BAND`` of the object's size), then least squares (the inliers' mean height) with the
tolerance from their spread as above, at most ``MAX_TOL_BANDS`` bands. It is a support when its inliers cover
``MIN_RING_COVERAGE`` of the ring's ``RING_SECTORS`` angular sectors (a level layer all around the base, not a ledge
or a few floaters) and ``min_cameras_above`` of the cameras lie above it. An object's own faces lie inside the
base's footprint or above the ring, so they are never in it; an object standing on nothing has an empty ring.

What the plane then does (:mod:`.reconstruct`): the object's Gaussians on it (within its tolerance) or below it
are dropped; the voxel grid is placed so that a layer of voxel faces lies on it (:func:`align_to_plane`) and the
carved solid is cut there (no voxel straddles the contact); and each view's object mask loses the pixels whose
rendered surface is the support's (the support's Gaussians around the object, :func:`support_gaussians`, rendered
opaque where the object's are not): the masks' spill onto the floor carves nothing.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from .capture import CaptureView
from .carve import mask_view_votes, signed_mask_distances
from .grid import VoxelGrid

__all__ = ["MAX_TOL_BANDS", "SupportConfig", "SupportPlane", "align_to_plane", "find_support", "find_support_plane",
           "seen_under_plane", "support_gaussians", "support_plane_or_reason", "views_up"]


# Fixed rules (module doc), each with its physical meaning; not options.
SEARCH_BAND = 0.01
"""the foreground search's RANSAC band, as a share of the points' extent (5-95% quantiles): the thickness of a
floor's layer of Gaussian centres at demo settings (a few millimetres on a metre of floor)"""
SAMPLE_QUANTILES = (1 / 3, 1.0)
"""the foreground search draws its planes' three points from the lowest this share of the points (heights along the
views' up), each share in turn until a plane passes the tests: the lowest third first (a floor under a table top
that the masks took in too), then all of them (a splat puts a shiny floor's reflections under it, and they are the
lowest third: the GPU's ``indoor_room`` at 512 px)"""
MAX_TOL_GROWTH = 3.0
"""a plane is a thin layer: the foreground search's refined tolerance may be at most this many times its band;
beyond, the "plane" is a cut through a diffuse cloud, whose tolerance grows with each refinement (2 m on the GPU's
``indoor_room`` reflections)"""
WIDER_QUANTILE = 0.05
""""wider than what stands on it" compares the plane's footprint with the 5-95% quantiles of everything above it in
its neighbourhood, beside the footprint too (a lamp's shade overhangs its base); quantiles, not extremes, so that a
few floaters beside a floor (0.4-3% of what stands on the GPU ``indoor_room``'s floor) do not reject it"""
FOOTPRINT_CELLS = 64
"""cells along the longer side of a plane's footprint grid (:func:`seen_under_plane`)"""
ITERATIONS = 200
MAX_POINTS = 200_000
"""the foreground search's RANSAC hypotheses, and the points it looks at at most (a random subset beyond)"""

BASE_SHARE = 0.1
""":func:`find_support`: the object's *base* is its Gaussians within this share of its height above its lowest
ones (2% quantile): the feet of a table or a chair, a mug's or a bucket's bottom rim, a lying hammer's whole
underside. Its footprint is where the support is hidden under the object; a tenth of the height holds the lowest
part of every development family and none of a chair's seat or a lamp's shade"""
RING_GAP = 0.05
"""the ring starts this share of the object's horizontal size (1-99% quantiles) beyond the base's footprint: the
base's own Gaussians spread across their surface by about their scale (a few millimetres), and the object's walls
rising from its base are not the support's"""
RING_WIDTH = 0.2
"""... and is this share wide: a table top of the benchmark's layouts reaches at least a quarter of the object's
size beyond it on every side (its shorter side is 1.5 times the object's footprint), so the ring lies on the
support wherever the object stands on one"""
RING_HEIGHT = 0.15
"""the ring's Gaussians lie within this share of the object's size (its 3-D extent, 2-98% quantiles) of the base's
lowest height, above or below: a floor that the masks left out lies at the object's bottom, one that they took in
is the selection's bottom (its spill around the object), and the splat's reflections under a glossy floor lie
deeper"""
RING_SECTORS = 16
"""the ring is cut into this many equal angles about the base's centre; a sector is covered when at least one of the
plane's inliers lies in it (a floor seen from around its object is reconstructed all around it; 16 sectors of a
mug's ring are about 2 cm of arc, a few Gaussians of a demo-settings floor)"""
MIN_RING_COVERAGE = 0.75
"""a support covers at least this share of the ring's sectors: a level layer all around the object's base, not a
ledge or a few floaters on one side of it. Objects that stand on nothing (the generated presets) have no Gaussian
in their ring; those on a floor or a table cover it whole, less the sectors that the object itself hides from
every view (a chair's or a table's legs hide none)"""
RING_BAND = 0.01
"""the ring's RANSAC band (a level plane through each inlier candidate, counting the ring's Gaussians within this
share of the object's size of it): about a voxel of the object's 128-voxel grid"""
MAX_TOL_BANDS = 3
"""the plane's tolerance, its inliers' robust thickness (``tol_sigmas`` x 1.4826 x their distances' MAD), is at most
this many ring bands: uncapped, a fuzzy floor's tolerance grew to 4.6 cm under a path-traced pan and cut its
bottom away; three bands hold a floor's centres at demo settings"""


@dataclass
class SupportConfig:
    """How the support plane is found and accepted (module doc)."""

    enabled: bool = True
    """look for a support plane at all"""
    max_tilt_deg: float = 25.0
    """largest angle between its normal and the views' mean up direction (the foreground search; the ring's plane
    is level)"""
    max_below: float = 0.02
    """largest share of the foreground near it that may lie below it (a table's legs, seen past its top from the
    low views, are a tenth of the foreground near it; a floor's own scatter a per cent)"""
    min_cameras_above: float = 0.9
    """smallest share of the cameras that must lie above it (an object-centric capture of something standing on a
    support is shot from above the support)"""
    margin: float = 0.05
    """its inliers reach beyond the footprint of what stands on it by this fraction of that footprint, every side"""
    min_share: float = 0.1
    """smallest share of the foreground near it that it holds"""
    tol_sigmas: float = 3.0
    """inlier tolerance in robust standard deviations of the inliers' distances (a Gaussian layer's whole
    thickness: 99.7% of a normal spread)"""
    min_tol: float = 0.002
    """the tolerance's floor, as a fraction of the foreground's extent (5-95% quantiles): the flatness of a
    perfect splat's layer"""


@dataclass
class SupportPlane:
    normal: np.ndarray
    """unit normal, pointing up (towards the cameras)"""
    offset: float
    """the plane is ``x . normal = offset``"""
    tol: float
    """inlier distance, scene units"""
    share: float
    """share of the foreground near the plane within ``tol`` of it"""
    size: float = 0.0
    """the longer side of its inliers' footprint (1-99% quantiles in the plane), scene units"""

    def height(self, x: np.ndarray) -> np.ndarray:
        """Signed distance of points [N, 3] above the plane."""
        return x @ self.normal - self.offset

    def above_voxels(self, grid: VoxelGrid) -> np.ndarray:
        """bool [X, Y, Z]: the voxels of ``grid`` whose centres lie on or above the plane."""
        ax = [grid.origin[i] + (np.arange(grid.shape[i]) + 0.5) * grid.voxel_size for i in range(3)]
        n = np.asarray(self.normal, dtype=np.float64)
        return (ax[0][:, None, None] * n[0] + ax[1][None, :, None] * n[1] + ax[2][None, None, :] * n[2]) >= self.offset

    def drops(self, x: np.ndarray) -> np.ndarray:
        """bool [N]: points on the plane (within its tolerance) or below it."""
        return self.height(x) <= self.tol


def views_up(views: Sequence[CaptureView]) -> np.ndarray:
    """The world's up direction seen by the views: the direction perpendicular to every camera's image x axis
    (a camera held upright, at any pitch and heading, has a level image x axis), oriented along their mean image up
    (OpenCV cameras: image up is camera -y). Exact for cameras without roll and a least-squares estimate under a
    small random roll, where the mean image up is tilted towards the side the cameras look from (every camera that
    looks down at an object tilts its up towards it). Views whose x axes are all parallel (a single camera or a
    straight track) leave it undetermined: then the mean image up."""
    rights = np.stack([v.viewmat[0, :3].double().cpu().numpy() for v in views])
    ups = np.stack([-v.viewmat[1, :3].double().cpu().numpy() for v in views])
    mean_up = ups.mean(0)
    n = np.linalg.norm(mean_up)
    mean_up = mean_up / n if n > 1e-9 else np.array([0.0, 0.0, 1.0])
    if len(views) < 2:
        return mean_up
    _u, s, vt = np.linalg.svd(rights, full_matrices=False)
    if s[1] < 0.1 * s[0]:  # the x axes span no plane: the level direction is not determined
        return mean_up
    level = vt[-1] if len(s) == 3 else np.cross(vt[0], vt[1])
    return level if level @ mean_up >= 0 else -level


def _fit(x: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane of points [N, 3], its normal oriented along ``up``."""
    c = x.mean(0)
    n = np.linalg.svd(x - c, full_matrices=False)[2][-1]
    n = n if n @ up >= 0 else -n
    return n, float(c @ n)


def _in_plane(n: np.ndarray) -> np.ndarray:
    """[3, 2]: two orthonormal directions perpendicular to the unit vector ``n`` (columns)."""
    a = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    return np.stack([a, np.cross(n, a)], 1)


def find_support_plane(means: np.ndarray, cameras: np.ndarray, up: np.ndarray,
                       cfg: SupportConfig | None = None) -> SupportPlane | None:  # fmt: skip
    """The support plane under the foreground Gaussians' ``means`` [N, 3] (module doc), or None when there is none.
    ``cameras``: the camera centres [V, 3]; ``up``: the views' up direction (:func:`views_up`)."""
    return support_plane_or_reason(means, cameras, up, cfg)[0]


def support_plane_or_reason(means: np.ndarray, cameras: np.ndarray, up: np.ndarray, cfg: SupportConfig | None = None,
                            views: Sequence[CaptureView] | None = None) -> tuple[SupportPlane | None, str]:  # fmt: skip
    """:func:`find_support_plane`, with the test that the best plane failed when there is none (for the log).
    ``views`` (their cameras are ``cameras``): "below everything" counts only the points under the plane that some view
    sees past it on its mask (:func:`seen_under_plane`); None: every point under it."""
    cfg = cfg or SupportConfig()
    if not cfg.enabled:
        return None, "off"
    if len(means) < 50:
        return None, f"{len(means)} points"
    rng = np.random.default_rng(0)
    x = means[rng.permutation(len(means))[:MAX_POINTS]] if len(means) > MAX_POINTS else means
    x = np.asarray(x, dtype=np.float64)
    up = np.asarray(up, dtype=np.float64) / max(np.linalg.norm(up), 1e-12)
    ext = float(np.max(np.quantile(x, 0.95, axis=0) - np.quantile(x, 0.05, axis=0)))
    if ext <= 0:
        return None, "no extent"
    why = []
    for q in SAMPLE_QUANTILES:
        plane, reason = _search(x, cameras, up, ext, q, cfg, views, rng)
        if plane is not None:
            return plane, ""
        why.append(f"lowest {q:.0%}: {reason}" if q < 1 else f"all: {reason}")
    return None, "; ".join(why)


def _search(x: np.ndarray, cameras: np.ndarray, up: np.ndarray, ext: float, quantile: float, cfg: SupportConfig,
            views: Sequence[CaptureView] | None, rng: np.random.Generator) -> tuple[SupportPlane | None, str]:  # fmt: skip
    """One RANSAC search with its planes' points drawn from the lowest ``quantile`` of ``x`` (module doc), and the
    acceptance tests; (the plane, "") or (None, the test the best plane failed)."""
    h = x @ up
    tol0 = SEARCH_BAND * ext
    low = np.flatnonzero(h <= np.quantile(h, quantile))
    cos_max = np.cos(np.deg2rad(cfg.max_tilt_deg))
    best, best_n, best_d = -1, up, float(np.quantile(h, 0.01))
    tri = low[rng.integers(0, len(low), size=(ITERATIONS, 3))]
    p0, p1, p2 = x[tri[:, 0]], x[tri[:, 1]], x[tri[:, 2]]
    nrm = np.cross(p1 - p0, p2 - p0)
    ln = np.linalg.norm(nrm, axis=1)
    ok = ln > 1e-12
    nrm[ok] /= ln[ok, None]
    nrm *= np.sign(nrm @ up)[:, None]
    ok &= nrm @ up >= cos_max
    for i in np.flatnonzero(ok):  # (at most ``ITERATIONS`` hypotheses, each one product over the points)
        d = float(p0[i] @ nrm[i])
        cnt = int((np.abs(x @ nrm[i] - d) <= tol0).sum())
        if cnt > best:
            best, best_n, best_d = cnt, nrm[i], d
    if best < 0:
        return None, "no level plane"
    n, d = best_n, best_d
    tol = tol0
    for _ in range(3):  # refine: least squares on the inliers, the tolerance from their spread
        r = x @ n - d
        inl = np.abs(r) <= tol
        if inl.sum() < 3:
            return None, "fewer than 3 inliers"
        n, d = _fit(x[inl], up)
        r = x @ n - d
        mad = float(np.median(np.abs(r[np.abs(r) <= tol])))
        tol = max(cfg.tol_sigmas * 1.4826 * mad, cfg.min_tol * ext)
    if tol > MAX_TOL_GROWTH * tol0:
        return None, f"no thin layer (its inliers' spread grew to {tol / tol0:.0f}x the search's band)"
    r = x @ n - d
    on = np.abs(r) <= tol
    if n @ up < cos_max or on.sum() < 10:
        return None, "not level" if n @ up < cos_max else "fewer than 10 inliers"
    uv = x @ _in_plane(n)
    lo_on, hi_on = np.quantile(uv[on], 0.01, axis=0), np.quantile(uv[on], 0.99, axis=0)
    size = float(np.max(hi_on - lo_on))
    # the plane's neighbourhood: far floaters and background (other clusters) neither support nor refute it
    beside = np.all((uv >= lo_on - 0.5 * size) & (uv <= hi_on + 0.5 * size), 1)  # over or beside it, any height
    near = beside & (np.abs(r) <= size)
    plane = SupportPlane(n, d, tol, float(on.sum() / max(near.sum(), 1)), size)
    over = np.all((uv >= lo_on) & (uv <= hi_on), 1)
    under = near & (r < -tol) & over
    if views is not None and under.any():
        under[under] = seen_under_plane(x[under], uv[on], n, d, tol, views, FOOTPRINT_CELLS)
    below = float(under.sum() / max(near.sum(), 1))
    if plane.share < cfg.min_share:
        return None, f"holds {plane.share:.1%} of the foreground near it (min_share {cfg.min_share:.0%})"
    if below > cfg.max_below:
        return None, f"{below:.1%} of the foreground near it lies below it (max_below {cfg.max_below:.0%})"
    above = float((np.asarray(cameras, dtype=np.float64) @ n - d > tol).mean()) if len(cameras) else 1.0
    if above < cfg.min_cameras_above:
        return None, f"{above:.0%} of the cameras above it (min_cameras_above {cfg.min_cameras_above:.0%})"
    rest = beside & (r > tol)
    if rest.sum() < 10:
        return None, "nothing stands on it"
    lo_r, hi_r = np.quantile(uv[rest], WIDER_QUANTILE, axis=0), np.quantile(uv[rest], 1 - WIDER_QUANTILE, axis=0)
    grow = cfg.margin * float(np.max(hi_r - lo_r))
    if np.any(lo_on > lo_r - grow) or np.any(hi_on < hi_r + grow):
        return None, "not wider than what stands on it"
    return plane, ""


def seen_under_plane(points: np.ndarray, inliers_uv: np.ndarray, n: np.ndarray, d: float, tol: float,
                     views: Sequence[CaptureView], cells: int = 64) -> np.ndarray:  # fmt: skip
    """bool [P]: which ``points`` [P, 3] under the plane ``x . n = d`` the views see *past* the plane on their
    foreground masks: of the views that see a point past the plane (the view's camera lies under the plane, or its
    segment to the point crosses the plane outside the plane's footprint, and the point is in its frame), at least
    two and at least half have it on their mask (the carving's lookup, :func:`.carve_views.mask_view_votes`).
    The footprint is the cells of a
    ``cells``-wide grid over the in-plane coordinates that hold an inlier (``inliers_uv`` [M, 2], :func:`_in_plane`
    coordinates), grown by a cell and with its holes filled (the floor under an object standing on it holds no inlier,
    but it is there). A table's legs are seen so from the low views; what lies under a floor is seen only through it,
    or, past its edge, on the background (module doc, "below everything"). Vectorised over the points, view by view."""
    from scipy import ndimage

    points = np.asarray(points, dtype=np.float64)
    n_past = np.zeros(len(points), dtype=np.int64)
    n_on = np.zeros(len(points), dtype=np.int64)
    if len(points) == 0:
        return n_on > 0
    B = _in_plane(n)
    lo = inliers_uv.min(0)
    cell = max(float((inliers_uv.max(0) - lo).max()) / cells, 1e-12)
    shape = np.floor((inliers_uv.max(0) - lo) / cell).astype(int) + 3  # a margin of one cell for the growth
    occ = np.zeros(tuple(shape), dtype=bool)
    ij = np.floor((inliers_uv - lo) / cell).astype(int) + 1
    occ[ij[:, 0], ij[:, 1]] = True
    occ = ndimage.binary_fill_holes(ndimage.binary_dilation(occ))
    # the carving's projection and mask lookup: which views frame each point, and which have it on their mask
    dev = views[0].mask.device
    framed, off_mask = mask_view_votes(torch.from_numpy(points).float().to(dev), views,
                                       [t.to(dev) for t in signed_mask_distances([v.mask for v in views])], 0.0)  # fmt: skip
    on_mask = (framed & ~off_mask).cpu().numpy()
    framed = framed.cpu().numpy()
    hp = points @ n - d  # < 0
    for k, v in enumerate(views):  # (tens of views; each step a few products over the points)
        c = v.centre.double().cpu().numpy()
        h = float(c @ n - d)
        past = np.ones(len(points), dtype=bool)  # a camera under the plane sees under it
        if h > tol:  # where the segment camera -> point crosses the plane, t in (0, 1)
            x = c + (h / (h - hp))[:, None] * (points - c)
            ij = np.floor((x @ B - lo) / cell).astype(int) + 1
            inside = np.all((ij >= 0) & (ij < occ.shape), 1)
            past[inside] = ~occ[ij[inside, 0], ij[inside, 1]]
        n_past += past & framed[k]
        n_on += past & on_mask[k]
    return (n_on >= 2) & (2 * n_on >= n_past)


def _base_ring(p: np.ndarray, selected: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float, float] | None:
    """The ring around the object's base (module doc, "The support under the object"), in the frame ``p`` [N, 3]
    (horizontal, horizontal, up) of every Gaussian: (the ring's points' indices, their sector, the base's lowest
    height, the object's size, its horizontal size), or None when the object has no extent."""
    from scipy.spatial import cKDTree

    obj = p[selected]
    lo3, hi3 = np.quantile(obj, 0.02, axis=0), np.quantile(obj, 0.98, axis=0)
    size = float(np.max(hi3 - lo3))
    if not size > 0:
        return None
    h0 = float(lo3[2])
    base = obj[obj[:, 2] <= h0 + BASE_SHARE * (hi3[2] - lo3[2])]
    if len(base) < 3:
        return None
    wide = float(np.max(np.quantile(obj[:, :2], 0.99, axis=0) - np.quantile(obj[:, :2], 0.01, axis=0)))
    gap, width = RING_GAP * wide, RING_WIDTH * wide
    blo, bhi = base[:, :2].min(0) - gap - width, base[:, :2].max(0) + gap + width
    near = np.all((p[:, :2] >= blo) & (p[:, :2] <= bhi), 1) & (np.abs(p[:, 2] - h0) <= RING_HEIGHT * size)
    idx = np.flatnonzero(near)
    dist = cKDTree(base[:, :2]).query(p[idx, :2], k=1)[0]
    ring = (dist > gap) & (dist <= gap + width)
    idx = idx[ring]
    c = base[:, :2].mean(0)
    ang = np.arctan2(p[idx, 1] - c[1], p[idx, 0] - c[0])
    sector = np.minimum(((ang + np.pi) / (2 * np.pi) * RING_SECTORS).astype(int), RING_SECTORS - 1)
    return idx, sector, h0, size, wide


def find_support(means: np.ndarray, selected: np.ndarray, cameras: np.ndarray, up: np.ndarray,
                 cfg: SupportConfig | None = None) -> tuple[SupportPlane | None, str]:  # fmt: skip
    """The support under the object (module doc, "The support under the object"): a level layer of Gaussians in a
    ring around the object's base, or None, with the reason (for the log). ``means`` [N, 3]: every Gaussian's
    centre (opaque enough to count); ``selected`` bool [N]: the object's; ``cameras`` [V, 3]: the camera centres;
    ``up``: the views' up direction (:func:`views_up`), the plane's normal."""
    cfg = cfg or SupportConfig()
    means = np.asarray(means, dtype=np.float64)
    if not cfg.enabled:
        return None, "off"
    if int(selected.sum()) < 50:
        return None, f"{int(selected.sum())} object Gaussians"
    up = np.asarray(up, dtype=np.float64) / max(float(np.linalg.norm(up)), 1e-12)
    p = means @ np.column_stack([_in_plane(up), up])  # horizontal, horizontal, up
    found = _base_ring(p, selected)
    if found is None:
        return None, "no extent"
    idx, sector, h0, size, wide = found
    if len(idx) < RING_SECTORS:
        return None, f"{len(idx)} Gaussians in the ring around its base"
    h = p[idx, 2]
    band = RING_BAND * size
    hs = np.sort(h)  # RANSAC with a level normal, every ring point a hypothesis: the densest band of heights
    counts = np.searchsorted(hs, hs + band, side="right") - np.searchsorted(hs, hs - band, side="left")
    d, tol = float(hs[int(np.argmax(counts))]), band
    for _ in range(20):  # least squares (the normal fixed level: the inliers' mean height), the tolerance their
        # spread, until the layer stops moving (on a fuzzy floor the densest band is a noisy estimate of its middle)
        d0, d = d, float(h[np.abs(h - d) <= tol].mean())
        mad = float(np.median(np.abs(h[np.abs(h - d) <= tol] - d)))
        tol = min(max(cfg.tol_sigmas * 1.4826 * mad, band), MAX_TOL_BANDS * band)
        if abs(d - d0) < 1e-3 * band:
            break
    on = np.abs(h - d) <= tol
    covered = len(np.unique(sector[on])) / RING_SECTORS
    if covered < MIN_RING_COVERAGE:
        return None, (f"its level layer covers {covered:.0%} of the ring around its base (min "
                      f"{MIN_RING_COVERAGE:.0%}; {len(idx)} Gaussians in the ring)")  # fmt: skip
    above = float((np.asarray(cameras, dtype=np.float64) @ up - d > tol).mean()) if len(cameras) else 1.0
    if above < cfg.min_cameras_above:
        return None, f"{above:.0%} of the cameras above it (min_cameras_above {cfg.min_cameras_above:.0%})"
    plane = SupportPlane(up.copy(), d, tol, float(on.mean()), wide + 2 * (RING_GAP + RING_WIDTH) * wide)
    return plane, (f"{covered:.0%} of the ring's sectors, {on.mean():.0%} of its {len(idx)} Gaussians, "
                   f"{d - h0:+.3g} above the base, tolerance {tol:.3g}")  # fmt: skip


def support_gaussians(means: np.ndarray, selected: np.ndarray, plane: SupportPlane) -> np.ndarray:
    """bool [N]: the Gaussians of the support around the object, for the masks' trim: within ``plane``'s tolerance
    of it, under the object's footprint grown by the ring (:func:`find_support`), the object's own excepted."""
    means = np.asarray(means, dtype=np.float64)
    B = _in_plane(plane.normal)
    uv = means @ B
    obj = uv[selected]
    grow = (RING_GAP + RING_WIDTH) * float(np.max(obj.max(0) - obj.min(0))) if len(obj) else 0.0
    box = np.all((uv >= obj.min(0) - grow) & (uv <= obj.max(0) + grow), 1) if len(obj) else np.zeros(len(uv), bool)
    return box & (np.abs(plane.height(means)) <= plane.tol) & ~selected


def align_to_plane(grid: VoxelGrid, plane: SupportPlane | None) -> VoxelGrid:
    """``grid`` moved down by less than a voxel (and one voxel taller) along the axis nearest the plane's normal so
    that a layer of its voxel faces lies on ``plane`` at the grid's centre: the solid's cut at the plane then
    falls between voxels, and no voxel straddles the contact (exact when the normal is the axis; None: unchanged)."""
    if plane is None:
        return grid
    n = np.asarray(plane.normal, dtype=np.float64)
    a = int(np.argmax(np.abs(n)))
    origin = np.asarray(grid.origin, dtype=np.float64)
    centre = origin + 0.5 * grid.voxel_size * np.asarray(grid.shape)
    others = [i for i in range(3) if i != a]
    at = (plane.offset - sum(n[i] * centre[i] for i in others)) / n[a]  # the plane's coordinate along the axis
    shift = (origin[a] - at) / grid.voxel_size
    origin[a] -= (shift - math.floor(shift)) * grid.voxel_size
    shape = list(grid.shape)
    shape[a] += 1
    return VoxelGrid(tuple(float(v) for v in origin), grid.voxel_size, tuple(shape))  # type: ignore[arg-type]
