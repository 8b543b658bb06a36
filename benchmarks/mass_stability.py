"""Mass stability over the documented range of every geometry option, on finished demo runs.

    python benchmarks/mass_stability.py /tmp/ms/table_s101 /tmp/ms/chair_s101 --jobs 4

For each run folder (a `physgs demo --output-dir` folder, trained and exported), re-exports the mass with each
option set to each end of its documented range (one option at a time, the rest at their defaults) and prints
the mean mass relative to the default export. Issue 12's target: every change within 20%.
Results: a JSON per run folder (`mass_stability.json` inside it) and one line per setting.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

# option -> the ends of its documented range (GeometryConfig / CarveConfig docs)
SETTINGS: dict[str, list[str]] = {
    "default": [],
    "resolution=96": ["--mass.geometry.resolution", "96"],
    "resolution=160": ["--mass.geometry.resolution", "160"],
    "min_votes=1": ["--mass.geometry.carve.min-votes", "1"],
    "min_votes=3": ["--mass.geometry.carve.min-votes", "3"],
    "min_vote_fraction=0.1": ["--mass.geometry.carve.min-vote-fraction", "0.1"],
    "min_vote_fraction=0.25": ["--mass.geometry.carve.min-vote-fraction", "0.25"],
    "mask_margin_px=-0.5": ["--mass.geometry.carve.mask-margin-px", "-0.5"],
    "mask_margin_px=+0.5": ["--mass.geometry.carve.mask-margin-px", "0.5"],
    "depth_margin_voxels=-0.5": ["--mass.geometry.carve.depth-margin-voxels", "-0.5"],
    "depth_margin_voxels=1": ["--mass.geometry.carve.depth-margin-voxels", "1"],
    "hidden_skin_voxels=3": ["--mass.geometry.hidden-skin-voxels", "3"],
    "hidden_skin_tolerance=1.25": ["--mass.geometry.hidden-skin-tolerance", "1.25"],
    "hidden_skin_tolerance=2": ["--mass.geometry.hidden-skin-tolerance", "2"],
    "hidden_min_open_half=8": ["--mass.geometry.hidden-min-open-half", "8"],
    "hidden_passes=1": ["--mass.geometry.hidden-passes", "1"],
    "hidden_skin_seen=0.5": ["--mass.geometry.hidden-skin-seen", "0.5"],
    "hidden_skin_seen=2": ["--mass.geometry.hidden-skin-seen", "2"],
    "hidden_skin_band=1": ["--mass.geometry.hidden-skin-band", "1"],
    "min_voxel_evidence=0.25": ["--mass.geometry.min-voxel-evidence", "0.25"],
    "min_voxel_evidence=1": ["--mass.geometry.min-voxel-evidence", "1"],
    "hull_vote_fraction=0.35": ["--mass.geometry.select.hull-vote-fraction", "0.35"],
    "hull_vote_fraction=0.65": ["--mass.geometry.select.hull-vote-fraction", "0.65"],
    "complete_min_share=0.01": ["--mass.geometry.complete-min-share", "0.01"],
    "complete_min_share=0.05": ["--mass.geometry.complete-min-share", "0.05"],
    "depth_consensus=0.35": ["--mass.geometry.carve.depth-consensus", "0.35"],
    "depth_consensus=0.65": ["--mass.geometry.carve.depth-consensus", "0.65"],
    "extent_pad_voxels=1": ["--mass.geometry.extent-pad-voxels", "1"],
    "extent_outlier_fraction=0": ["--mass.geometry.extent-outlier-fraction", "0"],
    "extent_outlier_fraction=0.003": ["--mass.geometry.extent-outlier-fraction", "0.003"],
    "evidence_surface_voxels=0.5": ["--mass.geometry.evidence-surface-voxels", "0.5"],
    "evidence_surface_voxels=2": ["--mass.geometry.evidence-surface-voxels", "2"],
    "no_variants": ["--mass.geometry.no-variants"],
    "structure_evidence=material": ["--mass.geometry.structure.evidence", "material"],
    "hidden_boundary=whole": ["--mass.geometry.hidden-boundary", "whole"],
    "boundary_subsamples=3": ["--mass.geometry.boundary-subsamples", "3"],
}


def export(run: Path, name: str, flags: list[str], extra: Sequence[str] = (), tag: str = "") -> dict:
    cfg = next((run / "runs").glob("**/config.yml"))
    out = run / f"stability{tag}" / name.replace("=", "_").replace("+", "p")
    cmd = [sys.executable, "-m", "physgs_nerfstudio.cli", "export", "--load-config", str(cfg), "--output-dir",
           str(out), "--outputs", "mass", "--overwrite", *extra, *flags]  # fmt: skip
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", type=Path, help="physgs demo output folders")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--base-args", default="", help="extra `physgs export` flags for every setting, one quoted "
                    "string (a geometry option's stability under another default); results then go to "
                    "stability_NAME/ and mass_stability_NAME.json")
    ap.add_argument("--name", default="", help="NAME for --base-args (or --settings)")
    ap.add_argument("--settings", nargs="+", default=None, choices=list(SETTINGS), metavar="S",
                    help="only these settings (the default export always runs first)")
    a = ap.parse_args()
    extra, tag = a.base_args.split(), f"_{a.name}" if a.name else ""
    chosen = {k: SETTINGS[k] for k in SETTINGS if a.settings is None or k == "default" or k in a.settings}
    for run in a.runs:
        with ThreadPoolExecutor(max(1, a.jobs)) as pool:
            rows = list(pool.map(export, [run] * len(chosen), chosen, chosen.values(), [extra] * len(chosen),
                                 [tag] * len(chosen)))
        base = rows[0].get("mean_kg")
        for r in rows:
            if base and "mean_kg" in r:
                r["relative_to_default"] = r["mean_kg"] / base
            print(run.name, json.dumps(r), flush=True)
        ok = [abs(r["relative_to_default"] - 1) for r in rows if "relative_to_default" in r]
        worst = max(ok) if ok else float("nan")
        failed = [r["setting"] for r in rows if "error" in r]
        print(f"{run.name}: largest change {worst:.1%} over {len(ok) - 1} settings (target <= 20%)"
              + (f"; {len(failed)} failed: {' '.join(failed)}" if failed else ""))
        (run / f"mass_stability{tag}.json").write_text(json.dumps({"rows": rows, "largest_change": worst}, indent=2))


if __name__ == "__main__":
    main()
