"""The parameters of one member of an object family: its canonical values or a draw from a seed.

A family builder (``objects.py``) asks a `Draw` for every dimension, count, wall thickness, hollow-or-solid
choice and material, each with its range and its canonical value. `CANONICAL` answers the canonical value
(the family's fixed preset, which `physgs demo` and the tests use); `Draw.seeded(seed, family)` draws each from
its range with a generator seeded by (seed, family), so one seed gives one reproducible object.

A material draw (`Draw.material`) returns a `MaterialDraw`: the library name, drawn among the family's plausible
materials for that part, and ``density_u`` in [0, 1], where the part's true density lies in the material's
library density range (``dataset.part_density``: log-uniform between low and high); the canonical draw has
``density_u`` None, meaning the library's typical density as before.
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

T = TypeVar("T")


@dataclass(frozen=True)
class MaterialDraw:
    """A part's library material and where its true density lies in the material's range (None: typical)."""

    name: str
    density_u: float | None = None


class Draw:
    """Answers a family builder's parameter requests: canonical values, or draws from a seeded generator."""

    def __init__(self, rng: np.random.Generator | None = None) -> None:
        self.rng = rng

    @classmethod
    def seeded(cls, seed: int, family: str) -> Draw:
        return cls(np.random.default_rng([int(seed), zlib.crc32(family.encode()), 70]))

    @property
    def canonical(self) -> bool:
        return self.rng is None

    def uniform(self, lo: float, hi: float, canonical: float) -> float:
        """A length or proportion in [lo, hi] (canonical: `canonical`)."""
        if self.rng is None:
            return canonical
        return float(self.rng.uniform(lo, hi))

    def derived(self, value: float, canonical: float) -> float:
        """A quantity that follows from drawn ones (a position, a fit); the canonical preset states its own."""
        return canonical if self.rng is None else value

    def integer(self, lo: int, hi: int, canonical: int) -> int:
        """A count in lo..hi inclusive."""
        if self.rng is None:
            return canonical
        return int(self.rng.integers(lo, hi + 1))

    def choice(self, options: Sequence[T], canonical: T) -> T:
        if self.rng is None:
            return canonical
        return options[int(self.rng.integers(len(options)))]

    def coin(self, p_true: float, canonical: bool) -> bool:
        """True with probability `p_true` (e.g. hollow rather than solid)."""
        if self.rng is None:
            return canonical
        return bool(self.rng.random() < p_true)

    def material(self, options: Sequence[str], canonical: str) -> MaterialDraw:
        """One of the part's plausible library materials, with its density's place in the material's range."""
        if self.rng is None:
            return MaterialDraw(canonical)
        name = options[int(self.rng.integers(len(options)))]
        return MaterialDraw(name, float(self.rng.random()))


CANONICAL = Draw()
