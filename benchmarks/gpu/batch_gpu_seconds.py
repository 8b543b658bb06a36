"""GPU-seconds per scene of a `physgs batch` run, read from the batch's own records (issue 14).

    python3 benchmarks/gpu/batch_gpu_seconds.py --output-dir BATCH_OUT --out batch_gpu.json

Reads BATCH_OUT/scenes/<scene>/state.json: the train and export stages' seconds and the device they ran on,
counted as `physgs_nerfstudio/batch/summary.py` counts GPU-seconds (train + export seconds of stages run on
CUDA; training is timed around the whole `ns-train` process). From each scene's train.log it reads nerfstudio's
profiler line ``Trainer.train_iteration: S`` (mean seconds of one training step) and from the checkpoint's
name the steps trained, and splits training into steps x step time and the rest (process start-up, dataset
loading, callbacks such as densification and lifting, evaluation, checkpoint). A batch stopped part-way is read
as it stands: a stage still running when it was stopped counts nothing; a failed one counts its seconds in the
scene's GPU-seconds (`<stage>_failed_s`), and the per-scene statistics are over complete scenes. Also prints `physgs batch --dry-run`'s
per-scene estimate at the same steps (`batch/plan.py`'s rates), for comparison.
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
from pathlib import Path

from physgs_nerfstudio.batch.plan import DEFAULT_ITERATIONS, EXPORT_SECONDS, SECONDS_PER_ITERATION
from physgs_nerfstudio.batch.state import load_state
from physgs_nerfstudio.batch.summary import totals

_ITER = re.compile(r"Trainer\.train_iteration:\s*([0-9.eE+-]+)")
_CKPT = re.compile(r"step-(\d+)\.ckpt$")


def mean_step_seconds(log: Path) -> float | None:
    """nerfstudio's profiler line at the end of ``ns-train`` (the last one in the log), or None."""
    try:
        found = _ITER.findall(log.read_text(errors="replace"))
    except OSError:
        return None
    return float(found[-1]) if found else None


def steps_trained(checkpoint: str | None) -> int | None:
    """Steps of a finished run from its last checkpoint's name (step-000000499.ckpt: steps 0..499 -> 500)."""
    m = _CKPT.search(checkpoint or "")
    return int(m.group(1)) + 1 if m else None


def scene_record(state: dict) -> dict:
    st = state.get("stages", {})
    train, export = st.get("train") or {}, st.get("export") or {}
    rec: dict = {"status": {s: (st.get(s) or {}).get("status") for s in ("perceive", "train", "export")}}
    gpu = 0.0
    for name, stage, key in (("train", train, "train_seconds"), ("export", export, "export_seconds")):
        if stage.get("status") == "failed":  # held the device all the same (summary.py counts it too)
            rec[f"{name}_failed_s"] = stage.get("seconds", 0.0)
            gpu += stage.get("seconds", 0.0) if stage.get("device") == "cuda" else 0.0
        if stage.get("status") != "done":
            continue
        m = stage.get("metrics", {})
        rec[f"{name}_s"] = m.get(key, 0.0)
        rec[f"{name}_device"] = m.get("device")
        if m.get("device") == "cuda":
            gpu += m.get(key, 0.0)
    if train.get("status") == "done":
        out = train.get("outputs", {})
        steps, step_s = steps_trained(out.get("checkpoint")), mean_step_seconds(Path(out.get("log", "")))
        rec.update(steps=steps, step_ms=None if step_s is None else step_s * 1000)
        if steps is not None and step_s is not None:
            rec["train_other_s"] = rec["train_s"] - steps * step_s
    rec["gpu_s"] = gpu
    rec["complete"] = train.get("status") == "done" and export.get("status") == "done"
    mass = export.get("metrics", {}).get("mass_kg") if export.get("status") == "done" else None
    rec["mass_kg"] = mass
    return rec


def _stats(values: list[float]) -> dict | None:
    if not values:
        return None
    return {"n": len(values), "median": statistics.median(values), "mean": statistics.fmean(values),
            "min": min(values), "max": max(values)}  # fmt: skip


