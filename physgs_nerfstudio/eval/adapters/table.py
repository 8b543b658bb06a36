"""Plain tables for your own measurements and predictions (CSV or JSON).

Ground truth -- CSV with a header (``#`` comment lines and blank lines are skipped)::

    item,property,value,unit,scale,group
    mug_01,mass,0.352,kg,,kitchen
    mug_01,shore_hardness,82,,D,kitchen
    shoe_sole,kinetic_friction,0.61,,,
    mug_01,material,ceramic,,,

``item``, ``property``, ``value`` and ``unit`` are required columns (``unit`` may be blank for
dimensionless quantities); ``scale`` (Shore ``A``, ``D`` or ``00``) is required for ``shore_hardness``
(``unit`` may say ``Shore D`` instead); ``group`` is optional (per-group tables). For ``material`` the
value is the material name (scored as accuracy; aliases of the material library match).

Predictions -- CSV::

    item,property,mean,low,high,level,std,unit,scale,method
    mug_01,mass,0.40,0.31,0.52,0.9,,kg,,physgs
    mug_01,shore_hardness,120,,,,6,,A_eq,physgs

``item``, ``property``, ``mean`` are required; optional ``low``/``high`` (an interval; ``level`` its nominal
coverage, e.g. ``0.9``, when known), ``std`` (Gaussian standard deviation), ``unit`` (blank = the
property's canonical unit), ``scale`` (for hardness: ``A``, ``D``, ``00`` or ``A_eq``, the canonical scale
of our exports; blank = the measurement's scale), ``method`` (default: the name given on the command line),
``material`` (predicted material name, when ``property`` is numeric).

JSON: a list of objects with the same keys (or ``{"measurements": [...]}`` / ``{"predictions": [...]}``);
JSON predictions may also carry a Gaussian mixture ``"mixture": {"weights": [...], "means": [...],
"stds": [...]}`` or Monte Carlo ``"samples": [...]`` (same unit as ``mean``).

Properties: ``mass`` (kg, g, lb, oz), ``density`` (kg/m^3, g/cm^3), ``kinetic_friction``, ``shore_hardness``,
``youngs_modulus`` (Pa, kPa, MPa, GPa, psi), ``bending_stiffness`` (lbf*in^2, N*m^2), ``material``, and
common spellings (``friction``, ``hardness``, ``stiffness``); any other name is compared as written, in the
unit written (ground truth and predictions must then use the same unit).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import input_error
from ..fileio import load_json, opt_float, read_csv, to_float, to_str
from ..records import Measurement, Mixture, Prediction
from ..units import CANONICAL_UNITS, canonical_property, normalize_unit, unit_factor

__all__ = ["GT_COLUMNS", "PRED_COLUMNS", "read_prediction_table", "read_truth_table"]

GT_COLUMNS = (("item", "property", "value", "unit"), ("scale", "group"))
PRED_COLUMNS = (("item", "property", "mean"), ("low", "high", "level", "std", "unit", "scale", "method", "material"))
_JSON_ONLY = ("mixture", "samples")
_SHORE_UNITS = {"shorea": "A", "shored": "D", "shore00": "00", "shoreoo": "00"}


def _records(path: Path, key: str, columns: tuple[tuple[str, ...], tuple[str, ...]],
             json_only: tuple[str, ...] = ()) -> list[tuple[str, dict[str, Any]]]:
    """(where, record) pairs from a CSV or JSON table."""
    required, optional = columns
    if path.suffix.lower() == ".csv":
        return [(f"line {n}", row) for n, row in read_csv(path, required, optional)]
    data = load_json(path)
    if isinstance(data, dict) and key in data:
        data = data[key]
    if not isinstance(data, list):
        raise input_error(path, None, f"expected a JSON list of records (or {{\"{key}\": [...]}})",
                          f"Write one object per row with keys {', '.join(required)}")
    out = []
    allowed = set(required) | set(optional) | set(json_only)
    for i, rec in enumerate(data):
        where = f"entry {i}"
        if not isinstance(rec, dict):
            raise input_error(path, where, f"expected an object, got {type(rec).__name__}", "Write each row as an object")
        rec = {str(k).lower(): v for k, v in rec.items()}
        miss = [c for c in required if c not in rec]
        if miss:
            raise input_error(path, where, f"missing key(s) {', '.join(miss)}", f"Each row needs {', '.join(required)}")
        unknown = [c for c in rec if c not in allowed]
        if unknown:
            raise input_error(path, where, f"unknown key(s) {', '.join(unknown)}", f"Allowed keys: {', '.join(sorted(allowed))}")
        out.append((where, rec))
    return out


def _prop(raw: Any, path: Path, where: str) -> str:
    text = to_str(raw, path, where, "property")
    return canonical_property(text) or text


def _scale(raw: Any, unit: str, path: Path, where: str, allow_canonical: bool) -> str | None:
    from ...materials.hardness import normalize_scale

    text = "" if raw is None else str(raw).strip()
    if not text:
        return _SHORE_UNITS.get(normalize_unit(unit))
    if allow_canonical and text.lower() in ("a_eq", "aeq", "canonical"):
        return "A_eq"
    try:
        return normalize_scale(text)
    except ValueError as err:
        raise input_error(path, where, str(err).rstrip("."), "Write A, D or 00" + (" (or A_eq)" if allow_canonical else "")) from None


def _factor(prop: str, unit: str, path: Path, where: str) -> float:
    if prop not in CANONICAL_UNITS:
        return 1.0
    f = unit_factor(prop, unit)
    if f is None:
        raise input_error(path, where, f"unit {unit!r} is not a known unit of {prop}",
                          f"Use the canonical unit {CANONICAL_UNITS[prop] or '(blank: dimensionless)'} or a listed alternative")
    return f


def _mixture(raw: Any, path: Path, where: str) -> Mixture | None:
    if raw is None:
        return None
    w = f"{where}, mixture"
    if not isinstance(raw, dict) or not all(isinstance(raw.get(k), list) for k in ("weights", "means", "stds")):
        raise input_error(path, w, "expected {\"weights\": [...], \"means\": [...], \"stds\": [...]}",
                          "Give the Gaussian components as three equally long lists")
    n = len(raw["means"])
    if n == 0 or len(raw["weights"]) != n or len(raw["stds"]) != n:
        raise input_error(path, w, "weights, means and stds must be non-empty and equally long", "Fix the lists")
    weights = [to_float(x, path, f"{w}.weights[{i}]", "weight") for i, x in enumerate(raw["weights"])]
    if any(x < 0 for x in weights) or sum(weights) <= 0:
        raise input_error(path, w, "weights must be >= 0 with a positive sum", "Fix the weights")
    total = sum(weights)
    return Mixture(tuple(x / total for x in weights),
                   tuple(to_float(x, path, f"{w}.means[{i}]", "mean") for i, x in enumerate(raw["means"])),
                   tuple(to_float(x, path, f"{w}.stds[{i}]", "std", positive=True) for i, x in enumerate(raw["stds"])))


def read_truth_table(path: Path) -> list[Measurement]:
    """Ground truth from a CSV/JSON table (see the module docstring)."""
    path = Path(path)
    out = []
    for where, rec in _records(path, "measurements", GT_COLUMNS):
        item = to_str(rec.get("item"), path, where, "item")
        prop = _prop(rec.get("property"), path, where)
        unit = "" if rec.get("unit") is None else str(rec.get("unit")).strip()
        group = str(rec["group"]).strip() if rec.get("group") not in (None, "") else None
        src = f"{path}:{where}"
        if prop == "material":
            label = to_str(rec.get("value"), path, where, "value (material name)")
            out.append(Measurement(item, prop, None, "", label=label, group=group, source=src))
            continue
        scale = _scale(rec.get("scale"), unit, path, where, allow_canonical=False) if prop == "shore_hardness" else None
        if prop == "shore_hardness" and scale is None:
            raise input_error(path, where, "shore_hardness without a scale",
                              "Fill the scale column with A, D or 00 (the durometer the reading was taken with)")
        value = to_float(rec.get("value"), path, where, "value") * _factor(prop, unit, path, where)
        out.append(Measurement(item, prop, value, CANONICAL_UNITS.get(prop, unit), scale=scale, group=group, source=src))
    if not out:
        raise input_error(path, None, "no rows", "Add one row per measurement")
    return out


def read_prediction_table(path: Path, method: str = "physgs") -> list[Prediction]:
    """Predictions from a CSV/JSON table (see the module docstring)."""
    path = Path(path)
    out = []
    for where, rec in _records(path, "predictions", PRED_COLUMNS, _JSON_ONLY):
        item = to_str(rec.get("item"), path, where, "item")
        prop = _prop(rec.get("property"), path, where)
        meth = str(rec.get("method") or "").strip() or method
        src = f"{path}:{where}"
        if prop == "material":
            label = to_str(rec.get("mean"), path, where, "mean (material name)")
            out.append(Prediction(item, prop, None, method=meth, label=label, source=src))
            continue
        unit = "" if rec.get("unit") is None else str(rec.get("unit")).strip()
        f = _factor(prop, unit, path, where)
        mean = to_float(rec.get("mean"), path, where, "mean")
        low = opt_float(rec.get("low"), path, where, "low")
        high = opt_float(rec.get("high"), path, where, "high")
        if (low is None) != (high is None):
            raise input_error(path, where, "only one of low/high given", "Give both interval bounds or neither")
        if low is not None and high is not None and low > high:
            raise input_error(path, where, f"low {low:g} > high {high:g}", "Swap or fix the bounds")
        level = opt_float(rec.get("level"), path, where, "level")
        if level is not None and level > 1:
            level /= 100.0
        if level is not None and not 0 < level < 1:
            raise input_error(path, where, f"level {level:g} outside (0, 1)", "Write the interval's coverage, e.g. 0.9")
        std = opt_float(rec.get("std"), path, where, "std", positive=True)
        scale = _scale(rec.get("scale"), unit, path, where, allow_canonical=True) if prop == "shore_hardness" else None
        label = str(rec.get("material") or "").strip() or None
        low, high, std = (None if v is None else v * f for v in (low, high, std))
        mixture = _mixture(rec.get("mixture"), path, where)
        samples = rec.get("samples")
        if samples is not None:
            if not isinstance(samples, list) or not samples:
                raise input_error(path, f"{where}, samples", "expected a non-empty list of numbers", "Fix or drop it")
            samples = tuple(to_float(x, path, f"{where}, samples[{i}]", "sample") * f for i, x in enumerate(samples))
        out.append(Prediction(item, prop, mean * f, method=meth, low=low, high=high, level=level, std=std,
                              mixture=None if mixture is None else mixture.scaled(f), samples=samples,
                              unit=CANONICAL_UNITS.get(prop, unit), scale=scale, label=label, source=src))
    if not out:
        raise input_error(path, None, "no rows", "Add one row per prediction")
    return out
