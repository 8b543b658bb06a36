"""Which Gaussians the mass export's object selection takes as foreground, and why a support plane was or was not
found under them, on a trained run of a generated scene (issue 12: `indoor_room` on the GPU).

    python benchmarks/selection_diag.py RUN [--out DIR]

RUN is a folder whose ``runs/`` holds a `ns-train physgs` config.yml, on a dataset from `physgs synth` + `physgs
perceive`. Prints, for the foreground candidates of :func:`physgs_nerfstudio.geometry.select.select_object`
(foreground probability >= ``min_prob``, opacity >= ``min_opacity``): how many lie on the ground, on each generated
object or off every part (centre within ``--near-m`` of a part), how many of them no view sees (their probability is
the prior's), and the support-plane search's outcome (:func:`physgs_nerfstudio.geometry.support.support_plane_or_reason`):
the export's own, with the views (``plane_export``), and without them (every point under the plane counts) on all
the candidates and on the seen ones alone. Writes ``DIR/selection_diag.json`` and ``DIR/selection.npz`` (the
candidates' means, opacities and view evidence, their part, the camera centres and the views' up direction: enough
to rerun the plane search and the clusters offline).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from geometry_diag import _part_of, _to_world, _transform, load_run_on_device  # noqa: E402

from physgs_nerfstudio.geometry.gaussians import lift_masks  # noqa: E402
from physgs_nerfstudio.geometry.select import SelectConfig, select_object  # noqa: E402
from physgs_nerfstudio.geometry.support import support_plane_or_reason, views_up  # noqa: E402
from physgs_nerfstudio.synth.objects import build_layout  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--out", type=Path, default=None, help="default: RUN/selection_diag")
    ap.add_argument("--near-m", type=float, default=0.02)
    a = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    out = a.out or a.run / "selection_diag"
    out.mkdir(parents=True, exist_ok=True)
    cfg_path = next((a.run / "runs").glob("**/config.yml"))
    run = load_run_on_device(cfg_path)
    g, views, cfg = run.field, run.views, SelectConfig()
    inside, outside = lift_masks(g, views)
    prob = ((cfg.prior[0] + inside) / (sum(cfg.prior) + inside + outside)).float()
    cand = ((prob >= cfg.min_prob) & (g.opacities >= cfg.min_opacity)).cpu().numpy()
    seen = ((inside + outside) > 0).cpu().numpy()
    means = g.means.double().cpu().numpy()
    T, s = _transform(cfg_path.parent)
    truth = json.loads((run.data_dir / "ground_truth.json").read_text())
    parts = list(build_layout(truth["layout"], int(truth.get("seed", 0))).parts)
    on = _part_of(parts, _to_world(means[cand], T, s), a.near_m)
    owner = np.array(["ground" if i >= 0 and parts[i].role == "ground" else parts[i].object if i >= 0 else "off"
                      for i in on])  # fmt: skip
    cams = np.stack([v.centre.double().cpu().numpy() for v in views])
    up = views_up(views)
    res: dict = {"gaussians": int(len(means)), "candidates": int(cand.sum()),
                 "candidates_unseen": int((cand & ~seen).sum())}  # fmt: skip
    # the export's own search, with the views (a point under the plane counts where a view sees it past the plane)
    plane, why = support_plane_or_reason(means[cand], cams, up, cfg.support, views)
    res["plane_export"] = why or {"share": plane.share, "tol": plane.tol, "size": plane.size}
    # without the views: every point under the plane counts
    for name, sub in (("all", np.ones(int(cand.sum()), bool)), ("seen", seen[cand])):
        plane, why = support_plane_or_reason(means[cand][sub], cams, up, cfg.support)
        res[f"plane_{name}"] = why or {"share": plane.share, "tol": plane.tol, "size": plane.size}
        if plane is not None:
            h = plane.height(means[cand])
            res[f"plane_{name}_drops_by_owner"] = {o: int(((owner == o) & (h <= plane.tol)).sum())
                                                   for o in sorted(set(owner))}  # fmt: skip
            res[f"plane_{name}_unseen_below"] = int(((h < -plane.tol) & ~seen[cand]).sum())
    res["candidates_by_owner"] = {o: int((owner == o).sum()) for o in sorted(set(owner))}
    res["unseen_by_owner"] = {o: int(((owner == o) & ~seen[cand]).sum()) for o in sorted(set(owner))}
    sel = select_object(g, views, cfg).selected.cpu().numpy()
    on_sel = _part_of(parts, _to_world(means[sel], T, s), a.near_m)
    res["selected"] = int(sel.sum())
    res["selected_on_ground"] = int(sum(1 for i in on_sel if i >= 0 and parts[i].role == "ground"))
    np.savez_compressed(out / "selection.npz", means=means[cand].astype(np.float32),
                        opacity=g.opacities.cpu().numpy()[cand].astype(np.float16),
                        inside=inside.cpu().numpy()[cand].astype(np.float16),
                        outside=outside.cpu().numpy()[cand].astype(np.float16), part=on.astype(np.int16),
                        selected=sel[cand], cameras=cams, up=up, transform=T, scale=s)  # fmt: skip
    (out / "selection_diag.json").write_text(json.dumps(res, indent=1))
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
