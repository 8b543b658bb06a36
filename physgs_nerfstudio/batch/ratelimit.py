"""A requests-per-minute and tokens-per-minute bucket shared by every VLM call of a batch.

:class:`TokenBucket` is the whole logic (thread-safe, injectable clock). ``reserve(requests, tokens)`` books
the capacity at once and returns how long the caller must wait before using it (the buckets may go into
debt; later callers wait for the debt to refill). Tokens are charged after a response, when they are known:
``acquire(0, tokens)`` never waits, it makes later requests wait. :class:`LocalRateLimiter` sleeps for the
local backend; on Ray one actor holds the bucket for the whole cluster (ray_backend.py) and
:class:`ReservingRateLimiter` is the client each Ray task gives the OpenAI backend.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable


class TokenBucket:
    def __init__(self, requests_per_minute: float | None = None, tokens_per_minute: float | None = None,
                 clock: Callable[[], float] = time.monotonic):  # fmt: skip
        for name, v in (("requests_per_minute", requests_per_minute), ("tokens_per_minute", tokens_per_minute)):
            if v is not None and v <= 0:
                raise ValueError(f"{name} must be > 0 (or None for no limit), got {v}")
        self.rpm, self.tpm = requests_per_minute, tokens_per_minute
        self._clock = clock
        self._lock = threading.Lock()
        self._t = clock()
        self._req = float(requests_per_minute or 0.0)  # start full: a minute's worth
        self._tok = float(tokens_per_minute or 0.0)
        self.requests = 0
        self.tokens = 0
        self.waited_s = 0.0

    def _refill(self) -> None:
        now = self._clock()
        dt, self._t = max(0.0, now - self._t), now
        if self.rpm:
            self._req = min(self.rpm, self._req + dt * self.rpm / 60.0)
        if self.tpm:
            self._tok = min(self.tpm, self._tok + dt * self.tpm / 60.0)

    def reserve(self, requests: int, tokens: int) -> float:
        """Book ``requests`` and ``tokens``; seconds the caller must wait before sending (0 with requests=0)."""
        with self._lock:
            self._refill()
            wait = 0.0
            if requests and self.rpm:
                self._req -= requests
                wait = max(wait, -self._req * 60.0 / self.rpm)
            if requests and self.tpm and self._tok < 0:  # earlier responses' tokens not yet paid back
                wait = max(wait, -self._tok * 60.0 / self.tpm)
            if tokens and self.tpm:
                self._tok -= tokens
            self.requests += requests
            self.tokens += tokens
            self.waited_s += wait
            return wait

    def stats(self) -> dict:
        with self._lock:
            return {"requests": self.requests, "tokens": self.tokens, "waited_s": self.waited_s,
                    "requests_per_minute": self.rpm, "tokens_per_minute": self.tpm}  # fmt: skip


class ReservingRateLimiter:
    """The :class:`~physgs_nerfstudio.perception.vlm.RateLimiter` protocol over any ``reserve`` function."""

    def __init__(self, reserve: Callable[[int, int], float], sleep: Callable[[float], None] = time.sleep):
        self._reserve, self._sleep = reserve, sleep

    def acquire(self, requests: int, tokens: int) -> None:
        wait = self._reserve(requests, tokens)
        if wait > 0:
            self._sleep(wait)


class LocalRateLimiter(ReservingRateLimiter):
    def __init__(self, bucket: TokenBucket, sleep: Callable[[float], None] = time.sleep):
        self.bucket = bucket
        super().__init__(bucket.reserve, sleep)
