"""Sample exported property fields at query locations: voxel grid (.npz), point cloud (.ply), 2D map (.npz).

Readers accept the export's key names and a few spellings of each property (``friction`` or
``kinetic_friction``...). Each field gives, per query, the property mean and -- when the export carries it --
the predictive standard deviation (from ``<prop>_std``, or the square root of ``<prop>_total`` /
``<prop>_var`` variance arrays), which the scorer uses for NLL / CRPS / coverage.

Voxel grid npz (``physgs export``, format ``physgs-voxels/1``): the grid's minimum *corner* and voxel size
in scene units (``origin_scene``, ``voxel_size_scene``) and metres (``origin_m``, ``voxel_size_m``) -- or
generic ``origin``/``voxel_size`` --, per-property arrays ``[X, Y, Z]`` (index order x, y, z; ``<key>_mean``
and ``<key>_total`` variance) and ``occupancy`` ``[X, Y, Z]``. ``frame`` picks scene units or metres.
Sampling is ``trilinear`` (between voxel centres, clamped at the border) or ``nearest`` (voxel
containing the point). A query outside the grid or in an empty voxel is a miss (NaN) and is reported.

PLY point cloud: ``vertex`` element with ``x, y, z`` and per-property scalar fields; sampling takes the
nearest point (``max_distance`` turns far queries into misses). Positions are in scene units; with
``frame="metres"`` they are scaled by the ``metres_per_unit`` of the export's ``comment physgs {...}`` header.

2D map npz (a view's property maps, for pixel queries): per-property arrays ``[H, W]``, sampled at pixel
(u = column, v = row) -- ``nearest`` or ``bilinear``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from .errors import input_error

__all__ = ["PROPERTY_FIELD_NAMES", "FieldSample", "MapField", "PointField", "VoxelField", "load_field"]

# canonical property -> names an export may use for its mean array
PROPERTY_FIELD_NAMES: dict[str, tuple[str, ...]] = {
    "density": ("density", "density_mean"),
    "kinetic_friction": ("kinetic_friction", "kinetic_friction_mean", "friction", "friction_mean"),
    "shore_hardness": ("shore_hardness", "shore_hardness_mean", "hardness", "hardness_mean"),
    "youngs_modulus": ("youngs_modulus", "youngs_modulus_mean", "stiffness", "stiffness_mean"),
}
_STD_SUFFIXES = ("_std",)
_VAR_SUFFIXES = ("_total", "_var", "_variance", "_total_uncertainty")


@dataclass(frozen=True)
class FieldSample:
    """Per-query values: mean [Q] (NaN = miss) and std [Q] or None when the field has no uncertainty."""

    mean: np.ndarray
    std: np.ndarray | None
    field_name: str


def _stem_names(prop: str) -> tuple[str, ...]:
    names = PROPERTY_FIELD_NAMES.get(prop, (prop,))
    return tuple(n.removesuffix("_mean") for n in names)


def _find(keys, prop: str, path: Path) -> tuple[str, str | None, str | None]:
    """(mean key, std key or None, var key or None) for ``prop`` among ``keys``."""
    keys = list(keys)
    mean_key = next((k for k in PROPERTY_FIELD_NAMES.get(prop, (prop, f"{prop}_mean")) if k in keys), None)
    if mean_key is None:
        raise input_error(path, None, f"no array for property {prop!r} (arrays/fields present: {', '.join(keys)})",
                          f"Export that property (names accepted: {', '.join(PROPERTY_FIELD_NAMES.get(prop, (prop,)))})")
    std_key = var_key = None
    for stem in _stem_names(prop):
        std_key = std_key or next((stem + s for s in _STD_SUFFIXES if stem + s in keys), None)
        var_key = var_key or next((stem + s for s in _VAR_SUFFIXES if stem + s in keys), None)
    return mean_key, std_key, var_key


def _std_from(std: np.ndarray | None, var: np.ndarray | None) -> np.ndarray | None:
    if std is not None:
        return np.asarray(std, dtype=np.float64)
    if var is not None:
        return np.sqrt(np.clip(np.asarray(var, dtype=np.float64), 0.0, None))
    return None


class VoxelField:
    """A voxel grid npz written by ``physgs export``."""

    def __init__(self, path: Path, frame: Literal["scene", "metres"] = "scene"):
        self.path = Path(path)
        try:
            with np.load(self.path, allow_pickle=False) as data:
                self.arrays = {k: data[k] for k in data.files}
        except Exception as err:  # noqa: BLE001 - any numpy/zip error means the same to the user
            raise input_error(self.path, None, f"cannot read as a numpy .npz archive ({err})",
                              "Pass the voxel grid written by `physgs export`") from None
        suffix = "_m" if frame == "metres" else "_scene"
        o_key = next((k for k in (f"origin{suffix}", "origin") if k in self.arrays), f"origin{suffix}")
        v_key = next((k for k in (f"voxel_size{suffix}", "voxel_size") if k in self.arrays), f"voxel_size{suffix}")
        for key in (o_key, v_key):
            if key not in self.arrays:
                raise input_error(self.path, f"array {key!r}", "missing",
                                  f"A voxel grid npz needs the grid's min corner and voxel size ({o_key!r}, {v_key!r}, "
                                  "or 'origin'/'voxel_size'); re-export it with `physgs export`")
        self.origin = np.asarray(self.arrays[o_key], dtype=np.float64).reshape(-1)
        vs = np.asarray(self.arrays[v_key], dtype=np.float64).reshape(-1)
        self.voxel_size = np.broadcast_to(vs, (3,)).astype(np.float64) if vs.size in (1, 3) else None
        if self.origin.shape != (3,) or self.voxel_size is None or (self.voxel_size <= 0).any():
            raise input_error(self.path, "arrays 'origin'/'voxel_size'",
                              f"origin must have 3 values and voxel_size 1 or 3 positive values "
                              f"(got {self.origin.tolist()}, {vs.tolist()})", "Re-export the voxel grid")
        self.occupancy = self.arrays.get("occupancy")

    def sample(self, points: np.ndarray, prop: str, method: Literal["trilinear", "nearest"] = "trilinear") -> FieldSample:
        mean_key, std_key, var_key = _find(self.arrays.keys(), prop, self.path)
        grid = np.asarray(self.arrays[mean_key], dtype=np.float64)
        if grid.ndim != 3:
            raise input_error(self.path, f"array {mean_key!r}", f"expected a 3D [X, Y, Z] array, got shape {grid.shape}",
                              "Re-export the voxel grid")
        std = _std_from(self.arrays.get(std_key) if std_key else None, self.arrays.get(var_key) if var_key else None)
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        shape = np.array(grid.shape)
        cont = (pts - self.origin) / self.voxel_size  # continuous index, voxel i spans [i, i+1)
        inside = np.all((cont >= 0) & (cont < shape), axis=1)
        cell = np.clip(np.floor(cont).astype(np.int64), 0, shape - 1)
        occupied = np.ones(len(pts), dtype=bool)
        if self.occupancy is not None:
            occupied = self.occupancy[cell[:, 0], cell[:, 1], cell[:, 2]].astype(bool)
        if method == "nearest":
            mean = grid[cell[:, 0], cell[:, 1], cell[:, 2]]
            sd = None if std is None else std[cell[:, 0], cell[:, 1], cell[:, 2]]
        else:
            mean = _trilinear(grid, cont - 0.5, self.occupancy)
            sd = None if std is None else _trilinear(std, cont - 0.5, self.occupancy)
        valid = inside & occupied & np.isfinite(mean)
        mean = np.where(valid, mean, np.nan)
        if sd is not None:
            sd = np.where(valid, sd, np.nan)
        return FieldSample(mean, sd, f"{self.path.name}:{mean_key}")


def _trilinear(grid: np.ndarray, idx: np.ndarray, occupancy: np.ndarray | None) -> np.ndarray:
    """Interpolate between voxel centres (``idx`` in centre units), ignoring empty voxels' values."""
    shape = np.array(grid.shape)
    base = np.floor(idx).astype(np.int64)
    frac = idx - base
    num = np.zeros(len(idx))
    den = np.zeros(len(idx))
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                c = np.clip(base + np.array([dx, dy, dz]), 0, shape - 1)
                w = (np.where(dx, frac[:, 0], 1 - frac[:, 0]) * np.where(dy, frac[:, 1], 1 - frac[:, 1])
                     * np.where(dz, frac[:, 2], 1 - frac[:, 2]))
                v = grid[c[:, 0], c[:, 1], c[:, 2]]
                ok = np.isfinite(v)
                if occupancy is not None:
                    ok &= occupancy[c[:, 0], c[:, 1], c[:, 2]].astype(bool)
                w = np.where(ok, w, 0.0)
                num += w * np.where(ok, v, 0.0)
                den += w
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / np.where(den > 0, den, 1.0), np.nan)


