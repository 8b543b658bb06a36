"""The mass geometry of one trained run on a generated scene, checked against the generator's ground truth.

    python benchmarks/geometry_diag.py --load-config RUN/config.yml --out DIR [--dump]

The dataset must come from `physgs synth` (its ``ground_truth.json`` names the layout and seed, from which the
parts' exact shapes are rebuilt). Writes ``DIR/geometry_diag.json``:

* **masks**: per view, the foreground masks the carving starts from vs the true object mask (IoU, recall,
  precision), and the selected Gaussians' rendered silhouette vs the true mask;
* **selection**: how many Gaussians lie on the true object (centre within ``--near-m`` of a part), how many of
  those the selection kept (recall, per part) and how many selected ones are off the object (floaters,
  background), the foreground probability of the object's Gaussians, and how the 3-D clusters split them;
* **carving**: the nominal carved solid vs the true occupancy on the same grid (IoU, volume ratio, per part
  recall: which part was lost);

and with ``--dump`` a compact copy of the splat (``splat.npz``: means, scales, quats, opacities, foreground
probability, selected, on-object flags; float16 except the means) for offline experiments.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from physgs_nerfstudio.export.command import load_run, object_geometry  # noqa: E402
from physgs_nerfstudio.geometry import reconstruct  # noqa: E402
from physgs_nerfstudio.geometry.clusters import cluster_labels  # noqa: E402
from physgs_nerfstudio.geometry.gaussians import render_depth  # noqa: E402
from physgs_nerfstudio.geometry.select import select_object  # noqa: E402
from physgs_nerfstudio.mass.integrate import integrate_mass  # noqa: E402
from physgs_nerfstudio.synth.objects import build_layout  # noqa: E402

_OFFSETS = np.array([[a, b, c] for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)], float)


def load_run_on_device(config: Path, **kw):
    """:func:`load_run` with the field moved to the GPU where there is one, as `physgs export` does (on the CPU the
    selection of a GPU run's million Gaussians takes minutes on the reference rasterizer)."""
    run = load_run(config, **kw)
    run.field = run.field.to("cuda" if torch.cuda.is_available() else "cpu")
    return run


def _transform(run_dir: Path) -> tuple[np.ndarray, float]:
    meta = json.loads((run_dir / "dataparser_transforms.json").read_text())
    return np.asarray(meta["transform"], float), float(meta["scale"])


def _to_world(x_scene: np.ndarray, T: np.ndarray, s: float) -> np.ndarray:
    R, t = T[:, :3], T[:, 3]
    return (x_scene / s - t) @ R  # inverse of p_s = s (R p_d + t)


def _part_of(parts: list, pw: np.ndarray, near: float) -> np.ndarray:
    """int [N]: index of the first part whose solid holds a point within ``near`` (a 27-point stencil), -1 if none."""
    out = np.full(len(pw), -1, np.int64)
    for i, p in enumerate(parts):
        hit = np.zeros(len(pw), bool)
        for o in _OFFSETS * (near / np.sqrt(3) if near > 0 else 0.0):
            hit |= p.primitive.contains(p.to_local(pw + o))
            if near == 0:
                break
        out[(out < 0) & hit] = i
    return out


def _mask_stats(pred: np.ndarray, gt: np.ndarray) -> dict[str, float]:
    i, u = float((pred & gt).sum()), float((pred | gt).sum())
    return {"iou": i / u if u else 1.0, "recall": i / max(float(gt.sum()), 1.0), "precision": i / max(float(pred.sum()), 1.0)}


def _true_masks(data_dir: Path, views: list) -> list[np.ndarray | None]:
    import cv2
    from PIL import Image

    gt = json.loads((data_dir / "ground_truth.json").read_text())
    by_name = {f["file_path"]: f for f in gt.get("frames", [])}
    out = []
    for v in views:
        f = by_name.get(v.name)
        if f is None or not (data_dir / f["part_path"]).is_file():
            out.append(None)
            continue
        m = (np.asarray(Image.open(data_dir / f["part_path"])) > 0).astype(np.uint8)
        if m.ndim == 3:
            m = m[..., 0]
        out.append(cv2.resize(m, (v.width, v.height), interpolation=cv2.INTER_NEAREST).astype(bool))
    return out


def _pct(a: list[float]) -> dict[str, float]:
    q = np.percentile(np.asarray(a, float), [0, 10, 50, 90, 100]) if a else [float("nan")] * 5
    return dict(zip(("min", "p10", "median", "p90", "max"), (round(float(x), 4) for x in q)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--load-config", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--near-m", type=float, default=0.01, help="a Gaussian is on the object within this (metres)")
    ap.add_argument("--dump", action="store_true")
    ap.add_argument("--max-view-width", type=int, default=640)
    ap.add_argument("--no-hull", action="store_true", help="select without the masks' hull test")
    ap.add_argument("--baseline", action="store_true",
                    help="the geometry before the hull test and the mask completion (before/after comparisons)")
    ap.add_argument("--tag", default="", help="suffix of the output files (geometry_diag<tag>.json)")
    ap.add_argument("--hull-vote-fraction", type=float, default=None,
                    help="the selection's hull_vote_fraction (default: the shipped one)")
    a = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    a.out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    out: dict = {"config": str(a.load_config), "near_m": a.near_m, "timings_s": {}}
    path = a.out / f"geometry_diag{a.tag}.json"

    def done(stage: str) -> None:  # each stage's result is on disk as soon as it is known
        out["timings_s"][stage] = round(time.time() - t0, 1)
        path.write_text(json.dumps(out, indent=1))
        print(f"[{time.time() - t0:.1f} s] {stage}", flush=True)

    run = load_run_on_device(a.load_config, max_view_width=a.max_view_width)
    pf, views, data_dir = run.field, run.views, run.data_dir
    T, s = _transform(a.load_config.parent)
    truth = json.loads((data_dir / "ground_truth.json").read_text())
    layout = build_layout(truth["layout"], int(truth.get("seed", 0)))
    parts = [p for p in layout.parts if p.role == "object"]
    names = [p.name for p in parts]
    out["parts"] = names
    done("load")
    means = pf.means.double().cpu().numpy()
    pw = _to_world(means, T, s)
    on = _part_of(parts, pw, a.near_m)
    op = pf.opacities.double().cpu().numpy()
    real = op >= 0.05
    done("ground truth per Gaussian")
    cfg = reconstruct.GeometryConfig()
    if a.hull_vote_fraction is not None:
        cfg.select.hull_vote_fraction = a.hull_vote_fraction
    if a.no_hull or a.baseline:
        cfg.select.hull_vote_fraction = 2.0
    if a.baseline:
        cfg.complete_masks = False
    out["geometry_config"] = {"hull_vote_fraction": cfg.select.hull_vote_fraction, "complete_masks": cfg.complete_masks}
    sel = select_object(pf, views, cfg.select, backend=cfg.backend)
    prob = sel.prob.double().cpu().numpy()
    chosen = sel.selected.cpu().numpy()
    if a.dump:
        f16 = lambda t: t.detach().cpu().numpy().astype(np.float16)  # noqa: E731
        np.savez_compressed(a.out / "splat.npz", means=means.astype(np.float32), scales=f16(pf.scales),
                            quats=f16(pf.quats), opacities=f16(pf.opacities), prob=prob.astype(np.float16),
                            selected=chosen, on_part=on.astype(np.int8), transform=T, scale=s)  # fmt: skip
        print(f"wrote {a.out / 'splat.npz'} ({(a.out / 'splat.npz').stat().st_size / 2**20:.1f} MiB)", flush=True)
    done("selection")
    cand = (prob >= cfg.select.min_prob) & real
    lab, _, cell, ids = cluster_labels(means[cand], cfg.select)
    lab = lab.cpu().numpy()
    lab_all = np.zeros(len(means), np.int64)
    lab_all[cand] = lab
    obj_real = (on >= 0) & real
    clusters_of_object = np.bincount(lab_all[obj_real & cand], minlength=1)
    top = np.argsort(clusters_of_object)[::-1][:5]
    sizes = np.bincount(lab_all[cand])
    selection = {
        "gaussians": int(len(means)), "opaque": int(real.sum()), "on_object": int(obj_real.sum()),
        "candidates": int(cand.sum()), "selected": int(chosen.sum()),
        "recall": float((chosen & obj_real).sum() / max(obj_real.sum(), 1)),
        "precision": float((chosen & (on >= 0)).sum() / max(chosen.sum(), 1)),
        "candidate_recall": float((cand & obj_real).sum() / max(obj_real.sum(), 1)),
        "candidate_precision": float((cand & (on >= 0)).sum() / max(cand.sum(), 1)),
        "per_part_recall": {n: float((chosen & (on == i) & real).sum() / max(((on == i) & real).sum(), 1))
                            for i, n in enumerate(names)},
        "per_part_candidate_recall": {n: float((cand & (on == i) & real).sum() / max(((on == i) & real).sum(), 1))
                                      for i, n in enumerate(names)},
        "object_prob": _pct(list(prob[obj_real][:: max(1, obj_real.sum() // 200000)])),
        "offobject_prob": _pct(list(prob[real & (on < 0)][:: max(1, (real & (on < 0)).sum() // 200000)])),
        "clusters": int(len(ids)), "cluster_cell_scene": float(cell),
        "object_gaussians_by_cluster_top5": {int(k): int(clusters_of_object[k]) for k in top if clusters_of_object[k]},
        "cluster_sizes_top5": {int(k): int(sizes[k]) for k in np.argsort(sizes)[::-1][:5] if k > 0},
        "chosen_cluster": int(np.bincount(lab_all[chosen]).argmax()) if chosen.any() else -1,
        "capture_centre_world": _to_world(sel.centre[None], T, s)[0].round(4).tolist(),
    }
    out["selection"] = selection
    done("selection vs truth")
    # masks vs truth
    true = _true_masks(data_dir, views)
    sub = reconstruct._Subset(pf, sel.selected)
    renders = render_depth(sub, views, backend=cfg.backend)
    per_view = []
    for v, t_m, r in zip(views, true, renders):
        if t_m is None:
            continue
        fg = v.mask.cpu().numpy()
        sil = r.alpha.cpu().numpy() > 0.5
        per_view.append({"view": v.name, "mask": _mask_stats(fg, t_m), "silhouette": _mask_stats(sil, t_m)})
    out["masks"] = {k: {m: _pct([pv[k][m] for pv in per_view]) for m in ("iou", "recall", "precision")}
                    for k in ("mask", "silhouette")}
    out["per_view"] = per_view
    done("masks vs truth")
    # carving vs truth
    geo = object_geometry(run, cfg)  # what `physgs export` carves
    out["selection"]["outside_hull"] = geo.selection.outside_hull
    done("reconstruct_object")
    rep = integrate_mass(pf, geo)
    out["mass"] = {"truth_kg": float(truth.get("total_mass_kg", float("nan"))), "mean_kg": rep.mean_kg,
                   "median_kg": rep.median_kg, "interval_kg": list(rep.interval_kg)}
    grid = geo.grid
    ijk = np.argwhere(np.ones(grid.shape, bool))
    centres = grid.centres(torch.from_numpy(ijk)).double().numpy()
    gt_part = _part_of(parts, _to_world(centres, T, s), 0.0).reshape(grid.shape)
    solid = geo.solid
    true_occ = gt_part >= 0
    vox_m3 = (grid.voxel_size / s) ** 3
    true_vol = sum(p.material_volume() if p.volume_model == "solid" else p.enclosed_volume() for p in parts)
    carving = {
        "grid_shape": list(grid.shape), "voxel_m": grid.voxel_size / s,
        "solid_m3": float(solid.sum() * vox_m3), "true_on_grid_m3": float(true_occ.sum() * vox_m3),
        "true_enclosed_m3": float(true_vol),
        "iou": float((solid & true_occ).sum() / max((solid | true_occ).sum(), 1)),
        "per_part_recall": {n: float((solid & (gt_part == i)).sum() / max((gt_part == i).sum(), 1))
                            for i, n in enumerate(names)},
        "false_solid_m3": float((solid & ~true_occ).sum() * vox_m3),
        "mask_sources": geo.mask_sources,
    }
    out["carving"] = carving
    done("carving vs truth")
    print(json.dumps({k: out[k] for k in ("selection", "masks", "carving", "mass")}, indent=1))
    m = out["mass"]
    print(f"[{time.time() - t0:.1f} s] summary: mass {m['mean_kg']:.3f} kg, 90% [{m['interval_kg'][0]:.3f}, "
          f"{m['interval_kg'][1]:.3f}], truth {m['truth_kg']:.3f} kg; carved {carving['solid_m3']:.5f} m^3 against "
          f"{carving['true_on_grid_m3']:.5f} m^3 true on the grid (IoU {carving['iou']:.3f})", flush=True)


if __name__ == "__main__":
    main()
