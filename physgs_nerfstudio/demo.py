"""`physgs demo`: the whole pipeline on a generated scene with known materials, on CPU, in minutes.

Stages (each skipped when its output exists, so an interrupted demo resumes):

1. ``scene/``: a generated object (`physgs synth`) with ground-truth materials and mass;
2. perception with the built-in segmenter and the SIMULATED VLM (a noise and confusion model of a VLM, for
   generated scenes only: every printout says so) -> ``scene/materials.json`` and material maps;
3. ``ns-train physgs-lite`` on the CPU, run in this process (:mod:`.nerfstudio.train`: nerfstudio's trainer, without
   ``ns-train``'s start-up) -> ``runs/.../config.yml``;
4. ``physgs export`` -> ``export/`` (PLY, voxel grid, maps, report.json) and the mass table;
5. predicted vs ground-truth mass with ADE / ALDE / APE / MnRE and whether the interval covers the truth.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["DemoCommand"]

SIM = "[bold yellow][SIMULATED VLM][/]"
METHOD = "physgs-lite"


def _latest_checkpoint(run_dir: Path) -> Path | None:
    ckpts = sorted((run_dir / "nerfstudio_models").glob("step-*.ckpt"))
    return ckpts[-1] if ckpts else None


@dataclass
class DemoCommand:
    """Generated scene -> perception (simulated VLM) -> physgs-lite training on CPU -> export -> mass vs truth."""

    output_dir: Path = Path("demo_output")
    """Folder the scene, the run and the export are written to."""
    object: str = "mug"
    """The generated object (`physgs synth --help` lists them)."""
    views: int = 16
    """Camera views of the generated scene."""
    resolution: int = 96
    """Image width and height in pixels."""
    iterations: int = 300
    """Training iterations of physgs-lite."""
    seed: int = 0
    """Seed of the scene, the training and the mass's Monte Carlo samples."""
    export_resolution: int = 96
    """Voxels along the object's longest side for the mass."""
    n_samples: int = 4000
    """Monte Carlo samples of the mass."""
    device: str = "cpu"
    """Training device type (cpu or cuda)."""
    force: tuple[str, ...] = ()
    """Stages to redo even if their outputs exist: scene, perceive, train, export (a stage redone redoes the later ones)."""
    train_args: tuple[str, ...] = field(default_factory=tuple)
    """Extra arguments appended to ns-train."""
    mesh_dir: Path | None = None
    """Folder of bunny.obj and armadillo.obj for the objects made of them (None: ../shared/data beside the project)."""

    # ---------------------------------------------------------------- paths
    @property
    def scene_dir(self) -> Path:
        return self.output_dir / "scene"

    @property
    def run_dir(self) -> Path:
        return self.output_dir / "runs" / "demo" / METHOD / "demo"

    @property
    def export_dir(self) -> Path:
        return self.output_dir / "export"

    # ---------------------------------------------------------------- stages
    def stage_scene(self, console: Any) -> dict:
        from .synth.dataset import SynthConfig, generate_scene, load_ground_truth

        gt_path = self.scene_dir / "ground_truth.json"
        if gt_path.exists() and "scene" not in self.force:
            console.log(f"[1/4] scene: {self.scene_dir} exists, skipped")
        else:
            console.log(f"[1/4] scene: generating {self.object!r} ({self.views} views, {self.resolution}px)")
            meshes = {"mesh_dir": self.mesh_dir} if self.mesh_dir is not None else {}
            generate_scene(SynthConfig(out=self.scene_dir, object=self.object, views=self.views, seed=self.seed,
                                       resolution=self.resolution, overwrite=True, **meshes))  # fmt: skip
        return load_ground_truth(self.scene_dir)

    def stage_perceive(self, console: Any, env: str | None) -> None:
        from .perception import PerceptionConfig, run_perception
        from .perception.segment_builtin import BuiltinSegmenterConfig
        from .perception.simulated import SimulatedConfig

        if (self.scene_dir / "materials.json").exists() and "perceive" not in self.force:
            console.log(f"[2/4] perception {SIM}: materials.json exists, skipped")
            return
        console.log(f"[2/4] perception with the built-in segmenter and the {SIM} (not a real VLM)")
        cfg = PerceptionConfig(data=self.scene_dir, vlm=SimulatedConfig(), segmenter=BuiltinSegmenterConfig(),
                               env=env or "indoor", overwrite="perceive" in self.force)  # fmt: skip
        res = run_perception(cfg)
        console.log(f"      {res.observations} observations on {res.masks} masks -> {', '.join(res.materials)} {SIM}")

    def _forced(self, stage: str) -> bool:
        """Whether ``stage`` or a stage before it is in ``force``."""
        order = ("scene", "perceive", "train", "export")
        return any(s in self.force for s in order[: order.index(stage) + 1])

    def stage_train(self, console: Any) -> Path:
        from .nerfstudio.train import train_in_process

        config = self.run_dir / "config.yml"
        ckpt = _latest_checkpoint(self.run_dir)
        done = ckpt is not None and int(ckpt.stem.split("-")[1]) >= self.iterations - 1
        if config.exists() and done and not self._forced("train"):
            console.log(f"[3/4] training: {ckpt} exists, skipped")
            return config
        args = [
            "--data", str(self.scene_dir), "--output-dir", str(self.output_dir / "runs"), "--experiment-name", "demo",
            "--timestamp", "demo", "--machine.device-type", self.device, "--max-num-iterations", str(self.iterations),
            "--steps-per-save", str(max(50, self.iterations // 4)), "--save-only-latest-checkpoint", "True",
            "--vis", "tensorboard", "--machine.seed", str(self.seed), *self.train_args,
        ]  # fmt: skip
        console.log(f"[3/4] training {METHOD} on {self.device} for {self.iterations} iterations, in this process "
                    f"(the same as `ns-train {METHOD} {' '.join(args)}`)")  # fmt: skip
        t0 = time.perf_counter()
        try:
            config = train_in_process(METHOD, args)
        except (KeyboardInterrupt, SystemExit):
            raise
        except Exception as e:  # any failure of the training: say so, and how to resume
            console.print_exception(max_frames=4)
            raise SystemExit(f"training failed ({type(e).__name__}: {e}); rerun `physgs demo` to resume.") from e
        console.log(f"      trained in {time.perf_counter() - t0:.0f} s")
        if not config.exists():
            raise SystemExit(f"training finished but {config} is missing")
        return config

    def stage_export(self, console: Any, config: Path, truth_kg: float):
        from dataclasses import replace

        from .export.command import ExportCommand
        from .export.report import print_mass_table
        from .mass import MassConfig

        report_path = self.export_dir / "report.json"
        if report_path.exists() and not self._forced("export"):
            console.log(f"[4/4] export: {report_path} exists, skipped")
            report = self.saved_mass(report_path, config)
            print_mass_table(report, title=f"Mass of the generated {self.object}", truth_kg=truth_kg, console=console)
            return report
        console.log("[4/4] export: PLY, voxel grid, property maps, mass")
        base = MassConfig()
        mass = replace(base, geometry=replace(base.geometry, resolution=self.export_resolution),
                       n_samples=self.n_samples, seed=self.seed)  # fmt: skip
        cmd = ExportCommand(load_config=config, output_dir=self.export_dir, mass=mass, truth_kg=truth_kg, views=(0,),
                            device="cpu")  # fmt: skip
        return cmd.main().mass

    def saved_mass(self, report_path: Path, config: Path) -> Any:
        """The :class:`~.mass.MassReport` of an earlier export's ``report.json``. An export whose object geometry
        failed wrote ``"mass": null`` and why (``mass_error``): then a :class:`~.errors.PhysGSError` says so and
        how to export the run again; the scene, the run and the rest of that export stay as they are."""
        from .errors import PhysGSError
        from .mass import MassReport

        data = json.loads(report_path.read_text())
        if data.get("mass") is None:
            why = " ".join(str(data.get("mass_error") or "no reason recorded").rstrip(".").split())
            raise PhysGSError(
                f"{report_path}: the earlier export has no mass ({why}); the scene, the run and the rest of the "
                f"export are kept. Export the run again with other --mass.geometry settings (`physgs export "
                f"--load-config {config} --output-dir {report_path.parent} --mass.geometry.resolution "
                f"{self.export_resolution} --mass.n-samples {self.n_samples} --mass.seed {self.seed} ...`), then "
                "rerun `physgs demo` to compare its mass with the truth.")  # fmt: skip
        return MassReport.from_dict(data["mass"])

    def main(self) -> None:
        from rich.console import Console
        from rich.table import Table

        from .eval.metrics import point_metrics

        console = Console()
        t0 = time.perf_counter()
        self.output_dir.mkdir(parents=True, exist_ok=True)
        console.rule(f"PhysGS demo: generated {self.object!r}, {SIM} perception, {METHOD} on {self.device}")
        gt = self.stage_scene(console)
        self.stage_perceive(console, gt.get("env"))
        config = self.stage_train(console)
        truth = float(gt["total_mass_kg"])
        report = self.stage_export(console, config, truth)
        metrics = {k: float(v[0]) for k, v in point_metrics([truth], [report.mean_kg]).items()}
        pct = round(report.level * 100)
        table = Table(title=f"Predicted vs ground-truth mass {SIM}")
        for col in ("object", "truth kg", "predicted kg", f"{pct}% interval kg", "covers", "ADE kg", "ALDE",
                    "APE", "MnRE"):  # fmt: skip
            table.add_column(col, justify="right" if col != "object" else "left")
        table.add_row(self.object, f"{truth:.4g}", f"{report.mean_kg:.4g}",
                      f"[{report.interval_kg[0]:.4g}, {report.interval_kg[1]:.4g}]",
                      "yes" if report.covers(truth) else "no", f"{metrics['ADE']:.4g}", f"{metrics['ALDE']:.3f}",
                      f"{metrics['APE']:.3f}", f"{metrics['MnRE']:.3f}")  # fmt: skip
        console.print(table)
        summary = {"object": self.object, "truth_kg": truth, "predicted_kg": report.mean_kg,
                   "interval_kg": list(report.interval_kg), "level": report.level, "covers": report.covers(truth),
                   "metrics": metrics, "simulated_vlm": True, "seconds": time.perf_counter() - t0,
                   "config": str(config)}  # fmt: skip
        (self.output_dir / "demo_summary.json").write_text(json.dumps(summary, indent=2))
        console.log(f"demo finished in {summary['seconds']:.0f} s; outputs in {self.output_dir} "
                    "(materials came from the SIMULATED VLM)")  # fmt: skip


if __name__ == "__main__":
    import tyro

    from physgs_nerfstudio.cli import one_line_errors

    with one_line_errors("physgs demo"):
        tyro.cli(DemoCommand).main()
