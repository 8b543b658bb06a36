"""Simulator-ready objects from an export: MuJoCo, URDF, USD physics, MPM particles and posterior samples
(docs/simulation.md). :func:`write_sim` writes them from the export's geometry and the mass report's Monte Carlo."""

from .config import SimConfig, SimError
from .write import write_sim

__all__ = ["SimConfig", "SimError", "write_sim"]
