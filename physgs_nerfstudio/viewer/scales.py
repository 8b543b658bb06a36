"""Fixed, labelled colour scales of the viewer's property outputs (one per property, the same in every frame).

nerfstudio's viewer normalises a one-channel output to each frame's own min and max, so a ceramic mug would
change colour whenever a steel spoon enters the frame. PhysGS outputs are therefore rendered as colours
(three channels, which the viewer shows as they are) on fixed ranges:

* a property's mean: the span of every material's range in the built-in indoor and outdoor libraries
  (`physgs materials`), on a log10 axis for density and Young's modulus (the properties fused in log space);
* an uncertainty (standard deviation, property units): from 0 to the total standard deviation of a Gaussian
  that perception never labelled (the scene's prior), so "as unsure as knowing nothing" is the top colour.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from jaxtyping import Float
from torch import Tensor

from ..materials.hardness import from_canonical

__all__ = [
    "COLORMAP",
    "UNITS",
    "DisplayScale",
    "colourise",
    "format_value",
    "library_ranges",
    "property_scales",
    "shore_reading",
    "uncertainty_scale",
]  # fmt: skip

COLORMAP = "turbo"
UNITS: dict[str, str] = {
    "density": "kg/m^3",
    "kinetic_friction": "",
    "shore_hardness": "Shore A-eq",
    "youngs_modulus": "Pa",
}
_LOG_DISPLAY = {"density", "youngs_modulus"}


@dataclass(frozen=True)
class DisplayScale:
    """A fixed colour scale: values ``lo``..``hi`` (property units) map to the colormap's ends."""

    key: str
    """property key (``density``, ...)"""
    label: str
    """what the colour shows, e.g. ``density mean`` or ``density epistemic std``"""
    lo: float
    hi: float
    log10: bool
    unit: str

    def __post_init__(self) -> None:
        if not (math.isfinite(self.lo) and math.isfinite(self.hi) and self.lo < self.hi):
            raise ValueError(f"DisplayScale {self.label!r}: need finite lo < hi, got {self.lo}, {self.hi}.")
        if self.log10 and self.lo <= 0:
            raise ValueError(f"DisplayScale {self.label!r}: a log10 scale needs lo > 0, got {self.lo}.")

    def normalise(self, values: Tensor) -> Tensor:
        """Values in property units -> [0, 1] on this scale (clamped)."""
        if self.log10:
            v = torch.log10(values.clamp_min(self.lo * 1e-3))
            lo, hi = math.log10(self.lo), math.log10(self.hi)
        else:
            v, lo, hi = values, self.lo, self.hi
        return ((v - lo) / (hi - lo)).clamp(0.0, 1.0)

    def describe(self) -> str:
        """One line for the legend, e.g. ``density mean: 10 .. 1.05e+04 kg/m^3 (log), turbo``."""
        axis = ", log axis" if self.log10 else ""
        unit = f" {self.unit}" if self.unit else ""
        return (f"{self.label}: {format_value(self.key, self.lo)} .. {format_value(self.key, self.hi)}{unit}"
                f"{axis} ({COLORMAP}: blue low, red high)")  # fmt: skip


def format_value(key: str, value: float) -> str:
    """A number as the panel prints it: 3 significant digits, scientific notation outside 0.01 .. 1e5."""
    if not math.isfinite(value) or value == 0:
        return str(value) if value != 0 else "0"
    return f"{value:.3g}" if 1e-2 <= abs(value) < 1e5 else f"{value:.2e}"


def library_ranges(keys: Sequence[str], envs: Sequence[str] = ("indoor", "outdoor")) -> dict[str, tuple[float, float]]:
    """Per property the span (lowest low, highest high) of every material in the built-in libraries."""
    from ..materials import load_library

    lo = {k: math.inf for k in keys}
    hi = {k: -math.inf for k in keys}
    for env in envs:
        for m in load_library(env).materials:
            for k in keys:
                r = m.properties.get(k)
                if r is not None:
                    lo[k], hi[k] = min(lo[k], r.low), max(hi[k], r.high)
    missing = [k for k in keys if not lo[k] < hi[k]]
    if missing:
        raise ValueError(f"no library range for {missing}: the viewer's colour scales need every property in the "
                         "built-in material libraries.")  # fmt: skip
    return {k: (lo[k], hi[k]) for k in keys}


def property_scales(keys: Sequence[str]) -> dict[str, DisplayScale]:
    """The fixed scale of each property's mean (module doc). Friction starts at 0."""
    return dict(_property_scales(tuple(keys)))


@functools.lru_cache(maxsize=8)
def _property_scales(keys: tuple[str, ...]) -> dict[str, DisplayScale]:
    ranges = library_ranges(keys)
    out = {}
    for k in keys:
        lo, hi = ranges[k]
        if k == "kinetic_friction":
            lo = 0.0
        out[k] = DisplayScale(k, f"{k} mean", lo, hi, k in _LOG_DISPLAY, UNITS.get(k, ""))
    return out


def uncertainty_scale(key: str, kind: str, prior_std: float) -> DisplayScale:
    """0 .. the prior's total standard deviation (an unlabelled Gaussian's), property units."""
    hi = prior_std if math.isfinite(prior_std) and prior_std > 0 else 1.0
    return DisplayScale(key, f"{key} {kind} std", 0.0, hi, False, UNITS.get(key, ""))


def colourise(values: Float[Tensor, "*bs 1"], scale: DisplayScale) -> Float[Tensor, "*bs 3"]:
    """Values -> RGB in [0, 1] on the fixed scale (the viewer then shows them as they are)."""
    from nerfstudio.utils.colormaps import apply_float_colormap

    return apply_float_colormap(scale.normalise(values.float()), colormap=COLORMAP)


def shore_reading(a_eq: float) -> tuple[str, float]:
    """A Shore A-equivalent value as the reading a durometer user expects: Shore A up to A 90, Shore D above
    (harder materials are measured on D), e.g. ``("D", 75.0)``."""
    if a_eq > 90.0:
        return "D", float(from_canonical(a_eq, "D"))
    return "A", float(from_canonical(a_eq, "A"))
