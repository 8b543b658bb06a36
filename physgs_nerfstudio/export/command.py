"""`physgs export`: PLY property point cloud, voxel grid, property maps and mass report of a trained run.

nerfstudio's own ``ns-export`` is a closed tyro union of exporters (nerfstudio/scripts/exporter.py) with no
plugin hook, so PhysGS exports live in ``physgs export``; ``ns-export gaussian-splat --load-config ...``
still writes the plain splat of the same run. From Python: ``ExportCommand(load_config=...).main()``, or
:func:`run_export` on a :class:`~.run.LoadedRun` (loading a run and its object's geometry: :mod:`.run`).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Literal

import torch

from ..errors import PhysGSError
from ..geometry import GeometryError, ObjectGeometry
from ..geometry.capture import viewmat_from_c2w
from ..mass import MassConfig, MassReport, integrate_mass, mass_draws
from ..sim import SimConfig
from . import geometry_cache
from .maps import View, save_property_maps
from .ply import write_property_ply
from .progress import stage
from .report import print_mass_table, write_report
from .run import (
    MAX_VIEW_WIDTH,
    LoadedRun,
    RunSource,
    load_run,
    object_geometry,
    precompute_geometry,
    run_from_pipeline,
)
from .staging import ExportStage, ExportWriteError, check_output_dir
from .voxel import write_voxel_grid

logger = logging.getLogger(__name__)

__all__ = ["ExportCommand", "ExportResult", "LoadedRun", "RunSource", "load_run", "object_geometry",
           "precompute_geometry", "run_export", "run_from_pipeline", "views_from_cameras", "write_export"]

Output = Literal["ply", "voxels", "maps", "mass", "sim"]


@dataclass
class ExportResult:
    files: dict[str, list[Path]]
    mass: MassReport | None
    error: str | None = None
    """why mass and voxels were not written (the object's geometry failed: :class:`GeometryError`); None = all were"""
    geometry: ObjectGeometry | None = None
    """the object's geometry the mass and voxels were computed from (None: neither was asked for, or it failed)"""


def views_from_cameras(cameras: Any, indices: Sequence[int], max_width: int = 480) -> list[View]:
    """Views from nerfstudio ``Cameras`` (scene frame), downscaled to at most ``max_width`` pixels wide."""
    views = []
    n = int(cameras.camera_to_worlds.shape[0])
    for i in indices:
        if not -n <= i < n:
            raise IndexError(f"view index {i} out of range: the run has {n} training cameras.")
        i = i % n
        w, h = int(cameras.width[i]), int(cameras.height[i])
        s = min(1.0, max_width / w)
        K = torch.tensor([[float(cameras.fx[i]) * s, 0.0, float(cameras.cx[i]) * s],
                          [0.0, float(cameras.fy[i]) * s, float(cameras.cy[i]) * s], [0.0, 0.0, 1.0]])  # fmt: skip
        views.append(View(viewmat_from_c2w(cameras.camera_to_worlds[i].cpu()), K, max(1, round(w * s)),
                          max(1, round(h * s)), name=f"view{i:03d}"))  # fmt: skip
    return views


def run_export(run: LoadedRun, output_dir: Path, *, overwrite: bool = False, source: Path | None = None,
               **kwargs: Any) -> ExportResult:  # fmt: skip
    """Write the chosen outputs of ``run`` into ``output_dir`` as one unit (:mod:`.staging`: staged beside it,
    checked, swapped in; a failure leaves the previous export as it was) and print the mass table. ``kwargs``:
    those of :func:`write_export`; ``overwrite`` replaces a folder that is not a previous export."""
    stage = ExportStage.open(output_dir, overwrite=overwrite, protect=(source, run.data_dir))
    try:
        result = write_export(run, stage.path, final_dir=stage.final, **kwargs)
        result.files = stage.commit(result.files, {"source": str(source) if source else None})
    except OSError as err:
        stage.abort()
        if isinstance(err, ExportWriteError):
            raise
        raise ExportWriteError(f"{stage.final}: writing the export failed ({err}); nothing there was changed (the "
                               "previous export is kept). Free space or fix the cause and rerun.") from None  # fmt: skip
    except BaseException:
        stage.abort()
        raise
    return result


def write_export(
    run: LoadedRun,
    output_dir: Path,
    *,
    mass: MassConfig | None = None,
    outputs: Sequence[Output] = ("ply", "voxels", "maps", "mass"),
    views: Sequence[View] = (),
    top_k: int = 3,
    truth_kg: float | None = None,
    title: str | None = None,
    quiet: bool = False,
    final_dir: Path | None = None,
    geometry: ObjectGeometry | None = None,
    sim: SimConfig | None = None,
) -> ExportResult:
    """Write the chosen outputs of ``run`` straight into ``output_dir`` (no staging; ``final_dir``: where the
    report says the files are) and print the mass table. ``geometry``: the object's geometry already computed with
    ``mass.geometry`` (:mod:`.geometry_cache`); None = computed here. ``sim``: the settings of the "sim" output
    (:mod:`physgs_nerfstudio.sim`)."""
    from rich.console import Console

    console = Console(quiet=quiet)
    pf = run.field
    out = Path(output_dir)
    out.mkdir(parents=True, exist_ok=True)
    mass = mass or MassConfig()
    files: dict[str, list[Path]] = {}
    if pf.simulated:
        console.print("[bold yellow]Material posteriors come from the SIMULATED VLM (generated scene).[/]")
    if "ply" in outputs:
        files["ply"] = [write_property_ply(pf, out / "property_field.ply", top_k=top_k)]
        console.log(f"PLY: {files['ply'][0]} ({pf.num_gaussians} Gaussians)")
    report, error, geo = None, None, geometry
    if {"mass", "voxels", "sim"} & set(outputs):
        try:
            with stage(console, "object geometry", unit="steps") as st:
                if geo is None:
                    geo = object_geometry(run, mass.geometry, progress=lambda s: st.advance(1, s))
                st.result = (f"{geo.selection.num_selected} Gaussians selected, {int(geo.solid.sum())} solid voxels, "
                             f"{geo.num_parts} parts, {len(geo.variant_names)} carving variants"
                             + (" (stored: the run's geometry cache)" if geometry is not None else ""))  # fmt: skip
        except GeometryError as err:  # the data's, not a bug: the outputs that need no geometry are still written
            error = " ".join(str(err).split())
            console.print(f"[bold red]mass and voxels not written:[/] {error}")
        else:
            if "mass" in outputs or "sim" in outputs:
                draws = mass_draws(pf, geo, mass)
                report = integrate_mass(pf, geo, mass, draws=draws)
            if "voxels" in outputs:
                files["voxels"] = [write_voxel_grid(pf, out / "voxels.npz", geo)]
                console.log(f"voxel grid: {files['voxels'][0]}")
            if "sim" in outputs:
                files["sim"] = _write_sim(run, geo, draws, report, out / "sim", sim or SimConfig(), mass.seed)
                console.log(f"simulator object: {out / 'sim'} ({len(files['sim'])} files)")
    if "maps" in outputs and views:
        with stage(console, "property maps", total=len(views), unit="views") as st:
            files["maps"] = save_property_maps(pf, views, out / "maps", on_view=lambda name: st.advance(1, name))
            st.result = str(out / "maps")
    if "mass" in outputs and (report is not None or error is not None):
        shown = Path(final_dir or out)
        extra: dict[str, Any] = {"files": {k: [str(shown / p.relative_to(out)) for p in v] for k, v in files.items()},
                                 "legend": pf.legend(), "simulated": pf.simulated}  # fmt: skip
        if error is not None:
            extra["mass_error"] = error
        else:
            extra["geometry_source"] = "stored" if geometry is not None else "computed"  # the run's physgs_cache/
        if truth_kg is not None:
            extra["ground_truth_kg"] = truth_kg
            if report is not None:
                extra["interval_covers_truth"] = report.covers(truth_kg)
        files["report"] = [write_report(report, out / "report.json", extra)]
        if report is not None:
            print_mass_table(report, title=title, truth_kg=truth_kg, console=console)
    return ExportResult(files, report if "mass" in outputs else None, error, geo if error is None else None)


def _write_sim(run: LoadedRun, geo: ObjectGeometry, draws: Any, report: MassReport, folder: Path,
               cfg: SimConfig, seed: int) -> list[Path]:  # fmt: skip
    """The "sim" output (:func:`physgs_nerfstudio.sim.write_sim`) with the run's views, dataset and transform."""
    import json

    from ..sim import write_sim
    from .scale import DATAPARSER_TRANSFORMS

    dp = None
    if run.source is not None and (run.source.run_dir / DATAPARSER_TRANSFORMS).is_file():
        dp = json.loads((run.source.run_dir / DATAPARSER_TRANSFORMS).read_text())
    return write_sim(run.field, geo, draws, report, folder, cfg, views=run.views, data_dir=run.data_dir, seed=seed,
                     dataparser=dp)  # fmt: skip


@dataclass
class ExportCommand:
    """Export a trained PhysGS run: property PLY, voxel grid, property maps and the mass (mean, interval)."""

    fast_exit: ClassVar[bool] = True
    """The console script ends the process at once when the export is complete (``physgs_nerfstudio.cli.main``)."""

    load_config: Path
    """The config.yml of the trained run (`ns-train physgs` or `physgs-lite`)."""
    output_dir: Path = Path("export")
    """Folder the outputs are written to."""
    outputs: tuple[Output, ...] = ("ply", "voxels", "maps", "mass")
    """Which outputs to write."""
    mass: MassConfig = field(default_factory=MassConfig)
    """How the mass and its interval are computed."""
    sim: SimConfig = field(default_factory=SimConfig)
    """The simulator-ready object that --outputs sim writes (MuJoCo, URDF, USD, MPM particles, samples)."""
    scale: float | None = None
    """Metres per dataset unit (None: the dataset is metric)."""
    known_length: tuple[float, float, float, float, float, float, float] | None = None
    """Two points in dataset coordinates and their true distance, x1 y1 z1 x2 y2 z2 metres, to set the scale."""
    views: tuple[int, ...] = (0,)
    """Training camera indices to render property maps for."""
    max_map_width: int = 480
    """Widest property map in pixels (larger views are downscaled)."""
    top_k: int = 3
    """Most likely materials written per Gaussian in the PLY."""
    env: str | None = None
    """Material library for thickness fallbacks (None: the one in materials.json)."""
    truth_kg: float | None = None
    """The true mass in kg, if known, printed and checked against the interval."""
    device: Literal["auto", "cpu", "cuda"] = "auto"
    """Where to compute (auto: CUDA when available)."""
    geometry_cache: bool = True
    """Reuse the object's geometry stored in the run's physgs_cache/ when its inputs are unchanged, and store it."""
    overwrite: bool = False
    """Replace a non-empty --output-dir that is not an earlier export (an earlier export is always replaced)."""

    def main(self) -> ExportResult:
        check_output_dir(self.output_dir, overwrite=self.overwrite, protect=(self.load_config,))  # before loading
        needs_geometry = bool({"mass", "voxels", "sim"} & set(self.outputs))
        run = load_run(self.load_config, scale=self.scale, known_length=self.known_length, env=self.env,
                       capture=False)  # fmt: skip
        if "sim" in self.outputs:  # before any geometry is computed
            from ..sim.build import check_metric_scale

            check_metric_scale(run.field.scale_source, run.data_dir)
        device = ("cuda" if torch.cuda.is_available() else "cpu") if self.device == "auto" else self.device
        mass = self.mass
        cache, geo = None, None
        if needs_geometry and self.geometry_cache:
            load_args = geometry_cache.load_args(self.scale, self.known_length, self.env, MAX_VIEW_WIDTH)
            cache = geometry_cache.cache_for_run(run, mass.geometry, device, load_args)
            geo = cache.load(device) if cache is not None else None
        if needs_geometry and geo is None:
            run.load_capture()
        run.field = run.field.to(device)
        cameras = run.cameras
        views = views_from_cameras(cameras, self.views, self.max_map_width) if cameras is not None else []
        if "maps" in self.outputs and cameras is None:
            logger.warning("no training cameras found in the run: property maps skipped")
        result = run_export(run, self.output_dir, mass=mass, outputs=self.outputs, views=views,
                            top_k=self.top_k, truth_kg=self.truth_kg, overwrite=self.overwrite,
                            source=self.load_config, title=f"Mass of {self.load_config.parent.name}",
                            geometry=geo, sim=self.sim)  # fmt: skip
        if cache is not None and geo is None and result.geometry is not None:
            cache.save(result.geometry)
        if result.error is not None:  # the rest is written (a complete export of what could be made): say so, exit 1
            written = ", ".join(sorted(result.files)) or "nothing"
            raise PhysGSError(f"{self.output_dir}: mass and voxels not written ({result.error}); written: {written} "
                              "(report.json has mass null and mass_error).")  # fmt: skip
        return result
