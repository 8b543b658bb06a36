"""Each rule of the mass geometry switched off, on finished `mass_suite.py` runs: what the rule is worth over the suite.

    python benchmarks/mass_suite.py --renderers mitsuba --seeds 71001 --out OUT --jobs 2 \\
        --families mug chair hammer bottle shoe table pan lamp crate stool dumbbell vase bowl bucket book plank
    python benchmarks/geometry_ablation.py --out OUT --jobs 2                        # every rule off, on OUT's runs
    python benchmarks/geometry_ablation.py --out OUT1 OUT2 --only noslope concave2   # two suites (seeds) as one
    python benchmarks/geometry_ablation.py --out OUT1 OUT2 --summarize --json results.json

Each row re-exports every finished run of OUT (`mass_suite.py --export-args ... --alt-name NAME`: the trained splat
and its perception are the same, only the geometry's settings change) with one rule off or moved, and scores it
beside the runs' own export (``default``). Per row: median APE, mean |log(predicted / true)| (every object's error
counts, not only the middle one), median volume error, 90% coverage, objects off by 2x, share with the support
counted, and the objects whose mass moved by more than 5% against the default. A rule is worth keeping when switching
it off makes the suite worse, not when it helps one object. Re-exports reuse nothing of the default's geometry
(the geometry cache's key holds the settings), and take about a minute and a half for 16 CPU runs on 2 cores.
Families are the runs' own: run it on the development families (`synth.families.DEVELOPMENT`) only; defaults are
never chosen on the held-out ones.

Output: a JSON (``--json``; default OUT/geometry_ablation.json of the first OUT: the rows and per-object ratios) and a
printed Markdown table.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import subprocess
import sys
from pathlib import Path

# name -> (flags of `physgs export`, what the row switches off or moves)
RULES: dict[str, tuple[str, str]] = {
    "noextent": ("--mass.geometry.extent-pad-voxels 1e6", "no cut to the seen Gaussians' polytope"),
    "noconsensus": ("--mass.geometry.carve.depth-consensus 0", "no depth consensus in the free-space vote"),
    "noslope": ("--mass.geometry.carve.depth-slope-margin 0", "no depth-lookup slack in the margin"),
    "noseen": ("--mass.geometry.hidden-skin-seen 1e6", "every axis end samples the hidden-space skin"),
    "norefit": ("--mass.geometry.refit-fraction 0", "no second carving on a grid fitted to the solid"),
    "up1": ("--mass.geometry.interior-up-weight 1", "interior materials by Euclidean nearest voxel"),
    "nosupport": ("--mass.geometry.select.support.no-enabled", "no support plane (the contact cut only)"),
    "noconcave": ("--mass.geometry.concavity-px 1e6", "no concavities: a wall's inner face counts as wall"),
    "concave2": ("--mass.geometry.concavity-px 2", "concavities from 2 px inside the masks' hull (default 3)"),
    "concave5": ("--mass.geometry.concavity-px 5", "concavities from 5 px inside the masks' hull (default 3)"),
    "noevid": ("--mass.geometry.evidence-surface-voxels 1e6", "every selected Gaussian's labels are evidence"),
    "nodilate": ("--mass.geometry.object-mask-dilate-px 0", "the object's silhouette cuts the masks undilated"),
    "nohulldrop": ("--mass.geometry.select.hull-vote-fraction 1.0 --mass.geometry.select.hull-min-framed-fraction 0",
                   "no selected Gaussian dropped outside the masks' hull"),
    "nofillcav": ("--mass.geometry.carve.no-fill-cavities", "enclosed empty pockets stay empty"),
    "nominseen": ("--mass.geometry.carve.min-seen-fraction 0", "space out of frame in most views stays"),
    "nooutlier": ("--mass.geometry.extent-outlier-fraction 0", "the polytope's outermost Gaussians all count"),
    "nocband": ("--mass.geometry.select.contact-band 0", "no contact band over the support in the clusters"),
    "nominpart": ("--mass.geometry.min-part-fraction 0 --mass.geometry.min-part-observation 0",
                  "no pooling of small or unobserved parts"),
    "novoxevid": ("--mass.geometry.min-voxel-evidence 1e-3", "almost every voxel with evidence has its own mixture"),
    "novariants": ("--mass.geometry.no-variants", "the nominal carving only (the interval without geometry)"),
    "seam0": ("--mass.seam-offset-voxels 0", "no seam offset between parts"),
}


def _rows(outs: list[Path], name: str) -> dict[str, dict] | None:
    """Every OUT's rows of one re-export (``default``: the runs' own), keyed by run; None where an OUT lacks it."""
    rows: dict[str, dict] = {}
    for out in outs:
        f = out / ("mass_suite.json" if name == "default" else f"mass_suite_{name}.json")
        if not f.is_file():
            return None
        rows.update({f"{r['family']}_s{r['seed']}_{r['renderer']}": r for r in json.loads(f.read_text())["rows"]})
    return rows


def _ok(r: dict) -> bool:
    return not r.get("failed") and r.get("pred_kg") is not None


def row_summary(rows: dict[str, dict], default: dict[str, dict]) -> dict:
    """One row of the table (module doc); ``default``: the runs' own export, for the objects that moved."""
    ok = [r for r in rows.values() if _ok(r)]
    ratio = {k: r["pred_kg"] / r["truth_kg"] for k, r in rows.items() if _ok(r)}
    vol = [abs(r["error"]["volume"] - 1) for r in ok if r.get("error", {}).get("volume") is not None]
    moved = sorted(k for k, r in rows.items()
                   if _ok(r) and k in default and _ok(default[k])
                   and abs(r["pred_kg"] / default[k]["pred_kg"] - 1) > 0.05)  # fmt: skip
    return {"objects": len(ok), "failed": len(rows) - len(ok),
            "median_ape": statistics.median(r["ape"] for r in ok) if ok else None,
            "mean_abs_log": statistics.fmean(abs(math.log(x)) for x in ratio.values() if x > 0) if ratio else None,
            "median_volume_error": statistics.median(vol) if vol else None,
            "coverage": sum(bool(r["covered"]) for r in ok) / len(ok) if ok else None,
            "off_2x": sum(not 0.5 <= x <= 2 for x in ratio.values()),
            "support_counted": sum(bool(r.get("support_kg", 0) > 0.05 * r["truth_kg"]) for r in ok),
            "moved_5pct": moved, "ratios": ratio}  # fmt: skip


