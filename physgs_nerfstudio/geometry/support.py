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
  the plane's tolerance below it, and at least ``min_cameras_above`` of the cameras lie above it (a table's top
  has its legs below it; the views of an object-centric capture from below its bottom face are under that face);
* **wider than what stands on it**: the plane's inliers reach beyond the footprint of the rest of the foreground,
  on all four sides, by ``margin`` of that footprint's size (an object's own bottom face *is* its footprint);
* **substantial**: it holds at least ``min_share`` of the foreground near it.

Where the masks leave the floor out, :func:`find_resting_plane` runs the same search among all the Gaussians around
the object, and the carved solid ends at the plane it finds (``cut_below``).

The plane is fitted by RANSAC with the normal constrained to be level (three points from the lowest third of the
foreground, best inlier count), refined by least squares on its inliers. The tolerance is the inliers' own
thickness: ``tol_sigmas`` robust standard deviations (1.4826 x MAD) of their distances to the plane, at least
``min_tol`` of the foreground's extent, so a rug on the floor (8 mm at demo settings, where a pixel covers
3 cm of the floor) counts with it. The Gaussians within the tolerance of the plane and below it are not the
object's; those above it are clustered as before.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .capture import CaptureView
from .grid import VoxelGrid

__all__ = ["SupportConfig", "SupportPlane", "find_resting_plane", "find_support_plane", "views_up"]


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
    cfg = cfg or SupportConfig()
    if not cfg.enabled or len(means) < 50:
        return None
    rng = np.random.default_rng(cfg.seed)
    x = means[rng.permutation(len(means))[: cfg.max_points]] if len(means) > cfg.max_points else means
    x = np.asarray(x, dtype=np.float64)
    up = np.asarray(up, dtype=np.float64) / max(np.linalg.norm(up), 1e-12)
    h = x @ up
    ext = float(np.max(np.quantile(x, 0.95, axis=0) - np.quantile(x, 0.05, axis=0)))
    if ext <= 0:
        return None
    tol0 = 0.01 * ext
    low = np.flatnonzero(h <= np.quantile(h, 1 / 3))
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
        return None
    n, d = best_n, best_d
    tol = tol0
    for _ in range(3):  # refine: least squares on the inliers, the tolerance from their spread
        r = x @ n - d
        inl = np.abs(r) <= tol
        if inl.sum() < 3:
            return None
        n, d = _fit(x[inl], up)
        r = x @ n - d
        mad = float(np.median(np.abs(r[np.abs(r) <= tol])))
        tol = max(cfg.tol_sigmas * 1.4826 * mad, cfg.min_tol * ext)
    r = x @ n - d
    on = np.abs(r) <= tol
    if n @ up < cos_max or on.sum() < 10:
        return None
    uv = x @ _in_plane(n)
    lo_on, hi_on = np.quantile(uv[on], 0.01, axis=0), np.quantile(uv[on], 0.99, axis=0)
    size = float(np.max(hi_on - lo_on))
    # the plane's neighbourhood: far floaters and background (other clusters) neither support nor refute it
    near = np.all((uv >= lo_on - 0.5 * size) & (uv <= hi_on + 0.5 * size), 1) & (np.abs(r) <= size)
    plane = SupportPlane(n, d, tol, float(on.sum() / max(near.sum(), 1)), size)
    if plane.share < cfg.min_share or (near & (r < -tol)).sum() > cfg.max_below * near.sum():
        return None
    if len(cameras) and (np.asarray(cameras, dtype=np.float64) @ n - d > tol).mean() < cfg.min_cameras_above:
        return None
    rest = near & (r > tol)
    if rest.sum() < 10:
        return None
    lo_r, hi_r = np.quantile(uv[rest], 0.01, axis=0), np.quantile(uv[rest], 0.99, axis=0)
    grow = cfg.margin * float(np.max(hi_r - lo_r))
    if np.any(lo_on > lo_r - grow) or np.any(hi_on < hi_r + grow):
        return None
    return plane


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
