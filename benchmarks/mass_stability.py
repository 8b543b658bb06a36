"""Mass stability over the documented range of every geometry option, on finished demo runs.

    python benchmarks/mass_stability.py /tmp/ms/table_s101 /tmp/ms/chair_s101 --jobs 4

For each run folder (a `physgs demo --output-dir` folder, trained and exported), re-exports the mass with each
option set to each end of its documented range (one option at a time, the rest at their defaults) and prints
the mean mass relative to the default export. Target: every change within 20%.
Writes one summary JSON (``--out``: every setting's mass per run) and prints one table (per run its largest change
and the setting that made it).

**Ablation** (``--ablation OUT [OUT ...]``): each rule of the mass geometry switched off (or moved), one at a time,
on finished `mass_suite.py` runs, scored against the truth. Each row re-exports every run of OUT
(`mass_suite.py --export-args ... --alt-name NAME`: the trained splat and its perception are the same, only the
geometry's settings change) and scores it beside the runs' own export (``default``): median APE, mean
|log(predicted / true)| (every object's error counts, not only the middle one), median volume error, 90% coverage,
objects off by 2x, the support counted, and the objects whose mass moved by more than 5% against the default. A rule
is worth keeping when switching it off makes the suite worse, not when it helps one object. Run it on the
development families only (`synth.families.DEVELOPMENT`); defaults are never chosen on the held-out ones. About a
minute and a half a row for 16 CPU runs on 2 cores. Writes ``--out`` (the rows and per-object ratios) and prints a
Markdown table.

    python benchmarks/mass_suite.py --renderers mitsuba --seeds 71001 --jobs 2 --out OUT --families mug chair \
        hammer bottle shoe table pan lamp crate stool dumbbell vase bowl bucket book plank
    python benchmarks/mass_stability.py --ablation OUT --jobs 2 --out geometry_ablation.json
    python benchmarks/mass_stability.py --ablation OUT1 OUT2 --only noslope concave2   # two seeds as one suite

**Surface offset** (``--surface-offset OUT [OUT ...]``): how far the carved surface lies off the true one, over the
finished runs' objects whose every part is solid: ``z = (V - V_true) / (S u)``, the volume error in resolution units
of surface (``S`` the carved surface area, ``u`` the carving's resolution). Its robust spread is the spread of
the surface placement that the mass's interval draws (``MassConfig.surface_offset_voxels``). Writes ``--out`` and
prints each object's offset.

    python benchmarks/mass_stability.py --surface-offset OUT1 OUT2 --out surface_offset_cpu.json
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import format_table, write_summary

# option -> the ends of its documented range (GeometryConfig / CarveConfig docs)
SETTINGS: dict[str, list[str]] = {
    "default": [],
    "resolution=96": ["--mass.geometry.resolution", "96"],
    "resolution=160": ["--mass.geometry.resolution", "160"],
    "min_votes=1": ["--mass.geometry.carve.min-votes", "1"],
    "min_votes=3": ["--mass.geometry.carve.min-votes", "3"],
    "min_vote_fraction=0.1": ["--mass.geometry.carve.min-vote-fraction", "0.1"],
    "min_vote_fraction=0.25": ["--mass.geometry.carve.min-vote-fraction", "0.25"],
    "depth_margin_voxels=-0.5": ["--mass.geometry.carve.depth-margin-voxels", "-0.5"],
    "depth_margin_voxels=1": ["--mass.geometry.carve.depth-margin-voxels", "1"],
    "hidden_skin_voxels=3": ["--mass.geometry.hidden-skin-voxels", "3"],
    "hidden_skin_tolerance=1.25": ["--mass.geometry.hidden-skin-tolerance", "1.25"],
    "hidden_skin_tolerance=2": ["--mass.geometry.hidden-skin-tolerance", "2"],
    "hidden_min_open_half=8": ["--mass.geometry.hidden-min-open-half", "8"],
    "hidden_skin_seen=0.5": ["--mass.geometry.hidden-skin-seen", "0.5"],
    "hidden_skin_seen=2": ["--mass.geometry.hidden-skin-seen", "2"],
    "hidden_skin_band=1": ["--mass.geometry.hidden-skin-band", "1"],
    "min_voxel_evidence=0.25": ["--mass.geometry.min-voxel-evidence", "0.25"],
    "min_voxel_evidence=1": ["--mass.geometry.min-voxel-evidence", "1"],
    "hull_vote_fraction=0.35": ["--mass.geometry.select.hull-vote-fraction", "0.35"],
    "hull_vote_fraction=0.65": ["--mass.geometry.select.hull-vote-fraction", "0.65"],
    "depth_consensus=0.35": ["--mass.geometry.carve.depth-consensus", "0.35"],
    "depth_consensus=0.65": ["--mass.geometry.carve.depth-consensus", "0.65"],
    "extent_pad_voxels=1": ["--mass.geometry.extent-pad-voxels", "1"],
    "extent_outlier_fraction=0": ["--mass.geometry.extent-outlier-fraction", "0"],
    "extent_outlier_fraction=0.003": ["--mass.geometry.extent-outlier-fraction", "0.003"],
    "evidence_surface_voxels=0.5": ["--mass.geometry.evidence-surface-voxels", "0.5"],
    "evidence_surface_voxels=2": ["--mass.geometry.evidence-surface-voxels", "2"],
    "no_variants": ["--mass.geometry.no-variants"],
    "structure_evidence=material": ["--mass.geometry.structure.evidence", "material"],
}


def export(run: Path, name: str, flags: list[str]) -> dict:
    cfg = next((run / "runs").glob("**/config.yml"))
    out = run / "stability" / name.replace("=", "_").replace("+", "p")
    cmd = [sys.executable, "-m", "physgs_nerfstudio.cli", "export", "--load-config", str(cfg), "--output-dir",
           str(out), "--outputs", "mass", "--overwrite", *flags]  # fmt: skip
    proc = subprocess.run(cmd, check=False, capture_output=True, text=True)
    if proc.returncode != 0:  # the error's own line (a CUDA error's last line is only advice), the rest on disk
        out.mkdir(parents=True, exist_ok=True)
        (out / "stderr.log").write_text(proc.stderr[-20000:])
        lines = proc.stderr.strip().splitlines() or ["failed"]
        said = [ln for ln in lines if "Error" in ln or "error:" in ln]
        return {"setting": name, "error": (said or lines)[-1], "rc": proc.returncode}
    rep = json.loads((out / "report.json").read_text())["mass"]
    return {"setting": name, "mean_kg": rep["mean_kg"], "interval_kg": rep["interval_kg"],
            "volume_m3": rep["volume_m3"]}  # fmt: skip


def sweep(run: Path, chosen: dict[str, list[str]], jobs: int) -> dict:
    """Every chosen setting's export of one run, each relative to the default's mass (the first)."""
    with ThreadPoolExecutor(max(1, jobs)) as pool:
        rows = list(pool.map(export, [run] * len(chosen), chosen, chosen.values()))
    base = rows[0].get("mean_kg")
    for r in rows:
        if base and "mean_kg" in r:
            r["relative_to_default"] = r["mean_kg"] / base
    changes = [(abs(r["relative_to_default"] - 1), r["setting"]) for r in rows[1:] if "relative_to_default" in r]
    worst, at = max(changes) if changes else (None, None)
    failed = [r["setting"] for r in rows if "error" in r]
    return {"default_kg": base, "largest_change": worst, "largest_change_setting": at, "failed": failed, "rows": rows}


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
    "surface0": ("--mass.surface-offset-voxels 0", "no surface offset (the surface where the carving put it)"),
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


def ablation_table(summary: dict[str, dict], rules: dict[str, tuple[str, str]] = RULES) -> str:
    def f(x, fmt):
        return "-" if x is None else format(x, fmt)

    head = ("| row | switched off or moved | objects | median APE | mean abs log | median volume error | coverage "
            "| off by 2x | support counted | moved > 5% |")
    lines = [head, "|---" * 10 + "|"]
    for name, s in summary.items():
        what = "the defaults" if name == "default" else rules[name][1]
        lines.append(f"| {name} | {what} | {s['objects']} | {f(s['median_ape'], '.3f')} | {f(s['mean_abs_log'], '.3f')}"
                     f" | {f(s['median_volume_error'], '.3f')} | {f(s['coverage'], '.0%')} | {s['off_2x']} | "
                     f"{s['support_counted']} | {len(s['moved_5pct'])} |")
    return "\n".join(lines)


def ablation(outs: list[Path], only: list[str] | None, jobs: int, summarize: bool, out: Path) -> None:
    """``--ablation`` (module doc): re-export OUT's runs once per rule (unless ``summarize``), then score every row."""
    default = _rows(outs, "default")
    if default is None:
        sys.exit(f"mass_stability: mass_suite.json not found in every one of {[str(o) for o in outs]}: run "
                 "benchmarks/mass_suite.py first.")  # fmt: skip
    names = only if only is not None else list(RULES)
    suite = Path(__file__).resolve().with_name("mass_suite.py")
    for name in names if not summarize else []:
        print(f"== {name}: {RULES[name][1]}", file=sys.stderr, flush=True)
        for o in outs:
            runs = json.loads((o / "mass_suite.json").read_text())["rows"]
            cmd = [sys.executable, str(suite), "--out", str(o), "--seeds", *sorted({str(r["seed"]) for r in runs}),
                   "--renderers", *sorted({r["renderer"] for r in runs}), "--families",
                   *sorted({r["family"] for r in runs}), "--jobs", str(jobs), "--alt-name", name,
                   f"--export-args={RULES[name][0]}"]  # fmt: skip
            subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    summary = {"default": row_summary(default, default)}
    for name in names:
        rows = _rows(outs, name)
        if rows is not None:
            summary[name] = row_summary(rows, default)
    write_summary(out, {"seeds": sorted({r["seed"] for r in default.values()}),
                        "renderers": sorted({r["renderer"] for r in default.values()}),
                        "rules": {n: RULES[n] for n in summary if n in RULES}, "summary": summary})  # fmt: skip
    print(ablation_table(summary))


