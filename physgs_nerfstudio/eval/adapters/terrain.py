"""Terrain Class Friction (Ewen et al. 2022): per-class friction ground truth, per-image predictions.

Following that paper's protocol (and PhysGS supplement B.2), the truth for every image of a terrain class
is the mean of the class's unimodal Gaussian fit of measured friction coefficients. The seven classes and
their fits are built in (:data:`EWEN2022_FRICTION`, values as printed in the PhysGS supplement's table);
``--terrain-table`` replaces them with a CSV ``class,mu,sigma``.

Images and their classes come from either

* a labels file: CSV ``image,class`` or JSON ``{"<image>": "<class>"}``; or
* a folder with one sub-folder per class (``carpet/``, ``concrete/``, ``laminated_flooring/`` ...) holding
  the images (``.jpg``, ``.jpeg``, ``.png``); an image is named by its path relative to the folder.

Class names are matched case- and separator-insensitively, with a few aliases (``laminate``, ``pebble``,
``rock``). Predictions (table layout, property ``kinetic_friction``) are keyed by image -- the relative path
or, when unique, the bare file name -- or by class name, which scores one prediction per class. Results
are reported per class (group) and overall.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path

from ..errors import input_error
from ..fileio import load_json, read_csv, to_float, to_str
from ..records import Measurement, Prediction

__all__ = [
    "EWEN2022_FRICTION",
    "align_terrain_predictions",
    "class_truth",
    "load_class_table",
    "normalize_class",
    "read_terrain_truth",
]

# class -> (mu, sigma) of the kinetic friction coefficient: Ewen et al. 2022, as tabulated in PhysGS supp. B.2
EWEN2022_FRICTION: dict[str, tuple[float, float]] = {
    "concrete": (0.543, 0.065),
    "pebbles": (0.428, 0.059),
    "rocks": (0.478, 0.113),
    "wood": (0.372, 0.055),
    "rubber": (0.616, 0.048),
    "carpet": (0.583, 0.068),
    "laminated_flooring": (0.311, 0.045),
}
_ALIASES = {"laminate": "laminated_flooring", "laminated": "laminated_flooring", "laminate_flooring": "laminated_flooring",
            "pebble": "pebbles", "rock": "rocks"}
_IMAGE_EXT = {".jpg", ".jpeg", ".png"}


def normalize_class(name: str) -> str:
    key = "_".join(str(name).strip().lower().replace("-", " ").replace("_", " ").split())
    return _ALIASES.get(key, key)


def load_class_table(path: Path | None) -> dict[str, tuple[float, float]]:
    """Class -> (mu, sigma): the built-in table, or a CSV ``class,mu,sigma``."""
    if path is None:
        return dict(EWEN2022_FRICTION)
    path = Path(path)
    table: dict[str, tuple[float, float]] = {}
    for n, row in read_csv(path, ("class", "mu"), ("sigma",)):
        where = f"line {n}"
        cls = normalize_class(to_str(row["class"], path, where, "class"))
        if cls in table:
            raise input_error(path, where, f"class {cls!r} listed twice", "Keep one row per class")
        sigma = to_float(row["sigma"], path, where, "sigma", positive=True) if row.get("sigma") else float("nan")
        table[cls] = (to_float(row["mu"], path, where, "mu", positive=True), sigma)
    if not table:
        raise input_error(path, None, "no classes", "Add rows class,mu,sigma")
    return table


def _labels(path: Path) -> list[tuple[str, str, str]]:
    """(image, class as written, where) from a labels file or a class-folder tree."""
    if path.is_dir():
        out = []
        for sub in sorted(p for p in path.iterdir() if p.is_dir()):
            for img in sorted(sub.rglob("*")):
                if img.suffix.lower() in _IMAGE_EXT:
                    out.append((img.relative_to(path).as_posix(), sub.name, f"folder {sub.name!r}"))
        if not out:
            raise input_error(path, None, "no images in class sub-folders",
                              "Use one sub-folder per terrain class holding .jpg/.png images, or pass a labels file")
        return out
    if path.suffix.lower() == ".csv":
        return [(to_str(r["image"], path, f"line {n}", "image"), to_str(r["class"], path, f"line {n}", "class"), f"line {n}")
                for n, r in read_csv(path, ("image", "class"))]
    data = load_json(path)
    if not isinstance(data, dict) or not data:
        raise input_error(path, None, "expected a JSON object {\"<image>\": \"<class>\"}", "Map each image to its class")
    return [(str(k), to_str(v, path, f"entry {k!r}", "class"), f"entry {k!r}") for k, v in data.items()]


def read_terrain_truth(path: Path, table: Mapping[str, tuple[float, float]] | None = None) -> list[Measurement]:
    """Per-image measurements (truth = class mean, group = class) from labels or class folders."""
    path = Path(path)
    table = dict(EWEN2022_FRICTION if table is None else table)
    if not path.exists():
        raise input_error(path, None, "not found", "Pass the labels file or the folder of class sub-folders")
    out = []
    for image, cls_raw, where in _labels(path):
        cls = normalize_class(cls_raw)
        if cls not in table:
            raise input_error(path, where, f"unknown terrain class {cls_raw!r}",
                              f"Use one of {', '.join(table)} (or give --terrain-table with your classes)")
        out.append(Measurement(item=image, prop="kinetic_friction", value=table[cls][0], group=cls,
                               source=f"{path}:{where}"))
    return out


def class_truth(table: Mapping[str, tuple[float, float]] | None = None) -> list[Measurement]:
    """One measurement per class (for per-class predictions)."""
    table = dict(EWEN2022_FRICTION if table is None else table)
    return [Measurement(item=c, prop="kinetic_friction", value=mu, group=c, source="terrain class table")
            for c, (mu, _) in table.items()]


def align_terrain_predictions(preds: Sequence[Prediction], items: Sequence[str]) -> list[Prediction]:
    """Match predictions by exact image path, else by unique file name / stem, else by class name spelling."""
    keys = set(items)
    by_name: dict[str, list[str]] = {}
    for k in items:
        for alias in {Path(k).name, Path(k).stem, normalize_class(k)}:
            by_name.setdefault(alias, []).append(k)
    out = []
    for p in preds:
        if p.item in keys:
            out.append(p)
            continue
        cands = by_name.get(Path(p.item).name) or by_name.get(Path(p.item).stem) or by_name.get(normalize_class(p.item)) or []
        out.append(replace(p, item=cands[0]) if len(set(cands)) == 1 else p)
    return out
