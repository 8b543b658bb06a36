"""Our predictions: the mass of ``physgs export``'s ``report.json``, one file per scene.

Read from ``report.json`` (``export/report.py``: ``{"mass": MassReport.to_dict(), ...}``)::

    {"mass": {"mean_kg": 1.93, "interval_kg": [1.41, 2.57], "level": 0.9,   # kg; 90 % interval
              "simulated": false, ...},                                    # other keys are ignored
     "scene": "B07B4MNDQB_0"}                      # optional; else the scene folder's name

Also accepted: ``mean``/``estimate`` for the mean, ``low``/``high`` for the bounds, ``interval_level``/
``confidence`` for the level (a fraction, or a percentage > 1), ``std`` (kg), ``samples`` (Monte Carlo
draws, kg), ``unit`` (default kg), a bare number ``"mass": 1.93`` or top-level ``"mass_kg"``.

A results directory holds one report per scene: ``<results>/<scene>/report.json`` (or deeper, e.g.
``<results>/<scene>/export/report.json``); the scene is the first folder under ``<results>``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import input_error
from ..fileio import load_json, opt_float, to_float
from ..records import Prediction
from ..units import unit_factor

__all__ = ["find_reports", "is_mass_report", "read_mass_report", "read_results_dir"]


def is_mass_report(data: Any) -> bool:
    return isinstance(data, dict) and ("mass" in data or "mass_kg" in data)


def _first(d: dict, *keys: str) -> Any:
    return next((d[k] for k in keys if k in d), None)


def read_mass_report(path: Path, scene: str | None = None, method: str = "physgs") -> Prediction:
    """The mass prediction of one report.json (scene: ``report["scene"]``, else ``scene``, else the folder)."""
    path = Path(path)
    data = load_json(path)
    if not is_mass_report(data):
        raise input_error(path, None, "no 'mass' entry", "Pass the report.json written by `physgs export`")
    name = data.get("scene") if isinstance(data.get("scene"), str) else None
    name = scene or name or path.parent.name
    where = "entry 'mass'"
    mass = data.get("mass", data.get("mass_kg"))
    if not isinstance(mass, dict):
        mean = to_float(mass, path, where, "mass", positive=True)
        return Prediction(item=name, prop="mass", mean=mean, method=method, unit="kg", source=str(path))
    unit = mass.get("unit", "kg")
    factor = unit_factor("mass", unit)
    if factor is None:
        raise input_error(path, f"{where}.unit", f"unknown mass unit {unit!r}", "Use kg, g, lb or oz")
    mean = to_float(_first(mass, "mean", "mean_kg", "estimate"), path, f"{where}.mean", "mass mean", positive=True)
    low = opt_float(_first(mass, "low", "low_kg"), path, f"{where}.low", "interval low")
    high = opt_float(_first(mass, "high", "high_kg"), path, f"{where}.high", "interval high")
    interval = _first(mass, "interval", "interval_kg")
    if interval is not None:
        if not isinstance(interval, (list, tuple)) or len(interval) != 2:
            raise input_error(path, f"{where}.interval", f"expected [low, high], got {interval!r}",
                              "Write the interval as a two-number list")
        low = to_float(interval[0], path, f"{where}.interval[0]", "interval low")
        high = to_float(interval[1], path, f"{where}.interval[1]", "interval high")
    if (low is None) != (high is None):
        raise input_error(path, where, "only one interval bound given", "Give both low and high, or neither")
    if low is not None and high is not None and low > high:
        raise input_error(path, where, f"interval low {low:g} > high {high:g}", "Swap or fix the bounds")
    level = opt_float(_first(mass, "level", "interval_level", "confidence"), path, f"{where}.level", "interval level")
    if level is not None and level > 1:
        level /= 100.0
    if level is not None and not 0 < level < 1:
        raise input_error(path, f"{where}.level", f"interval level {level:g} outside (0, 1)", "Write e.g. 0.9 for 90 %")
    std = opt_float(mass.get("std"), path, f"{where}.std", "mass std", positive=True)
    notes: tuple[str, ...] = ("simulated VLM",) if mass.get("simulated") is True else ()
    samples = mass.get("samples")
    if samples is not None:
        if not isinstance(samples, list) or not samples:
            raise input_error(path, f"{where}.samples", "expected a non-empty list of numbers", "Fix or drop 'samples'")
        samples = tuple(to_float(s, path, f"{where}.samples[{i}]", "sample") * factor for i, s in enumerate(samples))
    scale = lambda v: None if v is None else v * factor
    return Prediction(item=name, prop="mass", mean=mean * factor, method=method, low=scale(low), high=scale(high),
                      level=level, std=scale(std), samples=samples, unit="kg", source=str(path), notes=notes)


def find_reports(results: Path) -> dict[str, Path]:
    """Scene name -> report.json under a results directory (one per scene; duplicates are an error)."""
    results = Path(results)
    if not results.is_dir():
        raise input_error(results, None, "not a directory", "Pass the folder holding one sub-folder per scene")
    found: dict[str, Path] = {}
    if (results / "report.json").is_file():
        found[results.name] = results / "report.json"
    for sub in sorted(p for p in results.iterdir() if p.is_dir()):
        reports = sorted(sub.rglob("report.json"))
        if len(reports) > 1:
            raise input_error(sub, None, f"{len(reports)} report.json files ({', '.join(str(r.relative_to(sub)) for r in reports)})",
                              "Keep one export per scene folder, or pass the export folder you mean")
        if reports:
            found[sub.name] = reports[0]
    return found


def read_results_dir(results: Path, method: str = "physgs") -> list[Prediction]:
    """Mass predictions of every scene under ``results`` (scene = sub-folder name)."""
    reports = find_reports(results)
    if not reports:
        raise input_error(results, None, "no report.json found",
                          "Run `physgs export` per scene into <results>/<scene>/ first")
    root = Path(results) / "report.json"
    return [read_mass_report(path, scene=None if path == root else scene, method=method)
            for scene, path in reports.items()]
