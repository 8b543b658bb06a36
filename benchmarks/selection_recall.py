"""How much of each object the selection holds, on runs of `benchmarks/mass_suite.py`.

    python benchmarks/selection_recall.py --out /work/tune --seed 71001 --renderer mitsuba --mesh-dir .meshes

For every finished run OUT/FAMILY_sSEED_RENDERER: the trained splat's Gaussians (opacity > 0.1) whose centres lie
inside the object's true envelope (its parts' outer shapes, from the suite's layout), their median foreground
probability (the masks lifted onto the Gaussians, `geometry.select`), and the share of them that
`geometry.select.select_object` selects with the export's defaults. The geometry ends the solid at the selected
Gaussians' polytope, so an object part the selection lacks is not carved. One line per run and the median share.
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

import numpy as np
from mass_suite import _to_world


def recall(run_dir: Path, family: str, seed: int, mesh_dir: Path | None) -> dict:
    """The run's object Gaussians, their median foreground probability and the share selected (module doc)."""
    from physgs_nerfstudio.export.run import load_run
    from physgs_nerfstudio.geometry.config import GeometryConfig
    from physgs_nerfstudio.geometry.reconstruct import _views_used
    from physgs_nerfstudio.geometry.select import select_object
    from physgs_nerfstudio.synth.support import suite_layout

    run = load_run(next((run_dir / "runs").glob("**/config.yml")))
    dp = json.loads(next((run_dir / "runs").glob("**/dataparser_transforms.json")).read_text())
    cfg = GeometryConfig()
    g = run.field
    sel = select_object(g, _views_used(run.views, cfg), cfg.select, backend=cfg.backend)
    world = _to_world(g.means.double().cpu().numpy(), np.asarray(dp["transform"], float), float(dp["scale"]))
    meshes = {"mesh_dir": mesh_dir} if mesh_dir is not None else {}
    parts = suite_layout(family, seed, shape="drawn", support="drawn", pose="drawn", **meshes).parts
    inside = np.zeros(len(world), bool)
    for p in parts:
        if p.role != "ground":
            inside |= p.outer().contains(p.to_local(world))
    obj = inside & (g.opacities.reshape(-1).cpu().numpy() > 0.1)
    prob, selected = sel.prob.cpu().numpy()[obj], sel.selected.cpu().numpy()[obj]
    return {"family": family, "gaussians": int(obj.sum()),
            "median_prob": float(np.median(prob)) if obj.any() else None,
            "selected_share": float(selected.mean()) if obj.any() else None}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="mass_suite.py's --out folder")
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--renderer", default="mitsuba", choices=["mitsuba", "project"])
    ap.add_argument("--mesh-dir", type=Path, default=None, help="the figurine family's meshes")
    a = ap.parse_args()
    rows = []
    for d in sorted(a.out.glob(f"*_s{a.seed}_{a.renderer}")):
        if not (d / "demo_summary.json").is_file():
            continue
        r = recall(d, d.name.split(f"_s{a.seed}_")[0], a.seed, a.mesh_dir)
        rows.append(r)
        print(f"{r['family']:10s} object Gaussians {r['gaussians']:5d}  median probability {r['median_prob']:.2f}  "
              f"selected {r['selected_share']:.2f}", flush=True)
    shares = [r["selected_share"] for r in rows if r["selected_share"] is not None]
    if shares:
        print(f"median selected share over {len(shares)} runs: {statistics.median(shares):.2f}")


if __name__ == "__main__":
    main()
