"""Carving rules side by side on trained runs of generated scenes, against the generator's exact parts.

    python benchmarks/carve_diag.py RUN_DIR [RUN_DIR ...] --rules baseline median ... [--cache DIR]

RUN_DIR: a `physgs demo` output folder (runs/**/config.yml and scene/ground_truth.json). Per run the selection,
the object's views and their renders (expected depth with its spread, median depth) are computed once (cached
with ``--cache``); then each rule's nominal carving is compared voxel by voxel with the true occupancy on the
same grid: carved / true volume, per-part recall, false solid. Cheaper than a re-export (no materials, parts,
structure or variants) and exact about geometry, so it screens carving rules before `mass_suite.py` measures
them. ``--account PART ...``: for each rule, which views' votes emptied those true parts' lost voxels
(:func:`view_account`). On a GPU machine the field is loaded on the GPU, as `physgs export` does.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from geometry_diag import _part_of, _to_world, _transform, load_run_on_device

from physgs_nerfstudio.geometry import reconstruct as rc
from physgs_nerfstudio.geometry.carve import (
    CarveConfig,
    carve_votes,
    resolve_depth_render,
    signed_mask_distance,
)
from physgs_nerfstudio.geometry.gaussians import ViewRender, render_depth
from physgs_nerfstudio.geometry.select import select_object
from physgs_nerfstudio.render.backend import resolve_backend
from physgs_nerfstudio.synth.objects import build_layout

RULES = {
    "baseline": {},
    "median": {"depth_render": "median"},
    "spread1": {"front_spread": 1.0},
    "spread0.5": {"front_spread": 0.5},
    "maxspread1": {"max_spread_voxels": 1.0},
    "maxspread2": {"max_spread_voxels": 2.0},
    "median_maxspread2": {"depth_render": "median", "max_spread_voxels": 2.0},
    "first0.5": {"depth_render": "first", "mixed_depth_voxels": 0.5},
    "first1": {"depth_render": "first", "mixed_depth_voxels": 1.0},
    "first2": {"depth_render": "first", "mixed_depth_voxels": 2.0},
    "nodepth": {"use_depth": False},
    "expected": {"depth_render": "expected"},
    "margin0.5": {"depth_margin_voxels": 0.5},
    "consensus0.5": {"depth_consensus": 0.5},
    "consensus0.34": {"depth_consensus": 0.34},
    "consensus0.5_band2": {"depth_consensus": 0.5, "near_band_voxels": 2.0},
    "expected_margin0.5": {"depth_render": "expected", "depth_margin_voxels": 0.5},
    "expected_margin1": {"depth_render": "expected", "depth_margin_voxels": 1.0},
    "expected_consensus0.5": {"depth_render": "expected", "depth_consensus": 0.5},
    "expected_consensus0.34": {"depth_render": "expected", "depth_consensus": 0.34},
    "expected_consensus0.5_band2": {"depth_render": "expected", "depth_consensus": 0.5, "near_band_voxels": 2.0},
    "margin1": {"depth_margin_voxels": 1.0},
    "margin-0.5": {"depth_margin_voxels": -0.5},
    "median_extent1": {"depth_render": "median", "front_extent": 1.0},
}


def prepare(run_dir: Path, cache: Path | None, median: bool = True) -> dict:
    f = cache / f"{run_dir.name}.pt" if cache else None
    if f is not None and f.is_file():
        return torch.load(f, weights_only=False)
    cfg_path = next((run_dir / "runs").glob("**/config.yml"))
    run = load_run_on_device(cfg_path, max_view_width=640)
    pf, views = run.field, run.views
    cfg = rc.GeometryConfig()
    sel = select_object(pf, views, cfg.select, backend=cfg.backend)
    rc._within_hull(pf, sel, views, cfg)
    obj_views, _ = rc._object_views(pf, sel, views, cfg)
    sub = rc._Subset(pf, sel.selected)
    ed = render_depth(sub, views, backend=cfg.backend, spread=True, extent=True)
    # the median depth runs the reference compositor, on CUDA too: minutes per run at 60 views of 512 px
    med = render_depth(sub, views, backend=cfg.backend, depth="median") if median else None
    grid = rc._domain(pf, sel.selected, cfg)
    T, s = _transform(cfg_path.parent)
    truth = json.loads((run.data_dir / "ground_truth.json").read_text())
    layout = build_layout(truth["layout"], int(truth.get("seed", 0)))
    parts = [p for p in layout.parts if p.role == "object"]
    out = {"views": obj_views, "ed": ed, "med": med, "grid": grid, "T": T, "s": s, "parts": parts,
           "names": [p.name for p in parts], "truth": truth, "means": pf.means[sel.selected].detach().cpu(),
           "backend": resolve_backend(cfg.backend, pf.means.device)}
    if f is not None:
        torch.save(out, f)
    return out


def rule_config(rule: dict, backend: str) -> CarveConfig:
    """The carving setting of ``rule`` (CarveConfig fields over its defaults), its ``depth_render`` "auto" resolved
    for the rasterizer that rendered the depth, as the export does (`reconstruct_object`): an unresolved "auto"
    would carve with the median wherever a median was rendered."""
    cc = replace(CarveConfig(), **rule)
    return replace(cc, depth_render=resolve_depth_render(cc.depth_render, backend))


def carve(d: dict, rule: dict, account: Sequence[str] = ()) -> dict:
    # caches written before the backend was kept were rendered on the GPU (gsplat) or the CPU (reference) as now
    cc = rule_config(rule, d.get("backend") or ("gsplat" if torch.cuda.is_available() else "reference"))
    if d["med"] is None and rule.get("depth_render") in ("median", "first"):
        raise SystemExit(f"rule {rule} needs the median depth: run without --no-median")
    med = d["med"] if d["med"] is not None else [None] * len(d["ed"])
    renders = [ViewRender(e.depth, e.alpha, e.spread, m.depth if m is not None else None, e.extent)
               for m, e in zip(med, d["ed"])]  # fmt: skip
    sdf = [signed_mask_distance(v.mask) for v in d["views"]]
    grid = d["grid"]
    cfg = rc.GeometryConfig()
    means = d.get("means")  # (caches written before it was kept: no extent cut)
    dev = "cuda" if torch.cuda.is_available() else "cpu"
    views = [replace(v, mask=v.mask.to(dev)) for v in d["views"]] if dev == "cuda" else d["views"]
    carve_on = lambda g: rc._carve_variants(g, views, renders, [("nominal", cc)], sdf, dev,
                                            None if means is None else means.to(dev), cfg.extent_pad_voxels)[0][0]
    solid = carve_on(grid)
    lo, hi = rc._solid_bounds(grid, solid)
    if lo is not None and float((hi - lo).max()) < cfg.refit_fraction * float(np.max(grid.shape)) * grid.voxel_size:
        pad = float((hi - lo).max()) * (cfg.pad_fraction + 2.0 / cfg.resolution)
        grid = rc.VoxelGrid.from_bounds(torch.from_numpy(lo - pad), torch.from_numpy(hi + pad), cfg.resolution)
        solid = carve_on(grid)
    ijk = np.argwhere(np.ones(grid.shape, bool))
    centres = grid.centres(torch.from_numpy(ijk)).double().numpy()
    gt = _part_of(d["parts"], _to_world(centres, d["T"], d["s"]), 0.0).reshape(grid.shape)
    true = gt >= 0
    out = {"ratio": float(solid.sum() / max(true.sum(), 1)),
           "iou": float((solid & true).sum() / max((solid | true).sum(), 1)),
           "false": float((solid & ~true).sum() / max(true.sum(), 1)),
           "recall": {n: round(float((solid & (gt == i)).sum() / max((gt == i).sum(), 1)), 3)
                      for i, n in enumerate(d["names"])}}
    if account:
        out["account"] = {n: view_account(d, grid, views, renders, sdf, cc, solid, gt == d["names"].index(n), dev)
                          for n in account if n in d["names"]}
    return out


def view_account(d: dict, grid: Any, views: list, renders: list, sdf: list, cc: CarveConfig, solid: np.ndarray,
                 part: np.ndarray, dev: str) -> dict:
    """Which views empty a true part's voxels that the nominal carving lost: per view, its empty votes on them by
    mask and by depth, how many of them it sees near its surface (its say in the depth consensus), and the angle
    between its axis and the world's down direction (0: looking straight down); and over the lost voxels, the
    median numbers of depth votes and of near views (the consensus compares the two)."""
    lost = torch.from_numpy((part & ~solid).reshape(-1)).to(dev)
    kept = torch.from_numpy((part & solid).reshape(-1)).to(dev)
    R = np.asarray(d["T"], float)[:, :3]
    down = R @ np.array([0.0, 0.0, -1.0])  # the world's down in scene axes (p_s = s (R p_w + t))
    rows, n_depth, n_near = [], torch.zeros(int(lost.sum()), device=dev), torch.zeros(int(lost.sum()), device=dev)
    for j, (v, r, sd) in enumerate(zip(views, renders, sdf)):
        vt = carve_votes(grid, [v], [r], cc, sdf=[sd], device=dev)
        de = vt.depth_empty.bool()
        me = vt.empty.bool() & ~de
        near = vt.near.bool() if vt.near is not None else torch.zeros_like(de)
        n_depth += de[lost].float()
        n_near += near[lost].float()
        axis = v.axis.double().cpu().numpy()
        ang = float(np.degrees(np.arccos(np.clip(axis @ down / np.linalg.norm(axis), -1, 1))))
        rows.append({"view": j, "from_down_deg": round(ang, 1), "lost_depth": int(de[lost].sum()),
                     "lost_mask": int(me[lost].sum()), "lost_near": int(near[lost].sum()),
                     "kept_depth": int(de[kept].sum()), "kept_near": int(near[kept].sum())})
    rows.sort(key=lambda x: -x["lost_depth"])
    med = (lambda t: float(t.median()) if len(t) else None)
    return {"lost": int(lost.sum()), "kept": int(kept.sum()), "median_depth_votes": med(n_depth),
            "median_near": med(n_near), "views": rows}


def parts_report(run_dir: Path, resolution: int | None) -> dict:
    """The export's whole geometry (``physgs export`` defaults; ``resolution``: the grid's, None = the export's)
    against the true parts: per true part, the share of its voxels in the nominal solid and, of those, how many each
    predicted part holds; per predicted part, its material, volume (m^3) and which true parts its voxels lie on.
    Tells a part lost by the carving from one whose voxels went to a neighbour's material."""
    from physgs_nerfstudio.export.command import object_geometry

    cfg_path = next((run_dir / "runs").glob("**/config.yml"))
    run = load_run_on_device(cfg_path, max_view_width=640)
    gc = rc.GeometryConfig() if resolution is None else rc.GeometryConfig(resolution=resolution)
    geo = object_geometry(run, gc)
    T, s = _transform(cfg_path.parent)
    truth = json.loads((run.data_dir / "ground_truth.json").read_text())
    parts = [p for p in build_layout(truth["layout"], int(truth.get("seed", 0))).parts if p.role == "object"]
    grid = geo.grid
    ijk = np.argwhere(np.ones(grid.shape, bool))
    world = _to_world(grid.centres(torch.from_numpy(ijk)).double().numpy(), T, s)
    gt = _part_of(parts, world, 0.0).reshape(grid.shape)
    names = run.field.material_names
    dom = np.argmax(geo.part_mixture, 1)
    mpu3 = float(run.field.metres_per_unit) ** 3
    # where each true part's lost voxels lie: its bottom or top 1.5 voxels (world height), or elsewhere (sides)
    z = world[:, 2].reshape(grid.shape)
    dz = 1.5 * grid.voxel_size / s

    def lost(i: int) -> dict:
        m = gt == i
        miss = m & ~geo.solid
        lo, hi = z[m].min(), z[m].max()
        bot, top = int((miss & (z < lo + dz)).sum()), int((miss & (z > hi - dz)).sum())
        return {"bottom": bot, "top": top, "other": int(miss.sum()) - bot - top}

    true = {p.name: {"material": p.material, "lost": lost(i),
                     "kept": round(float((geo.solid & (gt == i)).sum() / max((gt == i).sum(), 1)), 3),
                     "to_parts": {int(j): int(c) for j, c in enumerate(np.bincount(geo.parts[(gt == i) & geo.solid],
                                                                                   minlength=geo.num_parts)) if c}}
            for i, p in enumerate(parts)}  # fmt: skip
    pred = []
    for j in range(geo.num_parts):
        on = gt[(geo.parts == j) & geo.solid]
        pred.append({"material": names[dom[j]], "volume_m3": float(geo.volumes[0, j]) * mpu3,
                     "on": {p.name: int((on == i).sum()) for i, p in enumerate(parts) if (on == i).any()},
                     "off": int((on < 0).sum())})
    return {"voxel_m": grid.voxel_size * float(run.field.metres_per_unit), "true": true, "predicted": pred,
            "false_solid": int((geo.solid & (gt < 0)).sum()), "true_voxels": int((gt >= 0).sum())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--rules", nargs="*", default=list(RULES))
    ap.add_argument("--cache", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--parts", action="store_true", help="also the export's whole geometry per part (parts_report)")
    ap.add_argument("--resolution", type=int, default=None, help="--parts: the grid's resolution (export default)")
    ap.add_argument("--account", nargs="*", default=[], metavar="PART",
                    help="per-view account of these true parts' lost voxels under each rule (view_account)")
    ap.add_argument("--no-median", action="store_true", help="skip the median depth (slow on large runs): only "
                    "rules that carve with the expected depth")
    a = ap.parse_args()
    if a.cache:
        a.cache.mkdir(parents=True, exist_ok=True)
    res = {}
    for r in a.runs:
        d = prepare(r, a.cache, median=not a.no_median)
        res[r.name] = {}
        for name in a.rules:
            m = carve(d, RULES[name], a.account)
            res[r.name][name] = m
            print(f"{r.name:14s} {name:18s} ratio {m['ratio']:.3f} iou {m['iou']:.3f} false {m['false']:.3f} "
                  f"recall {m['recall']}", flush=True)
            for part, acc in m.get("account", {}).items():
                print(f"  {part}: lost {acc['lost']} kept {acc['kept']}; over the lost, median depth votes "
                      f"{acc['median_depth_votes']} of median near views {acc['median_near']}; the views that "
                      f"empty most: " + ", ".join(f"#{x['view']} ({x['from_down_deg']} deg from down) "
                                                  f"{x['lost_depth']} by depth, near {x['lost_near']}"
                                                  for x in acc["views"][:6]), flush=True)
        if a.parts:
            res[r.name]["parts"] = rep = parts_report(r, a.resolution)
            print(f"{r.name:14s} parts: " + "; ".join(f"{n} kept {t['kept']} lost {t['lost']} -> {t['to_parts']}"
                                                      for n, t in rep["true"].items()))
            print(f"{r.name:14s} predicted: " + "; ".join(f"{j} {p['material']} {p['volume_m3'] * 1e6:.0f} cm3 on {p['on']}"
                                                          for j, p in enumerate(rep["predicted"])), flush=True)
        if a.out:  # after each run: a stopped command keeps what finished
            a.out.write_text(json.dumps(res, indent=1))
    if a.out:
        a.out.write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
