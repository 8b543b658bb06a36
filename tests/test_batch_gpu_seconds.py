"""benchmarks/gpu/batch_gpu_seconds.py on hand-written batch records with known answers."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from helpers.benchmarks import load_benchmark


@pytest.fixture(scope="module")
def bench():
    return load_benchmark("gpu/batch_gpu_seconds.py", "physgs_batch_gpu_seconds")


_LOG_END = """Printing profiling stats, from longest to shortest duration in seconds
VanillaPipeline.get_eval_image_metrics_and_images: 0.0500
Trainer.train_iteration: 0.0125
VanillaPipeline.get_train_loss_dict: 0.0070
"""


def _scene(out: Path, name: str, train: dict | None, export: dict | None, log: str = _LOG_END) -> None:
    d = out / "scenes" / name
    d.mkdir(parents=True)
    (d / "train.log").write_text("Step (% Done) ...\nTrainer.train_iteration: 9.9\n" + log)  # the last line counts
    stages: dict = {"perceive": {"status": "done", "metrics": {"vlm_calls": 3}}}
    if train is not None:
        stages["train"] = train
        train.setdefault("outputs", {}).update(log=str(d / "train.log"))
    if export is not None:
        stages["export"] = export
    (d / "state.json").write_text(json.dumps({"scene": name, "stages": stages}))


def _train(seconds: float, device: str = "cuda", ckpt: str = "step-000000999.ckpt") -> dict:
    return {"status": "done", "seconds": seconds, "outputs": {"checkpoint": f"/r/nerfstudio_models/{ckpt}"},
            "metrics": {"train_seconds": seconds, "device": device}}  # fmt: skip


def _export(seconds: float, device: str = "cuda", mass: float = 1.5) -> dict:
    return {"status": "done", "seconds": seconds, "metrics": {"export_seconds": seconds, "device": device,
                                                              "mass_kg": mass}}  # fmt: skip


def test_per_scene_gpu_seconds_split_into_steps_and_the_rest(bench, tmp_path) -> None:
    _scene(tmp_path, "mug", _train(30.0), _export(5.0))
    _scene(tmp_path, "chair", _train(40.0), _export(7.0, mass=6.0))
    _scene(tmp_path, "vase", _train(35.0), {"status": "failed", "seconds": 4.0, "device": "cuda", "error": "export: x",
                                            "error_kind": "export failed"})  # fmt: skip
    _scene(tmp_path, "pan", {"status": "running"}, None)  # stopped mid-training
    res = bench.summarise(tmp_path, "physgs")
    mug = res["scenes"]["mug"]
    assert mug["gpu_s"] == pytest.approx(35.0) and mug["steps"] == 1000 and mug["step_ms"] == pytest.approx(12.5)
    assert mug["train_other_s"] == pytest.approx(30.0 - 1000 * 0.0125)
    vase = res["scenes"]["vase"]  # the failed export held the GPU 4 s
    assert vase["gpu_s"] == pytest.approx(39.0) and vase["export_failed_s"] == 4.0 and not vase["complete"]
    assert res["scenes"]["pan"]["gpu_s"] == 0.0 and "train_s" not in res["scenes"]["pan"]
    assert (res["scenes_found"], res["scenes_complete"], res["steps"]) == (4, 2, [1000])
    gpu = res["per_complete_scene"]["gpu_s"]  # complete scenes only: 35 and 47
    assert (gpu["n"], gpu["median"], gpu["min"], gpu["max"]) == (2, pytest.approx(41.0), 35.0, 47.0)
    assert res["totals"]["gpu_seconds"] == pytest.approx(35 + 47 + 39)  # summary.py's own count, failed included
    assert res["dry_run_estimate_s_per_scene_at_these_steps"] == pytest.approx(1000 * 0.0123 + 6.0)


def test_cpu_stages_are_no_gpu_seconds_and_a_log_without_profiler_gives_no_split(bench, tmp_path) -> None:
    _scene(tmp_path, "mug", _train(30.0, device="cpu", ckpt="step-000000029.ckpt"), _export(5.0, device="cpu"))
    (tmp_path / "scenes" / "mug" / "train.log").write_text("Step (% Done)\n10 (33.33%)\n")  # no profiler lines
    res = bench.summarise(tmp_path, "physgs-lite")
    mug = res["scenes"]["mug"]
    assert mug["gpu_s"] == 0.0 and mug["steps"] == 30 and mug["train_s"] == 30.0 and mug["complete"]
    assert mug["step_ms"] is None and "train_other_s" not in mug
    assert res["per_complete_scene"]["gpu_s"]["median"] == 0.0 and res["per_complete_scene"]["step_ms"] is None
    assert bench.mean_step_seconds(tmp_path / "nothing.log") is None
    assert bench.steps_trained(None) is None and bench.steps_trained("/x/step-000000499.ckpt") == 500
