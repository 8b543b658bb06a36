"""Picture of what generated data looks like: rendered views next to their ground-truth material maps.

    python -m physgs_nerfstudio.synth.example docs/synth_example.png
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

from .dataset import SynthConfig, _atomic_write, _png, generate_scene, load_ground_truth

EXAMPLES: tuple[tuple[str, int], ...] = (("mug", 2), ("chair", 2), ("indoor_room", 2), ("outdoor_patch", 0))


def material_legend_image(labels: np.ndarray, materials: list[dict]) -> np.ndarray:
    """Label map (0 = background) -> RGB with the library's legend colours (background black)."""
    lut = np.zeros((256, 3), dtype=np.uint8)
    for m in materials:
        lut[m["id"]] = m["color"]
    return lut[labels]


def write_example(path: Path, resolution: int = 192, seed: int = 0) -> Path:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, frame in EXAMPLES:
            out = generate_scene(SynthConfig(out=Path(tmp) / name, object=name, views=4, seed=seed,
                                             resolution=resolution, num_points=500, background_points=0,
                                             supersample=2))
            gt = load_ground_truth(out)
            rgb = np.asarray(Image.open(out / gt["frames"][frame]["file_path"]).convert("RGB"))
            labels = np.asarray(Image.open(out / gt["frames"][frame]["material_path"]))
            gap = np.full((resolution, 4, 3), 255, np.uint8)
            rows.append(np.concatenate([rgb, gap, material_legend_image(labels, gt["materials"])], 1))
    # two pairs per row: | rgb | material | rgb | material |
    vgap = np.full((resolution, 12, 3), 255, np.uint8)
    lines = [np.concatenate([rows[i], vgap, rows[i + 1]], 1) for i in range(0, len(rows), 2)]
    hgap = np.full((12, lines[0].shape[1], 3), 255, np.uint8)
    sheet = np.concatenate([np.concatenate([line, hgap], 0) for line in lines], 0)[:-12]
    _atomic_write(Path(path), _png(sheet))
    return Path(path)


if __name__ == "__main__":
    print(write_example(Path(sys.argv[1] if len(sys.argv) > 1 else "docs/synth_example.png")))
