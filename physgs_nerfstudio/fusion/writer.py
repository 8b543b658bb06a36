"""Write fusion results into a nerfstudio dataset (contract: docs/architecture.md).

* ``materials.json``: legend (id, name, colour) with per-property NIG posterior and prior, alpha0/lambda;
* ``materials/labels/<frame>.png`` (8-bit material id, 0 = unknown), ``materials/confidence/<frame>.png``
  (confidence * 255), ``materials/preview/<frame>.png`` (legend colours over a dimmed grey copy of the
  image, for people) and ``materials/legend.png``;
* ``transforms.json``: ``material_path`` and ``material_confidence_path`` per frame, every other key
  preserved; written atomically, with ``transforms.json.bak`` kept from before the first modification.

Each writer takes an optional :class:`~.transaction.DatasetTransaction`: with one, files are staged and
the dataset changes only when it commits (dataset.py uses one for a whole run's outputs).
"""

from __future__ import annotations

import io
import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import asdict, is_dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DatasetError
from ..materials import CANONICAL_SCALE, PROPERTY_KEYS, MaterialLibrary
from . import transaction as _transaction
from .maps import MapFusionConfig, ViewMaps
from .properties import PropertyPosteriors, posterior_means
from .transaction import DatasetTransaction

MATERIALS_JSON_VERSION = 1
LABEL_DIR = "materials/labels"
CONFIDENCE_DIR = "materials/confidence"
PREVIEW_DIR = "materials/preview"


