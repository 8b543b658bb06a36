"""Generated scenes (``physgs synth``): the known total mass of each scene's ``ground_truth.json``.

``--ground-truth`` is one generated scene folder, or a folder of them (``physgs synth --suite`` writes
``<out>/<object>/``). Each scene is scored by its folder name against ``<results>/<scene>/**/report.json``
(``physgs export``); group = the generated object's name. This is how the design goal "90 % intervals
cover the truth about 90 % of the time" is measured.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import input_error
from ..fileio import load_json, to_float
from ..records import Measurement

__all__ = ["GROUND_TRUTH_FILE", "read_synth_truth"]

GROUND_TRUTH_FILE = "ground_truth.json"


def read_synth_truth(path: Path) -> list[Measurement]:
    path = Path(path)
    if (path / GROUND_TRUTH_FILE).is_file():
        files = [path / GROUND_TRUTH_FILE]
    elif path.is_dir():
        files = sorted(p / GROUND_TRUTH_FILE for p in path.iterdir() if (p / GROUND_TRUTH_FILE).is_file())
    else:
        files = []
    if not files:
        raise input_error(path, None, f"no {GROUND_TRUTH_FILE} here or in its sub-folders",
                          "Pass a scene folder written by `physgs synth` (or the --suite output folder)")
    out = []
    for f in files:
        gt = load_json(f)
        if not isinstance(gt, dict) or "total_mass_kg" not in gt:
            raise input_error(f, "key 'total_mass_kg'", "missing", "Regenerate the scene with `physgs synth`")
        mass = to_float(gt["total_mass_kg"], f, "key 'total_mass_kg'", "total mass (kg)", positive=True)
        out.append(Measurement(item=f.parent.name, prop="mass", value=mass, unit="kg",
                               group=str(gt.get("object") or f.parent.name), source=str(f)))
    return out
