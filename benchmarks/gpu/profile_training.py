"""Where a training step's time goes: torch.profiler over a few steps of each method (same loop as
bench_training.py). Prints the top operators by CUDA and by CPU self time.

    python3 benchmarks/gpu/profile_training.py --data SCENE [--methods splatfacto-big physgs]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import torch
from bench_training import build_trainer, stepper  # same directory
from torch.profiler import ProfilerActivity, profile


def run(method: str, data: Path, warmup: int, steps: int, rows: int) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        trainer = build_trainer(method, data, warmup + steps + 10_000, Path(tmp))  # no last-step lifting
        step_fn = stepper(trainer)
        for step in range(warmup):
            step_fn(step)
        torch.cuda.synchronize()
        with profile(activities=[ProfilerActivity.CPU, ProfilerActivity.CUDA]) as prof:
            for step in range(warmup, warmup + steps):
                step_fn(step)
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        for step in range(warmup + steps, warmup + steps + 200):  # the same steps' wall time, unprofiled
            step_fn(step)
        torch.cuda.synchronize()
        wall_ms = (time.perf_counter() - t0) / 200 * 1000
        events = prof.key_averages()
        cuda_us = sum(getattr(e, "self_device_time_total", getattr(e, "self_cuda_time_total", 0)) for e in events)
        cpu_us = sum(e.self_cpu_time_total for e in events)
        print(f"===== {method}: {steps} steps after {warmup}: per step, GPU kernels {cuda_us / steps / 1000:.3f} ms, "
              f"host (profiled ops) {cpu_us / steps / 1000:.3f} ms, {trainer.pipeline.model.num_points} Gaussians; "
              f"unprofiled wall {wall_ms:.3f} ms per step over the next 200 =====")
        print(prof.key_averages().table(sort_by="cuda_time_total", row_limit=rows, max_name_column_width=60))
        print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=rows, max_name_column_width=60))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--methods", nargs="+", default=["splatfacto-big", "physgs"])
    ap.add_argument("--warmup", type=int, default=300)
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--rows", type=int, default=18)
    args = ap.parse_args()
    for m in args.methods:
        run(m, args.data, args.warmup, args.steps, args.rows)


if __name__ == "__main__":
    main()
