"""Where the export puts the seams between an object's parts, against the generator's exact parts: the spread that
`--mass.seam-offset-voxels` draws (physgs_nerfstudio/mass/integrate.py, "Seams").

    python benchmarks/seam_offset.py RUN_DIR [RUN_DIR ...] [--export-args="..."] [--out seams.json]

Each RUN_DIR is a `physgs demo` (or `mass_suite.py --trained`) output folder of a generated object,
OBJ_sSEED/{scene,runs}. The run is exported once more with `--outputs mass voxels` (into RUN_DIR/export_seams/), and
every voxel of the export's nominal solid is compared with the layout rebuilt from the object and seed:

* a voxel's *true part* is the one part whose outer surface encloses its centre (voxels inside two parts, a bar
  through a plate, are left out); its *read material* is the material of the export part that holds it
  (report.json);
* for two true parts A and B of different materials that touch (``F`` voxel faces between them on the grid),
  ``n_AB`` kept voxels of A read as B's material and ``n_BA`` of B as A's give the seam's offset
  ``(n_AB - n_BA) / F`` voxels (positive: B grew into A), and in the carving's resolution units (the larger of the
  voxel and the views' pixel footprint, as the mass's Monte Carlo uses) ``offset / max(1, pixel footprint)``;
* a pair where more than half of one part's kept voxels read as the other's material is a *misread* part (the stool's
  steel footrest read as pine), a material error and not a seam's place: listed, and left out of the spread.

Prints each seam and the root mean square of the offsets over the seams that are not misread, in resolution units:
the measured ``s_seam``.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from mass_suite import _demo_export_args
from voxel_truth import voxel_centres_world

from physgs_nerfstudio.export.voxel import load_voxel_grid
from physgs_nerfstudio.geometry.parts import seam_areas
from physgs_nerfstudio.synth.objects import build_layout


def true_labels(vx: dict, transform: np.ndarray, scale: float, parts: list) -> np.ndarray:
    """int [X, Y, Z]: the index of the one part (of ``parts``) whose outer surface encloses each voxel's centre; -1
    for none, -2 for more than one."""
    world = voxel_centres_world(vx, transform, scale)
    count = np.zeros(len(world), np.int64)
    label = np.full(len(world), -1, np.int64)
    for i, p in enumerate(parts):
        inside = p.outer().contains(p.to_local(world))
        count += inside
        label[inside] = i
    label[count > 1] = -2
    return label.reshape(vx["occupancy"].shape)


def seam_offsets(vx: dict, materials_by_part: list[str], transform: np.ndarray, scale: float,
                 parts: list) -> list[dict]:  # fmt: skip
    """The seams between ``parts`` of unlike materials (module doc) in the voxel grid ``vx`` (:func:`load_voxel_grid`),
    whose export part ``i`` reads as ``materials_by_part[i]``."""
    occ = vx["occupancy"].astype(bool)
    pid = vx["part_id"]
    truth = true_labels(vx, transform, scale, parts)
    P = len(parts)
    faces = seam_areas(np.where(truth >= 0, truth, -1), P, 1.0)
    read = np.where(pid >= 0, np.asarray([*materials_by_part, ""])[pid], "")  # "" outside the solid
    footprint = max(1.0, float(vx["meta"]["geometry"].get("pixel_footprint_voxels", 1.0)))
    out = []
    for a in range(P):
        for b in range(a + 1, P):
            ma, mb = parts[a].material, parts[b].material
            if faces[a, b] <= 0 or ma == mb:
                continue
            in_a, in_b = occ & (truth == a), occ & (truth == b)
            n_ab, n_ba = int((in_a & (read == mb)).sum()), int((in_b & (read == ma)).sum())
            off = (n_ab - n_ba) / faces[a, b]
            out.append({"a": parts[a].name, "b": parts[b].name, "materials": [ma, mb], "faces": int(faces[a, b]),
                        "kept_a": int(in_a.sum()), "kept_b": int(in_b.sum()), "a_read_as_b": n_ab, "b_read_as_a": n_ba,
                        "offset_voxels": off, "offset_units": off / footprint,
                        "misread": n_ab > 0.5 * max(int(in_a.sum()), 1) or n_ba > 0.5 * max(int(in_b.sum()), 1)})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--export-args", default="", help="more `physgs export` flags")
    ap.add_argument("--trained", action="store_true", help="GPU runs: export with the defaults, not the demo's flags")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    rows = []
    for run in a.runs:
        m = re.match(r"(.+)_s(\d+)$", run.name)
        if not m:
            raise SystemExit(f"{run}: expected a folder named OBJECT_sSEED")
        obj, seed = m.group(1), int(m.group(2))
        cfg = next((run / "runs").glob("**/config.yml"))
        exp = run / "export_seams"
        cmd = [sys.executable, "-m", "physgs_nerfstudio.cli", "export", "--load-config", str(cfg), "--output-dir",
               str(exp), "--outputs", "mass", "voxels", "--overwrite",
               *([] if a.trained else _demo_export_args(seed)), *a.export_args.split()]  # fmt: skip
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            print(f"{run.name}: export failed: {(proc.stderr.strip().splitlines() or ['?'])[-1]}", flush=True)
            continue
        rep = json.loads((exp / "report.json").read_text())["mass"]
        mats = [p["material"] for p in rep["parts"]]
        tf = json.loads(next(run.glob("runs/**/dataparser_transforms.json")).read_text())
        parts = [p for p in build_layout(obj, seed).parts if p.role != "ground"]
        for s in seam_offsets(load_voxel_grid(exp / "voxels.npz"), mats, np.asarray(tf["transform"], float),
                              float(tf["scale"]), parts):  # fmt: skip
            rows.append({"object": obj, "seed": seed, **s})
            print(f"{obj:9s} {seed} {s['a']:>8s}|{s['b']:<8s} faces {s['faces']:5d} a->b {s['a_read_as_b']:5d} "
                  f"b->a {s['b_read_as_a']:5d} offset {s['offset_voxels']:+.2f} vox {s['offset_units']:+.2f} units"
                  f"{'  MISREAD' if s['misread'] else ''}", flush=True)
    ok = [r["offset_units"] for r in rows if not r["misread"]]
    rms = float(np.sqrt(np.mean(np.square(ok)))) if ok else float("nan")
    print(f"{len(ok)} seams (of {len(rows)}; misread left out): mean {np.mean(ok) if ok else float('nan'):+.2f}, "
          f"root mean square {rms:.2f} resolution units")
    if a.out:
        a.out.write_text(json.dumps({"rows": rows, "rms_units": rms, "n": len(ok)}, indent=1))


if __name__ == "__main__":
    main()
