"""Figures of single-image mode (matplotlib, Agg): one PNG per map with a colour bar or legend, and an
overview panel like the paper's outdoor figure: RGB | material | friction | Young's modulus | total
uncertainty.

Uncertainty figures show standard deviations (square roots of the variances stored in maps.npz) in the
property's unit, so that the colour bar reads like the mean's. Properties fused in log space (density,
Young's modulus by default) span decades: their means use a logarithmic colour scale and their
uncertainties are shown in decades (the standard deviation of log10(value), maps.npz's ``<key>_log10_*``),
because an absolute deviation in Pa is dominated by the stiffest materials and would make a stiff,
well-known part look less certain than an unknown region. A thin white line marks the border of the covered pixels
(outside it, the prior).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .maps import LABELS, ImageMaps

CMAPS = {"density": "cividis", "kinetic_friction": "viridis", "shore_hardness": "magma", "youngs_modulus": "plasma"}
UNCERTAINTY_CMAP = "inferno"
STAT_TITLES = {"mean": "mean", "aleatoric": "aleatoric std", "epistemic": "epistemic std", "total": "total std"}


def _figure(width_in: float, height_in: float):
    """A matplotlib Figure on an Agg canvas (no pyplot state: safe to use from any thread)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in))
    FigureCanvasAgg(fig)
    return fig


def in_decades(maps: ImageMaps, key: str, stat: str) -> bool:
    """Is this uncertainty shown in decades (a log-space property's variance)?"""
    return stat != "mean" and f"log10_{stat}" in maps.fields[key]


def display_values(maps: ImageMaps, key: str, stat: str) -> np.ndarray:
    """The mean; the standard deviation for a variance (of log10(value) for a log-space property)."""
    if stat == "mean":
        return maps.fields[key]["mean"].astype(np.float64)
    arr = maps.fields[key][f"log10_{stat}" if in_decades(maps, key, stat) else stat].astype(np.float64)
    return np.sqrt(np.clip(arr, 0, None))


def _norm(values: np.ndarray, log: bool):
    from matplotlib.colors import LogNorm, Normalize

    v = values[np.isfinite(values)]
    if log:
        v = v[v > 0]
    if v.size == 0:
        return Normalize(0, 1)
    lo, hi = float(v.min()), float(v.max())
    if log:
        if hi <= lo * (1 + 1e-6):
            lo, hi = lo / 1.5, hi * 1.5
        return LogNorm(lo, hi)
    if hi - lo <= 1e-12 * max(1.0, abs(hi)):
        pad = 0.05 * max(abs(hi), 1e-3)
        lo, hi = lo - pad, hi + pad
    return Normalize(lo, hi)


def material_rgb(maps: ImageMaps) -> np.ndarray:
    return maps.colors[maps.material]


def _unit_label(maps: ImageMaps, key: str) -> str:
    u = maps.units[key]
    return "" if u == "1" else f" [{u}]"


def _covered_outline(ax, maps: ImageMaps) -> None:
    if maps.covered.any() and not maps.covered.all():
        ax.contour(maps.covered.astype(np.float32), levels=[0.5], colors="white", linewidths=0.6)


def _draw_property(ax, cax, fig, maps: ImageMaps, key: str, stat: str, orientation: str = "vertical"):
    vals = display_values(maps, key, stat)
    log = maps.log_space.get(key, False) and stat == "mean"
    cmap = CMAPS.get(key, "viridis") if stat == "mean" else UNCERTAINTY_CMAP
    im = ax.imshow(vals, cmap=cmap, norm=_norm(vals, log), interpolation="antialiased", aspect="auto")
    _covered_outline(ax, maps)
    ax.set_axis_off()
    cb = fig.colorbar(im, cax=cax, orientation=orientation)
    if log:  # ticks at 1, 2, 5 x 10^k when the range spans few decades; minor-tick labels would overlap
        from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

        if im.norm.vmax / im.norm.vmin < 100:
            cb.locator = LogLocator(subs=(1.0, 2.0, 5.0))
            cb.formatter = FuncFormatter(_sci_label)
        (cb.ax.xaxis if orientation == "horizontal" else cb.ax.yaxis).set_minor_formatter(NullFormatter())
        cb.update_ticks()
    if in_decades(maps, key, stat):
        cb.set_label(f"{LABELS[key]} {STAT_TITLES[stat]} [decades]", fontsize=8)
    else:
        cb.set_label(f"{LABELS[key]} {STAT_TITLES[stat]}{_unit_label(maps, key)}", fontsize=8)
    cb.ax.tick_params(labelsize=7)
    return im


def _sci_label(value: float, _pos=None) -> str:
    """1, 2, 5 x 10^k tick labels in mathtext (10^k alone for the decades)."""
    if not (value > 0 and np.isfinite(value)):
        return ""
    e = int(np.floor(np.log10(value) + 1e-9))
    m = value / 10.0**e
    if -2 <= e <= 3:
        return f"{value:g}"
    return f"$10^{{{e}}}$" if abs(m - 1) < 1e-6 else f"${m:.0f}\\times10^{{{e}}}$"


def _legend_handles(maps: ImageMaps, with_unknown: bool = True):
    from matplotlib.patches import Patch

    total = maps.material.size
    counts = np.bincount(maps.material.reshape(-1), minlength=len(maps.names) + 1)
    handles = []
    for i, name in enumerate(maps.names):
        if counts[i + 1] == 0:
            continue
        handles.append(Patch(color=maps.colors[i + 1] / 255.0, label=f"{name} ({_pct(counts[i + 1], total)})"))
    if with_unknown and counts[0] > 0:
        handles.append(Patch(color=maps.colors[0] / 255.0, label=f"unknown ({_pct(counts[0], total)})"))
    return handles


