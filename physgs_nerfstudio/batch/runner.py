"""One stage of one scene with its bookkeeping: skip it when done, mark it running, run it, record the
outputs and timing or the one-line error. Both backends call :func:`run_stage` (a Ray task calls it in a
worker), so a scene's state means the same whatever ran it.
"""

from __future__ import annotations

import shutil
import time
from dataclasses import dataclass
from pathlib import Path

from . import stages as st
from .scenes import Scene
from .state import STAGES, load_state, save_state, scene_dir, stage_status


@dataclass(frozen=True)
class Policy:
    """Which recorded stages a run redoes."""

    force: tuple[str, ...] = ()
    """Redo these stages (and the stages after them) even when done."""
    retry_failed: bool = False
    """Redo failed stages even after ``max_attempts``."""
    max_attempts: int = 2
    """A failed stage is retried by later runs until it has failed this many times."""


def needs_run(state: dict, stage: str, policy: Policy, run_id: str = "") -> tuple[bool, str]:
    """(run it?, why) for ``stage`` of a scene in ``state``; a forced stage runs once per batch run ``run_id``."""
    rec = state.get("stages", {}).get(stage) or {}
    status = rec.get("status")
    forced = any(STAGES.index(stage) >= STAGES.index(f) for f in policy.force if f in STAGES)
    if forced and state.get("forced", {}).get(stage) != run_id:
        return True, "forced"
    if status == "done":
        return False, "done"
    if status == "failed" and not policy.retry_failed and rec.get("attempts", 0) >= policy.max_attempts:
        return False, f"failed {rec.get('attempts')} times (--retry-failed to retry)"
    return True, {"failed": "retry", "running": "interrupted"}.get(status or "", "new")


def _prerequisite(state: dict, stage: str) -> str | None:
    """The earlier stage this one waits for when that one is not done, else None."""
    i = STAGES.index(stage)
    if i == 0:
        return None
    prev = STAGES[i - 1]
    return None if stage_status(state, prev) == "done" else prev


def run_stage(scene: Scene, stage: str, settings: st.StageSettings, output_dir: Path, policy: Policy,
              run_id: str, gpu: int | None = None) -> dict:  # fmt: skip
    """Run ``stage`` of ``scene`` if it needs to; returns the stage's record (also saved in state.json)."""
    out = scene_dir(output_dir, scene.name)
    state = load_state(output_dir, scene.name)
    state["data"] = str(scene.data)
    todo, why = needs_run(state, stage, policy, run_id)
    if not todo:
        return {**state["stages"][stage], "skipped": why}
    prereq = _prerequisite(state, stage)
    # perceive may be left out of --stages when the dataset already has materials.json
    external = stage == "train" and stage_status(state, "perceive") is None and (scene.data / "materials.json").is_file()
    if prereq is not None and not external:
        return {"status": "blocked", "error": f"waits for {prereq} ({stage_status(state, prereq) or 'not run'})"}
    rec = state["stages"].get(stage, {})
    attempts = int(rec.get("attempts", 0)) + 1 if rec.get("status") in ("failed", "running") else 1
    rec = {"status": "running", "attempts": attempts, "started": time.time(), "reason": why}
    state["stages"][stage] = rec
    if why == "forced":
        for later in STAGES[STAGES.index(stage) + 1:]:
            state["stages"].pop(later, None)
    for forced in [s for s in STAGES if why == "forced" and STAGES.index(s) >= STAGES.index(stage)]:
        state.setdefault("forced", {})[forced] = run_id
    save_state(output_dir, scene.name, state)
    t0 = time.perf_counter()
    try:
        if stage == "perceive":
            outputs, metrics = st.run_perceive(scene, settings, out, overwrite=why == "forced")
        elif stage == "train":
            if why == "forced":
                shutil.rmtree(st.run_dir(out, scene, settings.method), ignore_errors=True)
            outputs, metrics = st.run_train(scene, settings, out, gpu=gpu)
        elif stage == "export":
            config = state["stages"].get("train", {}).get("outputs", {}).get("config")
            if config is None:
                raise st.StageError("no trained config.yml recorded; run the train stage first", "missing input")
            if gpu is not None and settings.device == "cuda":  # this worker's GPU (current device is per thread)
                import torch

                with torch.cuda.device(gpu):
                    outputs, metrics = st.run_export(scene, settings, out, Path(config))
            else:
                outputs, metrics = st.run_export(scene, settings, out, Path(config))
        else:
            raise ValueError(f"unknown stage {stage!r}")
    except st.StageError as err:
        rec.update(status="failed", error=str(err), error_kind=err.kind)
    except (Exception, SystemExit) as err:  # noqa: BLE001 - a scene's failure must not stop the others
        rec.update(status="failed", error=f"{type(err).__name__}: {st._one_line(err)}", error_kind=type(err).__name__)
    else:
        rec.update(status="done", outputs=outputs, metrics=metrics, error=None, error_kind=None)
    rec.update(finished=time.time(), seconds=time.perf_counter() - t0)
    if stage in ("train", "export"):  # a failed attempt held the device too (summary.py counts its seconds)
        rec["device"] = settings.device
    state["stages"][stage] = rec
    save_state(output_dir, scene.name, state)
    return rec