class PointField:
    """A PLY property point cloud written by ``physgs export`` (one vertex per Gaussian)."""

    def __init__(self, path: Path, max_distance: float | None = None, frame: Literal["scene", "metres"] = "scene"):
        self.path = Path(path)
        try:
            from plyfile import PlyData

            ply = PlyData.read(str(self.path))
            vertex = ply["vertex"]
            comments = list(ply.comments) + list(ply.obj_info)
        except Exception as err:  # noqa: BLE001
            raise input_error(self.path, None, f"cannot read a PLY 'vertex' element ({err})",
                              "Pass the property point cloud written by `physgs export`") from None
        names = [p.name for p in vertex.properties]
        for axis in "xyz":
            if axis not in names:
                raise input_error(self.path, "element 'vertex'", f"no {axis!r} field (fields: {', '.join(names)})",
                                  "Pass a point cloud with x, y, z positions")
        self.fields = {n: np.asarray(vertex[n], dtype=np.float64) for n in names}
        self.xyz = np.stack([self.fields["x"], self.fields["y"], self.fields["z"]], axis=1)
        if frame == "metres":
            self.xyz = self.xyz * _ply_metres_per_unit(self.path, comments)
        self.max_distance = max_distance
        from scipy.spatial import cKDTree

        self._tree = cKDTree(self.xyz)

    def sample(self, points: np.ndarray, prop: str, method: str = "nearest") -> FieldSample:
        mean_key, std_key, var_key = _find(self.fields.keys(), prop, self.path)
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        dist, idx = self._tree.query(pts, k=1)
        mean = self.fields[mean_key][idx]
        std = _std_from(self.fields.get(std_key) if std_key else None, self.fields.get(var_key) if var_key else None)
        sd = None if std is None else std[idx]
        if self.max_distance is not None:
            far = dist > self.max_distance
            mean = np.where(far, np.nan, mean)
            sd = None if sd is None else np.where(far, np.nan, sd)
        return FieldSample(mean, sd, f"{self.path.name}:{mean_key}")


