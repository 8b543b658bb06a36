"""One view's property maps as one image sheet (PNG), composed with numpy and Pillow.

A matplotlib figure per view (subplots, colour bars, tight layout, savefig) cost about 1.2 s of CPU a view, more
than rendering the maps on a GPU; this composes the same panels directly: each map colour-mapped through a
256-entry lookup table of a matplotlib colormap (viridis for values, magma for standard deviations, log-scaled for
density and Young's modulus), a title above it, a colour bar with its range beside it, the material panel with
its legend (the materials present in the view). Blank pixels (NaN, no material) are white.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache

import numpy as np
from PIL import Image, ImageDraw, ImageFont

__all__ = ["colorize", "compose_sheet"]

PAD = 8
TITLE_H = 18
BAR_W = 12
SIDE_W = 96
"""room right of each panel: the colour bar and its labels, or the material legend"""
HEADER_H = 24
WHITE = 255


@lru_cache(maxsize=4)
def _lut(name: str) -> np.ndarray:
    from matplotlib import colormaps

    return (colormaps[name](np.linspace(0.0, 1.0, 256))[:, :3] * 255).round().astype(np.uint8)


@lru_cache(maxsize=1)
def _font() -> ImageFont.ImageFont:
    try:
        return ImageFont.load_default(size=11)
    except TypeError:  # Pillow < 10.1: the bitmap font
        return ImageFont.load_default()


def colorize(v: np.ndarray, cmap: str, *, log: bool = False) -> tuple[np.ndarray, float, float, bool]:
    """``v`` [H, W] (NaN = blank) -> (RGB uint8 [H, W, 3], low, high, log used). A constant map gets a range
    around its value; ``log`` applies only when every finite value is > 0."""
    finite = v[np.isfinite(v)]
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    if hi - lo <= 1e-6 * max(abs(hi), 1e-12):
        lo, hi = (lo * 0.99, hi * 1.01) if lo > 0 else (lo - 1.0, hi + 1.0)
    log = log and lo > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (np.log(v) - np.log(lo)) / (np.log(hi) - np.log(lo)) if log else (v - lo) / (hi - lo)
    idx = np.clip(np.nan_to_num(t, nan=0.0) * 255.0, 0, 255).astype(np.int64)
    rgb = _lut(cmap)[idx]
    rgb[~np.isfinite(v)] = WHITE
    return rgb, lo, hi, log


def _bar(cmap: str, height: int) -> np.ndarray:
    ramp = np.linspace(255, 0, max(height, 2)).round().astype(np.int64)
    return np.repeat(_lut(cmap)[ramp][:, None, :], BAR_W, axis=1)


def compose_sheet(
    panels: Sequence[tuple[str, np.ndarray, str | None]],
    *,
    header: str,
    legend: Sequence[tuple[str, tuple[int, int, int]]] = (),
    ncol: int = 4,
) -> np.ndarray:
    """The sheet: ``panels`` of (title, image, colour-bar spec) laid out ``ncol`` to a row under ``header``.
    An image is RGB uint8 [H, W, 3] (all the same size); a spec ``"cmap|low|high|log"`` draws a colour bar with
    its range, None draws ``legend`` ((name, RGB) of the materials) beside the first panel without a bar that is
    not the first panel (the material panel)."""
    h, w = panels[0][1].shape[:2]
    cell_w, cell_h = w + SIDE_W + PAD, h + TITLE_H + PAD
    nrow = -(-len(panels) // ncol)
    sheet = np.full((HEADER_H + nrow * cell_h + PAD, PAD + ncol * cell_w, 3), WHITE, np.uint8)
    spots = []
    for i, (_, img, _) in enumerate(panels):
        y, x = HEADER_H + (i // ncol) * cell_h + TITLE_H, PAD + (i % ncol) * cell_w
        sheet[y : y + h, x : x + w] = img
        spots.append((x, y))
    for (_, _, spec), (x, y) in zip(panels, spots):
        if spec:
            sheet[y : y + h, x + w + 4 : x + w + 4 + BAR_W] = _bar(spec.split("|")[0], h)
    im = Image.fromarray(sheet)
    draw = ImageDraw.Draw(im)
    font = _font()
    draw.text((PAD, 4), header, fill=(0, 0, 0), font=font)
    legend_done = False
    for i, ((title, _, spec), (x, y)) in enumerate(zip(panels, spots)):
        draw.text((x, y - TITLE_H + 3), title, fill=(0, 0, 0), font=font)
        if spec:
            _, lo, hi, log = spec.split("|")
            tx = x + w + 6 + BAR_W
            draw.text((tx, y), f"{float(hi):.3g}", fill=(0, 0, 0), font=font)
            draw.text((tx, y + h - 12), f"{float(lo):.3g}", fill=(0, 0, 0), font=font)
            if log == "1":
                draw.text((tx, y + h // 2 - 6), "log", fill=(90, 90, 90), font=font)
        elif i > 0 and not legend_done:
            legend_done = True
            for j, (name, rgb) in enumerate(legend[: max(h // 14, 1)]):
                ly = y + 14 * j
                draw.rectangle((x + w + 4, ly + 2, x + w + 14, ly + 12), fill=tuple(int(c) for c in rgb))
                draw.text((x + w + 18, ly), name[:12], fill=(0, 0, 0), font=font)
    return np.asarray(im)
