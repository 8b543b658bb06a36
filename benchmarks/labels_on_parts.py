"""What the perceived material maps say on each true part of a generated scene, over all its views.

    python benchmarks/labels_on_parts.py SCENE [SCENE ...]

SCENE is a dataset from `physgs synth` after `physgs perceive` (its ``gt/part`` maps and ``materials/labels``).
Prints per part: its name and true material, its pixel count over the views, and the four most frequent perceived
labels on those pixels as shares ("unlabelled": label 0). Separates a mass miss that perception makes (a thin steel
part labelled as the wood around it) from one the geometry makes (issue 12).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from PIL import Image


def label_shares(scene: Path) -> list[tuple[str, str, int, dict[str, float]]]:
    truth = json.loads((scene / "ground_truth.json").read_text())
    parts = {i + 1: (p["name"], p["material"]) for i, p in enumerate(truth["parts"])}  # gt/part ids are 1-based
    names = {m["id"]: m["name"] for m in json.loads((scene / "materials.json").read_text())["materials"]}
    counts: dict[int, dict[str, int]] = {}
    for f in sorted((scene / "gt" / "part").glob("*.png")):
        part = np.asarray(Image.open(f))
        labels = Image.open(scene / "materials" / "labels" / f.name)
        lab = np.asarray(labels.resize(part.shape[::-1], Image.Resampling.NEAREST))
        for pid in np.unique(part[part > 0]):
            vals, n = np.unique(lab[part == pid], return_counts=True)
            d = counts.setdefault(int(pid), {})
            for v, c in zip(vals, n):
                key = names.get(int(v), "unlabelled")
                d[key] = d.get(key, 0) + int(c)
    out = []
    for pid, d in sorted(counts.items()):
        total = sum(d.values())
        top = dict(sorted(((k, v / total) for k, v in d.items()), key=lambda kv: -kv[1])[:4])
        name, material = parts.get(pid, (f"part {pid}", "?"))
        out.append((name, material, total, top))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", type=Path, nargs="+")
    for scene in ap.parse_args().scenes:
        print(scene)
        for name, material, total, top in label_shares(scene):
            shares = ", ".join(f"{k} {v:.3f}" for k, v in top.items())
            print(f"  {name:12s} ({material}) {total:6d} px: {shares}")


if __name__ == "__main__":
    main()
