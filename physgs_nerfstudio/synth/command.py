"""`physgs synth`: write a generated scene (or the named suite) as nerfstudio datasets with ground truth."""

from __future__ import annotations

import time
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Literal

from .dataset import SynthConfig, generate_scene, load_ground_truth, scene_names
from .objects import DEFAULT_MESH_DIR, SUITE


@dataclass
class SynthCommand:
    """Generate scenes with known materials: a nerfstudio dataset plus ground_truth.json per scene."""

    out: Path
    """Output directory (with --suite: one sub-directory per object)."""
    object: str = "mug"
    """Object preset, family or scene layout; list: mug chair hammer bottle shoe table pan lamp crate stool dumbbell
    vase bowl bucket book plank kettle lidded_box pipe bin toy_car jar figurine, bunny armadillo (figurine, bunny and
    armadillo need their meshes in --mesh-dir) indoor_room outdoor_patch."""
    views: int = 24
    """Number of camera views."""
    seed: int = 0
    """Seed of everything random; the same seed gives identical bytes."""
    resolution: int = 128
    """Image width and height in pixels."""
    fov_deg: float = 50.0
    """Horizontal field of view in degrees."""
    radius: float | None = None
    """Camera distance in metres (default: frame the object)."""
    elevation_deg: tuple[float, float] | None = None
    """Camera elevation band in degrees (default: the layout's)."""
    env: str | None = None
    """Material library, indoor or outdoor (default: the layout's)."""
    num_points: int = 20000
    """Seed points on the surfaces (points.ply)."""
    property_jitter: float = 0.0
    """Spread of the true material properties around the library's typical values (0 = typical)."""
    supersample: int = 1
    """RGB supersampling per axis (anti-aliasing)."""
    mesh_dir: Path = DEFAULT_MESH_DIR
    """Directory of optional meshes (bunny.obj, armadillo.obj)."""
    shape: Literal["canonical", "drawn"] = "canonical"
    """canonical (the fixed preset) or drawn (a family member drawn from the seed; families only)."""
    support: Literal["none", "floor", "table", "drawn"] = "none"
    """none (floating), floor, table or drawn: a support under the object (families only)."""
    pose: Literal["standing", "lying", "stand", "drawn"] = "standing"
    """standing, lying, stand (on a small stand) or drawn (families only)."""
    renderer: Literal["project", "mitsuba"] = "project"
    """project (built-in ray caster) or mitsuba (path traced, needs the pathtrace extra)."""
    spp: int = 64
    """Samples per pixel of the mitsuba renderer."""
    suite: bool = False
    """Write every object of the named suite (SUITE) into out/<object>/ instead of one scene."""
    overwrite: bool = False
    """Replace existing datasets."""

    def config(self, name: str | None = None, out: Path | None = None) -> SynthConfig:
        shared = {f.name: getattr(self, f.name) for f in fields(SynthConfig) if hasattr(self, f.name)}
        cfg = SynthConfig(**shared)
        return replace(cfg, object=name or self.object, out=out or self.out)

    def main(self) -> None:
        if self.suite:
            jobs = [(name, Path(self.out) / name) for name in SUITE]
        else:
            if self.object not in scene_names():
                raise SystemExit(f"unknown object {self.object!r}; choose from: {', '.join(scene_names())}")
            jobs = [(self.object, Path(self.out))]
        rows = []
        for name, out in jobs:
            t0 = time.perf_counter()
            path = generate_scene(self.config(name, out))
            gt = load_ground_truth(path)
            rows.append((name, len(gt["parts"]), ", ".join(m["name"] for m in gt["materials"]),
                         gt["total_mass_kg"], time.perf_counter() - t0, path))
        _print_summary(rows, self.views, self.resolution)


def _print_summary(rows: list, views: int, resolution: int) -> None:
    try:
        from rich.console import Console
        from rich.table import Table
    except ImportError:  # pragma: no cover - rich ships with nerfstudio
        for r in rows:
            print(f"{r[0]}: {r[1]} parts, {r[3]:.3f} kg ({r[2]}) -> {r[5]} [{r[4]:.1f} s]")
        return
    table = Table(title=f"generated scenes ({views} views, {resolution}x{resolution})")
    for col in ("object", "parts", "materials", "mass [kg]", "time [s]", "dataset"):
        table.add_column(col)
    for name, n_parts, mats, mass, secs, path in rows:
        table.add_row(name, str(n_parts), mats, f"{mass:.3f}", f"{secs:.1f}", str(path))
    Console().print(table)


def entrypoint() -> None:
    """Stand-alone entry point (``python -m physgs_nerfstudio.synth.command``)."""
    import tyro

    tyro.cli(SynthCommand).main()


if __name__ == "__main__":
    entrypoint()
