"""Point annotations of kinetic friction and Shore hardness (NeRF2Physics' real-object measurements).

NeRF2Physics' friction/hardness data pairs multi-view captures of household objects with measurements
at points of each object: a kinetic friction coefficient, or a Shore hardness reading with its durometer
scale (A or D). This module reads such annotations in the layout below -- written from that public
description, not from the dataset's files (they could not be downloaded here); a converter of the
original files into this layout is a few lines.

Ground truth, JSON::

    {"objects": {
       "<object>": {"scene": "<scene folder>",            # optional, default: the object name
                    "points": [
                      {"id": "p0", "xyz": [0.01, 0.02, 0.10], "property": "kinetic_friction", "value": 0.42},
                      {"id": "p1", "pixel": [312, 240], "view": "canonical",
                       "property": "shore_hardness", "value": 62, "scale": "A"}]}}}

or CSV ``object,point,property,value,scale,x,y,z,u,v,view,scene`` (first four required; each row gives
``x,y,z`` or ``u,v``). ``xyz`` is in the export's scene frame (default), in metres of that frame, or in the
dataset's world frame (``transforms.json``; mapped with nerfstudio's ``dataparser_transforms.json``, as
NeRF2Physics does for its point clouds) -- ``physgs eval --points-frame scene|metres|world``. ``pixel`` is (column, row) in
the named view. Hardness needs ``scale``; friction is dimensionless. Items are ``<object>/<point>``,
grouped by object.

Our predictions are sampled from each scene's export under a results folder:
``<results>/<scene>/**/*.npz`` voxel grid (``trilinear`` or ``nearest``) or ``*.ply`` point cloud (nearest
Gaussian) for 3D points; ``<results>/<scene>/**/<view>.npz`` 2D property maps for pixel queries. Hardness
in exports is in the canonical A_eq scale and is converted to each reading's scale by the scorer.

NeRF2Physics' point predictions: ``{"<object>": {"<point>": [low, high] or value}}`` (one file per property;
a point's property is taken from the ground truth). Their hardness values use NeRF2Physics' combined
encoding -- Shore A as is, Shore D plus 100 (``gpt_inference.parse_material_hardness``) -- decoded here.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ..errors import input_error
from ..fileio import load_json, read_csv, to_float, to_str
from ..records import Measurement, Prediction
from ..sampling import MapField, PointField, VoxelField
from ..units import canonical_property

__all__ = [
    "PointDataset",
    "PointQuery",
    "decode_n2p_hardness",
    "read_n2p_point_predictions",
    "read_point_annotations",
    "sample_export_predictions",
    "world_to_scene",
]

_POINT_PROPS = ("kinetic_friction", "shore_hardness")
_CSV_REQUIRED = ("object", "point", "property", "value")
_CSV_OPTIONAL = ("scale", "x", "y", "z", "u", "v", "view", "scene")


@dataclass(frozen=True)
class PointQuery:
    item: str                    # "<object>/<point>"
    obj: str
    scene: str
    prop: str
    xyz: tuple[float, float, float] | None
    pixel: tuple[float, float] | None
    view: str | None


@dataclass
class PointDataset:
    measurements: list[Measurement]
    queries: list[PointQuery] = field(default_factory=list)


def _point(path: Path, where: str, obj: str, scene: str, pid: str, prop_raw: Any, value: Any, scale: Any,
           xyz: Any, pixel: Any, view: Any) -> tuple[Measurement, PointQuery]:
    prop = canonical_property(to_str(prop_raw, path, where, "property")) or str(prop_raw)
    if prop not in _POINT_PROPS:
        raise input_error(path, where, f"property {prop_raw!r} is not a point property",
                          "Use kinetic_friction (or friction) or shore_hardness (or hardness)")
    v = to_float(value, path, where, "value")
    sc = None
    if prop == "shore_hardness":
        from ...materials.hardness import normalize_scale

        if scale in (None, ""):
            raise input_error(path, where, "hardness reading without a scale", "Add \"scale\": \"A\" or \"D\" (or \"00\")")
        try:
            sc = normalize_scale(scale)
        except ValueError as err:
            raise input_error(path, where, str(err).rstrip("."), "Write A, D or 00") from None
    has_xyz = xyz is not None and not (isinstance(xyz, (list, tuple)) and all(c in ("", None) for c in xyz))
    has_px = pixel is not None and not (isinstance(pixel, (list, tuple)) and all(c in ("", None) for c in pixel))
    if has_xyz == has_px:
        raise input_error(path, where, "a point needs exactly one location: xyz (3D) or pixel (u, v)",
                          "Give \"xyz\": [x, y, z] or \"pixel\": [u, v] (CSV: x,y,z or u,v)")
    loc3 = loc2 = None
    if has_xyz:
        if not isinstance(xyz, (list, tuple)) or len(xyz) != 3:
            raise input_error(path, where, f"xyz must have 3 numbers, got {xyz!r}", "Write [x, y, z]")
        loc3 = tuple(to_float(c, path, where, f"xyz[{i}]") for i, c in enumerate(xyz))
    else:
        if not isinstance(pixel, (list, tuple)) or len(pixel) != 2:
            raise input_error(path, where, f"pixel must have 2 numbers, got {pixel!r}", "Write [u, v] (column, row)")
        loc2 = tuple(to_float(c, path, where, f"pixel[{i}]") for i, c in enumerate(pixel))
    item = f"{obj}/{pid}"
    m = Measurement(item=item, prop=prop, value=v, unit="", scale=sc, group=obj, source=f"{path}:{where}")
    q = PointQuery(item=item, obj=obj, scene=scene, prop=prop, xyz=loc3, pixel=loc2,  # type: ignore[arg-type]
                   view=(str(view).strip() if view not in (None, "") else ("canonical" if loc2 else None)))
    return m, q


def read_point_annotations(path: Path) -> PointDataset:
    """Friction / hardness point measurements from the JSON or CSV layout of the module docstring."""
    path = Path(path)
    ms: list[Measurement] = []
    qs: list[PointQuery] = []
    if path.suffix.lower() == ".csv":
        for n, row in read_csv(path, _CSV_REQUIRED, _CSV_OPTIONAL):
            where = f"line {n}"
            obj = to_str(row["object"], path, where, "object")
            pid = to_str(row["point"], path, where, "point")
            xyz = [row.get("x", ""), row.get("y", ""), row.get("z", "")]
            px = [row.get("u", ""), row.get("v", "")]
            m, q = _point(path, where, obj, row.get("scene") or obj, pid, row["property"], row["value"],
                          row.get("scale"), xyz, px, row.get("view"))
            ms.append(m)
            qs.append(q)
    else:
        data = load_json(path)
        objects = data.get("objects") if isinstance(data, dict) else None
        if not isinstance(objects, dict) or not objects:
            raise input_error(path, None, "expected {\"objects\": {\"<object>\": {\"points\": [...]}}}",
                              "See physgs_nerfstudio/eval/adapters/points.py for the layout")
        for obj, entry in objects.items():
            if not isinstance(entry, dict) or not isinstance(entry.get("points"), list):
                raise input_error(path, f"object {obj!r}", "needs a \"points\" list", "Add \"points\": [...]")
            scene = str(entry.get("scene") or obj)
            for i, pt in enumerate(entry["points"]):
                where = f"object {obj!r}, point {i}"
                if not isinstance(pt, dict):
                    raise input_error(path, where, f"expected an object, got {type(pt).__name__}", "Write each point as an object")
                pid = to_str(pt.get("id", str(i)), path, where, "id")
                m, q = _point(path, where, str(obj), scene, pid, pt.get("property"), pt.get("value"), pt.get("scale"),
                              pt.get("xyz"), pt.get("pixel"), pt.get("view"))
                ms.append(m)
                qs.append(q)
    if not ms:
        raise input_error(path, None, "no points", "Add measurements")
    return PointDataset(ms, qs)


# ------------------------------------------------------------------------------------------ our exports
def _scene_files(results: Path, scene: str) -> list[Path]:
    d = Path(results) / scene
    return sorted(d.rglob("*")) if d.is_dir() else []


def _voxel_or_ply(files: Sequence[Path], prefer: str) -> Path | None:
    grids = []
    for f in files:
        if f.suffix.lower() == ".npz":
            try:
                with np.load(f, allow_pickle=False) as z:
                    if any(k.startswith("origin") for k in z.files) and any(k.startswith("voxel_size") for k in z.files):
                        grids.append(f)
            except Exception:  # noqa: BLE001, S112 - unreadable npz: not a voxel grid (maps are read later)
                continue
    plys = [f for f in files if f.suffix.lower() == ".ply"]
    order = (grids, plys) if prefer == "voxel" else (plys, grids)
    for group in order:
        if len(group) > 1:
            raise input_error(group[0].parent, None, f"{len(group)} candidate fields ({', '.join(p.name for p in group)})",
                              "Keep one export per scene folder")
        if group:
            return group[0]
    return None


def world_to_scene(points_xyz: np.ndarray, dataparser_transforms: Path) -> np.ndarray:
    """Dataset world frame -> nerfstudio scene frame: ``scale * (R x + t)`` from ``dataparser_transforms.json``."""
    path = Path(dataparser_transforms)
    d = load_json(path)
    try:
        t = np.asarray(d["transform"], dtype=np.float64)
        scale = float(d["scale"])
    except (KeyError, TypeError, ValueError):
        raise input_error(path, None, "needs 'transform' (3x4 or 4x4) and 'scale'",
                          "Use the dataparser_transforms.json nerfstudio wrote next to the run's config.yml") from None
    if t.shape not in ((3, 4), (4, 4)) or not np.isfinite(t).all() or not scale > 0:
        raise input_error(path, "'transform'/'scale'", f"transform shape {t.shape}, scale {scale}",
                          "Use the dataparser_transforms.json nerfstudio wrote")
    return scale * (np.asarray(points_xyz, dtype=np.float64) @ t[:3, :3].T + t[:3, 3])


def sample_export_predictions(data: PointDataset, results: Path, method: str = "physgs",
                              prefer: Literal["voxel", "ply"] = "voxel",
                              interpolation: Literal["trilinear", "nearest"] = "trilinear",
                              max_distance: float | None = None,
                              frame: Literal["scene", "metres", "world"] = "scene") -> list[Prediction]:
    """Our predictions at every query, sampled from ``<results>/<scene>`` exports.

    ``frame`` says what the annotation's xyz are in: ``scene`` (the export's scene units), ``metres``
    (scene units x metres_per_unit) or ``world`` (the dataset's transforms.json frame, mapped into scene
    units with the ``dataparser_transforms.json`` found under ``<results>/<scene>``). Queries whose scene
    has no export or whose point falls outside the field get no prediction: the scorer lists them as
    missing with the reason.
    """
    results = Path(results)
    if not results.is_dir():
        raise input_error(results, None, "not a directory", "Pass the folder holding one export folder per scene")
    out: list[Prediction] = []
    by_scene: dict[str, list[PointQuery]] = {}
    for q in data.queries:
        by_scene.setdefault(q.scene, []).append(q)
    for scene, qs in by_scene.items():
        files = _scene_files(results, scene)
        q3 = [q for q in qs if q.xyz is not None]
        q2 = [q for q in qs if q.pixel is not None]
        if q3:
            fpath = _voxel_or_ply(files, prefer)
            if fpath is not None:
                ff = "metres" if frame == "metres" else "scene"
                fld = VoxelField(fpath, ff) if fpath.suffix.lower() == ".npz" else PointField(fpath, max_distance, ff)
                to_scene = None
                if frame == "world":
                    dts = [f for f in files if f.name == "dataparser_transforms.json"]
                    if len(dts) != 1:
                        raise input_error(results / scene, None, f"{len(dts)} dataparser_transforms.json files "
                                          "(world-frame points need exactly one)",
                                          "Copy the run's dataparser_transforms.json into the scene's results folder, "
                                          "or give points in the export's frame (--points-frame scene)")
                    to_scene = dts[0]
                for prop in sorted({q.prop for q in q3}):
                    sel = [q for q in q3 if q.prop == prop]
                    xyz = np.array([q.xyz for q in sel])
                    if to_scene is not None:
                        xyz = world_to_scene(xyz, to_scene)
                    s = fld.sample(xyz, prop, interpolation if isinstance(fld, VoxelField) else "nearest")
                    out += _preds(sel, s.mean, s.std, method, s.field_name, "outside the exported field")
        for view in sorted({q.view for q in q2 if q.view}):
            sel_v = [q for q in q2 if q.view == view]
            maps = [f for f in files if f.suffix.lower() == ".npz" and f.stem == view]
            if len(maps) > 1:
                raise input_error(results / scene, None, f"several maps named {view}.npz", "Keep one map per view")
            if maps:
                mf = MapField(maps[0])
                for prop in sorted({q.prop for q in sel_v}):
                    sel = [q for q in sel_v if q.prop == prop]
                    s = mf.sample(np.array([q.pixel for q in sel]), prop,
                                  "bilinear" if interpolation == "trilinear" else "nearest")
                    out += _preds(sel, s.mean, s.std, method, s.field_name, "outside the view's map")
    return out


def _preds(qs: Sequence[PointQuery], mean: np.ndarray, std: np.ndarray | None, method: str, src: str,
           miss: str) -> list[Prediction]:
    out = []
    for i, q in enumerate(qs):
        mu = float(mean[i])
        sd = None if std is None or not np.isfinite(std[i]) or std[i] <= 0 else float(std[i])
        ok = np.isfinite(mu)
        out.append(Prediction(item=q.item, prop=q.prop, mean=mu if ok else None, method=method, std=sd if ok else None,
                              scale="A_eq" if q.prop == "shore_hardness" else None, source=src,
                              notes=() if ok else (f"query {miss}",)))
    return out


# ------------------------------------------------------------------------------------------ NeRF2Physics
def decode_n2p_hardness(value: float) -> float:
    """NeRF2Physics' combined hardness (A as is; D + 100) -> canonical A_eq."""
    from ...materials.hardness import to_canonical

    return float(to_canonical(value, "A") if value <= 100 else to_canonical(value - 100, "D"))


