"""Write and print an :class:`~.scorer.EvalResult`: JSON (everything), CSV (items, summary), rich tables."""

from __future__ import annotations

import csv
import json
import math
from dataclasses import asdict, fields
from pathlib import Path
from typing import Any

from .scorer import Aggregate, EvalResult, ItemScore

__all__ = ["SUMMARY_COLUMNS", "print_result", "write_result"]

SUMMARY_COLUMNS = ("ADE", "ALDE", "APE", "MnRE", "material_accuracy", "interval_coverage", "interval_level",
                   "coverage@0.5", "coverage@0.9", "nll", "crps", "crps_samples")


def _clean(x: Any) -> Any:
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_clean(v) for v in x]
    return x


def _summary_keys(aggs: list[Aggregate]) -> list[str]:
    present = {k for a in aggs for k in a.values}
    keys = [k for k in SUMMARY_COLUMNS if k in present]
    keys += sorted(k for k in present if k not in keys)
    return keys


def write_result(result: EvalResult, out_dir: Path) -> dict[str, Path]:
    """``eval.json``, ``items.csv``, ``summary.csv`` (and ``missing.csv`` when anything is missing)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {"json": out_dir / "eval.json", "items": out_dir / "items.csv", "summary": out_dir / "summary.csv"}
    paths["json"].write_text(json.dumps(_clean(result.to_dict()), indent=2) + "\n", encoding="utf-8")
    names = [f.name for f in fields(ItemScore)]
    with paths["items"].open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(names)
        for r in result.items:
            d = asdict(r)
            w.writerow(["" if d[n] is None else d[n] for n in names])
    keys = _summary_keys(result.aggregates)
    with paths["summary"].open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["method", "property", "group", "n_expected", "n_scored", "n_missing", *keys])
        for a in result.aggregates:
            w.writerow([a.method, a.prop, a.group, a.n_expected, a.n_scored, a.n_missing,
                        *["" if a.values.get(k) is None else a.values[k] for k in keys]])
    if result.missing or result.unmatched:
        paths["missing"] = out_dir / "missing.csv"
        with paths["missing"].open("w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(["kind", "method", "item", "property", "reason"])
            for m in result.missing:
                w.writerow(["missing", m.method, m.item, m.prop, m.reason])
            for m in result.unmatched:
                w.writerow(["unmatched_prediction", m.method, m.item, m.prop, m.reason])
    return paths


def _fmt(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.3f}" if abs(v) < 1e4 else f"{v:.3g}"
    return str(v)


ACCURACY_COLUMNS = ("ADE", "ALDE", "APE", "MnRE", "material_accuracy")
CALIBRATION_COLUMNS = ("interval_coverage", "interval_level", "coverage@0.5", "coverage@0.9", "nll", "crps", "crps_samples")
_HEADERS = {"material_accuracy": "mat.acc", "MnRE": "MnRE(up)", "interval_coverage": "in lo-hi",
            "interval_level": "nominal", "crps_samples": "CRPS(smp)", "nll": "NLL", "crps": "CRPS",
            "coverage@0.5": "cov@.5", "coverage@0.9": "cov@.9"}


def print_result(result: EvalResult, per_group: bool = False, console: Any = None, max_listed: int = 10) -> None:
    """Two rich tables (accuracy, calibration) plus the lists of missing items and unmatched predictions."""
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    console = console or Console()
    aggs = [a for a in result.aggregates if per_group or a.group == "all"]
    present = {k for a in aggs for k in a.values}
    extra_cal = sorted(k for k in present if k.startswith("coverage@") and k not in CALIBRATION_COLUMNS)
    dataset = result.protocol.get("dataset")
    for title, cols in (("accuracy", ACCURACY_COLUMNS), ("calibration", CALIBRATION_COLUMNS + tuple(extra_cal))):
        keys = [k for k in cols if k in present]
        if not keys:
            continue
        table = Table(title=f"physgs eval{' ' + dataset if dataset else ''}: {title}")
        for col in ("method", "property", "group", "scored"):
            table.add_column(col, overflow="fold")
        for k in keys:
            table.add_column(_HEADERS.get(k, k), justify="right")
        for a in aggs:
            if any(k in a.values for k in keys) or title == "accuracy":
                table.add_row(escape(a.method), escape(a.prop), escape(a.group), f"{a.n_scored}/{a.n_expected}",
                              *[_fmt(a.values.get(k)) for k in keys])
        console.print(table)
    if result.missing:
        console.print(f"[yellow]{len(result.missing)} ground-truth entries without a usable prediction "
                      f"(not scored; listed in missing.csv):[/yellow]")
        for m in result.missing[:max_listed]:
            console.print(escape(f"  {m.method}: {m.item} [{m.prop}] -- {m.reason}"))
        if len(result.missing) > max_listed:
            console.print(f"  ... and {len(result.missing) - max_listed} more")
    if result.unmatched:
        console.print(f"[yellow]{len(result.unmatched)} predictions without ground truth (not scored):[/yellow]")
        for m in result.unmatched[:max_listed]:
            console.print(escape(f"  {m.method}: {m.item} [{m.prop}]"))
        if len(result.unmatched) > max_listed:
            console.print(f"  ... and {len(result.unmatched) - max_listed} more")
