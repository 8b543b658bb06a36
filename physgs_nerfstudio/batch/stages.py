"""The stage commands of a batch, in one place: perception (in-process, so a Ray task's OpenAI backend can
use the cluster's rate limiter), ``ns-train``'s training (a subprocess of the plugin's one-method entry,
:mod:`physgs_nerfstudio.nerfstudio.train`), ``physgs export`` (in-process).

Each ``run_<stage>(scene, settings, out_dir)`` returns ``(outputs, metrics)`` (JSON-able dicts) or raises
:class:`StageError` with a one-line reason. Nothing here touches the state files (runner.py does).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Literal

from .scenes import Scene

RUN_TIMESTAMP = "batch"


class StageError(RuntimeError):
    """A stage failed; ``kind`` groups failures in the summary (bad input, VLM errors, training, ...)."""

    def __init__(self, message: str, kind: str):
        super().__init__(message)
        self.kind = kind


@dataclass
class StageSettings:
    """What the stages need; JSON-able (it travels to Ray workers)."""

    method: Literal["physgs", "physgs-lite"] = "physgs"
    iterations: int | None = None
    device: Literal["cpu", "cuda"] = "cuda"
    seed: int = 0
    vlm: Literal["openai", "replay", "simulated"] = "openai"
    model: str = "gpt-5"
    base_url: str = "https://api.openai.com/v1"
    api_key_env: str = "OPENAI_API_KEY"
    env: str | None = None
    cache_dir: str = ""
    max_concurrency: int = 4
    max_views: int | None = None
    usd_per_1k_prompt_tokens: float = 0.0
    usd_per_1k_completion_tokens: float = 0.0
    export_resolution: int = 128
    n_samples: int = 4000
    train_args: tuple[str, ...] = ()
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> StageSettings:
        d = dict(d)
        d["train_args"] = tuple(d.get("train_args", ()))
        return cls(**d)


def _one_line(err: BaseException | str, limit: int = 300) -> str:
    text = " ".join(str(err).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def run_dir(out: Path, scene: Scene, method: str) -> Path:
    return Path(out) / "runs" / scene.name / method / RUN_TIMESTAMP


def export_dir(out: Path) -> Path:
    return Path(out) / "export"


def _scene_env(scene: Scene, settings: StageSettings) -> str:
    if settings.env:
        return settings.env
    truth = scene.data / "ground_truth.json"
    if truth.is_file():
        try:
            return str(json.loads(truth.read_text()).get("env") or "indoor")
        except ValueError:
            pass
    return "indoor"


# ----------------------------------------------------------------------------------------------- perceive
def run_perceive(scene: Scene, settings: StageSettings, out: Path, overwrite: bool = False) -> tuple[dict, dict]:
    """`physgs perceive` in this process (built-in segmenter). Writes materials.json and the material maps
    into the dataset folder, as `physgs perceive` does."""
    from ..perception import PerceptionConfig, run_perception
    from ..perception.replay import ReplayConfig
    from ..perception.segment_builtin import BuiltinSegmenterConfig
    from ..perception.simulated import SimulatedConfig
    from ..perception.vlm import OpenAIConfig

    if settings.vlm == "openai":
        vlm = OpenAIConfig(base_url=settings.base_url, model=settings.model, api_key_env=settings.api_key_env,
                           usd_per_1k_prompt_tokens=settings.usd_per_1k_prompt_tokens,
                           usd_per_1k_completion_tokens=settings.usd_per_1k_completion_tokens)  # fmt: skip
    elif settings.vlm == "replay":
        vlm = ReplayConfig(source="openai", model=settings.model)
    else:
        vlm = SimulatedConfig()
    # strict: an unreadable frame fails the scene (ns-train would stop on it), as failed requests do
    cfg = PerceptionConfig(data=scene.data, vlm=vlm, segmenter=BuiltinSegmenterConfig(),
                           env=_scene_env(scene, settings), cache_dir=Path(settings.cache_dir) if settings.cache_dir else None,
                           max_concurrency=settings.max_concurrency, max_views=settings.max_views, progress=False,
                           overwrite=overwrite, strict=True)  # fmt: skip
    try:
        res = run_perception(cfg)
    except (OSError, ValueError) as err:  # unreadable/broken images and datasets
        raise StageError(f"perception input: {_one_line(err)}", "bad input") from None
    except RuntimeError as err:  # VLMError and friends
        raise StageError(f"VLM: {_one_line(err)}", "VLM errors") from None
    metrics = {"vlm_calls": res.calls, "cache_hits": res.cache_hits, "masks": res.masks,
               "prompt_tokens": res.usage.prompt_tokens, "completion_tokens": res.usage.completion_tokens,
               "cost_usd": res.cost_usd, "simulated": res.simulated, "failed_requests": len(res.failed)}  # fmt: skip
    if res.failed:
        raise StageError(f"{len(res.failed)} VLM requests failed (first: {_one_line(res.failed[0], 200)}); "
                         "answered ones are cached, a rerun asks only the rest", "VLM errors")  # fmt: skip
    if res.materials_json is None:
        raise StageError("perception wrote no materials.json (no mask was answered)", "VLM errors")
    return {"materials_json": str(res.materials_json)}, metrics


# ----------------------------------------------------------------------------------------------- train
def train_command(scene: Scene, settings: StageSettings, out: Path) -> list[str]:
    # ns-train's arguments to the plugin's one-method entry: the same configuration and nerfstudio Trainer, without
    # ns-train's start-up over every installed method (physgs_nerfstudio/nerfstudio/train.py)
    cmd = [sys.executable, "-m", "physgs_nerfstudio.nerfstudio.train", settings.method, "--data", str(scene.data),
           "--output-dir", str(Path(out) / "runs"), "--experiment-name", scene.name, "--timestamp", RUN_TIMESTAMP,
           "--machine.device-type", settings.device, "--save-only-latest-checkpoint", "True",
           "--vis", "tensorboard", "--machine.seed", str(settings.seed)]  # fmt: skip
    if settings.iterations is not None:
        cmd += ["--max-num-iterations", str(settings.iterations),
                "--steps-per-save", str(max(50, settings.iterations // 4))]  # fmt: skip
    return cmd + list(settings.train_args)


def run_train(scene: Scene, settings: StageSettings, out: Path, gpu: int | None = None) -> tuple[dict, dict]:
    """`ns-train <method>` as a subprocess (:func:`train_command`); its log goes to OUT/scenes/<scene>/train.log."""
    if not (scene.data / "materials.json").is_file():
        raise StageError(f"{scene.data}: no materials.json; run the perceive stage first", "missing input")
    env = dict(os.environ)
    env.setdefault("PYTHONWARNINGS", "ignore")
    if gpu is not None:
        env["CUDA_VISIBLE_DEVICES"] = str(gpu)
    log = Path(out) / "train.log"
    log.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with open(log, "w") as f:
        proc = subprocess.run(train_command(scene, settings, out), env=env, stdout=f, stderr=subprocess.STDOUT,
                              check=False)
    seconds = time.perf_counter() - t0
    config = run_dir(out, scene, settings.method) / "config.yml"
    if proc.returncode != 0:
        lines = [ln.strip() for ln in log.read_text(errors="replace").splitlines() if ln.strip()]
        last = next((ln for ln in reversed(lines) if "Error" in ln or "error" in ln), lines[-1] if lines else "")
        raise StageError(f"ns-train exited with code {proc.returncode}: {_one_line(last, 200)} (log: {log})",
                         "training failed")  # fmt: skip
    ckpts = sorted((config.parent / "nerfstudio_models").glob("step-*.ckpt"))
    if not config.is_file() or not ckpts:
        raise StageError(f"ns-train finished but wrote no config.yml/checkpoint under {config.parent}",
                         "training failed")  # fmt: skip
    return {"config": str(config), "checkpoint": str(ckpts[-1]), "log": str(log)}, \
        {"train_seconds": seconds, "device": settings.device}


# ----------------------------------------------------------------------------------------------- export
def run_export(scene: Scene, settings: StageSettings, out: Path, config: Path) -> tuple[dict, dict]:
    """`physgs export` in this process -> OUT/scenes/<scene>/export/ (report.json with the mass)."""
    import math
    from dataclasses import replace

    from ..export.command import ExportCommand
    from ..mass import MassConfig

    truth = None
    gt = scene.data / "ground_truth.json"
    if gt.is_file():
        truth = json.loads(gt.read_text()).get("total_mass_kg")
    t0 = time.perf_counter()
    try:
        base = MassConfig()
        mass_cfg = replace(base, geometry=replace(base.geometry, resolution=settings.export_resolution),
                           n_samples=settings.n_samples, seed=settings.seed)  # fmt: skip
        result = ExportCommand(load_config=Path(config), output_dir=export_dir(out), mass=mass_cfg, truth_kg=truth,
                               views=(0,), device=settings.device).main()  # fmt: skip
    except (OSError, ValueError, RuntimeError) as err:
        raise StageError(f"export: {_one_line(err)}", "export failed") from None
    seconds = time.perf_counter() - t0
    report = export_dir(out) / "report.json"
    mass = getattr(result, "mass", None)
    if mass is not None and not math.isfinite(mass.mean_kg):
        raise StageError(f"export: mass is {mass.mean_kg} (training diverged?)", "training diverged")
    outputs = {"export_dir": str(export_dir(out)), "report": str(report)}
    metrics = {"export_seconds": seconds, "device": settings.device}
    if mass is not None:
        metrics["mass_kg"] = mass.mean_kg
    return outputs, metrics