def jsonable(obj: Any) -> Any:
    """`obj` in plain JSON types: dataclasses and mappings as dicts (string keys), tuples and lists as lists,
    paths as strings, numpy scalars as Python numbers, non-finite floats as None (JSON has no inf / nan)."""
    if is_dataclass(obj) and not isinstance(obj, type):
        return {k: jsonable(v) for k, v in asdict(obj).items()}
    if isinstance(obj, Mapping):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return jsonable(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def atomic_write_text(path: Path, text: str) -> None:
    """``path`` replaced by ``text`` in one rename (transaction.atomic_write_bytes)."""
    _transaction.atomic_write_bytes(Path(path), text.encode("utf-8"))


def encode_png(image: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG")
    return buf.getvalue()


def _put(root: Path, rel: str, data: bytes, txn: DatasetTransaction | None) -> None:
    """Stage ``rel`` in ``txn``, or (no transaction) replace ``root / rel`` atomically on its own."""
    if txn is not None:
        txn.write_bytes(rel, data)
    else:
        _transaction.atomic_write_bytes(Path(root) / rel, data)


def frame_names(file_paths: Sequence[str]) -> dict[str, str]:
    """Output file stem per frame: the image's stem, or its path with '/' -> '__' when stems collide."""
    stems = [Path(p).stem for p in file_paths]
    dup = {s for s in stems if stems.count(s) > 1}
    out = {}
    for p, s in zip(file_paths, stems):
        if s in dup:
            s = re.sub(r"[^A-Za-z0-9_.-]+", "__", str(Path(p).with_suffix("")).strip("./"))
        out[p] = s
    return out


def _nig_entry(nig, i: int) -> dict[str, dict[str, float]]:
    out = {}
    for p, key in enumerate(PROPERTY_KEYS):
        out[key] = {f: float(getattr(nig, f)[i, p]) for f in ("tau", "kappa", "a", "b")}
    return out


def materials_document(
    post: PropertyPosteriors,
    library: MaterialLibrary,
    simulated: bool,
    map_config: MapFusionConfig,
    source: Mapping[str, Any] | None = None,
) -> dict:
    """The materials.json document (contract keys plus ``estimate`` per material and ``source``)."""
    means = posterior_means(post) if post.names else {}
    materials = []
    for i, name in enumerate(post.names):
        mat = library[name]
        thickness = post.thickness_m[i]
        materials.append(
            {
                "id": i + 1,
                "name": name,
                "color": [int(c) for c in mat.color],
                "category": mat.category,
                "posterior": _nig_entry(post.posterior, i),
                "prior": _nig_entry(post.prior, i),
                "estimate": {k: float(means[k][i]) for k in PROPERTY_KEYS},
                "thickness_m": None
                if thickness is None or not math.isfinite(thickness)
                else float(thickness),
                "num_observations": int(post.num_observations[i]),
                "observation_weight": float(post.weight[i]),
            }
        )
    return {
        "version": MATERIALS_JSON_VERSION,
        "env": library.env,
        "simulated": bool(simulated),
        "property_keys": list(PROPERTY_KEYS),
        "log_space": {k: bool(f) for k, f in zip(PROPERTY_KEYS, post.log_space)},
        "hardness_scale": CANONICAL_SCALE,
        "alpha0": float(map_config.alpha0),
        "lambda": float(map_config.lam),
        "level_weights": dict(map_config.level_weights),
        "source": dict(source or {}),
        "materials": materials,
    }


def write_materials_json(root: Path, document: dict, txn: DatasetTransaction | None = None) -> Path:
    _put(root, "materials.json", json.dumps(document, indent=2).encode("utf-8"), txn)
    return Path(root) / "materials.json"


def legend_colors(colors: Sequence[Sequence[int]]) -> np.ndarray:
    """Palette [K + 1, 3] uint8; row 0 (unknown) black."""
    return np.concatenate([np.zeros((1, 3), np.uint8), np.asarray(colors, np.uint8).reshape(-1, 3)], axis=0)


def preview_image(labels: np.ndarray, palette: np.ndarray, image: np.ndarray | None = None) -> np.ndarray:
    """Legend colours where a material is known; elsewhere a dimmed grey copy of the image (or black)."""
    out = palette[labels]
    if image is not None and image.shape[:2] == labels.shape:
        grey = (0.35 * image[..., :3].astype(np.float32).mean(-1, keepdims=True)).astype(np.uint8)
        out = np.where(labels[..., None] > 0, out, np.repeat(grey, 3, axis=-1))
    return out


def write_view_maps(
    root: Path,
    name: str,
    maps: ViewMaps,
    palette: np.ndarray,
    image: np.ndarray | None = None,
    txn: DatasetTransaction | None = None,
) -> tuple[str, str]:
    """Write the label, confidence and preview PNGs of one frame; returns the two dataset-relative paths."""
    label_rel = f"{LABEL_DIR}/{name}.png"
    conf_rel = f"{CONFIDENCE_DIR}/{name}.png"
    _put(root, label_rel, encode_png(maps.labels.astype(np.uint8)), txn)
    conf8 = np.clip(np.round(maps.confidence * 255.0), 0, 255).astype(np.uint8)
    _put(root, conf_rel, encode_png(conf8), txn)
    _put(root, f"{PREVIEW_DIR}/{name}.png", encode_png(preview_image(maps.labels, palette, image)), txn)
    return label_rel, conf_rel


def write_legend(
    root: Path, names: Sequence[str], colors: Sequence[Sequence[int]], txn: DatasetTransaction | None = None
) -> Path:
    """A swatch + name per material (materials/legend.png)."""
    import cv2

    row, width = 28, 320
    img = np.full((row * max(1, len(names)) + 8, width, 3), 255, np.uint8)
    for i, (name, color) in enumerate(zip(names, colors)):
        y = 4 + i * row
        img[y + 2 : y + row - 2, 6 : 6 + 40] = np.asarray(color, np.uint8)
        cv2.putText(
            img,
            f"{i + 1}: {name}",
            (56, y + row - 9),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.55,
            (0, 0, 0),
            1,
            cv2.LINE_AA,
        )
    _put(root, "materials/legend.png", encode_png(img), txn)
    return Path(root) / "materials" / "legend.png"


def update_transforms(
    root: Path,
    paths: Mapping[str, tuple[str, str]],
    transforms_name: str = "transforms.json",
    txn: DatasetTransaction | None = None,
) -> Path:
    """Set ``material_path`` / ``material_confidence_path`` of the frames whose ``file_path`` is a key of
    ``paths``; every other key (top level and per frame) and the key order are preserved. The original file
    is copied to ``transforms.json.bak`` before the first modification; the write is atomic."""
    path = Path(root) / transforms_name
    raw = path.read_bytes()
    try:
        data = json.loads(raw.decode("utf-8"))
    except ValueError as err:
        raise DatasetError(f"{path} is not valid JSON ({err}); fix the file or regenerate it") from None
    frames = data.get("frames") if isinstance(data, dict) else None
    if not isinstance(frames, list):
        raise DatasetError(f"{path} has no 'frames' list")
    changed = False
    for frame in frames:
        fp = frame.get("file_path") if isinstance(frame, dict) else None
        if fp in paths:
            label_rel, conf_rel = paths[fp]
            if frame.get("material_path") != label_rel or frame.get("material_confidence_path") != conf_rel:
                frame["material_path"] = label_rel
                frame["material_confidence_path"] = conf_rel
                changed = True
    if not changed:
        return path
    if not path.with_name(path.name + ".bak").exists():
        _put(root, transforms_name + ".bak", raw, txn)
    _put(root, transforms_name, (json.dumps(data, indent=4) + "\n").encode("utf-8"), txn)
    return path
