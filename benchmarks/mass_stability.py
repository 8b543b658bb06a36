"""Mass stability over the documented range of every geometry option, on finished demo runs.

    python benchmarks/mass_stability.py /tmp/ms/table_s101 /tmp/ms/chair_s101 --jobs 4

For each run folder (a `physgs demo --output-dir` folder, trained and exported), re-exports the mass with each
option set to each end of its documented range (one option at a time, the rest at their defaults) and prints
the mean mass relative to the default export. Target: every change within 20%.
Writes one summary JSON (``--out``: every setting's mass per run) and prints one table (per run its largest change
and the setting that made it).
"""

from __future__ import annotations

import argparse
import json
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", type=Path, help="physgs demo output folders")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--settings", nargs="+", default=None, choices=list(SETTINGS), metavar="S",
                    help="only these settings (the default export always runs first)")
    ap.add_argument("--out", type=Path, default=Path("mass_stability.json"), help="the summary JSON")
    a = ap.parse_args()
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
