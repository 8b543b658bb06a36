"""Training cost of the property head: `physgs` (and its variants) vs plain `splatfacto-big`, same data and steps.

    python3 benchmarks/gpu/bench_training.py --data SCENE --steps 1500 --warmup 300 --out training.json \
        --methods splatfacto-big physgs physgs:material_head=latent physgs:material_head=lifted

Each method runs in a process of its own (a second method in the same process inherits the first one's cached
allocations and compiled kernels: its peak memory reading is not its own). A method is a registered nerfstudio
method, optionally with config overrides after a colon, each a field of the model config or, failing that, of
the pipeline config: "physgs:material_head=lifted,lifting_every=500,lift_channel_chunk=16".

Each method is built from its registered config and stepped with the loop of nerfstudio's Trainer.train
(callbacks before/after each iteration, so densification and the physgs lifting pass are included) without
viewer, evaluation or checkpoint writing. Reported per method:

- iteration time: the median over windows of `--window` steps after `--warmup` steps, with and without the time
  spent in liftings (each lifting's time is reported on its own);
- peak memory (torch.cuda.max_memory_allocated, the peak reset before each phase) after the warm-up, per phase:
  the RGB-only training steps, the steps with a material pass (`PhysGSModel.material_pass_due`), the
  after-iteration callbacks (densification) of steps without a lifting, each lifting (`PhysGSPipeline.lift`,
  time and peak), and the largest of them (`peak_mem_mb`);
- static memory at the end: the bytes of the Gaussian parameters and of the optimizer state, per tensor;
- the final Gaussian count;
- with ``--rounds R``: the methods run in turn R times (A B A B ...), each ratio to the first method is taken
  within its round, and the median over rounds is reported beside the ratios of each round;
- on the eval views at the end (the model's `get_image_metrics_and_images`, as `ns-eval`: mean over views):
  PSNR and the material map's accuracy against the perceived label maps (physgs; the pipeline lifts at the last
  step, so the "lifted" head is read after a final lifting).

`--device cpu` is a smoke test of this script (memory figures are then null).
"""

from __future__ import annotations

import argparse
import copy
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import torch

MB = 2**20


def _sync() -> None:
    if torch.cuda.is_available():
        torch.cuda.synchronize()


def _reset_peak() -> None:
    if torch.cuda.is_available():
        _sync()
        torch.cuda.reset_peak_memory_stats()


def _peak_mb() -> float | None:
    if not torch.cuda.is_available():
        return None
    _sync()
    return torch.cuda.max_memory_allocated() / MB


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
    from torchmetrics.image import lpip

    class _OfflineLPIPS(torch.nn.Module):
        def __init__(self, *args, **kwargs):
            super().__init__()

        def forward(self, *args, **kwargs):
            return torch.tensor(float("nan"))

    lpip.LearnedPerceptualImagePatchSimilarity = _OfflineLPIPS


def _parse_value(current: Any, text: str) -> Any:
    """`text` as the type of the field's current value (None: int, float, "None" or the string)."""
    if isinstance(current, bool):
        return text.lower() in ("1", "true", "yes")
    if isinstance(current, (int, float)):
        return type(current)(text)
    if current is None:
        for cast in (int, float):
            try:
                return cast(text)
            except ValueError:
                pass
        return None if text == "None" else text
    return text


def apply_overrides(config: Any, overrides: str) -> None:
    """"key=value,key=value": each a field of the model config or else of the pipeline config."""
    for item in filter(None, overrides.split(",")):
        key, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"bench_training: override {item!r} is not key=value (e.g. physgs:material_head=latent)")
        for target in (config.pipeline.model, config.pipeline):
            if hasattr(target, key):
                setattr(target, key, _parse_value(getattr(target, key), value))
                break
        else:
            raise SystemExit(f"bench_training: {key!r} is neither a model nor a pipeline config field of this method")


def build_trainer(method: str, data: Path, steps: int, output_dir: Path, device: str = "cuda"):
    from nerfstudio.configs.method_configs import all_methods

    _seed_points_without_open3d()
    _no_lpips_download()

    name, _, overrides = method.partition(":")
    if name not in all_methods:
        raise SystemExit(f"bench_training: unknown method {name!r} (registered: {', '.join(sorted(all_methods))})")
    config = copy.deepcopy(all_methods[name])
    apply_overrides(config, overrides)
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


def stepper(trainer):
    """One training step of `trainer` as nerfstudio's Trainer.train takes it: the callbacks before the iteration, the
    iteration, the callbacks after it (densification, physgs's lifting). Returns ``step_fn(step)``."""
    from nerfstudio.engine.callbacks import TrainingCallbackLocation as Loc

    def step_fn(step: int) -> None:
        trainer.pipeline.train()
        for cb in trainer.callbacks:
            cb.run_callback_at_location(step, location=Loc.BEFORE_TRAIN_ITERATION)
        trainer.train_iteration(step)
        for cb in trainer.callbacks:
            cb.run_callback_at_location(step, location=Loc.AFTER_TRAIN_ITERATION)

    return step_fn


