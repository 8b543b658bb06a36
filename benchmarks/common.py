"""What more than one benchmark needs: a trained run on the export's device, a generated scene's truth in world
coordinates, and the one summary table each benchmark prints."""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from physgs_nerfstudio.export.command import load_run

_OFFSETS = np.array([[a, b, c] for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)], float)


def load_run_on_device(config: Path, **kw):
    """``load_run`` with the field moved to the GPU where there is one, as `physgs export` does (on the CPU the
    selection of a GPU run's million Gaussians takes minutes on the reference rasterizer)."""
    run = load_run(config, **kw)
    run.field = run.field.to("cuda" if torch.cuda.is_available() else "cpu")
    return run


def scene_transform(run_dir: Path) -> tuple[np.ndarray, float]:
    """The run's dataparser transform ([3, 4]) and scale, from ``dataparser_transforms.json`` beside its config."""
    meta = json.loads((run_dir / "dataparser_transforms.json").read_text())
    return np.asarray(meta["transform"], float), float(meta["scale"])


def to_world(x_scene: np.ndarray, T: np.ndarray, s: float) -> np.ndarray:
    """Points of the trained scene back in the dataset's (the generator's) coordinates: the inverse of
    ``p_s = s (R p_d + t)``."""
    R, t = T[:, :3], T[:, 3]
    return (x_scene / s - t) @ R


def part_of(parts: list, pw: np.ndarray, near: float) -> np.ndarray:
    """int [N]: index of the first generated part whose solid holds a point within ``near`` metres of each world
    point (a 27-point stencil), -1 if none."""
    out = np.full(len(pw), -1, np.int64)
    for i, p in enumerate(parts):
        hit = np.zeros(len(pw), bool)
        for o in _OFFSETS * (near / np.sqrt(3) if near > 0 else 0.0):
            hit |= p.primitive.contains(p.to_local(pw + o))
            if near == 0:
                break
        out[(out < 0) & hit] = i
    return out


def format_table(header: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    """A Markdown table: floats with 4 significant digits, None as a dash."""

    def cell(v: object) -> str:
        if v is None:
            return "-"
        if isinstance(v, float):
            return f"{v:.4g}"
        return str(v)

    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def write_summary(path: Path, summary: dict) -> None:
    """The benchmark's one summary JSON (its folder made if missing)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(summary, indent=1) + "\n")
