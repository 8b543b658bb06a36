"""Per-part meshes of the object: a watertight visual mesh and convex collision pieces, in the object frame (metres).

Visual: marching cubes (scikit-image) at level 1/2 of the export's own volume, the voxels' ``fill`` (the share of
each voxel the report's volume counts) restricted to the part (each voxel with fill takes its nearest solid
voxel's part), on a grid padded by one empty voxel so every surface closes; when the object's triangles would
exceed ``max_triangles`` the marching cubes step grows (2, 3, ... voxels), which keeps the mesh closed.
Collision: CoACD's convex decomposition (``pip install coacd``, the ``sim`` extra) where asked for and importable,
else each part's convex hull (what MuJoCo makes of any mesh geom anyway).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from .frame import ObjectFrame

logger = logging.getLogger(__name__)

__all__ = ["PartMesh", "collision_pieces", "part_meshes"]


@dataclass
class PartMesh:
    part: int
    vertices: np.ndarray
    """[V, 3] object frame, metres"""
    faces: np.ndarray
    """[F, 3] int, counter-clockwise seen from outside (normals out)"""
    collision: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    """convex pieces (vertices, faces), object frame"""

    def trimesh(self):
        import trimesh

        return trimesh.Trimesh(self.vertices, self.faces, process=False)


def _part_labels(solid: np.ndarray, parts: np.ndarray) -> np.ndarray:
    idx = ndimage.distance_transform_edt(~solid, return_distances=False, return_indices=True)
    return parts[tuple(idx)]


def _march(f: np.ndarray, step: int):
    from skimage.measure import marching_cubes

    v, faces, _, _ = marching_cubes(np.pad(f, 1), level=0.5, step_size=step, allow_degenerate=False)
    return v - 1.0, faces[:, ::-1]  # unpadded voxel index units; scikit-image winds normals inwards


def part_meshes(solid: np.ndarray, parts: np.ndarray, fill: np.ndarray, origin_m: np.ndarray, voxel_m: float,
                frame: ObjectFrame, max_triangles: int = 20000) -> list[PartMesh]:  # fmt: skip
    """The visual mesh of every part (module doc); a part whose volume makes no surface is left out."""
    labels = _part_labels(solid, parts)
    P = int(parts[solid].max()) + 1
    fields = [np.where(labels == p, fill, 0.0).astype(np.float32) for p in range(P)]
    out: list[PartMesh] = []
    for step in range(1, 9):
        out = []
        for p, f in enumerate(fields):
            if f.max() <= 0.5:
                continue
            v, faces = _march(f, step)
            out.append(PartMesh(p, frame.to_object(origin_m + (v + 0.5) * voxel_m), faces.astype(np.int64)))
        if sum(len(m.faces) for m in out) <= max_triangles:
            break
    return out


def collision_pieces(mesh: PartMesh, method: str = "hull", threshold: float = 0.08, max_pieces: int = 16
                     ) -> tuple[list[tuple[np.ndarray, np.ndarray]], str]:  # fmt: skip
    """Convex pieces of ``mesh`` and the method that made them: "coacd" (``method`` "coacd" or "auto" with CoACD
    importable) or "hull"."""
    tm = mesh.trimesh()
    if method in ("coacd", "auto"):
        try:
            import coacd
        except ImportError:
            if method == "coacd":
                raise ImportError("collision 'coacd' needs CoACD: pip install coacd (or physgs-nerfstudio[sim]); "
                                  "collision 'hull' needs nothing.") from None  # fmt: skip
        else:
            coacd.set_log_level("error")
            parts = coacd.run_coacd(coacd.Mesh(tm.vertices, tm.faces), threshold=threshold,
                                    max_convex_hull=max_pieces, seed=0)  # fmt: skip
            return [(np.asarray(v, np.float64), np.asarray(f, np.int64)) for v, f in parts], "coacd"
    hull = tm.convex_hull
    return [(np.asarray(hull.vertices), np.asarray(hull.faces))], "hull"
