"""The ``replay`` VLM: answers only from the response cache that a real (or simulated) backend filled.

A cache key holds the backend's name, model and variant (cache.py), so the replay backend takes the identity
of the backend that filled the cache (``ReplayConfig.source`` and ``model``); it is used behind
``vlm.CachedBackend`` like every backend, so a hit is answered by the cache and only a miss reaches
:meth:`ReplayBackend.query`, which raises :class:`~.vlm.ReplayMiss` naming the request.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from .prompts import VLMRequest
from .simulated import SIMULATED_MODEL, SimulatedConfig
from .vlm import ReplayMiss, Usage, VLMResponse, key_for


@dataclass
class ReplayConfig:
    """Cached answers only (no endpoint is called): re-run perception offline from an earlier run's cache."""

    source: Literal["openai", "simulated"] = "openai"
    """Which backend filled the cache."""
    model: str = "gpt-5"
    """With source openai: the model the answers came from (part of the cache key)."""
    simulated: SimulatedConfig = field(default_factory=SimulatedConfig)
    """With source simulated: the simulated VLM's settings (their fingerprint is part of the cache key)."""

    def setup(self, data=None, library=None) -> ReplayBackend:
        """The replay backend of this config (``data`` / ``library`` are not needed)."""
        if self.source == "simulated":
            return ReplayBackend("simulated", SIMULATED_MODEL, self.simulated.fingerprint(), simulated=True)
        return ReplayBackend("openai", self.model, "", simulated=False)


class ReplayBackend:
    """A backend that has no answer of its own: every query that reaches it is a cache miss."""

    def __init__(self, name: str, model: str, variant: str, *, simulated: bool):
        self.name, self.model, self.variant, self.simulated = name, model, variant, simulated

    def cost_usd(self, usage: Usage) -> float:
        return 0.0

    def query(self, request: VLMRequest) -> VLMResponse:
        key = key_for(self.name, self.model, self.variant, request)
        raise ReplayMiss(
            f"replay: no cached response for {request.describe()} (key {key}, backend {self.name}, model "
            f"{self.model!r}) in the response cache. Run once with the real backend, or check "
            "--vlm.model / --vlm.source and the prompt settings, which are part of the key."
        )
