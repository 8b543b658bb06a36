"""``sim/manifest.json``: every file of the simulator export, its units, the object's frame and the values written."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["manifest"]

FORMAT = "physgs-sim/1"


def _spread(rows: list[dict], report: Any) -> dict | None:
    if not rows:
        return None
    m = np.array([r["mass_kg"] for r in rows])
    return {"count": len(rows), "mass_mean_kg": float(m.mean()), "mass_min_kg": float(m.min()),
            "mass_max_kg": float(m.max()), "report_interval_kg": list(report.interval_kg) if report else None,
            "inside_report_interval": int(((m >= report.interval_kg[0]) & (m <= report.interval_kg[1])).sum())
            if report else None}  # fmt: skip


def manifest(build: Any, report: Any, files: list[Path], folder: Path, rows: list[dict],
             dataparser: dict | None) -> dict:  # fmt: skip
    """The manifest's content (module doc)."""
    obj = build.obj
    return {
        "format": FORMAT,
        "object": obj.name,
        "files": sorted(p.relative_to(folder).as_posix() for p in files),
        "units": {"length": "m", "mass": "kg", "inertia": "kg m^2", "density": "kg/m^3", "friction": "1",
                  "youngs_modulus": "Pa", "time": "s"},
        "frame": {"up": "+z (gravity -z)", "up_source": build.up_source,
                  "origin": "under the solid's centroid, at its lowest point (the object rests on z = 0)",
                  "pose_in_scene_m": build.frame.pose_matrix().tolist(),
                  "pose_note": "scene (nerfstudio's dataparser frame, scaled to metres) from object coordinates",
                  "scene_metres_per_unit": float(report.metres_per_unit) if report is not None else None,
                  "dataparser_transform": dataparser},
        "body": obj.body.to_dict(),
        "report_mass_mean_kg": report.mean_kg if report is not None else None,
        "parts": {str(p): {**vars(m), "triangles": next((len(x.faces) for x in obj.meshes if x.part == p), 0),
                           "collision_pieces": next((len(x.collision) for x in obj.meshes if x.part == p), 0)}
                  for p, m in obj.materials.items()},
        "collision": obj.collision_method,
        "usd": "object.usda" if (folder / "object.usda").is_file() else "not written: pip install usd-core",
        "friction_note": "kinetic (dynamic) friction of the fused posterior; static friction is not estimated",
        "samples": _spread(rows, report),
    }  # fmt: skip