def read_n2p_point_predictions(path: Path, data: PointDataset, method: str = "nerf2physics",
                               hardness_encoding: Literal["a_d100", "a_eq", "A", "D"] = "a_d100") -> list[Prediction]:
    """NeRF2Physics' per-point predictions ``{"<object>": {"<point>": [low, high] | value}}``."""
    path = Path(path)
    raw = load_json(path)
    if not isinstance(raw, dict):
        raise input_error(path, None, "expected {\"<object>\": {\"<point>\": [low, high]}}", "Pass per-point predictions")
    props: dict[str, set[str]] = {}
    for m in data.measurements:
        props.setdefault(m.item, set()).add(m.prop)
    out = []
    for obj, pts in raw.items():
        if not isinstance(pts, dict):
            raise input_error(path, f"object {obj!r}", "expected {\"<point>\": [low, high]}", "Nest points under their object")
        for pid, val in pts.items():
            where = f"object {obj!r}, point {pid!r}"
            item = f"{obj}/{pid}"
            ps = props.get(item)
            if not ps:
                out.append(Prediction(item, "unknown", None, method=method, source=f"{path}[{where}]"))
                continue
            if len(ps) > 1:
                raise input_error(path, where, f"the ground truth has several properties here ({', '.join(sorted(ps))})",
                                  "Split the predictions into one file per property")
            prop = next(iter(ps))
            if isinstance(val, (list, tuple)):
                if len(val) != 2:
                    raise input_error(path, where, f"expected [low, high] or a number, got {val!r}", "Fix the entry")
                low, high = (to_float(v, path, where, "bound") for v in val)
                if low > high:
                    raise input_error(path, where, f"low {low:g} > high {high:g}", "Swap or fix the bounds")
            else:
                low = high = to_float(val, path, where, "value")
            mean = 0.5 * (low + high)
            scale = None
            notes: tuple[str, ...] = ()
            if prop == "shore_hardness":
                if hardness_encoding == "a_d100":
                    mean, low, high = decode_n2p_hardness(mean), decode_n2p_hardness(low), decode_n2p_hardness(high)
                    scale = "A_eq"
                    notes = ("NeRF2Physics hardness decoded (A; D+100)",)
                    if low > high:
                        low, high = high, low
                else:
                    scale = "A_eq" if hardness_encoding == "a_eq" else hardness_encoding
            interval = (low, high) if high > low else (None, None)
            out.append(Prediction(item, prop, mean, method=method, low=interval[0], high=interval[1], level=None,
                                  scale=scale, source=f"{path}[{where}]", notes=notes))
    return out
