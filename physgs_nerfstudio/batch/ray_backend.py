"""The Ray backend: one Ray task per scene stage, chained per scene (train waits for its perceive task's
result, export for train), resources declared per stage (``num_gpus=1`` for training and export on CUDA,
one CPU each otherwise and for perception). One actor holds the VLM rate limit (ratelimit.TokenBucket)
for the whole cluster; each perception task runs in its worker process and gives the OpenAI backend a
client of that actor (perception.vlm.set_rate_limiter). Ray does the scheduling; we write no queue.

Every worker must see the same paths: the datasets, ``--output-dir`` and the VLM response cache
(``--cache-dir``, default ``OUT/vlm_cache``) must be on a filesystem all nodes mount at the same path.
"""

from __future__ import annotations

import logging
from pathlib import Path

from .runner import Policy, run_stage
from .scenes import Scene
from .stages import StageSettings

logger = logging.getLogger(__name__)
INSTALL_HINT = 'the Ray backend needs Ray: pip install "physgs-nerfstudio[ray]" (or pip install ray), or use --backend local'


def import_ray():
    try:
        import ray
    except ImportError:
        raise SystemExit(f"physgs batch: {INSTALL_HINT}") from None
    return ray


def _stage_task(scene: dict, stage: str, settings: dict, output_dir: str, policy: dict, run_id: str,
                limiter=None, previous: dict | None = None) -> dict:  # fmt: skip
    """Body of a Ray task (module level, so Ray pickles it by reference)."""
    from ..perception import vlm
    from .ratelimit import ReservingRateLimiter

    if previous is not None and previous.get("status") not in ("done", None):
        return {"status": "blocked", "error": f"previous stage {previous.get('status')}"}
    sc = Scene(scene["name"], Path(scene["data"]), scene["truth"])
    if limiter is not None:
        import ray

        vlm.set_rate_limiter(ReservingRateLimiter(lambda r, t: ray.get(limiter.reserve.remote(r, t))))
    try:
        return run_stage(sc, stage, StageSettings.from_dict(settings), Path(output_dir), Policy(**policy), run_id)
    finally:
        vlm.set_rate_limiter(None)


class _RateLimitActor:
    """The cluster's VLM budget: a TokenBucket behind a Ray actor (made with ray.remote at run time)."""

    def __init__(self, requests_per_minute, tokens_per_minute):
        from .ratelimit import TokenBucket

        self.bucket = TokenBucket(requests_per_minute, tokens_per_minute)

    def reserve(self, requests: int, tokens: int) -> float:
        return self.bucket.reserve(requests, tokens)

    def stats(self) -> dict:
        return self.bucket.stats()


def run_ray(scenes: list[Scene], stages: list[str], settings: StageSettings, output_dir: Path, policy: Policy,
            run_id: str, address: str | None = None, num_cpus: int | None = None,
            requests_per_minute: float | None = None, tokens_per_minute: float | None = None,
            refresh=None, init: bool = True) -> dict:  # fmt: skip
    """Submit every scene's stages and wait; returns the rate-limit actor's statistics (or {})."""
    ray = import_ray()
    refresh = refresh or (lambda: None)
    if init and not ray.is_initialized():
        kwargs = {"address": address} if address else {"num_cpus": num_cpus}
        ray.init(ignore_reinit_error=True, log_to_driver=False, include_dashboard=False, **kwargs)
    gpu = settings.device == "cuda"
    resources = {"perceive": {"num_cpus": 1},
                 "train": {"num_gpus": 1, "num_cpus": 1} if gpu else {"num_cpus": 1},
                 "export": {"num_gpus": 1, "num_cpus": 1} if gpu else {"num_cpus": 1}}  # fmt: skip
    task = ray.remote(max_retries=0)(_stage_task)
    limiter = None
    if "perceive" in stages and settings.vlm == "openai":
        limiter = ray.remote(num_cpus=0)(_RateLimitActor).remote(requests_per_minute, tokens_per_minute)
    s_dict, p_dict = settings.to_dict(), {"force": policy.force, "retry_failed": policy.retry_failed,
                                          "max_attempts": policy.max_attempts}  # fmt: skip
    pending = []
    for scene in scenes:
        sc = {"name": scene.name, "data": str(scene.data), "truth": scene.truth}
        prev = None
        for stage in stages:
            prev = task.options(**resources[stage], name=f"{stage}:{scene.name}").remote(
                sc, stage, s_dict, str(output_dir), p_dict, run_id, limiter if stage == "perceive" else None, prev)
            pending.append(prev)
    while pending:
        done, pending = ray.wait(pending, num_returns=len(pending), timeout=1.0)
        for ref in done:
            try:
                ray.get(ref)
            except Exception as err:  # noqa: BLE001 - a task that crashed its worker; its state shows "running"
                logger.warning("a Ray task ended with %s", type(err).__name__)
        refresh()
    stats = ray.get(limiter.stats.remote()) if limiter is not None else {}
    return stats
