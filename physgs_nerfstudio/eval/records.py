"""What adapters produce and the scorer consumes: ground-truth measurements and predictions.

Every adapter turns its files into these records, in canonical units (see :mod:`.units`), so one scorer
compares every method on every dataset the same way.

* :class:`Measurement` -- one ground-truth value (or material label) of one property of one item.
* :class:`Prediction` -- one method's estimate for the same (item, property): a point ``mean`` plus,
  when the method has them, an interval ``[low, high]`` (with its nominal ``level`` when known), a
  Gaussian ``std``, a Gaussian mixture, or Monte Carlo samples.

Shore hardness keeps its scale on both sides: ``Measurement.scale`` is the scale of the reading;
``Prediction.scale`` is the scale the prediction is expressed in (``"A_eq"`` = the canonical scale of
:mod:`physgs_nerfstudio.materials.hardness`, what our exports carry). The scorer converts predictions into
the measurement's scale.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

__all__ = ["Measurement", "Mixture", "Prediction", "item_key"]


def item_key(item: str) -> str:
    """Items are matched on their exact, whitespace-stripped name."""
    return str(item).strip()


@dataclass(frozen=True)
class Mixture:
    """Gaussian mixture predictive of one item: weights sum to 1, stds > 0 (same units as the mean)."""

    weights: tuple[float, ...]
    means: tuple[float, ...]
    stds: tuple[float, ...]

    def mean(self) -> float:
        return float(sum(w * m for w, m in zip(self.weights, self.means)))

    def scaled(self, factor: float) -> Mixture:
        return Mixture(self.weights, tuple(m * factor for m in self.means), tuple(s * abs(factor) for s in self.stds))


@dataclass(frozen=True)
class Measurement:
    """Ground truth of one (item, property).

    item: evaluation unit (ABO scene, ``object/point``, terrain image, your item name).
    prop: canonical property key (``mass``, ``density``, ``kinetic_friction``, ``shore_hardness``,
        ``youngs_modulus``, ``bending_stiffness``, ``material`` or a user's own name).
    value: canonical-unit value; None for ``material`` (then ``label`` holds the material name).
    unit: canonical unit (informational). scale: Shore scale of a hardness reading ("A", "D", "00").
    group: what per-group tables aggregate over (terrain class, object, split); may be None.
    source: ``file:line`` / ``file[entry]`` for messages.
    """

    item: str
    prop: str
    value: float | None
    unit: str = ""
    scale: str | None = None
    label: str | None = None
    group: str | None = None
    source: str = ""


@dataclass(frozen=True)
class Prediction:
    """One method's estimate of one (item, property), canonical units (hardness: in ``scale``)."""

    item: str
    prop: str
    mean: float | None
    method: str = "physgs"
    low: float | None = None
    high: float | None = None
    level: float | None = None        # nominal coverage of [low, high] (0.9 = 90 %); None = unknown
    std: float | None = None
    mixture: Mixture | None = None
    samples: tuple[float, ...] | None = None
    unit: str = ""
    scale: str | None = None
    label: str | None = None          # predicted material
    source: str = ""
    notes: tuple[str, ...] = field(default_factory=tuple)

    def with_method(self, method: str) -> Prediction:
        return replace(self, method=method)

    @property
    def has_interval(self) -> bool:
        return self.low is not None and self.high is not None

    def is_finite(self) -> bool:
        vals: Sequence[float | None] = (self.mean, self.low, self.high, self.std)
        return all(v is None or math.isfinite(v) for v in vals)