def static_memory(model: Any, optimizers: dict[str, torch.optim.Optimizer]) -> dict[str, Any]:
    """Bytes (MB) of the model's parameters and of the optimizers' state, per Gaussian tensor and in total."""

    def nbytes(t: Any) -> int:
        return t.numel() * t.element_size() if isinstance(t, torch.Tensor) else 0

    per_key: dict[str, dict[str, float]] = {}
    for name, p in model.gauss_params.items():
        per_key[name] = {"param_mb": nbytes(p) / MB, "optimizer_mb": 0.0}
    opt_total = 0
    for name, opt in optimizers.items():
        size = sum(nbytes(v) for state in opt.state.values() for v in state.values())
        opt_total += size
        if name in per_key:
            per_key[name]["optimizer_mb"] = size / MB
    params_total = sum(nbytes(p) for p in model.parameters())  # gauss_params (lifted tensors too), decoder, ...
    return {"params_mb": params_total / MB, "optimizer_mb": opt_total / MB,
            "total_mb": (params_total + opt_total) / MB, "per_gaussian_tensor": per_key}  # fmt: skip


@torch.no_grad()
def eval_metrics(pipeline: Any) -> dict[str, Any]:
    """Mean PSNR and material accuracy over the eval views (the model's own per-image metrics, as ns-eval)."""
    model = pipeline.model
    model.eval()
    rows = []
    for camera, batch in pipeline.datamanager.fixed_indices_eval_dataloader:
        outputs = model.get_outputs_for_camera(camera)
        metrics, _ = model.get_image_metrics_and_images(outputs, batch)
        rows.append({k: float(v) for k, v in metrics.items() if k in ("psnr", "material_acc")})
    model.train()
    acc = [r["material_acc"] for r in rows if "material_acc" in r]
    return {"eval_views": len(rows), "eval_psnr": statistics.mean(r["psnr"] for r in rows) if rows else None,
            "material_acc": statistics.mean(acc) if acc else None, "material_acc_per_view": acc}  # fmt: skip


class _PhasePeaks:
    """The largest peak memory seen in each phase (after the warm-up)."""

    def __init__(self) -> None:
        self.peaks: dict[str, float | None] = {}

    def add(self, phase: str, value: float | None) -> None:
        if value is not None:
            self.peaks[phase] = max(value, self.peaks.get(phase) or 0.0)
        else:
            self.peaks.setdefault(phase, None)


def _timed_lift(pipeline: Any, lifts: list[dict], clock: dict) -> None:
    """Wrap `pipeline.lift` (the lifting callback calls it) to record each lifting's time and peak memory."""
    original = getattr(pipeline, "lift", None)
    if original is None:
        return

    def lift():
        _reset_peak()
        t0 = time.perf_counter()
        result = original()
        _sync()
        lifts.append({"step": clock["step"], "s": time.perf_counter() - t0, "peak_mb": _peak_mb()})
        return result

    pipeline.lift = lift


def time_training(method: str, data: Path, steps: int, warmup: int, window: int, device: str = "cuda") -> dict:
    from nerfstudio.engine.callbacks import TrainingCallbackLocation as Loc

    with tempfile.TemporaryDirectory() as tmp:
        trainer = build_trainer(method, data, steps, Path(tmp), device)
        pipeline = trainer.pipeline
        model = pipeline.model
        lifts: list[dict] = []
        clock = {"step": -1}
        _timed_lift(pipeline, lifts, clock)
        peaks = _PhasePeaks()
        windows: list[float] = []
        windows_without_lifting: list[float] = []
        lifted_s = 0.0  # time spent lifting in the current window
        material_steps = 0
        _sync()
        t_window = time.perf_counter()
        for step in range(steps):
            clock["step"] = step
            if step == warmup:
                _sync()
                t_window = time.perf_counter()
            pipeline.train()
            for cb in trainer.callbacks:
                cb.run_callback_at_location(step, location=Loc.BEFORE_TRAIN_ITERATION)
            material = bool(getattr(model, "material_pass_due", lambda: False)())
            material_steps += int(material)
            _reset_peak()
            trainer.train_iteration(step)
            iteration_peak = _peak_mb()
            n_lifts = len(lifts)
            _reset_peak()
            for cb in trainer.callbacks:
                cb.run_callback_at_location(step, location=Loc.AFTER_TRAIN_ITERATION)
            callbacks_peak = _peak_mb()
            if step >= warmup:
                peaks.add("material_steps" if material else "rgb_steps", iteration_peak)
                if len(lifts) == n_lifts:
                    peaks.add("callbacks", callbacks_peak)
            lifted_s += sum(x["s"] for x in lifts[n_lifts:])
            if step >= warmup and (step - warmup + 1) % window == 0:
                _sync()
                now = time.perf_counter()
                windows.append((now - t_window) / window)
                windows_without_lifting.append((now - t_window - lifted_s) / window)
                t_window, lifted_s = now, 0.0
            elif step < warmup:
                lifted_s = 0.0
        for lifted in lifts:
            peaks.add("lifting", lifted["peak_mb"])
        known = [v for v in peaks.peaks.values() if v is not None]
        row = {"method": method, "steps": steps, "warmup": warmup, "material_steps": material_steps,
               "iter_s_median": statistics.median(windows) if windows else None, "iter_s_windows": windows,
               "iter_s_median_without_lifting": statistics.median(windows_without_lifting) if windows else None,
               "lifting_s_total": sum(x["s"] for x in lifts),
               "peak_mem_mb": max(known) if known else None, "peak_mem_mb_by_phase": peaks.peaks,
               "liftings": lifts, "final_gaussians": int(model.num_points),
               "static_memory": static_memory(model, trainer.optimizers.optimizers),
               "material_head": getattr(model, "material_head", None)}  # fmt: skip
        row.update(eval_metrics(pipeline))
        row["device"] = torch.cuda.get_device_name(0) if device == "cuda" else "cpu"
    return row


