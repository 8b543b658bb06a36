"""`physgs export`: PLY property point cloud, voxel grid, property maps and mass report of a trained run.

nerfstudio's own ``ns-export`` is a closed tyro union of exporters (nerfstudio/scripts/exporter.py) with no
plugin hook, so PhysGS exports live in ``physgs export``; ``ns-export gaussian-splat --load-config ...``
still writes the plain splat of the same run. From Python: ``ExportCommand(load_config=...).main()``, or
:func:`run_export` on any :class:`PropertyField`.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import torch

from .field import PropertyField
from .maps import View, save_property_maps, viewmat_from_c2w
from .mass import MassConfig, MassReport, integrate_mass, mass_geometry
from .occupancy import OccupancyConfig
from .ply import write_property_ply
from .report import print_mass_table, write_report
from .voxel import write_voxel_grid

logger = logging.getLogger(__name__)

__all__ = ["ExportCommand", "ExportResult", "load_run", "run_export", "views_from_cameras"]

Output = Literal["ply", "voxels", "maps", "mass"]


@dataclass
class ExportResult:
    files: dict[str, list[Path]]
    mass: MassReport | None


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


def load_run(
    config_path: Path,
    *,
    scale: float | None = None,
    known_length: Sequence[float] | None = None,
    env: str | None = None,
) -> tuple[PropertyField, Any]:
    """(PropertyField, training Cameras or None) of a trained run, through nerfstudio's ``eval_setup``."""
    from nerfstudio.utils.eval_utils import eval_setup

    from .scale import read_dataparser_scale

    config_path = Path(config_path)
    if not config_path.exists():
        raise FileNotFoundError(f"{config_path} not found: pass the config.yml of an `ns-train physgs` run.")
    config, pipeline, _, _ = eval_setup(config_path, test_mode="inference")
    dp_scale = read_dataparser_scale(config.get_base_dir())
    pf = PropertyField.from_model(pipeline.model, dp_scale, scale=scale, known_length=known_length, env=env)
    cameras = None
    dm = pipeline.datamanager
    for getter in (lambda: dm.train_dataparser_outputs.cameras, lambda: dm.train_dataset.cameras):
        try:
            cameras = getter()
            break
        except AttributeError:
            continue
    return pf, cameras


def run_export(
    pf: PropertyField,
    output_dir: Path,
    *,
    mass: MassConfig | None = None,
    outputs: Sequence[Output] = ("ply", "voxels", "maps", "mass"),
    views: Sequence[View] = (),
    voxel_resolution: int | None = None,
    top_k: int = 3,
    truth_kg: float | None = None,
    title: str | None = None,
    quiet: bool = False,
) -> ExportResult:
    """Write the chosen outputs of ``pf`` into ``output_dir`` and print the mass table."""
    from rich.console import Console

    console = Console(quiet=quiet)
    out = Path(output_dir)
    out.mkdir(parents=True, exist_ok=True)
    mass = mass or MassConfig()
    files: dict[str, list[Path]] = {}
    if pf.simulated:
        console.print("[bold yellow]Material posteriors come from the SIMULATED VLM (generated scene).[/]")
    if "ply" in outputs:
        files["ply"] = [write_property_ply(pf, out / "property_field.ply", top_k=top_k)]
        console.log(f"PLY: {files['ply'][0]} ({pf.num_gaussians} Gaussians)")
    geometry = None
    report = None
    if "mass" in outputs:
        geometry = mass_geometry(pf, mass)
        report = integrate_mass(pf, mass, geometry=geometry)
    if "voxels" in outputs:
        occ_cfg = mass.occupancy
        reuse = geometry.occupancy if geometry is not None and voxel_resolution in (None, occ_cfg.resolution) else None
        if voxel_resolution is not None and voxel_resolution != occ_cfg.resolution:
            from dataclasses import replace

            occ_cfg = replace(occ_cfg, resolution=voxel_resolution)
        files["voxels"] = [write_voxel_grid(pf, out / "voxels.npz", occ_cfg, occupancy=reuse)]
        console.log(f"voxel grid: {files['voxels'][0]}")
    if "maps" in outputs and views:
        files["maps"] = save_property_maps(pf, views, out / "maps")
        console.log(f"property maps: {len(files['maps'])} view(s) in {out / 'maps'}")
    if report is not None:
        extra: dict[str, Any] = {"files": {k: [str(p) for p in v] for k, v in files.items()},
                                 "legend": pf.legend(), "simulated": pf.simulated}  # fmt: skip
        if truth_kg is not None:
            extra["ground_truth_kg"] = truth_kg
            extra["interval_covers_truth"] = report.covers(truth_kg)
        files["report"] = [write_report(report, out / "report.json", extra)]
        print_mass_table(report, title=title, truth_kg=truth_kg, console=console)
    return ExportResult(files, report)