def _ply_metres_per_unit(path: Path, comments: list[str]) -> float:
    import json

    for c in comments:
        if c.startswith("physgs "):
            try:
                mpu = float(json.loads(c[len("physgs "):])["metres_per_unit"])
            except (ValueError, KeyError, TypeError):
                break
            if mpu > 0:
                return mpu
    raise input_error(path, "header", "no 'comment physgs {...}' with metres_per_unit",
                      "Sample in scene units (--points-frame scene) or re-export the PLY with `physgs export`")


class MapField:
    """Per-view 2D property maps (npz of ``[H, W]`` arrays) for pixel-location queries."""

    def __init__(self, path: Path):
        self.path = Path(path)
        try:
            with np.load(self.path, allow_pickle=False) as data:
                self.arrays = {k: data[k] for k in data.files}
        except Exception as err:  # noqa: BLE001
            raise input_error(self.path, None, f"cannot read as a numpy .npz archive ({err})",
                              "Pass an npz of [H, W] property maps") from None

    def sample(self, pixels: np.ndarray, prop: str, method: str = "nearest") -> FieldSample:
        mean_key, std_key, var_key = _find(self.arrays.keys(), prop, self.path)
        img = np.asarray(self.arrays[mean_key], dtype=np.float64)
        if img.ndim != 2:
            raise input_error(self.path, f"array {mean_key!r}", f"expected a 2D [H, W] map, got shape {img.shape}",
                              "Save one [H, W] array per property")
        std = _std_from(self.arrays.get(std_key) if std_key else None, self.arrays.get(var_key) if var_key else None)
        uv = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        h, w = img.shape
        inside = (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)

        def at(a: np.ndarray) -> np.ndarray:
            if method == "bilinear":
                u = np.clip(uv[:, 0], 0, w - 1)
                v = np.clip(uv[:, 1], 0, h - 1)
                u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)
                u1, v1 = np.minimum(u0 + 1, w - 1), np.minimum(v0 + 1, h - 1)
                fu, fv = u - u0, v - v0
                return ((1 - fu) * (1 - fv) * a[v0, u0] + fu * (1 - fv) * a[v0, u1]
                        + (1 - fu) * fv * a[v1, u0] + fu * fv * a[v1, u1])
            ui = np.clip(np.rint(uv[:, 0]).astype(int), 0, w - 1)
            vi = np.clip(np.rint(uv[:, 1]).astype(int), 0, h - 1)
            return a[vi, ui]

        mean = np.where(inside, at(img), np.nan)
        sd = None if std is None else np.where(inside, at(std), np.nan)
        return FieldSample(mean, sd, f"{self.path.name}:{mean_key}")


def load_field(path: Path, max_distance: float | None = None,
               frame: Literal["scene", "metres"] = "scene") -> VoxelField | PointField:
    """A 3D property field from an export file (``.npz`` voxel grid or ``.ply`` point cloud)."""
    path = Path(path)
    if not path.is_file():
        raise input_error(path, None, "file not found", "Pass the voxel grid (.npz) or point cloud (.ply) of the export")
    if path.suffix.lower() == ".npz":
        return VoxelField(path, frame)
    if path.suffix.lower() == ".ply":
        return PointField(path, max_distance, frame)
    raise input_error(path, None, f"unsupported field file type {path.suffix!r}", "Use the export's .npz voxel grid or .ply")
