"""`physgs batch` on the generated suite: local backend (sequential) vs Ray with 2 workers on this machine.

    python benchmarks/batch.py --out /tmp/batch_bench [--objects 12] [--views 8] [--resolution 48] [--iterations 30]

Each backend gets its own copy of the scenes (perception writes into the datasets). Simulated VLM,
physgs-lite on the CPU. Reports the wall times, their ratio (local / Ray), and Ray's overhead per task two
ways: (a) an upper bound, (2 x Ray wall - sum of the stage times measured inside the tasks) / tasks, which
also counts idle workers at the tail; (b) a rerun on Ray with every stage done (each task only reads its
state and returns), (wall - ray.init) / tasks. Writes OUT/batch_bench.json and prints one table.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import format_table, write_summary

from physgs_nerfstudio.batch.command import BatchCommand
from physgs_nerfstudio.synth.dataset import SynthConfig, generate_scene
from physgs_nerfstudio.synth.objects import SUITE


def stage_seconds(out: Path) -> tuple[float, int]:
    total, n = 0.0, 0
    for f in (out / "scenes").glob("*/state.json"):
        for rec in json.loads(f.read_text())["stages"].values():
            total += rec.get("seconds", 0.0)
            n += 1
    return total, n


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", type=Path, default=Path("/tmp/batch_bench"))
    ap.add_argument("--objects", type=int, default=len(SUITE))
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--resolution", type=int, default=48)
    ap.add_argument("--iterations", type=int, default=30)
    args = ap.parse_args()
    shutil.rmtree(args.out, ignore_errors=True)
    src = args.out / "src"
    for name in SUITE[: args.objects]:
        generate_scene(SynthConfig(out=src / name, object=name, views=args.views, resolution=args.resolution,
                                   num_points=4000))  # fmt: skip
    shared = {"method": "physgs-lite", "iterations": args.iterations, "device": "cpu", "vlm": "simulated",
                  "export_resolution": 48, "n_samples": 500, "progress": False}  # fmt: skip
    res: dict = {"objects": args.objects, "views": args.views, "resolution": args.resolution,
                 "iterations": args.iterations}  # fmt: skip
    for backend in ("local", "ray"):
        scenes = args.out / f"scenes_{backend}"
        shutil.copytree(src, scenes)
        extra = {"backend": "ray", "ray_num_cpus": 2} if backend == "ray" else {}
        t0 = time.perf_counter()
        tot = BatchCommand(scenes=scenes, output_dir=args.out / f"out_{backend}", **shared, **extra).run()
        wall = time.perf_counter() - t0
        inside, tasks = stage_seconds(args.out / f"out_{backend}")
        res[backend] = {"wall_s": wall, "stage_seconds_sum": inside, "tasks": tasks, "complete": tot["complete"],
                        "failures": tot["failures"]}  # fmt: skip
    import ray

    res["ratio_local_over_ray"] = res["local"]["wall_s"] / res["ray"]["wall_s"]
    r = res["ray"]
    res["ray_overhead_per_task_upper_bound_s"] = (2 * r["wall_s"] - r["stage_seconds_sum"]) / r["tasks"]
    # (b) the same batch again on the running Ray instance: every task finds its stage done
    t0 = time.perf_counter()
    BatchCommand(scenes=args.out / "scenes_ray", output_dir=args.out / "out_ray", **shared, backend="ray",
                 stages=("perceive", "train", "export")).run()  # fmt: skip
    res["ray_overhead_per_task_noop_s"] = (time.perf_counter() - t0) / r["tasks"]
    ray.shutdown()
    write_summary(args.out / "batch_bench.json", res)
    overhead = {"local": None, "ray": res["ray_overhead_per_task_noop_s"]}
    print(format_table(
        ("backend", "scenes", "wall s", "stage seconds (sum)", "tasks", "complete", "failures", "overhead s/task"),
        [(b, args.objects, res[b]["wall_s"], res[b]["stage_seconds_sum"], res[b]["tasks"], res[b]["complete"],
          res[b]["failures"], overhead[b]) for b in ("local", "ray")],
    ))  # fmt: skip
    print(f"local / Ray wall time: {res['ratio_local_over_ray']:.3f}")


if __name__ == "__main__":
    main()
