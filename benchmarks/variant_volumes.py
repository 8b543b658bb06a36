"""Each geometry variant's carved volume against the true enclosed volume, over saved mass-suite results.

    python benchmarks/variant_volumes.py benchmarks/results/gpu_*/mass_suite_gpu_s*.json
        [--variants nominal front2x] [--objects chair table crate stool dumbbell bottle] [--json out.json]

Every row of a suite JSON (`benchmarks/mass_suite.py`) records the export's carved volume under each of the
mass interval's geometry variants (``volume_by_variant_m3``: the nominal carving, the masks eroded and
dilated, the vote, the depth margin, the front extent k - 1 and k + 1, ...) and the true parts' enclosed
volumes. Dividing one by the other tells, from results already run, how a variant would do as the nominal
carving, without training again. Per file it prints, for each variant, the median over the objects of
``|carved / enclosed - 1|`` and the median ratio, then each object's ratio under the variants asked for.

Only objects whose true parts' enclosed volumes add up to their solid are counted (the default ``--objects``).
An open vessel's (mug, pan, vase) carving keeps only part of its open inside, the hammer's rubber grip
encloses its handle (counted twice), and the lamp's shade and the shoe's upper enclose space that no view
sees; their ratios say where the carving left that space, not how well it placed the faces. The total over an
object's parts also hides which part a voxel went to (`voxel_truth.py` tells that). A proxy for the mass,
then: the masses under a variant need the runs exported with it (`mass_suite.py --trained --export-args ...`).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

DEFAULT_OBJECTS = ("chair", "table", "crate", "stool", "dumbbell", "bottle")


Ratios = dict[str, dict[str, float]]


def variant_ratios(rows: list[dict], objects: tuple[str, ...] = DEFAULT_OBJECTS) -> Ratios:
    """{object: {variant: carved / true enclosed volume}} for the rows of ``objects`` with their variants."""
    out: Ratios = {}
    for r in rows:
        variants = r.get("volume_by_variant_m3") or {}
        if r.get("object") not in objects or not variants:
            continue
        enclosed = sum(float(p["enclosed_volume_m3"]) for p in r.get("true_parts", []))
        if enclosed > 0:
            out[r["object"]] = {k: float(v) / enclosed for k, v in variants.items()}
    return out


def summary(ratios: Ratios) -> dict[str, dict[str, float]]:
    """{variant: {"median_abs_error", "median_ratio", "objects"}} over the objects that have that variant."""
    names = sorted({v for r in ratios.values() for v in r}, key=lambda v: (v != "nominal", v))
    out = {}
    for v in names:
        vals = [r[v] for r in ratios.values() if v in r]
        out[v] = {"median_abs_error": statistics.median(abs(x - 1) for x in vals),
                  "median_ratio": statistics.median(vals), "objects": len(vals)}  # fmt: skip
    return out


def _rows(path: Path) -> list[dict]:
    d = json.loads(path.read_text())
    rows = d["rows"] if isinstance(d, dict) and "rows" in d else d
    if not isinstance(rows, list):
        raise SystemExit(f"{path}: not a mass-suite result (no list of rows)")
    return rows


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+", type=Path, help="mass_suite.py JSON files")
    ap.add_argument("--objects", nargs="+", default=list(DEFAULT_OBJECTS))
    ap.add_argument("--variants", nargs="+", default=["nominal"],
                    help="variants whose per-object ratios to print")
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args(argv)
    report = {}
    for path in a.results:
        ratios = variant_ratios(_rows(path), tuple(a.objects))
        if not ratios:
            print(f"{path.name}: no row of {' '.join(a.objects)} with its variants' volumes", file=sys.stderr)
            continue
        s = summary(ratios)
        report[str(path)] = {"summary": s, "ratios": ratios}
        print(f"{path.name} ({len(ratios)} objects): median |carved / enclosed - 1| by variant")
        for v, row in s.items():
            print(f"  {v:14s} {row['median_abs_error']:.3f}  (median ratio {row['median_ratio']:.3f})")
        for v in a.variants:
            print(f"  {v}: " + " ".join(f"{o} {r[v]:.2f}" for o, r in ratios.items() if v in r))
    if a.json:
        a.json.write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
