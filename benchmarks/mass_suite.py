"""Mass over the generated suite through the whole pipeline (synth -> perceive [SIMULATED VLM] -> train -> export).

    python benchmarks/mass_suite.py --seeds 101 --out /tmp/mass_suite            # CPU, demo settings
    python benchmarks/mass_suite.py --objects chair table --seeds 101 102          # a subset
    python benchmarks/mass_suite.py --seeds 202 303 --jobs 12                      # 12 demos at once (one core each)

Per object: truth, predicted mean, interval, covered, APE, and the error split into geometry (carved vs true
part volume: solid parts' volume, shells' wall volume), density (predicted vs true density of the dominant
material) and structure (the share of parts whose hollow/solid call is right). Runs `physgs demo` per object
(resumable: finished stages are skipped), then reads its export/report.json and the scene's ground_truth.json.
Seeds used by the tests (0, 7) should not be used here.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import statistics
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

OBJECTS = ("mug", "chair", "hammer", "bottle", "shoe", "table", "pan", "lamp", "crate", "stool", "dumbbell", "vase")


def _demo_export_args(seed: int) -> list[str]:
    """The flags that make `physgs export` match the demo's own export (its grid resolution, samples and seed)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from physgs_nerfstudio.demo import DemoCommand

    d = DemoCommand()
    return ["--mass.geometry.resolution", str(d.export_resolution), "--mass.n-samples", str(d.n_samples),
            "--mass.seed", str(seed)]  # fmt: skip


