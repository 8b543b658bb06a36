"""The object's frame: metres, z up (gravity along -z), origin on the object's lowest point under its centroid.

The up direction is the support plane's normal where the object rests on one (the geometry's
:class:`~physgs_nerfstudio.geometry.support.SupportPlane`), else the training views' mean up direction
(:func:`~physgs_nerfstudio.geometry.support.views_up`), else the scene's +z (nerfstudio's dataparser turns the
cameras' mean up onto +z). The frame's pose in the scene (metres: scene units x ``metres_per_unit``) goes into
the manifest, so a simulator can put the object back where the capture saw it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["ObjectFrame", "capture_up", "level_rotation", "object_frame"]


@dataclass(frozen=True)
class ObjectFrame:
    """The object's frame in the scene (metres): z along the capture's up direction (gravity is -z), x the scene's
    x made level, origin under the solid's centroid at its lowest point (the body rests on z = 0)."""

    rotation: np.ndarray
    """[3, 3]: columns are the object's x, y, z axes in scene coordinates"""
    origin_m: np.ndarray
    """[3]: the object's origin in scene coordinates, metres"""

    def to_object(self, x_m: np.ndarray) -> np.ndarray:
        """Scene points [N, 3] (metres) in the object frame."""
        return (np.asarray(x_m, dtype=np.float64) - self.origin_m) @ self.rotation

    def pose_matrix(self) -> np.ndarray:
        """[4, 4]: scene (metres) from object coordinates."""
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.rotation, self.origin_m
        return T


def level_rotation(up: np.ndarray) -> np.ndarray:
    """[3, 3] rotation whose z column is ``up`` and whose x column is the scene's x (else y) made level."""
    z = np.asarray(up, dtype=np.float64)
    z = z / np.linalg.norm(z)
    for e in np.eye(3):
        x = e - (e @ z) * z
        if np.linalg.norm(x) > 0.3:
            break
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], 1)




def capture_up(geo: Any, views: Sequence[Any] = ()) -> tuple[np.ndarray, str]:
    """(unit up vector in scene coordinates, where it comes from: "support_plane" | "views" | "scene_z")."""
    plane = getattr(geo.selection, "plane", None)
    if plane is not None:
        return np.asarray(plane.normal, dtype=np.float64), "support_plane"
    if views:
        from ..geometry.support import views_up

        return views_up(views), "views"
    return np.array([0.0, 0.0, 1.0]), "scene_z"


def object_frame(solid: np.ndarray, fill: np.ndarray, origin_m: np.ndarray, voxel_m: float,
                 up: np.ndarray) -> ObjectFrame:  # fmt: skip
    """The frame (module doc) of a voxel solid: origin under the fill-weighted centroid, at the lowest corner of
    the solid's voxels along ``up``."""
    R = level_rotation(up)
    idx = np.argwhere(fill > 0)
    w = fill[tuple(idx.T)].astype(np.float64)
    centres = origin_m + (idx + 0.5) * voxel_m
    centroid = (w[:, None] * centres).sum(0) / w.sum()
    solid_c = origin_m + (np.argwhere(solid) + 0.5) * voxel_m
    z = R[:, 2]
    low = float((solid_c @ z).min() - 0.5 * voxel_m * np.abs(z).sum())
    origin = centroid + (low - centroid @ z) * z
    return ObjectFrame(R, origin)
