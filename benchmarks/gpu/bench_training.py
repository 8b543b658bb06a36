"""Training cost of the property head: `physgs` vs plain `splatfacto-big`, same data, same GPU, same steps.

    python3 benchmarks/gpu/bench_training.py --data SCENE --steps 2000 --out training.json

Both methods are built from their registered nerfstudio configs and stepped with the loop of nerfstudio's
Trainer.train (callbacks before/after each iteration, so densification and the physgs lifting pass are
included) but without viewer, evaluation or checkpoint writing. The iteration time is the median over
windows of 100 steps after a warm-up; the slowest after-iteration callback (for physgs: the one-off lifting
pass over all training views) is reported on its own. Peak memory is
torch.cuda.max_memory_allocated over the timed steps.
"""

from __future__ import annotations

import argparse
import copy
import json
import statistics
import tempfile
import time
from pathlib import Path

import torch


def _sync() -> None:
    if torch.cuda.is_available():
        torch.cuda.synchronize()


def _seed_points_without_open3d() -> None:
    """nerfstudio reads the seed PLY through Open3D, which GPU images often lack; splatfacto-big then reads
    it the way the physgs dataparser does (plyfile), so both methods start from the same points."""
    from nerfstudio.data.dataparsers.nerfstudio_dataparser import Nerfstudio

    from physgs_nerfstudio.nerfstudio.dataparser import PhysGSDataParser

    try:
        import open3d  # noqa: F401
    except ImportError:
        Nerfstudio._load_3D_points = PhysGSDataParser._load_3D_points  # type: ignore[method-assign]


def _no_lpips_download() -> None:
    """splatfacto builds LPIPS (AlexNet weights from the internet) in populate_modules; it is used only for
    evaluation metrics, never in a training step, so an offline machine times training with a stand-in."""
    import torchmetrics.image.lpip as lpip

    class _OfflineLPIPS(torch.nn.Module):
        def __init__(self, *args, **kwargs):
            super().__init__()

        def forward(self, *args, **kwargs):
            return torch.tensor(float("nan"))

    lpip.LearnedPerceptualImagePatchSimilarity = _OfflineLPIPS


def build_trainer(method: str, data: Path, steps: int, output_dir: Path, device: str = "cuda"):
    from nerfstudio.configs.method_configs import all_methods

    _seed_points_without_open3d()
    _no_lpips_download()

    # "physgs:material_every=8,material_downscale=2" sets model config fields (variants side by side)
    name, _, overrides = method.partition(":")
    config = copy.deepcopy(all_methods[name])
    for item in filter(None, overrides.split(",")):
        key, value = item.split("=")
        field_type = type(getattr(config.pipeline.model, key))
        setattr(config.pipeline.model, key, field_type(value))
    config.pipeline.datamanager.data = data
    config.pipeline.datamanager.dataparser.data = data
    config.max_num_iterations = steps
    config.output_dir = output_dir
    config.vis = "tensorboard"
    config.machine.device_type = device
    config.steps_per_eval_batch = config.steps_per_eval_image = config.steps_per_eval_all_images = 10**9
    config.steps_per_save = 10**9
    config.set_timestamp()
    trainer = config.setup(local_rank=0, world_size=1)
    trainer.setup()
    return trainer


def time_training(method: str, data: Path, steps: int, warmup: int, window: int, device: str = "cuda") -> dict:
    from nerfstudio.engine.callbacks import TrainingCallbackLocation

    with tempfile.TemporaryDirectory() as tmp:
        trainer = build_trainer(method, data, steps, Path(tmp), device)
        pipeline = trainer.pipeline
        model = pipeline.model
        slowest_callback = (0.0, -1)
        windows: list[float] = []
        _sync()
        t_window = time.perf_counter()
        for step in range(steps):
            if step == warmup:
                _sync()
                if torch.cuda.is_available():
                    torch.cuda.reset_peak_memory_stats()
                t_window = time.perf_counter()
            pipeline.train()
            for cb in trainer.callbacks:
                cb.run_callback_at_location(step, location=TrainingCallbackLocation.BEFORE_TRAIN_ITERATION)
            trainer.train_iteration(step)
            _sync()
            t_cb = time.perf_counter()
            for cb in trainer.callbacks:
                cb.run_callback_at_location(step, location=TrainingCallbackLocation.AFTER_TRAIN_ITERATION)
            _sync()
            slowest_callback = max(slowest_callback, (time.perf_counter() - t_cb, step))
            if step >= warmup and (step - warmup + 1) % window == 0:
                _sync()
                now = time.perf_counter()
                windows.append((now - t_window) / window)
                t_window = now
        num_gaussians = int(model.num_points)
        peak_mb = torch.cuda.max_memory_allocated() / 2**20 if torch.cuda.is_available() else float('nan')
        del trainer, pipeline, model
        if torch.cuda.is_available():
            torch.cuda.empty_cache()
    return {"method": method, "steps": steps, "warmup": warmup, "iter_s_median": statistics.median(windows),
            "iter_s_windows": windows, "slowest_after_callbacks_s": slowest_callback[0],
            "slowest_after_callbacks_step": slowest_callback[1], "peak_mem_mb": peak_mb,
            "final_gaussians": num_gaussians}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--warmup", type=int, default=200)
    ap.add_argument("--window", type=int, default=100)
    ap.add_argument("--methods", nargs="+", default=["splatfacto-big", "physgs"])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--device", default="cuda", help="cuda (the figures) or cpu (a smoke test of this script)")
    args = ap.parse_args()
    if args.device == "cuda":  # splatfacto-big calls gsplat directly: load the stamped build first (no rebuild)
        from physgs_nerfstudio.render.gsplat_build import prepare_gsplat

        print("gsplat:", prepare_gsplat(), flush=True)
    rows = [time_training(m, args.data, args.steps, args.warmup, args.window, args.device) for m in args.methods]
    for row in rows:
        print({k: v for k, v in row.items() if k != "iter_s_windows"}, flush=True)
    base = rows[0]["iter_s_median"]
    result = {"device": torch.cuda.get_device_name(0) if args.device == "cuda" else "cpu", "data": str(args.data), "rows": rows,
              "ratio_vs_first": [r["iter_s_median"] / base for r in rows]}  # fmt: skip
    args.out.write_text(json.dumps(result, indent=2))
    print("ratios vs", rows[0]["method"], result["ratio_vs_first"])


if __name__ == "__main__":
    main()
