"""Mass report: ``report.json`` and a printed rich table (per material volume share, mass mean and interval)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ..mass import MassReport

__all__ = ["mass_table", "print_mass_table", "write_report"]


def _fmt(x: float) -> str:
    if x == 0:
        return "0"
    return f"{x:.4g}" if 1e-3 <= abs(x) < 1e5 else f"{x:.3e}"


def write_report(report: MassReport | None, path: Path, extra: dict[str, Any] | None = None) -> Path:
    """``report.json``: the mass report (kg, m^3, m^2, kg/m^3) plus ``extra`` (e.g. ground truth, files); a report
    of None writes ``"mass": null`` (``extra`` then says why, ``mass_error``)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = {"mass": report.to_dict() if report is not None else None, **(extra or {})}
    path.write_text(json.dumps(data, indent=2, default=float))
    return path


COARSE_LAYER_SHARE = 0.5
"""an object is coarse where one resolution unit of its solid parts' surface holds this share of its mass"""


def _layer_caption(geometry: dict[str, Any]) -> str:
    """The caption's line on how much of the mass one resolution unit of the solid parts' surface holds
    (integrate's ``surface_layer_share``), with what to do where that is coarse; "" without it."""
    share, unit = geometry.get("surface_layer_share"), geometry.get("resolution_unit_m")
    if share is None or unit is None:
        return ""
    line = (f"\none resolution unit ({unit * 1000:.3g} mm) of the solid parts' surface holds "
            f"{100 * share:.0f}% of the mass")
    if share < COARSE_LAYER_SHARE:
        return line
    footprint = geometry.get("pixel_footprint_voxels") or 1.0
    shape = (geometry.get("grid") or {}).get("shape")
    now = f" (now {max(shape)})" if shape else ""
    if footprint < 0.9:
        fix = f"a finer --mass.geometry.resolution{now}: the views resolve {footprint:.2g} voxel"
    else:
        fix = "more or closer views: the grid is already as fine as the views' pixels"
    moved = f"every face placed half a unit out moves its mass by up to ~{50 * share:.0f}%"
    return f"{line}: coarse for this object ({moved}); {fix}"


UNSEEN_SURFACE_SHARE = 0.05
"""the caption names the solid's unseen surface from this share of its faces on"""


def _unseen_caption(geometry: dict[str, Any]) -> str:
    """The caption's line on the share of the solid's surface that no view placed (the reconstruction's
    ``unseen_surface_share``: an underside, a cup's hidden inside); "" below ``UNSEEN_SURFACE_SHARE``."""
    share = geometry.get("unseen_surface_share")
    if share is None or share < UNSEEN_SURFACE_SHARE:
        return ""
    return (f"\n{100 * share:.0f}% of the solid's surface lies where no view saw past it (an underside, a "
            "hidden inside): the seen faces around it place it; views from those sides would")


def mass_table(report: MassReport, title: str | None = None, truth_kg: float | None = None):
    """A rich Table: one row per material present (volume share > 0.1% or mass share > 0.1%), then the total."""
    from rich.table import Table

    pct = int(round(report.level * 100))
    sim = " [SIMULATED VLM]" if report.simulated else ""
    table = Table(title=(title or "Mass estimate") + sim, caption=(
        f"{report.n_samples} Monte Carlo samples, seed {report.seed}; scale {report.metres_per_unit:.4g} m/unit "
        f"({report.scale_source})" + _layer_caption(report.geometry or {})
        + _unseen_caption(report.geometry or {})))  # fmt: skip
    for col, just in (("material", "left"), ("model", "left"), ("volume share", "right"),
                      ("density kg/m^3", "right"), ("mass mean kg", "right"), (f"{pct}% interval kg", "right")):
        table.add_column(col, justify=just)  # type: ignore[arg-type]
    for m in report.materials:
        if m.volume_share < 1e-3 and m.mass_share < 1e-3:
            continue
        model = m.volume_model if m.thickness_m is None else f"{m.volume_model} {m.thickness_m * 1000:.3g} mm"
        table.add_row(m.name, model, f"{100 * m.volume_share:.1f}%", _fmt(m.density_mean), _fmt(m.mass_mean_kg),
                      f"[{_fmt(m.mass_interval_kg[0])}, {_fmt(m.mass_interval_kg[1])}]")  # fmt: skip
    table.add_section()
    table.add_row("total", "", "100%", "", _fmt(report.mean_kg),
                  f"[{_fmt(report.interval_kg[0])}, {_fmt(report.interval_kg[1])}]", style="bold")  # fmt: skip
    if truth_kg is not None:
        table.add_row("ground truth", "", "", "", _fmt(truth_kg),
                      "covered" if report.covers(truth_kg) else "NOT covered", style="italic")  # fmt: skip
    return table


def print_mass_table(report: MassReport, title: str | None = None, truth_kg: float | None = None,
                     console: Any = None) -> None:  # fmt: skip
    from rich.console import Console

    (console or Console()).print(mass_table(report, title, truth_kg))