def run_isolated(method: str, args: argparse.Namespace) -> dict:
    """One method in a fresh Python process (module doc); its row, or the error it died with."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "row.json"
        cmd = [sys.executable, str(Path(__file__).resolve()), "--one", method, "--data", str(args.data),
               "--steps", str(args.steps), "--warmup", str(args.warmup), "--window", str(args.window),
               "--device", args.device, "--out", str(out)]  # fmt: skip
        proc = subprocess.run(cmd, check=False, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        if proc.returncode != 0 or not out.exists():
            tail = "\n".join(proc.stdout.splitlines()[-15:])
            print(f"[{method}] failed (exit {proc.returncode}):\n{tail}", flush=True)
            return {"method": method, "error": tail}
        return json.loads(out.read_text())


def _ratio(row: dict, base: dict, key: str) -> float | None:
    a, b = row.get(key), base.get(key)
    return a / b if a is not None and b else None


def summary(row: dict) -> str:
    if "error" in row:
        return f"{row['method']}: FAILED"
    it = row["iter_s_median"]
    parts = [f"{row['method']}: iter {1000 * it:.2f} ms" if it is not None else f"{row['method']}: iter n/a",
             f"peak {row['peak_mem_mb']} MB", f"phases {row['peak_mem_mb_by_phase']}",
             f"static {row['static_memory']['total_mb']:.1f} MB", f"N {row['final_gaussians']}",
             f"liftings {[(x['step'], round(x['s'], 3)) for x in row['liftings']]}",
             f"material_acc {row['material_acc']}", f"psnr {row['eval_psnr']}"]  # fmt: skip
    return ", ".join(parts)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--warmup", type=int, default=200)
    ap.add_argument("--window", type=int, default=100)
    ap.add_argument("--methods", nargs="+", default=["splatfacto-big", "physgs"])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--device", default="cuda", help="cuda (the figures) or cpu (a smoke test of this script)")
    ap.add_argument("--rounds", type=int, default=1, help="run the methods in turn this many times; the ratios are "
                    "taken within each round and their median reported (one pair's ratio varies by +-5%%)")
    ap.add_argument("--one", metavar="METHOD", help=argparse.SUPPRESS)  # the child process of one method
    args = ap.parse_args()
    if args.warmup >= args.steps:
        raise SystemExit(f"bench_training: --warmup ({args.warmup}) must be below --steps ({args.steps})")
    if args.one is not None:
        if args.device == "cuda":  # splatfacto-big calls gsplat directly: load the stamped build first (no rebuild)
            from physgs_nerfstudio.render.gsplat_build import prepare_gsplat

            print("gsplat:", prepare_gsplat(), flush=True)
        row = time_training(args.one, args.data, args.steps, args.warmup, args.window, args.device)
        args.out.write_text(json.dumps(row, indent=2))
        return
    rounds: list[list[dict]] = []
    for r in range(args.rounds):  # the methods in turn, round after round: pairs taken on the same machine state
        rows = []
        for method in args.methods:
            rows.append({**run_isolated(method, args), "round": r})
            print(summary(rows[-1]), flush=True)
        rounds.append(rows)
    result = {"device": rounds[0][0].get("device"), "data": str(args.data), "isolated_processes": True,
              "rows": [row for rows in rounds for row in rows], **round_ratios(rounds)}  # fmt: skip
    args.out.write_text(json.dumps(result, indent=2))
    first = args.methods[0]
    print("iteration ratios vs", first, result["ratio_vs_first"], "by round:", result["ratio_vs_first_by_round"])
    print("peak memory ratios vs", first, result["peak_mem_ratio_vs_first"])


def round_ratios(rounds: list[list[dict]]) -> dict[str, list]:
    """Per method (in ``--methods`` order) its ratio to the first method of the same round, per round, and the
    median over rounds (None where a run failed): iteration time and peak memory."""
    out: dict[str, list] = {}
    for key, name in (("iter_s_median", "ratio_vs_first"), ("peak_mem_mb", "peak_mem_ratio_vs_first")):
        by_round = [[_ratio(row, rows[0], key) for row in rows] for rows in rounds]
        per_method = list(zip(*by_round)) if by_round else []
        out[f"{name}_by_round"] = [list(r) for r in per_method]
        out[name] = [statistics.median(v) if (v := [x for x in r if x is not None]) else None for r in per_method]
    return out


if __name__ == "__main__":
    main()
