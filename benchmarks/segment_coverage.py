"""The built-in segmenter against the generator's material maps: how much of each material a mask names right.

    python benchmarks/segment_coverage.py --out /tmp/segcov --seed 19191 --resolution 512 --views 8
    python benchmarks/segment_coverage.py --out /tmp/segcov --resolution 96 --modes slic slic+graph --json F

Generates the suite (``physgs synth --suite``, skipped where it exists), segments every view with each
``--modes`` value of ``BuiltinSegmenterConfig.oversegment`` and reports, per object and material, the share of
the material's pixels that some mask whose majority ground-truth material is that material covers: what a VLM that
names a mask's majority material (the simulated one does) can get right. Also the masks per view (the VLM's calls)
and the object's recall by the ``whole``-level masks (the share of the object's pixels that their union holds, over
every view): the object masks that the carving's silhouettes come from. And per material the *mislabelled* share:
its pixels inside a part or subpart mask whose majority is another material (what that mask's answer paints wrong).
A mode ``MODE:thinX`` also groups the thin fragments (``BuiltinSegmenterConfig.thin_chroma`` X), e.g.
``--modes slic+graph slic+graph:thin4``.
Seeds used by the tests (0, 7) should not be used here.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from physgs_nerfstudio.perception.segment_builtin import BuiltinSegmenterConfig


def scene_coverage(root: Path, segmenter) -> tuple[dict[str, float], float, float, dict[str, float]]:
    """{material: covered share} over the scene's views, the masks per view, the whole masks' recall and {material:
    mislabelled share}: the share of its pixels inside a part or subpart mask whose majority is another material
    (what such a mask's answer paints wrong)."""
    gt = json.loads((root / "ground_truth.json").read_text())
    names = {m["id"]: m["name"] for m in gt["materials"]}
    covered_px = dict.fromkeys(names, 0)
    wrong_px = dict.fromkeys(names, 0)
    total_px = dict.fromkeys(names, 0)
    images = sorted((root / "images").glob("*.png"))
    n_masks = 0
    object_px = whole_px = 0
    for im in images:
        truth = np.asarray(Image.open(root / "gt" / "material" / im.name))  # 8-bit material index, 0 = background
        masks = segmenter.segment(np.asarray(Image.open(im).convert("RGB")))
        n_masks += len(masks)
        covered = np.zeros(truth.shape, bool)
        whole = np.zeros(truth.shape, bool)
        wrong = np.zeros(truth.shape, bool)
        for m in masks:
            vals, counts = np.unique(truth[m.segmentation], return_counts=True)
            majority = vals[np.argmax(counts)]
            if majority != 0:
                covered |= m.segmentation & (truth == majority)
                if m.level != "whole":
                    wrong |= m.segmentation & (truth != majority)
            if m.level == "whole":
                whole |= m.segmentation
        object_px += int((truth > 0).sum())
        whole_px += int((whole & (truth > 0)).sum())
        for k in names:
            sel = truth == k
            total_px[k] += int(sel.sum())
            covered_px[k] += int((covered & sel).sum())
            wrong_px[k] += int((wrong & sel).sum())
    cov = {names[k]: covered_px[k] / total_px[k] for k in names if total_px[k]}
    mislabelled = {names[k]: wrong_px[k] / total_px[k] for k in names if total_px[k]}
    return cov, n_masks / max(len(images), 1), whole_px / max(object_px, 1), mislabelled


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True, help="the generated suite's directory")
    ap.add_argument("--seed", type=int, default=19191)
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--modes", nargs="*", default=["slic", "slic+graph"],
                    help="oversegment values; MODE:thinX also sets thin_chroma=X (e.g. slic+graph:thin4)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    if not (args.out / "vase" / "ground_truth.json").is_file():
        subprocess.run([sys.executable, "-m", "physgs_nerfstudio.cli", "synth", "--suite", "--out", str(args.out),
                        "--views", str(args.views), "--seed", str(args.seed), "--resolution", str(args.resolution),
                        "--overwrite"], check=True)  # fmt: skip
    objects = sorted(p.parent for p in args.out.glob("*/ground_truth.json"))
    result: dict = {"seed": args.seed, "resolution": args.resolution, "views": args.views, "modes": {}}
    for mode in args.modes:
        over, _, thin = mode.partition(":thin")
        seg = BuiltinSegmenterConfig(oversegment=over, thin_chroma=float(thin) if thin else None).setup()
        t0 = time.perf_counter()
        per = {}
        for root in objects:
            cov, mpv, recall, wrong = scene_coverage(root, seg)
            per[root.name] = {"coverage": cov, "masks_per_view": mpv, "whole_recall": recall, "mislabelled": wrong}
            shares = " ".join(f"{k}:{v:.2f}" for k, v in cov.items())
            print(f"{mode:11s} {root.name:9s} masks/view {mpv:5.1f}  whole recall {recall:.2f}  {shares}", flush=True)
        shares = [v for o in per.values() for v in o["coverage"].values()]
        wrongs = [v for o in per.values() for v in o["mislabelled"].values()]
        summary = {"mean_coverage": statistics.fmean(shares), "min_coverage": min(shares),
                   "mean_mislabelled": statistics.fmean(wrongs), "max_mislabelled": max(wrongs),
                   "masks_per_view": statistics.fmean(o["masks_per_view"] for o in per.values()),
                   "whole_recall": statistics.fmean(o["whole_recall"] for o in per.values()),
                   "seconds": time.perf_counter() - t0}  # fmt: skip
        result["modes"][mode] = {"objects": per, **summary}
        print(f"{mode}: mean material coverage {summary['mean_coverage']:.3f}, lowest {summary['min_coverage']:.3f}, "
              f"mislabelled mean {summary['mean_mislabelled']:.3f} (highest {summary['max_mislabelled']:.3f}), "
              f"{summary['masks_per_view']:.1f} masks per view, whole recall {summary['whole_recall']:.3f}, "
              f"{summary['seconds']:.0f} s")
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
