"""Perception front end (paper sec. 3.4, supplement C.1): part masks, triplet VLM prompts, cached VLM
backends (openai / replay / simulated), strict validation and a resumable observation store.

Submodules import their heavy dependencies lazily. ``PerceptionConfig`` (config.py) chooses the VLM and the
segmenter by config type; ``run_perception`` is the entry point (``run_active_perception`` for active
querying), both one ``PerceptionRun`` with another scheduler.
"""

from .active import ActiveConfig, ActiveResult, run_active_perception
from .config import PerceptionConfig
from .pipeline import PerceptionResult, PerceptionRun, run_perception

__all__ = [
    "ActiveConfig",
    "ActiveResult",
    "PerceptionConfig",
    "PerceptionResult",
    "PerceptionRun",
    "run_active_perception",
    "run_perception",
]