def surface_offsets(outs: list[Path], out: Path) -> None:
    """``--surface-offset`` (module doc): the carved surface's offset ``z = (V - V_true) / (S u)`` in resolution
    units, over the objects whose every true part is solid (a hollow part's envelope is not its mass), from each
    run's own export; its robust spread (1.4826 x the median of |z|) is what ``MassConfig.surface_offset_voxels``
    draws."""
    rows = _rows(outs, "default")
    if rows is None:
        sys.exit(f"mass_stability: mass_suite.json not found in every one of {[str(o) for o in outs]}: run "
                 "benchmarks/mass_suite.py first.")  # fmt: skip
    z: dict[str, float] = {}
    for key, r in sorted(rows.items()):
        obj = [p for p in r.get("true_parts", []) if p.get("role", "object") == "object"]
        if not _ok(r) or not obj or any(p["volume_model"] != "solid" for p in obj):
            continue
        report = next(o / key / "export" / "report.json" for o in outs if (o / key).is_dir())
        rep = json.loads(report.read_text())["mass"]
        S = sum(p["surface_area_m2"] for p in rep["parts"])
        V = sum(p["volume_m3"] for p in rep["parts"])
        z[key] = (V - sum(p["volume_m3"] for p in obj)) / (S * rep["geometry"]["resolution_unit_m"])
    if not z:
        sys.exit("mass_stability: no finished run of an all-solid object in the given folders.")
    spread = 1.4826 * statistics.median(abs(v) for v in z.values())
    write_summary(out, {"objects": len(z), "robust_spread_voxels": spread, "median_voxels": statistics.median(z.values()),
                        "offsets_voxels": z})  # fmt: skip
    print(format_table(("run", "offset (resolution units)"), sorted(z.items())))
    print(f"{len(z)} all-solid objects: robust spread {spread:.2f}, median {statistics.median(z.values()):+.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="*", type=Path, help="physgs demo output folders")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--settings", nargs="+", default=None, choices=list(SETTINGS), metavar="S",
                    help="only these settings (the default export always runs first)")
    ap.add_argument("--out", type=Path, default=None, help="the summary JSON (default: mass_stability.json, or "
                    "geometry_ablation.json with --ablation)")
    ap.add_argument("--ablation", type=Path, nargs="+", default=None, metavar="OUT",
                    help="finished mass_suite.py output folders: each geometry rule switched off (module doc)")
    ap.add_argument("--only", nargs="+", default=None, choices=sorted(RULES), help="--ablation: these rows only")
    ap.add_argument("--summarize", action="store_true", help="--ablation: score the re-exports already there")
    ap.add_argument("--surface-offset", type=Path, nargs="+", default=None, metavar="OUT",
                    help="finished mass_suite.py output folders: the carved surface's offset (module doc)")
    a = ap.parse_args()
    if a.surface_offset is not None:
        return surface_offsets(a.surface_offset, a.out or Path("surface_offset.json"))
    if a.ablation is not None:
        return ablation(a.ablation, a.only, a.jobs, a.summarize, a.out or Path("geometry_ablation.json"))
    if not a.runs:
        ap.error("give physgs demo output folders, or --ablation with mass_suite.py output folders")
    a.out = a.out or Path("mass_stability.json")
    chosen = {k: SETTINGS[k] for k in SETTINGS if a.settings is None or k == "default" or k in a.settings}
    runs = {}
    for run in a.runs:
        runs[run.name] = sweep(run, chosen, a.jobs)
        print(f"{run.name}: {len(chosen)} exports done", file=sys.stderr, flush=True)
    write_summary(a.out, {"target_largest_change": 0.2, "settings": chosen, "runs": runs})
    print(format_table(
        ("run", "default kg", "settings", "largest change", "at setting", "failed"),
        [(name, r["default_kg"], len(chosen) - 1, r["largest_change"], r["largest_change_setting"],
          " ".join(r["failed"]) or None) for name, r in runs.items()],
    ))  # fmt: skip


if __name__ == "__main__":
    main()
