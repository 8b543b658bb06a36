"""Where physgs's training step loses time against splatfacto-big: the same step with one physgs piece at a time
swapped for splatfacto's, each variant in its own process, the variants in turn over several rounds.

    python3 benchmarks/gpu/step_variants.py --data SCENE [--rounds 3] [--warmup 400] [--steps 400]

Variants (issue 13: the training iteration ratio):
- ``splatfacto-big``: the baseline;
- ``physgs``: as shipped;
- ``physgs-no-guard``: the screen-split guard's per-step reads of the camera size skipped (it reads the size once);
- ``physgs-splatfacto-outputs``: `get_outputs` in training replaced by splatfacto's own (the model's forward);
- ``physgs-no-callbacks``: the pipeline's lifting callback removed;
- ``physgs-no-maps``: the batch's material maps dropped by the datamanager.

Prints per variant the median wall time per step (synchronised at both ends of the timed steps, unprofiled) and its
ratio to splatfacto-big within each round; writes ``--out`` (JSON).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_training import build_trainer, stepper

VARIANTS = ("splatfacto-big", "physgs", "physgs-no-guard", "physgs-splatfacto-outputs", "physgs-no-callbacks",
            "physgs-no-maps")  # fmt: skip


def _sync() -> None:
    if torch.cuda.is_available():
        torch.cuda.synchronize()


def _patch(variant: str, trainer) -> None:
    pipeline = trainer.pipeline
    model = pipeline.model
    if variant == "physgs-no-guard":
        original = model._screen_split_guard

        def once(camera):
            if getattr(model, "_train_long_side", None) is None:
                original(camera)

        model._screen_split_guard = once
    elif variant == "physgs-splatfacto-outputs":
        from nerfstudio.models.splatfacto import SplatfactoModel

        physgs_outputs = model.get_outputs

        def outputs(camera):
            if model.training:
                return SplatfactoModel.get_outputs(model, camera)
            return physgs_outputs(camera)

        model.get_outputs = outputs
    elif variant == "physgs-no-callbacks":
        trainer.callbacks = [cb for cb in trainer.callbacks if getattr(cb.func, "__name__", "") != "_lift_on_schedule"]
    elif variant == "physgs-no-maps":
        dm = pipeline.datamanager
        next_train = dm.next_train

        def without_maps(step):
            camera, data = next_train(step)
            return camera, {k: v for k, v in data.items() if k not in ("material", "material_confidence")}

        dm.next_train = without_maps


def time_variant(variant: str, data: Path, warmup: int, steps: int, device: str = "cuda") -> dict:
    method = "splatfacto-big" if variant == "splatfacto-big" else "physgs"
    with tempfile.TemporaryDirectory() as tmp:
        trainer = build_trainer(method, data, warmup + steps + 10_000, Path(tmp), device)  # no last-step lifting
        _patch(variant, trainer)

        step_fn = stepper(trainer)
        for step in range(warmup):
            step_fn(step)
        _sync()
        t0 = time.perf_counter()
        for step in range(warmup, warmup + steps):
            step_fn(step)
        _sync()
        return {"variant": variant, "ms_per_step": (time.perf_counter() - t0) / steps * 1000,
                "gaussians": int(trainer.pipeline.model.num_points)}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--warmup", type=int, default=400)
    ap.add_argument("--steps", type=int, default=400)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.one:
        print("ROW " + json.dumps(time_variant(a.one, a.data, a.warmup, a.steps, a.device)), flush=True)
        return
    rows = []
    for r in range(a.rounds):
        for v in a.variants:
            cmd = [sys.executable, __file__, "--one", v, "--data", str(a.data), "--warmup", str(a.warmup),
                   "--steps", str(a.steps), "--device", a.device]  # fmt: skip
            proc = subprocess.run(cmd, check=False, capture_output=True, text=True)
            line = next((ln for ln in proc.stdout.splitlines() if ln.startswith("ROW ")), None)
            if line is None:
                print(f"[{v}] failed:\n{(proc.stdout + proc.stderr)[-1500:]}", flush=True)
                continue
            row = {**json.loads(line[4:]), "round": r}
            rows.append(row)
            print(json.dumps(row), flush=True)
    summary = {}
    for v in a.variants:
        ratios = []
        for r in range(a.rounds):
            mine = [x["ms_per_step"] for x in rows if x["variant"] == v and x["round"] == r]
            base = [x["ms_per_step"] for x in rows if x["variant"] == "splatfacto-big" and x["round"] == r]
            if mine and base:
                ratios.append(mine[0] / base[0])
        times = [x["ms_per_step"] for x in rows if x["variant"] == v]
        summary[v] = {"median_ms": statistics.median(times) if times else None,
                      "median_ratio": statistics.median(ratios) if ratios else None, "ratios": ratios}  # fmt: skip
        print(f"{v:28s} {summary[v]['median_ms'] or float('nan'):7.3f} ms  ratio {summary[v]['median_ratio']}")
    if a.out:
        a.out.write_text(json.dumps({"device": torch.cuda.get_device_name(0) if a.device == "cuda" else "cpu", "rows": rows, "summary": summary,
                                     "warmup": a.warmup, "steps": a.steps}, indent=1))  # fmt: skip


if __name__ == "__main__":
    main()
