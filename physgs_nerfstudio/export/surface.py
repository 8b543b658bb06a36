"""Object surface from the opacity field (marching cubes) for the shell volume model.

``auto`` (default): marching cubes of the object's volume fraction (:func:`.occupancy.volume_weights`,
lightly smoothed, level 0.5), i.e. the boundary of the filled object with thin layers around filled
cavities taken at their middle; each face then counts fully where the object is bulky under it (a closed
hollow object filled by the interior fill: the face is the wall) and half where the object is a sheet no
thicker than ``2 * sheet_depth`` (an open wall, reconstructed with both of its sides: each side is one
copy of the wall). The depth test uses the Euclidean distance transform of the filled object, maximised
over a neighbourhood of each face.
``mid``: marching cubes of the object's opacity field at the occupancy level gives both sides of
the splatted surface layer (3DGS reconstructs a wall, open or closed, as one thin sheet of Gaussians whose
layer has an outer and an inner boundary), so the wall's mid-surface area is half the mesh area.
``outer``: cavities of the filled object are raised above the level first, so only the outside boundary
remains; use it for reconstructions that fill the object's volume with Gaussians.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy import ndimage
from skimage.measure import marching_cubes

from .occupancy import Occupancy

__all__ = ["Surface", "extract_surface"]


@dataclass
class Surface:
    vertices: np.ndarray
    """float64 [V, 3], scene units"""
    faces: np.ndarray
    """int64 [T, 3]"""
    face_area: np.ndarray
    """float64 [T], scene units^2 (mesh area, before ``side_factor``)"""
    face_voxel: np.ndarray
    """int64 [T, 3] index (in ``occ.grid``) of the voxel containing each face's centroid"""
    side_factor: float
    """mid-surface area = side_factor * mesh area (0.5 for ``mid``, 1 for ``outer``)"""

    @property
    def area(self) -> float:
        """Wall (mid-surface) area in scene units^2."""
        return float(self.side_factor * self.face_area.sum())


def extract_surface(
    occ: Occupancy, mode: Literal["auto", "mid", "outer"] = "auto", sheet_depth: float | None = None
) -> Surface:
    """Wall surface of the object (module doc). ``sheet_depth`` (scene units, auto mode): objects at most
    twice as thick are sheets; default 2.5 voxels."""
    if mode not in ("auto", "mid", "outer"):
        raise ValueError(f"shell surface mode must be auto|mid|outer, got {mode!r}.")
    if mode == "auto":
        return _auto_surface(occ, sheet_depth)
    region = ndimage.binary_dilation(occ.solid, iterations=2)
    F = np.where(region, occ.field, 0.0).astype(np.float32)
    if mode == "outer":
        cavity = occ.solid & ~occ.layer
        F[cavity] = max(float(F.max()), 2.0 * occ.level)
    F = np.pad(F, 1)  # closes surfaces that touch the crop
    try:
        verts, faces, _, _ = marching_cubes(F, level=occ.level, spacing=(occ.grid.voxel_size,) * 3)
    except (ValueError, RuntimeError) as err:
        raise ValueError(f"marching cubes found no surface at level {occ.level:.4g}: {err}") from err
    h = occ.grid.voxel_size
    verts = verts.astype(np.float64) + np.asarray(occ.grid.origin) + 0.5 * h - h  # -h: the padding
    tri = verts[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    centroid = tri.mean(1)
    face_voxel = np.floor((centroid - np.asarray(occ.grid.origin)) / h).astype(np.int64)
    face_voxel = np.clip(face_voxel, 0, np.asarray(occ.grid.shape) - 1)
    return Surface(verts, faces.astype(np.int64), area, face_voxel, 0.5 if mode == "mid" else 1.0)


def _mesh(volume: np.ndarray, level: float, occ: Occupancy) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    h = occ.grid.voxel_size
    try:
        verts, faces, _, _ = marching_cubes(np.pad(volume, 1), level=level, spacing=(h,) * 3)
    except (ValueError, RuntimeError) as err:
        raise ValueError(f"marching cubes found no surface at level {level:.4g}: {err}") from err
    verts = verts.astype(np.float64) + np.asarray(occ.grid.origin) + 0.5 * h - h  # -h: the padding
    tri = verts[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    face_voxel = np.floor((tri.mean(1) - np.asarray(occ.grid.origin)) / h).astype(np.int64)
    face_voxel = np.clip(face_voxel, 0, np.asarray(occ.grid.shape) - 1)
    return verts, faces.astype(np.int64), area, face_voxel


def _auto_surface(occ: Occupancy, sheet_depth: float | None) -> Surface:
    from .occupancy import volume_weights

    h = occ.grid.voxel_size
    tau = max(float(sheet_depth) if sheet_depth is not None else 0.0, 2.5 * h)
    frac = ndimage.gaussian_filter(volume_weights(occ).astype(np.float32), 0.5, mode="constant")
    verts, faces, area, face_voxel = _mesh(frac, 0.5, occ)
    depth = ndimage.distance_transform_edt(occ.solid) * h
    r = int(np.ceil(tau / h)) + 1
    thick = ndimage.maximum_filter(depth, size=2 * r + 1, mode="constant")
    bulk = thick[face_voxel[:, 0], face_voxel[:, 1], face_voxel[:, 2]] > tau
    weight = np.where(bulk, 1.0, 0.5)
    return Surface(verts, faces, area * weight, face_voxel, 1.0)
