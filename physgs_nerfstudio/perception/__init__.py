"""Perception front end (paper sec. 3.4, supplement C.1): part masks, triplet VLM prompts, cached VLM
backends (openai / replay / simulated), strict validation and a resumable observation store.

Submodules import their heavy dependencies lazily; ``run_perception`` is the entry point
(``run_active_perception`` for active querying).
"""

from .active import ActiveConfig, ActiveResult, run_active_perception
from .pipeline import PerceptionConfig, PerceptionResult, run_perception

__all__ = [
    "ActiveConfig",
    "ActiveResult",
    "PerceptionConfig",
    "PerceptionResult",
    "run_active_perception",
    "run_perception",
]
