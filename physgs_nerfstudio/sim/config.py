"""Settings of the simulator export (``physgs export --outputs sim``) and its one-line refusals."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from ..advanced import Advanced
from ..errors import PhysGSError

__all__ = ["SimConfig", "SimError"]


class SimError(PhysGSError, ValueError):
    """The object cannot be written as a simulator body (one line: what, where, what to do)."""


@dataclass
class SimConfig:
    """The simulator-ready object written by ``--outputs sim``."""

    samples: int = 0
    """Posterior sample bodies to write as well, drawn from the mass report's Monte Carlo (0: none)."""
    collision: Literal["hull", "coacd", "auto"] = "hull"
    """Collision geometry: each part's convex hull, or CoACD's convex decomposition (auto: CoACD if installed)."""
    max_triangles: Advanced[int] = 20000
    """The visual meshes' triangle budget for the whole object."""
    coacd_threshold: Advanced[float] = 0.08
    """CoACD's concavity threshold (smaller: more, tighter pieces)."""
    max_pieces: Advanced[int] = 16
    """At most this many convex pieces per part (CoACD)."""
    min_voxels: Advanced[int] = 8
    """An object of fewer solid voxels is refused (too coarse for a body)."""

    def __post_init__(self) -> None:
        if self.samples < 0:
            raise ValueError(f"--sim.samples must be >= 0, got {self.samples}.")
        if self.collision not in ("auto", "coacd", "hull"):
            raise ValueError(f"--sim.collision must be auto|coacd|hull, got {self.collision!r}.")
        if self.max_triangles < 100:
            raise ValueError(f"--sim.max-triangles must be >= 100, got {self.max_triangles}.")
