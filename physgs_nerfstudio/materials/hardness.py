"""Shore hardness scales and the canonical internal hardness scale.

Canonical scale: **Shore A-equivalent** (``A_eq``), a continuous number that

* equals the Shore A reading wherever the A scale is defined (A 0 .. A 100),
* extends *above* 100 through the Shore D scale: from D 58 (taken as equal to A 100) upward, every Shore D
  point adds one canonical point, so ``A_eq = 42 + D`` for D >= 58 (D 100 -> A_eq 142),
* extends *below* 0 through the Shore 00 scale (the softest foams and gels), linearly continuing the
  00-to-A correlation (00 0 -> A_eq -17.5).

Readings on each scale map to ``A_eq`` through a piecewise-linear interpolation of a published durometer
comparison chart (the side-by-side A/D/00 charts distributed by durometer makers from ASTM D2240 readings,
e.g. the Rex Gauge chart, reproduced on eng-tips.com thread 50796): every table is strictly increasing, so
each conversion is monotone and invertible over the whole real line (linear extrapolation beyond the
tables, with positive slopes: no flat regions). Values outside a scale's 0..100 reading range are
well defined but mean "off this scale" (e.g. ``from_canonical(130, "A") == 130``).

These correlations are approximate (charts from different makers differ by several points, and the scales
use different indenters), which is why evaluation converts predictions back into the scale of each
measurement rather than comparing in ``A_eq``.

Works on floats, numpy arrays and torch tensors (torch stays differentiable).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = [
    "CANONICAL_SCALE",
    "SCALES",
    "convert",
    "from_canonical",
    "normalize_scale",
    "scale_knots",
    "to_canonical",
]

CANONICAL_SCALE = "A_eq"
SCALES: tuple[str, ...] = ("A", "D", "00")

# (reading on the scale, Shore A-equivalent). Strictly increasing in both columns.
# Shore 00 vs Shore A: durometer comparison chart (A 5..80 <-> 00 45..98).
_KNOTS_00: tuple[tuple[float, float], ...] = (
    (45.0, 5.0), (55.0, 10.0), (62.0, 15.0), (70.0, 20.0), (76.0, 25.0), (80.0, 30.0), (83.0, 35.0),
    (86.0, 40.0), (88.0, 45.0), (90.0, 50.0), (91.0, 55.0), (93.0, 60.0), (94.0, 65.0), (95.0, 70.0),
    (97.0, 75.0), (98.0, 80.0),
)
# Shore D vs Shore A: durometer comparison chart (A 30..100 <-> D 6..58); D 0 taken as A 0 (the chart's
# low-end slope of 5 A points per D point, continued); above D 58 one D point = one A_eq point.
_KNOTS_D: tuple[tuple[float, float], ...] = (
    (0.0, 0.0), (6.0, 30.0), (7.0, 35.0), (8.0, 40.0), (10.0, 45.0), (12.0, 50.0), (14.0, 55.0),
    (16.0, 60.0), (19.0, 65.0), (22.0, 70.0), (25.0, 75.0), (29.0, 80.0), (33.0, 85.0), (39.0, 90.0),
    (46.0, 95.0), (58.0, 100.0), (100.0, 142.0),
)
_KNOTS_A: tuple[tuple[float, float], ...] = ((0.0, 0.0), (100.0, 100.0))

_KNOTS = {"A": _KNOTS_A, "D": _KNOTS_D, "00": _KNOTS_00}

_ALIASES = {
    "a": "A", "shore a": "A", "shorea": "A",
    "d": "D", "shore d": "D", "shored": "D",
    "00": "00", "oo": "00", "0o": "00", "o0": "00", "shore 00": "00", "shore oo": "00", "shore00": "00",
    "shoreoo": "00",
}


def normalize_scale(scale: Any) -> str:
    """Return "A", "D" or "00" for a scale name ("a", "Shore D", "OO", ...); ValueError for an unknown name.

    The scale must be a string: an unquoted ``00`` in YAML is read as the integer 0, so it is rejected with
    a hint to quote it (TypeError).
    """
    if not isinstance(scale, str):
        raise TypeError(
            f"hardness scale must be a string, one of 'A', 'D', '00'; got {scale!r} ({type(scale).__name__})."
            " In YAML write the 00 scale quoted: scale: \"00\"."
        )
    key = " ".join(scale.strip().lower().replace("-", " ").replace("_", " ").split())
    if key not in _ALIASES:
        raise ValueError(f"unknown hardness scale {scale!r}; use one of 'A', 'D', '00' (Shore durometer scales).")
    return _ALIASES[key]


def scale_knots(scale: str) -> tuple[tuple[float, float], ...]:
    """The (reading, A_eq) correlation knots of ``scale`` (for documentation and plots)."""
    return _KNOTS[normalize_scale(scale)]


def _torch():
    return sys.modules.get("torch")


def _interp(x: Any, xp: Sequence[float], fp: Sequence[float]) -> Any:
    """Piecewise-linear interpolation with linear extrapolation from the end segments."""
    torch = _torch()
    if torch is not None and isinstance(x, torch.Tensor):
        dtype = x.dtype if x.is_floating_point() else torch.get_default_dtype()
        xs = x.to(dtype)
        xpt = torch.as_tensor(xp, dtype=dtype, device=x.device)
        fpt = torch.as_tensor(fp, dtype=dtype, device=x.device)
        idx = torch.searchsorted(xpt, xs.detach().contiguous(), right=True) - 1
        idx = idx.clamp(0, len(xp) - 2)
        x0, x1, f0, f1 = xpt[idx], xpt[idx + 1], fpt[idx], fpt[idx + 1]
        return f0 + (xs - x0) * (f1 - f0) / (x1 - x0)
    arr = np.asarray(x, dtype=np.float64)
    xpa = np.asarray(xp, dtype=np.float64)
    fpa = np.asarray(fp, dtype=np.float64)
    idx = np.clip(np.searchsorted(xpa, arr, side="right") - 1, 0, len(xpa) - 2)
    x0, x1, f0, f1 = xpa[idx], xpa[idx + 1], fpa[idx], fpa[idx + 1]
    out = f0 + (arr - x0) * (f1 - f0) / (x1 - x0)
    if np.ndim(x) == 0 and not isinstance(x, np.ndarray):
        return float(out)
    return out


def to_canonical(value: Any, scale: str) -> Any:
    """Convert a reading on Shore ``scale`` ("A", "D", "00") into the canonical A_eq scale."""
    knots = _KNOTS[normalize_scale(scale)]
    return _interp(value, [k[0] for k in knots], [k[1] for k in knots])


def from_canonical(value: Any, scale: str) -> Any:
    """Convert canonical A_eq values into readings on Shore ``scale`` (exact inverse of :func:`to_canonical`)."""
    knots = _KNOTS[normalize_scale(scale)]
    return _interp(value, [k[1] for k in knots], [k[0] for k in knots])


def convert(value: Any, from_scale: str, to_scale: str) -> Any:
    """Convert Shore readings between scales through A_eq (approximate, see the module docstring)."""
    return from_canonical(to_canonical(value, from_scale), to_scale)
