"""The property-map sheet (export/sheet.py) against matplotlib's own colour mapping."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib import colormaps
from matplotlib.colors import LogNorm, Normalize

from physgs_nerfstudio.export.sheet import HEADER_H, PAD, TITLE_H, colorize, compose_sheet


@pytest.mark.parametrize("log", [False, True])
def test_colorize_matches_matplotlib(log: bool) -> None:
    rng = np.random.default_rng(0)
    v = np.exp(rng.normal(3, 2, size=(40, 30))) if log else rng.normal(0, 5, size=(40, 30))
    v[3, 4] = np.nan
    rgb, lo, hi, used = colorize(v, "viridis", log=log)
    finite = v[np.isfinite(v)]
    assert (lo, hi, used) == (finite.min(), finite.max(), log)
    norm = (LogNorm if log else Normalize)(vmin=lo, vmax=hi)
    want = colormaps["viridis"](norm(np.nan_to_num(v, nan=lo)))[..., :3] * 255
    diff = np.abs(rgb.astype(float) - want)
    diff[3, 4] = 0
    assert diff.max() <= 4.0  # one step of a 256-entry table
    assert (rgb[3, 4] == 255).all()  # blank is white


def test_colorize_constant_and_nonpositive_log() -> None:
    rgb, lo, hi, used = colorize(np.full((4, 4), 7.0), "magma", log=True)
    assert lo < 7.0 < hi and used
    _, lo, hi, used = colorize(np.array([[-1.0, 2.0]]), "viridis", log=True)
    assert not used and (lo, hi) == (-1.0, 2.0)


def test_sheet_places_each_panel_where_the_layout_says() -> None:
    h, w = 20, 30
    panels = [(f"p{i}", np.full((h, w, 3), 10 * i + 5, np.uint8), None if i < 2 else "viridis|0|1|0")
              for i in range(6)]  # fmt: skip
    sheet = compose_sheet(panels, header="view", legend=[("oak", (200, 100, 50))], ncol=4)
    cell_w = sheet.shape[1] // 4  # PAD + 4 cells
    for i in range(6):
        y = HEADER_H + (i // 4) * (h + TITLE_H + PAD) + TITLE_H
        x = PAD + (i % 4) * ((sheet.shape[1] - PAD) // 4)
        assert (sheet[y + 5 : y + h - 5, x + 5 : x + w - 5] == 10 * i + 5).all(), i
    assert cell_w > w
    assert ((sheet == (200, 100, 50)).all(-1)).any()  # the legend swatch beside the material panel
