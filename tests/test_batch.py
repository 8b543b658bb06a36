"""`physgs batch`: scene discovery, state policy, rate limit, dry-run plan (fast), and end to end on 3 tiny
generated scenes plus a broken one: local backend killed mid-run and resumed (VLM calls counted at the local
test server), and Ray in local mode with the shared rate-limit actor."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers.perception_server import FakeServer, ok

from physgs_nerfstudio.batch.command import BatchCommand
from physgs_nerfstudio.batch.plan import EstimateRates, plan_scene
from physgs_nerfstudio.batch.ratelimit import LocalRateLimiter, TokenBucket
from physgs_nerfstudio.batch.runner import Policy, needs_run
from physgs_nerfstudio.batch.scenes import SceneListError, discover
from physgs_nerfstudio.batch.state import load_state, save_state

GOOD = ("bottle", "hammer", "mug")
TINY = dict(method="physgs-lite", iterations=10, device="cpu", export_resolution=48, n_samples=300,
            vlm="openai", api_key_env="", max_concurrency=2, progress=False)  # fmt: skip


def _dataset(path: Path, frames: int = 2) -> Path:
    path.mkdir(parents=True)
    (path / "transforms.json").write_text(json.dumps({"frames": [{"file_path": f"images/{i}.png"} for i in range(frames)]}))
    return path


# ----------------------------------------------------------------------------------------------- fast
def test_discover_folder_list_abo_and_duplicates(tmp_path):
    a, b = _dataset(tmp_path / "f" / "a"), _dataset(tmp_path / "f" / "b")
    (b / "ground_truth.json").write_text("{}")
    (tmp_path / "f" / "not_a_dataset").mkdir()
    s = discover(tmp_path / "f")
    assert [(x.name, x.truth) for x in s.scenes] == [("a", "none"), ("b", "synth")] and s.kind == "folder"
    assert [x.name for x in discover(a).scenes] == ["a"]
    lst = tmp_path / "list.txt"
    lst.write_text(f"# my scenes\nf/b\n{a}  # absolute\n\n")
    assert [x.data for x in discover(lst).scenes] == [b, a]
    _dataset(tmp_path / "g" / "a")
    lst.write_text(f"{a}\n{tmp_path / 'g' / 'a'}\n")
    with pytest.raises(SceneListError, match="two scenes are named 'a'"):
        discover(lst)
    lst.write_text("f/missing\n")
    with pytest.raises(SceneListError, match=r"list.txt:1: .*missing has no transforms.json"):
        discover(lst)
    root = tmp_path / "data" / "abo_500"
    for n in ("A1_x", "B2_y", "C3_z"):
        _dataset(root / "scenes" / n)
    (root / "filtered_product_weights.json").write_text(json.dumps({"A1": 1.0, "B2": 2.0, "C3": 3.0}))
    (root / "splits.json").write_text(json.dumps({"train": ["A1_x"], "val": [], "test": ["C3", "B2_y", "Q9"]}))
    abo = discover(tmp_path / "data" / "abo_500", split="test")
    assert [x.name for x in abo.scenes] == ["C3_z", "B2_y"] and abo.kind == "abo500" and abo.scenes[0].truth == "abo500"
    assert [x.name for x in discover(root, split="train+val").scenes] == ["A1_x"]
    with pytest.raises(SceneListError, match="no split nope"):
        discover(root, split="nope")


def test_policy_skips_done_retries_failed_until_max_and_forces_once_per_run():
    state = {"stages": {"perceive": {"status": "done"}, "train": {"status": "failed", "attempts": 1},
                        "export": {"status": "running", "attempts": 1}}}  # fmt: skip
    p = Policy()
    assert needs_run(state, "perceive", p) == (False, "done")
    assert needs_run(state, "train", p) == (True, "retry")
    assert needs_run(state, "export", p) == (True, "interrupted")
    state["stages"]["train"]["attempts"] = 2
    assert needs_run(state, "train", p)[0] is False
    assert needs_run(state, "train", Policy(retry_failed=True)) == (True, "retry")
    forced = Policy(force=("train",))
    assert needs_run(state, "perceive", forced, "run1") == (False, "done")  # stages before the forced one stay
    assert needs_run(state, "train", forced, "run1") == (True, "forced")
    state["forced"] = {"train": "run1", "export": "run1"}  # what run_stage records when it redoes them
    assert needs_run(state, "train", forced, "run1")[0] is False  # a failed stage, forced already in run1
    assert needs_run(state, "train", forced, "run2") == (True, "forced")


def test_token_bucket_waits_for_requests_and_charged_tokens():
    now = [0.0]
    b = TokenBucket(requests_per_minute=2, tokens_per_minute=600, clock=lambda: now[0])
    assert b.reserve(1, 0) == 0 and b.reserve(1, 0) == 0  # starts with a minute's worth
    assert b.reserve(1, 0) == pytest.approx(30.0)  # 1 request short at 2/min
    now[0] = 90.0  # refilled to 2 requests (capped)... minus the one booked in debt
    assert b.reserve(0, 900) == 0  # charging tokens never waits
    # tokens: 600 - 900 = -300 debt at 10 tokens/s -> 30 s; requests: 2 - 1 (debt) - 1 = 0 -> no wait
    assert b.reserve(1, 0) == pytest.approx(30.0)
    slept = []
    LocalRateLimiter(TokenBucket(requests_per_minute=60, clock=lambda: 0.0), sleep=slept.append).acquire(61, 0)
    assert slept == [pytest.approx(1.0)]
    with pytest.raises(ValueError, match="requests_per_minute must be > 0"):
        TokenBucket(0)


def test_openai_backend_calls_the_injected_rate_limiter():
    from physgs_nerfstudio.perception import vlm
    from physgs_nerfstudio.perception.prompts import VLMRequest

    calls = []

    class Recorder:
        def acquire(self, requests, tokens):
            calls.append((requests, tokens))

    with FakeServer(lambda i, body: ok(usage=(70, 30)) if i else (503, {}, {}, 0.0)) as srv:
        vlm.set_rate_limiter(Recorder())
        try:
            backend = vlm.OpenAIBackend(vlm.OpenAIConfig(base_url=srv.base_url, api_key_env="", backoff_base_s=0.01),
                                        sleep=lambda s: None)  # fmt: skip
        finally:
            vlm.set_rate_limiter(None)
        backend.query(VLMRequest(view="v", mask_id=1, level="part", system="s", text="t", images=(), mime="image/png"))
    assert calls == [(1, 0), (1, 0), (0, 100)]  # one request per HTTP attempt (retry included), then its tokens
    assert isinstance(vlm.OpenAIBackend(vlm.OpenAIConfig(api_key_env="")).rate_limiter, vlm._NoRateLimit)


def test_dry_run_plan_from_state_and_settings(tmp_path, capsys):
    data = _dataset(tmp_path / "scenes" / "s1", frames=10)
    _dataset(tmp_path / "scenes" / "s2", frames=4)
    out = tmp_path / "out"
    save_state(out, "s2", {"stages": {"perceive": {"status": "done", "metrics": {"vlm_calls": 12}},
                                      "train": {"status": "done"}}})  # fmt: skip
    rates = EstimateRates(masks_per_view=2.5, prompt_tokens_per_call=1000, completion_tokens_per_call=100,
                          seconds_per_iteration=0.01, train_seconds_per_view=1.5)  # fmt: skip
    from physgs_nerfstudio.batch.scenes import Scene

    p = plan_scene(Scene("s1", data), ["perceive", "train", "export"], out, Policy(), "physgs", 2000, None, rates)
    assert (p.calls, p.prompt_tokens, p.completion_tokens) == (25, 25000, 2500)
    assert p.device_seconds == pytest.approx(2000 * 0.01 + 10 * 1.5 + 6.0)  # steps, outside the steps (10 views), export
    tot = BatchCommand(scenes=tmp_path / "scenes", output_dir=out, dry_run=True, iterations=2000, estimate=rates,
                       usd_per_1k_prompt_tokens=0.01).run()  # fmt: skip
    assert tot["vlm_calls"] == 25 and tot["stages"] == 4  # s2 only needs export
    assert tot["cost_usd"] == pytest.approx(25 * 1000 / 1000 * 0.01)
    assert "Nothing was run" in capsys.readouterr().out and not (out / "scenes" / "s1").exists()


def test_ray_backend_without_ray_says_how_to_install(tmp_path, monkeypatch):
    _dataset(tmp_path / "s" / "a")
    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(SystemExit, match=r"pip install .*\[ray\]"):
        BatchCommand(scenes=tmp_path / "s", output_dir=tmp_path / "o", backend="ray", device="cpu").run()


def test_batch_eval_scores_abo500_split_unclamped(tmp_path):
    from rich.console import Console

    from physgs_nerfstudio.batch.summary import collect, run_batch_eval, totals

    root = tmp_path / "abo_500"
    for n in ("A1_x", "B2_y"):
        _dataset(root / "scenes" / n)
    (root / "filtered_product_weights.json").write_text(json.dumps({"A1": 2.0, "B2": 10.0}))
    (root / "splits.json").write_text(json.dumps({"test": ["A1_x", "B2_y"]}))
    out = tmp_path / "out"
    for n, kg in (("A1_x", 3.0), ("B2_y", 250.0)):
        rep = out / "scenes" / n / "export" / "report.json"
        rep.parent.mkdir(parents=True)
        rep.write_text(json.dumps({"mass": {"mean_kg": kg, "median_kg": kg, "n_samples": 8, "simulated": False,
                                            "units": {"mass": "kg"}}}))  # fmt: skip
        save_state(out, n, {"stages": {"export": {"status": "done", "metrics": {"device": "cuda", "export_seconds": 2.0}},
                                       "train": {"status": "done", "metrics": {"device": "cuda", "train_seconds": 5.0}}}})  # fmt: skip
    scene_set = discover(root, split="test")
    states = collect(out, [s.name for s in scene_set.scenes])
    result = run_batch_eval(out, scene_set, states, Console(quiet=True))
    preds = {r.item: r.pred for r in result.items}
    assert preds == {"A1_x": pytest.approx(3.0), "B2_y": pytest.approx(250.0)}  # as predicted: no clamp (issue 17)
    assert (out / "eval" / "eval.json").is_file() and (out / "eval" / "summary.csv").is_file()
    tot = totals(states)
    assert tot["gpu_seconds"] == pytest.approx(14.0) and tot["complete"] == 0  # perceive never ran


def test_local_backend_overlaps_next_perception_with_training_and_uses_each_gpu(monkeypatch):
    import threading

    from physgs_nerfstudio.batch import local
    from physgs_nerfstudio.batch.scenes import Scene

    events, lock = [], threading.Lock()

    def fake_stage(scene, stage, settings, output_dir, policy, run_id, gpu=None):
        with lock:
            events.append(("start", scene.name, stage, gpu))
        time.sleep(0.15 if stage == "train" else 0.05)
        with lock:
            events.append(("end", scene.name, stage, gpu))

    monkeypatch.setattr(local, "run_stage", fake_stage)
    scenes = [Scene(n, Path(n)) for n in ("a", "b", "c")]
    local.run_local(scenes, ["perceive", "train", "export"], None, Path("o"), Policy(), "r", overlap_perception=True)
    pos = {e[:3]: i for i, e in enumerate(events)}
    for n in "abc":
        assert pos[("end", n, "perceive")] < pos[("start", n, "train")] < pos[("end", n, "train")] < pos[("start", n, "export")]
    assert pos[("start", "b", "perceive")] < pos[("end", "a", "train")]  # b is perceived while a trains
    events.clear()
    local.run_local(scenes, ["train", "export"], None, Path("o"), Policy(), "r", gpus=(0, 1))
    gpus_used = {e[3] for e in events if e[2] == "train"}
    assert gpus_used == {0, 1} and len([e for e in events if e[0] == "end"]) == 6
    events.clear()
    local.run_local(scenes, ["perceive", "train", "export"], None, Path("o"), Policy(), "r")  # sequential
    assert [e[1:3] for e in events if e[0] == "start"] == [(n, s) for n in "abc" for s in ("perceive", "train", "export")]


def test_a_failed_gpu_stage_records_its_device_and_counts_as_gpu_seconds(tmp_path, monkeypatch):
    from physgs_nerfstudio.batch import runner
    from physgs_nerfstudio.batch import stages as st
    from physgs_nerfstudio.batch.scenes import Scene
    from physgs_nerfstudio.batch.summary import collect, totals

    def failing_export(scene, settings, out, config):
        time.sleep(0.2)  # the GPU is held while the export runs, whether it ends well or not
        raise st.StageError("export: carving left no solid voxel", "export failed")

    monkeypatch.setattr(st, "run_export", failing_export)
    scene, out = Scene("a", _dataset(tmp_path / "a")), tmp_path / "out"
    save_state(out, "a", {"stages": {"perceive": {"status": "done"}, "train": {
        "status": "done", "outputs": {"config": "c.yml"}, "metrics": {"device": "cuda", "train_seconds": 5.0}}}})
    for device in ("cuda", "cpu"):
        rec = runner.run_stage(scene, "export", st.StageSettings(device=device), out, Policy(retry_failed=True), "r")
        assert rec["status"] == "failed" and rec["device"] == device and rec["seconds"] >= 0.2
        tot = totals(collect(out, ["a"]))
        failed = rec["seconds"] if device == "cuda" else 0.0  # CPU seconds are no GPU-seconds
        assert tot["gpu_seconds_failed"] == pytest.approx(failed)
        assert tot["gpu_seconds"] == pytest.approx(5.0 + failed) and tot["export_seconds"] == 0.0


# ----------------------------------------------------------------------------------------------- end to end
@pytest.fixture(scope="module")
def tiny_scenes(tmp_path_factory):
    from physgs_nerfstudio.synth.dataset import SynthConfig, generate_scene

    root = tmp_path_factory.mktemp("batch_scenes")
    for name in GOOD:
        generate_scene(SynthConfig(out=root / "src" / name, object=name, views=8, resolution=48, num_points=2000))
    return root / "src"


def _copy(src: Path, dst: Path, broken: bool = False) -> Path:
    import shutil

    shutil.copytree(src, dst)
    if broken:
        shutil.copytree(src / "mug", dst / "broken")
        first = min((dst / "broken" / "images").iterdir())
        first.write_bytes(b"not a png")
    return dst


def _body_key(body: dict) -> str:
    return hashlib.sha256(json.dumps(body.get("messages"), sort_keys=True).encode()).hexdigest()


def _done(state: dict) -> dict:
    return {s: r for s, r in state["stages"].items() if r["status"] == "done"}


@pytest.mark.slow
def test_local_batch_killed_and_resumed_with_a_broken_scene(tiny_scenes, tmp_path):
    scenes = _copy(tiny_scenes, tmp_path / "scenes", broken=True)  # order: bottle broken hammer mug
    out = tmp_path / "out"
    with FakeServer() as srv:
        args = ["--scenes", str(scenes), "--output-dir", str(out), "--base-url", srv.base_url, "--method",
                "physgs-lite", "--iterations", "10", "--device", "cpu", "--export-resolution", "48",
                "--n-samples", "300", "--api-key-env", "", "--max-concurrency", "2", "--no-progress"]  # fmt: skip
        env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).parents[1]), os.environ.get("PYTHONPATH", "")])}
        proc = subprocess.Popen([sys.executable, "-m", "physgs_nerfstudio.cli", "batch", *args], env=env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)  # fmt: skip
        deadline = time.time() + 240
        while time.time() < deadline and proc.poll() is None:  # kill while hammer trains
            if load_state(out, "hammer")["stages"].get("train", {}).get("status") == "running":
                break
            time.sleep(0.3)
        assert proc.poll() is None, "the batch ended before the kill point"
        time.sleep(2.0)  # ns-train is running
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        before = {n: load_state(out, n) for n in ("bottle", "broken", "hammer", "mug")}
        calls_before = len(srv.requests)
        assert set(_done(before["bottle"])) == {"perceive", "train", "export"}
        assert before["broken"]["stages"]["perceive"]["status"] == "failed"
        assert before["hammer"]["stages"]["train"]["status"] == "running" and "mug" not in [
            n for n, s in before.items() if s["stages"]]  # fmt: skip
        assert calls_before > 0
        # rerun in-process to the end
        cmd = BatchCommand(scenes=scenes, output_dir=out, base_url=srv.base_url, **TINY)
        tot = cmd.run()
        after = {n: load_state(out, n) for n in before}
        keys = [_body_key(b) for b in srv.requests]
    # no finished stage reran: their records (start/finish times) are unchanged
    for name, state in before.items():
        for stage, rec in _done(state).items():
            assert after[name]["stages"][stage] == rec, (name, stage)
    assert after["hammer"]["stages"]["train"]["reason"] == "interrupted"
    for name in GOOD:
        assert set(_done(after[name])) == {"perceive", "train", "export"}, after[name]
        assert (out / "scenes" / name / "export" / "report.json").is_file()
    # no VLM request was sent twice, and the batch counted exactly what the server saw
    assert len(keys) == len(set(keys)) and len(keys) > calls_before
    assert tot["vlm_calls"] == len(keys) and tot["prompt_tokens"] == 100 * len(keys)
    # the broken scene: failed again with a one-line reason, counted by reason; the others went on
    b = after["broken"]["stages"]["perceive"]
    assert b["status"] == "failed" and b["attempts"] == 2 and "\n" not in b["error"] and "image" in b["error"]
    assert tot["failures_by_reason"] == {"perceive: bad input": 1} and tot["complete"] == 3
    ev = json.loads((out / "eval" / "eval.json").read_text())
    assert (out / "eval" / "summary.csv").is_file() and ev
    summary = json.loads((out / "batch_summary.json").read_text())
    assert summary["totals"]["vlm_calls"] == len(keys)
    # a third run has nothing to do but retry nothing: the broken scene reached --max-attempts
    with FakeServer() as srv2:
        again = BatchCommand(scenes=scenes, output_dir=out, base_url=srv2.base_url, **TINY).run()
        assert len(srv2.requests) == 0
    assert again["complete"] == 3 and {n: load_state(out, n) for n in before} == after


@pytest.mark.slow
def test_ray_local_mode_three_scenes_shared_rate_limit(tiny_scenes, tmp_path):
    ray = pytest.importorskip("ray")
    scenes = _copy(tiny_scenes, tmp_path / "scenes")
    out = tmp_path / "out"
    try:
        with FakeServer() as srv:
            cmd = BatchCommand(scenes=scenes, output_dir=out, base_url=srv.base_url, backend="ray", ray_num_cpus=2,
                               requests_per_minute=100000, tokens_per_minute=10_000_000, **TINY)  # fmt: skip
            tot = cmd.run()
            n = len(srv.requests)
    finally:
        ray.shutdown()
    assert tot["complete"] == 3 and tot["failures"] == 0 and tot["vlm_calls"] == n > 0
    limiter = json.loads((out / "batch_summary.json").read_text())["rate_limiter"]
    assert limiter["requests"] == n and limiter["tokens"] == 120 * n  # every call went through the one actor
    for name in GOOD:
        assert (out / "scenes" / name / "export" / "report.json").is_file()
    assert (out / "eval" / "eval.json").is_file()