def table(summary: dict[str, dict], rules: dict[str, tuple[str, str]] = RULES) -> str:
    def f(x, fmt):
        return "-" if x is None else format(x, fmt)

    lines = ["| row | switched off or moved | objects | median APE | mean abs log | median volume error | coverage "
             "| off by 2x | support counted | moved > 5% |", "|---" * 10 + "|"]
    for name, s in summary.items():
        what = "the defaults" if name == "default" else rules[name][1]
        lines.append(f"| {name} | {what} | {s['objects']} | {f(s['median_ape'], '.3f')} | {f(s['mean_abs_log'], '.3f')}"
                     f" | {f(s['median_volume_error'], '.3f')} | {f(s['coverage'], '.0%')} | {s['off_2x']} | "
                     f"{s['support_counted']} | {len(s['moved_5pct'])} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, nargs="+", required=True, help="finished mass_suite.py output folders")
    ap.add_argument("--only", nargs="*", default=None, choices=sorted(RULES), help="these rows only")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--mesh-dir", type=Path, default=None)
    ap.add_argument("--summarize", action="store_true", help="score the re-exports already in OUT, run nothing")
    ap.add_argument("--json", type=Path, default=None, help="where the JSON goes (default: the first OUT)")
    a = ap.parse_args(argv)
    default = _rows(a.out, "default")
    if default is None:
        sys.exit(f"geometry_ablation: mass_suite.json not found in every one of {[str(o) for o in a.out]}: run "
                 "benchmarks/mass_suite.py first.")  # fmt: skip
    names = a.only if a.only is not None else list(RULES)
    suite = Path(__file__).resolve().with_name("mass_suite.py")
    for name in names if not a.summarize else []:
        print(f"== {name}: {RULES[name][1]}", flush=True)
        for out in a.out:
            runs = json.loads((out / "mass_suite.json").read_text())["rows"]
            cmd = [sys.executable, str(suite), "--out", str(out), "--seeds", *sorted({str(r["seed"]) for r in runs}),
                   "--renderers", *sorted({r["renderer"] for r in runs}), "--families",
                   *sorted({r["family"] for r in runs}), "--jobs", str(a.jobs), "--alt-name", name,
                   f"--export-args={RULES[name][0]}", *(["--mesh-dir", str(a.mesh_dir)] if a.mesh_dir else [])]
            subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    summary = {"default": row_summary(default, default)}
    for name in names:
        rows = _rows(a.out, name)
        if rows is not None:
            summary[name] = row_summary(rows, default)
    seeds = sorted({r["seed"] for r in default.values()})
    (a.json or a.out[0] / "geometry_ablation.json").write_text(json.dumps(
        {"seeds": seeds, "renderers": sorted({r["renderer"] for r in default.values()}),
         "rules": {n: RULES[n] for n in summary if n in RULES}, "summary": summary}, indent=2))  # fmt: skip
    print(table(summary))


if __name__ == "__main__":
    main()