@dataclass
class ExportCommand:
    """Export a trained PhysGS run: property PLY, voxel grid, property maps and the mass (mean, interval)."""

    load_config: Path
    """config.yml of the `ns-train physgs` / `physgs-lite` run"""
    output_dir: Path = Path("export")
    outputs: tuple[Output, ...] = ("ply", "voxels", "maps", "mass")
    resolution: int = 128
    """voxels along the longest side of the object's box (mass)"""
    voxel_resolution: int | None = None
    """resolution of voxels.npz (default: the mass resolution)"""
    volume_model: Literal["auto", "solid", "shell"] = "auto"
    """auto: materials with a wall thickness (materials.json / library) are shells, the others solid"""
    volume_models: dict[str, str] = field(default_factory=dict)
    """per material name: solid | shell"""
    shell_surface: Literal["auto", "mid", "outer"] = "auto"
    fill: Literal["3d", "slices", "none"] = "3d"
    threshold: float = 0.5
    """occupancy threshold, a fraction of the opacity field's plateau"""
    select: Literal["auto", "labelled", "largest", "all"] = "auto"
    """which Gaussians make the object: labelled = those the material maps label (labelled fraction >=
    min_labelled, evidence >= min_evidence), then their largest connected part; largest = the largest part of
    all Gaussians; all = every part; auto = labelled when the run was lifted, else largest"""
    min_labelled: float = 0.5
    """select=labelled: minimum share of a Gaussian's blending weight that fell on labelled pixels"""
    min_evidence: float = 0.05
    """select=labelled: minimum total lifted evidence of a Gaussian"""
    bbox: tuple[float, float, float, float, float, float] | None = None
    """object box (xmin ymin zmin xmax ymax zmax) in scene units (the viewer's crop frame), combined with
    select; default: the Gaussians' extent"""
    scale: float | None = None
    """metres per dataset unit (default: the dataset is metric)"""
    known_length: tuple[float, float, float, float, float, float, float] | None = None
    """x1 y1 z1 x2 y2 z2 distance_m: two points in dataset coordinates and their true distance"""
    n_samples: int = 4000
    seed: int = 0
    level: float = 0.9
    views: tuple[int, ...] = (0,)
    """training camera indices to render property maps for"""
    max_map_width: int = 480
    top_k: int = 3
    env: str | None = None
    """material library for thickness fallbacks (default: materials.json's env)"""
    truth_kg: float | None = None
    """ground-truth mass, if known: printed and checked against the interval"""
    device: Literal["auto", "cpu", "cuda"] = "auto"

    def mass_config(self) -> MassConfig:
        occ = OccupancyConfig(resolution=self.resolution, threshold=self.threshold, fill=self.fill, bbox=self.bbox,
                              select=self.select, min_labelled=self.min_labelled,
                              min_evidence=self.min_evidence)  # fmt: skip
        return MassConfig(occupancy=occ, volume_model=self.volume_model, volume_models=dict(self.volume_models),
                          shell_surface=self.shell_surface, n_samples=self.n_samples, seed=self.seed,
                          level=self.level)  # fmt: skip

    def main(self) -> ExportResult:
        pf, cameras = load_run(self.load_config, scale=self.scale, known_length=self.known_length, env=self.env)
        device = ("cuda" if torch.cuda.is_available() else "cpu") if self.device == "auto" else self.device
        pf = pf.to(device)
        views = views_from_cameras(cameras, self.views, self.max_map_width) if cameras is not None else []
        if "maps" in self.outputs and cameras is None:
            logger.warning("no training cameras found in the run: property maps skipped")
        return run_export(pf, self.output_dir, mass=self.mass_config(), outputs=self.outputs, views=views,
                          voxel_resolution=self.voxel_resolution, top_k=self.top_k, truth_kg=self.truth_kg,
                          title=f"Mass of {self.load_config.parent.name}")  # fmt: skip