def summarise(output_dir: Path, method: str = "physgs") -> dict:
    names = sorted(p.parent.name for p in (Path(output_dir) / "scenes").glob("*/state.json"))
    states = {n: load_state(output_dir, n) for n in names}
    scenes = {n: scene_record(s) for n, s in states.items()}
    done = [r for r in scenes.values() if r["complete"]]
    per_scene = {k: _stats([r[k] for r in done if r.get(k) is not None])
                 for k in ("gpu_s", "train_s", "export_s", "step_ms", "train_other_s")}  # fmt: skip
    steps = sorted({r["steps"] for r in scenes.values() if r.get("steps") is not None})
    res = {"output_dir": str(output_dir), "method": method, "scenes_found": len(names),
           "scenes_complete": len(done), "steps": steps, "default_steps": DEFAULT_ITERATIONS.get(method),
           "per_complete_scene": per_scene, "scenes": scenes, "totals": totals(states)}  # fmt: skip
    if len(steps) == 1 and method in SECONDS_PER_ITERATION:
        res["dry_run_estimate_s_per_scene_at_these_steps"] = steps[0] * SECONDS_PER_ITERATION[method] + EXPORT_SECONDS
    return res


def _fmt(x: float | None, spec: str = ".1f") -> str:
    return "-" if x is None else format(x, spec)


def print_report(res: dict) -> None:
    print(f"{res['scenes_complete']}/{res['scenes_found']} scenes trained and exported; steps trained "
          f"{res['steps'] or '-'} (the method's default: {res['default_steps']})")  # fmt: skip
    print(f"{'scene':10s} {'train s':>8s} {'export s':>9s} {'GPU s':>7s} {'steps':>6s} {'step ms':>8s} "
          f"{'other s':>8s} {'mass kg':>8s}  status")  # fmt: skip
    for name, r in res["scenes"].items():
        status = " ".join(f"{k}={v}" for k, v in r["status"].items())
        train_s = r.get("train_s", r.get("train_failed_s"))
        export_s = r.get("export_s", r.get("export_failed_s"))
        print(f"{name:10s} {_fmt(train_s):>8s} {_fmt(export_s):>9s} {_fmt(r['gpu_s']):>7s} "
              f"{_fmt(r.get('steps'), 'd') if r.get('steps') else '-':>6s} {_fmt(r.get('step_ms'), '.2f'):>8s} "
              f"{_fmt(r.get('train_other_s')):>8s} {_fmt(r.get('mass_kg'), '.3g'):>8s}  {status}")  # fmt: skip
    for key, label in (("gpu_s", "GPU-seconds"), ("train_s", "train seconds"), ("export_s", "export seconds"),
                       ("step_ms", "step ms"), ("train_other_s", "train seconds outside the steps")):  # fmt: skip
        s = res["per_complete_scene"][key]
        if s:
            print(f"per complete scene, {label}: median {s['median']:.2f}, mean {s['mean']:.2f}, "
                  f"min {s['min']:.2f}, max {s['max']:.2f} (n={s['n']})")  # fmt: skip
    if "dry_run_estimate_s_per_scene_at_these_steps" in res:
        print(f"physgs batch --dry-run's estimate per scene at {res['steps'][0]} steps: "
              f"{res['dry_run_estimate_s_per_scene_at_these_steps']:.1f} device s")  # fmt: skip
    t = res["totals"]
    print(f"batch totals: GPU-seconds {t['gpu_seconds']:.1f} (train {t['train_seconds']:.1f} and export "
          f"{t['export_seconds']:.1f} of finished stages, {t.get('gpu_seconds_failed', 0.0):.1f} of failed ones), "
          f"complete {t['complete']}/{t['scenes']}, failures {t['failures_by_reason']}")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--output-dir", type=Path, required=True, help="the batch's --output-dir")
    ap.add_argument("--method", default="physgs")
    ap.add_argument("--out", type=Path, default=None, help="write the JSON here")
    args = ap.parse_args()
    if not (args.output_dir / "scenes").is_dir():
        raise SystemExit(f"{args.output_dir}: no scenes/ folder; pass the --output-dir of a physgs batch run")
    res = summarise(args.output_dir, args.method)
    if args.out:
        args.out.write_text(json.dumps(res, indent=2))
    print_report(res)


if __name__ == "__main__":
    main()