def run_one(obj: str, seed: int, out: Path, extra: list[str], jobs: int = 1,
            export_args: list[str] | None = None, alt_name: str = "alt", trained: bool = False) -> dict:  # fmt: skip
    d = out / f"{obj}_s{seed}"
    cmd = [sys.executable, "-m", "physgs_nerfstudio.cli", "demo", "--object", obj, "--seed", str(seed),
           "--output-dir", str(d), *extra]  # fmt: skip
    env = dict(os.environ)
    if jobs > 1:  # one core per demo
        env.update(OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    finished = export_args is not None and (d / "demo_summary.json").is_file() and any((d / "runs").glob("**/config.yml"))
    if trained:  # a run trained by `ns-train` (the GPU suite): OUT/OBJ_sSEED/{scene,runs}, exported with the defaults
        finished = True
        export_args = export_args if export_args is not None else []
    if not finished:  # a re-export of a finished demo does not run the demo again
        proc = subprocess.run(cmd, check=False, capture_output=True, text=True, env=env)
        (out / f"{obj}_s{seed}.log").write_text(proc.stdout[-20000:] + proc.stderr[-20000:])
        if proc.returncode != 0:
            return {"object": obj, "seed": seed, "error": proc.stderr.strip().splitlines()[-1:] or ["failed"]}
    gt = json.loads((d / "scene" / "ground_truth.json").read_text())
    export = d / "export"
    export_s = None
    if export_args is not None:
        cfg = next((d / "runs").glob("**/config.yml"))
        export = d / f"export_{alt_name}"
        cmd = [sys.executable, "-m", "physgs_nerfstudio.cli", "export", "--load-config", str(cfg), "--output-dir",
               str(export), "--outputs", "mass", "--overwrite", *([] if trained else _demo_export_args(seed)),
               *export_args]  # fmt: skip
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, check=False, capture_output=True, text=True, env=env)
        export_s = time.perf_counter() - t0
        if proc.returncode != 0:
            return {"object": obj, "seed": seed, "error": proc.stderr.strip().splitlines()[-1:] or ["failed"]}
    rep = json.loads((export / "report.json").read_text())["mass"]
    truth = float(gt["total_mass_kg"])
    pred = float(rep["mean_kg"])
    lo, hi = rep["interval_kg"]
    true_vol = sum(p["volume_m3"] for p in gt["parts"])
    pred_vol = sum(p["volume_m3"] * (1 - p["structure"]["p_hollow"]) + min(p["volume_m3"], p["area_m2"] *
                   p["structure"]["thickness_m"]) * p["structure"]["p_hollow"] for p in rep["parts"])  # fmt: skip
    shells = {p["material"] for p in gt["parts"] if p["volume_model"] == "shell"}
    solid_mats = {p["material"] for p in gt["parts"] if p["volume_model"] == "solid"}
    right = [(p["structure"]["p_hollow"] > 0.5) == (p["material"] in shells) for p in rep["parts"]
             if p["material"] in shells | solid_mats]  # fmt: skip
    return {"object": obj, "seed": seed, "truth_kg": truth, "pred_kg": pred, "interval_kg": [lo, hi],
            "covered": lo <= truth <= hi, "ape": abs(pred - truth) / truth, "export_s": export_s,
            "volume_ratio": pred_vol / true_vol if true_vol > 0 else None,
            "structure_right": (sum(right) / len(right)) if right else None,
            "true_parts": [{k: p[k] for k in ("name", "material", "volume_model", "volume_m3", "enclosed_volume_m3",
                                              "surface_area_m2", "mass_kg") if k in p} for p in gt["parts"]],
            "voxel_size_m": rep["geometry"].get("voxel_size_m"),
            "pixel_footprint_voxels": rep["geometry"].get("pixel_footprint_voxels"),
            "rests_on_plane": rep["geometry"].get("rests_on_plane"),
            "support_plane_in_masks": rep["geometry"].get("support_plane_in_masks"),
            "hidden_open_voxels": rep["geometry"].get("hidden_open_voxels"),
            "parts": [{"material": p["material"], "volume_m3": p["volume_m3"], "area_m2": p["area_m2"],
                       "surface_area_m2": p.get("surface_area_m2"),
                       "p_hollow": p["structure"]["p_hollow"], "thickness_m": p["structure"]["thickness_m"],
                       "observation_weight": p["structure"]["observation_weight"], "mass_mean_kg": p["mass_mean_kg"],
                       "mixture": p.get("mixture")} for p in rep["parts"]],
            "density_mean": {m["name"]: m["density_mean"] for m in rep["materials"]},
            "volume_by_variant_m3": rep["geometry"].get("volume_by_variant_m3")}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--objects", nargs="*", default=list(OBJECTS))
    ap.add_argument("--seeds", nargs="*", type=int, default=[101])
    ap.add_argument("--out", type=Path, default=Path("/tmp/physgs_mass_suite"))
    ap.add_argument("--demo-args", nargs="*", default=[])
    ap.add_argument("--export-args", type=shlex.split, default=None,
                    help="re-export every finished demo with these extra `physgs export` flags, one quoted string "
                         "(into export_NAME/, see --alt-name) "
                         "and score that export instead: a side-by-side comparison of geometry options")
    ap.add_argument("--alt-name", default="alt", help="name of the re-export (export_NAME/, mass_suite_NAME.json)")
    ap.add_argument("--jobs", type=int, default=1, help="demos run at once (each limited to one thread)")
    ap.add_argument("--trained", action="store_true",
                    help="score runs trained elsewhere (the GPU suite: OUT/OBJECT_sSEED/scene and runs/**/config.yml): "
                         "`physgs export --outputs mass` with its defaults (plus --export-args) into export_NAME/")
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    todo = [(o, s) for s in a.seeds for o in a.objects]

    def one(item: tuple[str, int]) -> dict:
        row = run_one(item[0], item[1], a.out, a.demo_args, a.jobs, a.export_args, a.alt_name, a.trained)
        short = {k: v for k, v in row.items() if k not in ("parts", "true_parts")}
        print(json.dumps(short), flush=True)
        return row

    with ThreadPoolExecutor(max(1, a.jobs)) as pool:
        rows = list(pool.map(one, todo))
    ok = [r for r in rows if "error" not in r]
    if ok:
        print(f"median APE {statistics.median(r['ape'] for r in ok):.3f}; covered {sum(r['covered'] for r in ok)}/"
              f"{len(ok)}; off by more than 2x: {sum(r['pred_kg'] > 2 * r['truth_kg'] or r['pred_kg'] < r['truth_kg'] / 2 for r in ok)}; "
              f"median volume error {statistics.median(abs(r['volume_ratio'] - 1) for r in ok):.3f}")  # fmt: skip
    name = "mass_suite.json" if a.export_args is None and not a.trained else f"mass_suite_{a.alt_name}.json"
    (a.out / name).write_text(json.dumps({"export_args": a.export_args, "rows": rows}, indent=2))


if __name__ == "__main__":
    main()
