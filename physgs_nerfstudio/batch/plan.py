"""``--dry-run``: what a batch would run, and what it would cost, before anything starts.

Per scene: the stages to run (state on disk decides: done ones are skipped), the VLM calls (views x masks
per view, minus the scene's cached answers when it was perceived before), tokens (calls x tokens per call)
and the training device time (iterations x seconds per iteration of the method, plus the training process's
time outside the steps, per view, plus export). The rates
are settings with measured defaults (docs/batch.md); the estimate is only as good as they are.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from .runner import Policy, needs_run
from .scenes import Scene
from .state import load_state

DEFAULT_ITERATIONS = {"physgs": 30000, "physgs-lite": 300}
"""The methods' ``max_num_iterations`` (method_configs/physgs_config.py)."""
SECONDS_PER_ITERATION = {"physgs": 0.0123, "physgs-lite": 0.0123}
"""H100, `physgs` with the material pass every 8th step (benchmarks/README.md, Training: 12.3 ms)."""
EXPORT_SECONDS = 6.0
"""H100 export incl. mass integration, 100k-1M Gaussians (benchmarks/README.md: 3.4-5.9 s)."""


@dataclass
class EstimateRates:
    masks_per_view: float = 2.75
    """Masks the built-in segmenter finds per view (2.75 on 6 generated objects: 132 masks over 48 views)."""
    prompt_tokens_per_call: int = 1000
    completion_tokens_per_call: int = 250
    seconds_per_iteration: float | None = None
    """Device seconds per training iteration (None: the method's measured H100 figure)."""
    train_seconds_per_view: float = 1.15
    """Seconds of a training process outside its steps (start, the dataset, liftings, evaluation), per view: H100,
    median 27.1 s over 5 scenes of 24 views and 47.7 s for one of 40 views (1.13 and 1.19 s a view;
    benchmarks/README.md, "Many scenes on the GPU"). Without it the estimate was 2.4x low."""


@dataclass
class ScenePlan:
    scene: str
    stages: list[str]
    views: int
    calls: int
    prompt_tokens: int
    completion_tokens: int
    device_seconds: float


def _views(data: Path, max_views: int | None) -> int:
    try:
        n = len(json.loads((data / "transforms.json").read_text()).get("frames", []))
    except (OSError, ValueError):
        n = 0
    return min(n, max_views) if max_views else n


def plan_scene(scene: Scene, stages: list[str], output_dir: Path, policy: Policy, method: str,
               iterations: int | None, max_views: int | None, rates: EstimateRates, run_id: str = "") -> ScenePlan:  # fmt: skip
    state = load_state(output_dir, scene.name)
    todo = [s for s in stages if needs_run(state, s, policy, run_id)[0]]
    views = _views(scene.data, max_views)
    calls = 0
    if "perceive" in todo:
        masks = round(views * rates.masks_per_view)
        answered = (state.get("stages", {}).get("perceive") or {}).get("metrics", {})
        calls = max(0, masks - int(answered.get("vlm_calls", 0)))
    iters = iterations if iterations is not None else DEFAULT_ITERATIONS[method]
    spi = rates.seconds_per_iteration if rates.seconds_per_iteration is not None else SECONDS_PER_ITERATION[method]
    train = iters * spi + views * rates.train_seconds_per_view
    secs = (train if "train" in todo else 0.0) + (EXPORT_SECONDS if "export" in todo else 0.0)
    return ScenePlan(scene.name, todo, views, calls, calls * rates.prompt_tokens_per_call,
                     calls * rates.completion_tokens_per_call, secs)  # fmt: skip


def print_plan(plans: list[ScenePlan], usd_prompt: float, usd_completion: float, console, max_rows: int = 30) -> dict:
    from rich.table import Table

    table = Table(title=f"physgs batch --dry-run: {len(plans)} scenes")
    for col in ("scene", "stages to run", "views", "VLM calls", "tokens", "device s"):
        table.add_column(col, justify="left" if col in ("scene", "stages to run") else "right")
    for p in plans[:max_rows]:
        table.add_row(p.scene, " ".join(p.stages) or "- (all done)", str(p.views), str(p.calls),
                      str(p.prompt_tokens + p.completion_tokens), f"{p.device_seconds:.0f}")  # fmt: skip
    if len(plans) > max_rows:
        table.add_row(f"... {len(plans) - max_rows} more", "", "", "", "", "")
    totals = {"scenes": len(plans), "stages": sum(len(p.stages) for p in plans),
              "vlm_calls": sum(p.calls for p in plans), "prompt_tokens": sum(p.prompt_tokens for p in plans),
              "completion_tokens": sum(p.completion_tokens for p in plans),
              "device_seconds": sum(p.device_seconds for p in plans)}  # fmt: skip
    totals["cost_usd"] = totals["prompt_tokens"] / 1000 * usd_prompt + totals["completion_tokens"] / 1000 * usd_completion
    table.add_row("[bold]total[/]", f"{totals['stages']} stages", "", str(totals["vlm_calls"]),
                  str(totals["prompt_tokens"] + totals["completion_tokens"]), f"{totals['device_seconds']:.0f}")  # fmt: skip
    console.print(table)
    console.print(f"estimate: {totals['vlm_calls']} VLM calls, {totals['prompt_tokens'] + totals['completion_tokens']} "
                  f"tokens, ${totals['cost_usd']:.2f} (at the given $/1k-token rates), "
                  f"{totals['device_seconds'] / 3600:.2f} device-hours of training and export. Nothing was run.")  # fmt: skip
    return totals
