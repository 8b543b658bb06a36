"""The plane the object stands on: a floor or a table top that the foreground masks took in with the objects.

Perception's whole-object masks leave out what touches the image border (walls, a floor that fills the frame), but
a floor or a platform seen whole, as in the generated ``indoor_room``, is a region like any other: its Gaussians
get a high foreground probability and join every object standing on it into one cluster
(:mod:`.select`; before this step, 12,837 of the 17,108 Gaussians selected in ``indoor_room`` at demo settings lay
on the floor and the rug, and the "object" came out 105x the table's volume).

The robotics answer is the tabletop one: find the support plane and drop it, then cluster what stands on it. Here
the plane is searched among the foreground Gaussians' means, and only accepted when it is a support, so that an
object's own flat bottom (a crate's, a shoe's sole) or top (a table's) is never taken for one:

* **level**: its normal is within ``max_tilt_deg`` of the views' mean up direction (an object-centric capture is
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
* **wider than what stands on it**: the plane's inliers reach beyond the 5-95% quantiles (``wider_quantile``) of
  the rest of the foreground above it, over and beside its footprint at any height, on all four sides, by
  ``margin`` of that extent (an object's own bottom face *is* its footprint; a lamp's base has its shade overhanging
  it; a few floaters beside a floor do not move the quantiles);
* **substantial**: it holds at least ``min_share`` of the foreground near it.

Where the masks leave the floor out, :func:`find_resting_plane` runs the same search among all the Gaussians around
the object, and the carved solid ends at the plane it finds (``cut_below``).

The plane is fitted by RANSAC with the normal constrained to be level (three points from the lowest third of the
foreground, best inlier count), refined by least squares on its inliers. The tolerance is the inliers' own
thickness: ``tol_sigmas`` robust standard deviations (1.4826 x MAD) of their distances to the plane, at least
``min_tol`` of the foreground's extent, so a rug on the floor (8 mm at demo settings, where a pixel covers
3 cm of the floor) counts with it. A plane is a thin layer: when the refinement grows the tolerance past
``max_tol_growth`` times the search's band, it cut through a diffuse cloud (a floor's reflections, the lowest
third of the GPU room's foreground), and the search is made again with the three points drawn from all the
points (``sample_quantiles``). The Gaussians within the tolerance of the plane and below it are not the
object's; those above it are clustered as before.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from .capture import CaptureView
from .carve import mask_view_votes, signed_mask_distances
from .grid import VoxelGrid

__all__ = ["SupportConfig", "SupportPlane", "find_resting_plane", "find_support_plane", "seen_under_plane",
           "support_plane_or_reason", "views_up"]


@dataclass
class SupportConfig:
    """How the support plane is found and accepted (module doc)."""

    enabled: bool = True
    """look for a support plane at all"""
    max_tilt_deg: float = 25.0
    """largest angle between its normal and the views' mean up direction"""
    max_below: float = 0.02
    """largest share of the foreground near it that may lie below it"""
    min_cameras_above: float = 0.9
    """smallest share of the cameras that must lie above it"""
    margin: float = 0.05
    """its inliers reach beyond the footprint of what stands on it by this fraction of that footprint, every side"""
    min_share: float = 0.1
    """smallest share of the foreground near it that it holds"""
    tol_sigmas: float = 3.0
    """inlier tolerance in robust standard deviations of the inliers' distances"""
    min_tol: float = 0.002
    """the tolerance's floor, as a fraction of the foreground's extent (5-95% quantiles)"""
    iterations: int = 200
    max_points: int = 200_000
    seed: int = 0
    cut_below: bool = True
    """the carved solid ends at the plane the object rests on (:func:`find_resting_plane`): voxels whose centres
    lie below it are empty"""
    resting_points: int = 50_000
    """:func:`find_resting_plane` looks at this many of the Gaussians around the object's bottom at most"""
    sample_quantiles: tuple[float, ...] = (1 / 3, 1.0)
    """RANSAC draws its planes' three points from the lowest this share of the points (heights along the views' up),
    each share in turn until a plane passes the tests: the lowest third first (a floor under a table top that the
    masks took in too), then all of them (a splat puts a shiny floor's reflections under it, and they are the lowest
    third: the GPU's `indoor_room` at 512 px)"""
    max_tol_growth: float = 3.0
    """a plane is a thin layer: its inliers' tolerance after the refinement (``tol_sigmas`` robust deviations) may be
    at most this many times the search's band (1% of the points' extent); beyond, the "plane" is a cut through a
    diffuse cloud, whose tolerance grows with each refinement (2 m on the GPU's `indoor_room` reflections)"""
    below_seen_past: bool = True
    """where the views are given (the selection's search among the foreground), the "below everything" test counts
    only the points under the plane that some view sees past it on its foreground mask (:func:`seen_under_plane`): a
    table's legs, seen from the low views. A splat puts a shiny floor's reflections under it, seen only through the
    floor (the GPU's `indoor_room` at 512 px: 27% of the foreground near the floor lay under it, and the floor was
    rejected). False: every point under the plane counts"""
    over_footprint: bool = True
    """the "below everything" test (and "wider than what stands on it" where ``wider_quantile`` is None) counts only
    the points over or under the plane's footprint (its inliers' 1-99% box), not those beside it: a table's legs
    stand under its top, and what stands on a floor stands over it. False: every point in the plane's neighbourhood,
    beside it too (the GPU's
    `indoor_room`: floaters beside the floor, a fifth of the points above it, reached past its edge, and the
    backdrop's Gaussians lay below its level beyond it)"""
    wider_quantile: float | None = 0.05
    """"wider than what stands on it" compares the plane's footprint with the q to 1 - q quantiles of *everything*
    above it in its neighbourhood, beside the footprint too: a lamp's base is no floor, for the shade standing on it
    overhangs it (otherwise a lamp's base top can be taken for a support plane). The
    quantiles, not the extremes, so that a few floaters beside a floor (0.4-3% of what stands on the GPU
    `indoor_room`'s floor) do not reject it. None: the 1-99% quantiles of the points over the footprint only
    (``over_footprint``)"""
    footprint_cells: int = 64
    """cells along the longer side of the plane's footprint grid (:func:`seen_under_plane`)"""

    def __post_init__(self) -> None:
        if self.wider_quantile is not None and not 0 <= self.wider_quantile < 0.5:
            raise ValueError(f"SupportConfig.wider_quantile must be in [0, 0.5) or None, got {self.wider_quantile}.")


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
    """The views' mean up direction in world coordinates (OpenCV cameras: image up is camera -y)."""
    ups = np.stack([-v.viewmat[1, :3].double().cpu().numpy() for v in views])
    up = ups.mean(0)
    n = np.linalg.norm(up)
    return up / n if n > 1e-9 else np.array([0.0, 0.0, 1.0])


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
    sees past it on its mask (``cfg.below_seen_past``, :func:`seen_under_plane`); None: every point under it."""
    cfg = cfg or SupportConfig()
    if not cfg.enabled:
        return None, "off"
    if len(means) < 50:
        return None, f"{len(means)} points"
    rng = np.random.default_rng(cfg.seed)
    x = means[rng.permutation(len(means))[: cfg.max_points]] if len(means) > cfg.max_points else means
    x = np.asarray(x, dtype=np.float64)
    up = np.asarray(up, dtype=np.float64) / max(np.linalg.norm(up), 1e-12)
    ext = float(np.max(np.quantile(x, 0.95, axis=0) - np.quantile(x, 0.05, axis=0)))
    if ext <= 0:
        return None, "no extent"
    why = []
    for q in cfg.sample_quantiles:
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
    tol0 = 0.01 * ext
    low = np.flatnonzero(h <= np.quantile(h, quantile))
    cos_max = np.cos(np.deg2rad(cfg.max_tilt_deg))
    best, best_n, best_d = -1, up, float(np.quantile(h, 0.01))
    tri = low[rng.integers(0, len(low), size=(cfg.iterations, 3))]
    p0, p1, p2 = x[tri[:, 0]], x[tri[:, 1]], x[tri[:, 2]]
    nrm = np.cross(p1 - p0, p2 - p0)
    ln = np.linalg.norm(nrm, axis=1)
    ok = ln > 1e-12
    nrm[ok] /= ln[ok, None]
    nrm *= np.sign(nrm @ up)[:, None]
    ok &= nrm @ up >= cos_max
    for i in np.flatnonzero(ok):  # (at most ``iterations`` hypotheses, each one product over the points)
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
    if tol > cfg.max_tol_growth * tol0:
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
    over = np.all((uv >= lo_on) & (uv <= hi_on), 1) if cfg.over_footprint else np.ones(len(uv), dtype=bool)
    under = near & (r < -tol) & over
    if views is not None and cfg.below_seen_past and under.any():
        under[under] = seen_under_plane(x[under], uv[on], n, d, tol, views, cfg.footprint_cells)
    below = float(under.sum() / max(near.sum(), 1))
    if plane.share < cfg.min_share:
        return None, f"holds {plane.share:.1%} of the foreground near it (min_share {cfg.min_share:.0%})"
    if below > cfg.max_below:
        return None, f"{below:.1%} of the foreground near it lies below it (max_below {cfg.max_below:.0%})"
    above = float((np.asarray(cameras, dtype=np.float64) @ n - d > tol).mean()) if len(cameras) else 1.0
    if above < cfg.min_cameras_above:
        return None, f"{above:.0%} of the cameras above it (min_cameras_above {cfg.min_cameras_above:.0%})"
    rest = (near & over) if cfg.wider_quantile is None else beside
    rest = rest & (r > tol)
    if rest.sum() < 10:
        return None, "nothing stands on it"
    q = 0.01 if cfg.wider_quantile is None else cfg.wider_quantile
    lo_r, hi_r = np.quantile(uv[rest], q, axis=0), np.quantile(uv[rest], 1 - q, axis=0)
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


def find_resting_plane(means: np.ndarray, selected: np.ndarray, cameras: np.ndarray, up: np.ndarray,
                       cfg: SupportConfig | None = None) -> SupportPlane | None:  # fmt: skip
    """The plane the object rests on, searched among *all* the Gaussians around it, or None.

    The support plane of :func:`find_support_plane` is searched among the foreground only, for the case where the
    masks took the floor in. Where they did not (perception's masks hold the object alone, the usual case), the
    floor or table under the object is background, but it is still there in the splat, and it says where the object
    ends below: nothing of the object lies under the surface it stands on, while the carving cannot tell, since no
    view sees past the underside (the generated objects, which stand on no floor, keep about a voxel layer under
    their bottoms: the lamp's steel base came out 1.3x its volume). ``means`` [N, 3]: every Gaussian's centre
    (opaque enough to count); ``selected`` bool [N]: the object's. The points are the object's and every Gaussian
    within the object's footprint grown by its size on each side and from half that size under its bottom up to
    its top; the plane must pass all the tests of :func:`find_support_plane` on them (level, below everything,
    wider than the object, substantial)."""
    cfg = cfg or SupportConfig()
    means = np.asarray(means, dtype=np.float64)
    obj = means[selected]
    if not cfg.enabled or len(obj) < 50:
        return None
    up = np.asarray(up, dtype=np.float64) / max(float(np.linalg.norm(up)), 1e-12)
    frame = np.column_stack([_in_plane(up), up])  # horizontal, horizontal, up
    p_obj = obj @ frame
    lo, hi = np.quantile(p_obj, 0.01, axis=0), np.quantile(p_obj, 0.99, axis=0)
    size = float(np.max(hi[:2] - lo[:2]))
    if size <= 0:
        return None
    p = means @ frame
    near = np.all((p[:, :2] >= lo[:2] - size) & (p[:, :2] <= hi[:2] + size), 1)
    near &= (p[:, 2] >= lo[2] - 0.5 * size) & (p[:, 2] <= hi[2])
    near |= selected
    pts = means[near]
    if len(pts) > cfg.resting_points:
        pts = pts[np.random.default_rng(cfg.seed).permutation(len(pts))[: cfg.resting_points]]
    return find_support_plane(pts, cameras, up, cfg)
