"""`physgs batch`: perceive -> train -> export for many scenes, then one eval over all of them."""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from ..advanced import Advanced
from .plan import EstimateRates
from .state import STAGES

Stage = Literal["perceive", "train", "export", "eval"]


@dataclass
class BatchCommand:
    """Run perception, training, export (and eval) over many scenes, resumably: each scene's state is in
    OUT/scenes/<scene>/state.json; a rerun skips finished stages and redoes failed or interrupted ones."""

    scenes: Path
    """A dataset folder, a folder of datasets, the ABO-500 folder (with --split) or a text file of dataset paths."""
    output_dir: Path = Path("batch_output")
    """OUT: scenes/<scene>/ (state.json, runs/, export/, train.log), vlm_cache/, eval/, batch_summary.json."""
    stages: tuple[Stage, ...] = ("perceive", "train", "export", "eval")
    """The stages to run, in this order."""
    method: Literal["physgs", "physgs-lite"] = "physgs"
    """The training method."""
    backend: Literal["local", "ray"] = "local"
    """Run the scenes on this machine or on a Ray cluster."""
    ray_address: str | None = None
    """Ray: address of an existing cluster (e.g. ray://head:10001 or auto); None: start Ray on this machine."""
    ray_num_cpus: int | None = None
    """Ray on this machine: CPUs it may use (None: all)."""
    split: Literal["train", "val", "test", "train+val", "all"] = "test"
    """ABO-500: which split of splits.json to run."""
    retry_failed: bool = False
    """Redo failed stages even after --max-attempts failures."""
    max_attempts: int = 2
    """A failed stage is retried by reruns until it failed this many times."""
    force: tuple[Literal["perceive", "train", "export"], ...] = ()
    """Redo these stages (and the ones after them) for every scene even when done."""
    dry_run: bool = False
    """Print the plan and the estimate (VLM calls, tokens, cost, device time) and run nothing."""
    device: Literal["auto", "cpu", "cuda"] = "auto"
    """Where to train and export (auto: CUDA when available)."""
    gpus: tuple[int, ...] = ()
    """Local backend: one worker per listed GPU (one scene per GPU at a time); empty: one worker."""
    overlap_perception: bool | None = None
    """Local backend: perceive the next scene while this one trains (None: on with CUDA, off on CPU)."""
    iterations: int | None = None
    """Training iterations (None: the method's default)."""
    vlm: Literal["openai", "replay", "simulated"] = "openai"
    """VLM backend of perception (simulated: generated scenes only)."""
    model: str = "gpt-5"
    """The VLM's name at the endpoint."""
    base_url: str = "https://api.openai.com/v1"
    """The VLM endpoint's root URL."""
    api_key_env: str = "OPENAI_API_KEY"
    """The environment variable that holds the API key ('' for a local server without a key)."""
    env: str | None = None
    """Material library (indoor/outdoor); None: the scene's ground_truth.json env or indoor."""
    cache_dir: Path | None = None
    """VLM response cache shared by all scenes (default OUT/vlm_cache); on Ray a path every worker sees."""
    max_views: int | None = None
    """Perceive at most this many frames per scene, evenly spaced (None: all)."""
    max_concurrency: int = 4
    """VLM requests in flight per scene."""
    requests_per_minute: float | None = None
    """Shared VLM limit over the whole batch (all workers); None: no limit."""
    tokens_per_minute: float | None = None
    """Shared VLM token limit over the whole batch (all workers); None: no limit."""
    usd_per_1k_prompt_tokens: float = 0.0
    """Price in USD per 1000 prompt tokens, for the cost estimate (0: unknown)."""
    usd_per_1k_completion_tokens: float = 0.0
    """Price in USD per 1000 completion tokens, for the cost estimate (0: unknown)."""
    export_resolution: int = 128
    """Voxels along the object's longest side for the mass."""
    n_samples: int = 4000
    """Monte Carlo samples of each mass."""
    seed: int = 0
    """Seed of training and of the mass's Monte Carlo samples."""
    train_args: tuple[str, ...] = ()
    """Extra arguments appended to ns-train."""
    estimate: Advanced[EstimateRates] = field(default_factory=EstimateRates)
    """The rates --dry-run estimates with."""
    progress: bool = True
    """Show progress bars."""

    def resolved_device(self) -> str:
        if self.device != "auto":
            return self.device
        import torch

        return "cuda" if torch.cuda.is_available() else "cpu"

    def settings(self):
        from .stages import StageSettings

        cache = self.cache_dir if self.cache_dir is not None else self.output_dir / "vlm_cache"
        return StageSettings(method=self.method, iterations=self.iterations, device=self.resolved_device(),  # type: ignore[arg-type]
                             seed=self.seed, vlm=self.vlm, model=self.model, base_url=self.base_url,
                             api_key_env=self.api_key_env, env=self.env, cache_dir=str(Path(cache).absolute()),
                             max_concurrency=self.max_concurrency, max_views=self.max_views,
                             usd_per_1k_prompt_tokens=self.usd_per_1k_prompt_tokens,
                             usd_per_1k_completion_tokens=self.usd_per_1k_completion_tokens,
                             export_resolution=self.export_resolution, n_samples=self.n_samples,
                             train_args=tuple(self.train_args))  # fmt: skip

    def run(self, console=None) -> dict:
        """Plan or run the batch; returns the totals (or the estimate with --dry-run)."""
        from rich.console import Console

        from .plan import plan_scene, print_plan
        from .progress import BatchProgress
        from .runner import Policy
        from .scenes import discover
        from .summary import collect, print_summary, run_batch_eval, totals, write_summary

        console = console or Console()
        self.output_dir = Path(self.output_dir).absolute()  # Ray workers and reruns may start elsewhere
        scene_set = discover(self.scenes, self.split)
        scenes = list(scene_set.scenes)
        stages = [s for s in STAGES if s in self.stages]
        policy = Policy(force=tuple(self.force), retry_failed=self.retry_failed, max_attempts=self.max_attempts)
        run_id = f"{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}"
        if self.dry_run:
            plans = [plan_scene(s, stages, self.output_dir, policy, self.method, self.iterations, self.max_views,
                                self.estimate, run_id) for s in scenes]  # fmt: skip
            return print_plan(plans, self.usd_per_1k_prompt_tokens, self.usd_per_1k_completion_tokens, console)
        if self.backend == "ray":
            from .ray_backend import import_ray

            import_ray()  # says how to install it before anything runs
        settings = self.settings()
        self.output_dir.mkdir(parents=True, exist_ok=True)
        console.rule(f"physgs batch: {len(scenes)} scenes ({scene_set.kind} {scene_set.source}), "
                     f"{' '.join(stages)}, {self.method} on {settings.device}, backend {self.backend}")  # fmt: skip
        t0 = time.perf_counter()
        limiter_stats: dict = {}
        names = [s.name for s in scenes]
        with BatchProgress(self.output_dir, names, stages, console=console, enabled=self.progress) as bar:
            stop = threading.Event()
            ticker = threading.Thread(target=lambda: [bar.refresh() for _ in iter(lambda: stop.wait(1.0), True)],
                                      daemon=True)  # fmt: skip
            ticker.start()
            try:
                if self.backend == "ray":
                    from .ray_backend import run_ray

                    limiter_stats = run_ray(scenes, stages, settings, self.output_dir, policy, run_id,
                                            address=self.ray_address, num_cpus=self.ray_num_cpus,
                                            requests_per_minute=self.requests_per_minute,
                                            tokens_per_minute=self.tokens_per_minute)  # fmt: skip
                else:
                    limiter_stats = self._run_local(scenes, stages, settings, policy, run_id)
            finally:
                stop.set()
        states = collect(self.output_dir, names)
        tot = totals(states)
        tot["wall_seconds"] = time.perf_counter() - t0
        print_summary(states, tot, console)
        extra = {"backend": self.backend, "method": self.method, "device": settings.device, "run_id": run_id,
                 "rate_limiter": limiter_stats}  # fmt: skip
        if "eval" in self.stages:
            result = run_batch_eval(self.output_dir, scene_set, states, console)
            extra["eval"] = str(self.output_dir / "eval") if result is not None else None
        paths = write_summary(self.output_dir, states, tot, extra)
        console.print("wrote " + ", ".join(str(p) for p in paths.values()))
        return tot

    def _run_local(self, scenes, stages, settings, policy, run_id) -> dict:
        from ..perception import vlm
        from .local import run_local
        from .ratelimit import LocalRateLimiter, TokenBucket

        bucket = None
        if self.requests_per_minute or self.tokens_per_minute:
            bucket = TokenBucket(self.requests_per_minute, self.tokens_per_minute)
            vlm.set_rate_limiter(LocalRateLimiter(bucket))
        overlap = self.overlap_perception if self.overlap_perception is not None else settings.device == "cuda"
        try:
            run_local(scenes, stages, settings, self.output_dir, policy, run_id, gpus=tuple(self.gpus),
                      overlap_perception=overlap)  # fmt: skip
        finally:
            vlm.set_rate_limiter(None)
        return bucket.stats() if bucket is not None else {}

    def main(self) -> None:
        from rich.console import Console

        from ..errors import PhysGSError

        tot = self.run(Console())  # a bad --scenes: SceneListError, one line (cli.one_line_errors)
        if not self.dry_run and tot.get("failures"):
            raise PhysGSError(f"{tot['failures']} scene(s) failed; the table above names each one's error "
                              "(rerun to retry them)")
