"""Settings of the simulator export (``physgs export --outputs sim``) and its one-line refusals."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

import tyro

from ..errors import PhysGSError

__all__ = ["SimConfig", "SimError"]


class SimError(PhysGSError, ValueError):
    """The object cannot be written as a simulator body (one line: what, where, what to do)."""


@dataclass
class SimConfig:
    """The simulator-ready object written by ``--outputs sim``."""

    samples: int = 0
    """posterior samples to write as well (each a body drawn from the mass report's Monte Carlo), 0 for none"""
    collision: Literal["hull", "coacd", "auto"] = "hull"
    """collision geometry: each part's convex hull, or CoACD's convex decomposition (minutes on a CPU; auto: CoACD
    where it is installed)"""
    max_triangles: Annotated[int, tyro.conf.Suppress] = 20000
    """the visual meshes' triangle budget for the whole object"""
    coacd_threshold: Annotated[float, tyro.conf.Suppress] = 0.08
    """CoACD's concavity threshold (smaller: more, tighter pieces)"""
    max_pieces: Annotated[int, tyro.conf.Suppress] = 16
    """at most this many convex pieces per part (CoACD)"""
    min_voxels: Annotated[int, tyro.conf.Suppress] = 8
    """an object of fewer solid voxels is refused (too coarse for a body)"""

    def __post_init__(self) -> None:
        if self.samples < 0:
            raise ValueError(f"--sim.samples must be >= 0, got {self.samples}.")
        if self.collision not in ("auto", "coacd", "hull"):
            raise ValueError(f"--sim.collision must be auto|coacd|hull, got {self.collision!r}.")
        if self.max_triangles < 100:
            raise ValueError(f"--sim.max-triangles must be >= 100, got {self.max_triangles}.")