def _pct(n: int, total: int) -> str:
    f = 100.0 * n / max(total, 1)
    return f"{f:.0f}%" if f >= 10 or f == 0 else f"{f:.1f}%"


# Layout in inches: fixed margins around images of a fixed width (manual placement: no tight-bbox pass).
_IMG_W = 3.6
_MARGIN = 0.1
_TITLE = 0.4


def _single_layout(maps: ImageMaps, right_in: float):
    """Figure with an image axes of width _IMG_W and ``right_in`` inches to its right."""
    h, w = maps.shape
    img_h = _IMG_W * h / max(w, 1)
    fw, fh = _MARGIN + _IMG_W + right_in, _MARGIN + img_h + _TITLE
    fig = _figure(fw, fh)
    ax = fig.add_axes((_MARGIN / fw, _MARGIN / fh, _IMG_W / fw, img_h / fh))
    return fig, ax, fw, fh, img_h


def save_material_figure(maps: ImageMaps, path: Path, title: str = "", dpi: int = 150) -> Path:
    fig, ax, *_ = _single_layout(maps, right_in=2.4)
    ax.imshow(material_rgb(maps), interpolation="nearest", aspect="auto")
    ax.set_axis_off()
    ax.set_title(title or "material", fontsize=10)
    handles = _legend_handles(maps)
    if handles:
        ax.legend(handles=handles, loc="center left", bbox_to_anchor=(1.03, 0.5), fontsize=8, frameon=False)
    return _save(fig, path, dpi)


def save_property_figure(maps: ImageMaps, key: str, stat: str, path: Path, title: str = "", dpi: int = 150) -> Path:
    fig, ax, fw, fh, img_h = _single_layout(maps, right_in=1.35)
    cax = fig.add_axes(((_MARGIN + _IMG_W + 0.15) / fw, (_MARGIN + 0.1 * img_h) / fh, 0.15 / fw, 0.8 * img_h / fh))
    _draw_property(ax, cax, fig, maps, key, stat)
    rel = " (log10, decades)" if in_decades(maps, key, stat) else ""
    ax.set_title(title or f"{LABELS[key]}: {STAT_TITLES[stat]}{rel}", fontsize=10)
    return _save(fig, path, dpi)


def save_overview(
    maps: ImageMaps,
    rgb: np.ndarray,
    path: Path,
    properties: Sequence[str] = ("kinetic_friction", "youngs_modulus"),
    uncertainty_property: str = "kinetic_friction",
    title: str = "",
    dpi: int = 150,
) -> Path:
    """RGB | material | <properties> means | total uncertainty (std) of ``uncertainty_property``, with the
    colour bars and the material legend below the panels."""
    props = [k for k in properties if k in maps.fields]
    panels: list[tuple[str, str | None]] = [("rgb", None), ("material", None)] + [("mean", k) for k in props]
    if uncertainty_property in maps.fields:
        panels.append(("total", uncertainty_property))
    h, w = maps.shape
    pw, gap, bottom = 3.0, 0.15, 1.0
    ph = pw * h / max(w, 1)
    top = _TITLE + (0.3 if title else 0.0)
    fw = gap + len(panels) * (pw + gap)
    fh = bottom + ph + top
    fig = _figure(fw, fh)
    for i, (kind, key) in enumerate(panels):
        x0 = gap + i * (pw + gap)
        ax = fig.add_axes((x0 / fw, bottom / fh, pw / fw, ph / fh))
        if kind == "rgb":
            ax.imshow(rgb, interpolation="antialiased", aspect="auto")
            ax.set_axis_off()
            ax.set_title("RGB", fontsize=9)
        elif kind == "material":
            ax.imshow(material_rgb(maps), interpolation="nearest", aspect="auto")
            ax.set_axis_off()
            ax.set_title("material", fontsize=9)
            handles = _legend_handles(maps)
            if handles:
                ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.02), fontsize=6, frameon=False,
                          ncol=2 if len(handles) > 3 else 1)
        else:
            assert key is not None
            cax = fig.add_axes(((x0 + 0.1 * pw) / fw, 0.55 / fh, 0.8 * pw / fw, 0.12 / fh))
            _draw_property(ax, cax, fig, maps, key, kind, orientation="horizontal")
            ax.set_title(LABELS[key] if kind == "mean" else f"total uncertainty ({LABELS[key]})", fontsize=9)
    if title:
        fig.suptitle(title, fontsize=10, y=1 - 0.12 / fh, va="top")
    return _save(fig, path, dpi)


def _save(fig, path: Path, dpi: int) -> Path:
    import os

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp.png")
    fig.savefig(tmp, dpi=dpi, format="png")
    os.replace(tmp, path)
    return path


def save_all(
    maps: ImageMaps,
    rgb: np.ndarray,
    out_dir: Path,
    *,
    overview_properties: Sequence[str],
    uncertainty_property: str,
    stats: Sequence[str] = ("mean", "aleatoric", "epistemic", "total"),
    title: str = "",
    dpi: int = 150,
) -> dict[str, str]:
    """Every figure of one image; returns {figure name: file name relative to out_dir}."""
    out_dir = Path(out_dir)
    files = {"material": "material.png"}
    save_material_figure(maps, out_dir / files["material"], title=f"{title}: material" if title else "", dpi=dpi)
    for key in maps.properties:
        for s in stats:
            name = f"{key}_{s}"
            files[name] = f"{name}.png"
            save_property_figure(maps, key, s, out_dir / files[name], dpi=dpi)
    files["overview"] = "overview.png"
    save_overview(maps, rgb, out_dir / files["overview"], overview_properties, uncertainty_property, title=title, dpi=dpi)
    return files
