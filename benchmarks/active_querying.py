"""Active querying vs asking every mask of every view, on the generated suite (SIMULATED VLM).

Uses the scenes and exhaustive perception of ``benchmarks/accuracy.py`` (same work dir, generated if
missing). The simulated VLM answers a (view, mask) request deterministically (seeded by the request), so a
query order can be replayed from the exhaustive observations: every policy below sees exactly the answers a
live run would get (checked once per run against a live ``run_active_perception`` on a copy of the first
object, from the response cache).

Policies (one query = one mask of one view):

* ``active``: :class:`physgs_nerfstudio.perception.active.ActiveSelector` (default ``ActiveConfig``);
* ``active (no transfer)``: the same without the cross-view appearance transfer (within-view Dirichlet
  entropy, NIG epistemic and exploration only);
* ``dataset order``: every mask of view 0, then view 1, ... (what a capped exhaustive run does);
* ``random``: uniformly random order (mean over ``--random-repeats`` seeds).

After every ``--step`` queries the object's mass is estimated with the PhysGS estimator (c) of
accuracy.py (and its MAP-material variant (c')) from the answers so far, ground-truth part volumes as there.
Reported per object and in aggregate: the queries needed until the mass APE is within 5% of the exhaustive
estimator's APE (absolute: APE <= APE_all + 0.05; relative: APE <= 1.05 APE_all), and the APE at 25% of
the queries.

Run:  OMP_NUM_THREADS=1 python benchmarks/active_querying.py [--quick] [--work-dir DIR]
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import accuracy as acc

from physgs_nerfstudio.materials import load_library
from physgs_nerfstudio.perception.active import ActiveConfig, ActiveSelector, mask_features

ESTIMATORS = {"c": False, "c_map": True}


def selector_inputs(root: Path, scene: acc.SceneData):
    from PIL import Image

    from physgs_nerfstudio.perception.pipeline import mask_path
    from physgs_nerfstudio.perception.segment import load_masks

    stacks, levels, feats = {}, {}, {}
    for view in scene.views:
        ms = load_masks(mask_path(root, view)) or []
        img = np.asarray(Image.open(root / view).convert("RGB"), dtype=np.uint8)
        stacks[view] = np.stack([m.segmentation for m in ms]) if ms else np.zeros((0,) + img.shape[:2], bool)
        levels[view] = [m.level for m in ms]
        feats[view] = mask_features(img, [m.segmentation for m in ms])
    return stacks, levels, feats


def active_order(root: Path, scene: acc.SceneData, library, cfg: ActiveConfig) -> list[tuple[str, int]]:
    stacks, levels, feats = selector_inputs(root, scene)
    sel = ActiveSelector(scene.views, stacks, levels, feats, library, cfg)
    by_mask = scene.by_mask()
    order = []
    while sel.remaining():
        batch = sel.select(cfg.batch_size)
        if not batch:
            break
        for view, mid in batch:
            sel.observe(view, mid, by_mask.get((view, mid), []))
            order.append((view, mid))
    return order


def dataset_order(scene: acc.SceneData) -> list[tuple[str, int]]:
    rank = {v: i for i, v in enumerate(scene.views)}
    return sorted(scene.masks, key=lambda k: (rank[k[0]], k[1]))


def curve(scene: acc.SceneData, library, order: Sequence[tuple[str, int]], ks: Sequence[int], map_material: bool,
          samples: int) -> np.ndarray:
    """Mass APE after the first k queries of ``order`` for each k."""
    by_mask = scene.by_mask()
    cfg = acc.PhysGSConfig(n_samples=samples, map_material=map_material)
    out = []
    for k in ks:
        obs = [o for key in order[:k] for o in by_mask.get(key, [])]
        sub = replace(scene, observations=obs)
        est = acc.estimate_physgs(sub, library, cfg)
        out.append(abs(est.mass_kg - scene.mass_kg) / scene.mass_kg)
    return np.asarray(out)


def first_within(ks: Sequence[int], apes: np.ndarray, target: float) -> int | None:
    for k, a in zip(ks, apes):
        if a <= target + 1e-12:
            return int(k)
    return None


def live_check(root: Path, work: Path, scene: acc.SceneData, library, cfg: ActiveConfig, budget: int,
               bench: acc.BenchConfig) -> dict:
    """Run run_active_perception for real on a copy of ``root`` (answers come from the response cache) and
    compare its query order with the replayed one."""
    from physgs_nerfstudio.perception.active import run_active_perception

    dst = work / f"live_{root.name}"
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(root, dst, ignore=shutil.ignore_patterns("observations.jsonl*", "progress.jsonl*", "run.json", "active.json"))
    pc = acc.perception_config(dst, bench)
    seg = acc.OracleSegmenter(dst) if bench.segmenter == "oracle" else None
    res = run_active_perception(pc, replace(cfg, budget=budget), segmenter=seg)
    replayed = active_order(root, scene, library, cfg)[:budget]
    same = [tuple(q) for q in res.queried] == [tuple(q) for q in replayed]
    return {"object": scene.name, "budget": budget, "answered": res.answered, "uncached_calls": res.calls,
            "cache_hits": res.cache_hits, "stop_reason": res.stop_reason, "same_order_as_replay": same}


def main(argv: Sequence[str] | None = None) -> dict:
    from physgs_nerfstudio.perception.simulated import SimulatedConfig
    from physgs_nerfstudio.synth import SUITE

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--objects", nargs="*", default=None)
    ap.add_argument("--views", type=int, default=16)
    ap.add_argument("--resolution", type=int, default=96)
    ap.add_argument("--jitter", type=float, default=0.2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--segmenter", choices=("oracle", "builtin"), default="oracle")
    ap.add_argument("--step", type=int, default=4, help="evaluate the mass after every STEP queries")
    ap.add_argument("--random-repeats", type=int, default=5)
    ap.add_argument("--samples", type=int, default=64, help="Monte Carlo draws per estimate (only the mean is used)")
    ap.add_argument("--work-dir", type=Path, default=Path("/tmp/physgs_bench/accuracy"))
    ap.add_argument("--results-dir", type=Path, default=None)
    ap.add_argument("--no-live-check", action="store_true")
    ap.add_argument("--quick", action="store_true", help="smoke run: 3 objects, 8 views, 64 px")
    args = ap.parse_args(argv)
    if args.quick:
        objects = tuple(args.objects or ("mug", "hammer", "bottle"))
        args.views, args.resolution, args.random_repeats = min(args.views, 8), min(args.resolution, 64), min(args.random_repeats, 2)
    else:
        objects = tuple(args.objects or SUITE)
    bench = acc.BenchConfig(objects, args.views, args.resolution, args.jitter, args.seed, args.segmenter, args.work_dir)
    sim = SimulatedConfig(seed=args.seed)
    library = load_library("indoor")
    acfg = ActiveConfig()
    print(acc.describe_noise(sim))
    print(f"masks: {args.segmenter}; {len(objects)} objects x {bench.views} views at {bench.resolution}px; "
          f"ActiveConfig: {asdict(acfg)}")
    print("Mass from ground-truth part volumes; estimator (c) PhysGS mixture mean and (c') its MAP-material variant.")
    t0 = time.time()
    rows = []
    agg: dict[str, dict[str, list]] = {}
    live = None
    for oi, obj in enumerate(objects):
        root = acc.prepare_scene(bench, obj)
        acc.run_scene_perception(root, bench, sim)
        scene = acc.load_scene(root, obj)
        N = len(scene.masks)
        ks = sorted(set(list(range(args.step, N, args.step)) + [N, math.ceil(0.25 * N)]))
        orders = {
            "active": [active_order(root, scene, library, acfg)],
            "active (no transfer)": [active_order(root, scene, library, replace(acfg, transfer=0.0))],
            "dataset order": [dataset_order(scene)],
        }
        rng = np.random.default_rng(args.seed)
        keys = dataset_order(scene)
        orders["random"] = [[keys[i] for i in rng.permutation(N)] for _ in range(args.random_repeats)]
        if oi == 0 and not args.no_live_check:
            live = live_check(root, bench.work_dir, scene, library, acfg, math.ceil(0.25 * N), bench)
            print(f"  live check ({obj}): {live}")
        k25 = ks.index(math.ceil(0.25 * N))
        for est, use_map in ESTIMATORS.items():
            full = curve(scene, library, keys, [N], use_map, args.samples)[0]
            for pol, ords in orders.items():
                cs = np.stack([curve(scene, library, o, ks, use_map, args.samples) for o in ords])
                need_abs = [first_within(ks, c, full + 0.05) for c in cs]
                need_rel = [first_within(ks, c, 1.05 * full) for c in cs]
                row = {
                    "object": obj, "estimator": est, "policy": pol, "queries_all": N, "ape_all": float(full),
                    "ape_at_25pct": float(cs[:, k25].mean()),
                    "queries_to_abs5": float(np.mean([n if n is not None else N for n in need_abs])),
                    "queries_to_rel5": float(np.mean([n if n is not None else N for n in need_rel])),
                    "curve_k": ks, "curve_ape": cs.mean(0).tolist(),
                }
                rows.append(row)
                a = agg.setdefault(f"{est}|{pol}", {"frac_abs": [], "frac_rel": [], "ape25": [], "ape_all": [],
                                                   "within_abs_at_25": [], "within_rel_at_25": []})
                a["frac_abs"].append(row["queries_to_abs5"] / N)
                a["frac_rel"].append(row["queries_to_rel5"] / N)
                a["ape25"].append(row["ape_at_25pct"])
                a["ape_all"].append(float(full))
                a["within_abs_at_25"].append(float(np.mean(cs[:, k25] <= full + 0.05 + 1e-12)))
                a["within_rel_at_25"].append(float(np.mean(cs[:, k25] <= 1.05 * full + 1e-12)))
        print(f"  {obj:10s} {N} masks ({time.time() - t0:.0f}s)", flush=True)
    lines = [("| estimator | policy | mean APE, all queries | mean APE at 25% | objects within 5 pts at 25% "
              "| within 5% rel. at 25% | mean fraction of queries to within 5 pts | ... to within 5% rel. |"),
             "|---|---|---|---|---|---|---|---|"]
    for est in ESTIMATORS:
        label = "(c) mixture mean" if est == "c" else "(c') MAP material"
        for pol in ("active", "active (no transfer)", "dataset order", "random"):
            a = agg[f"{est}|{pol}"]
            lines.append(f"| {label} | {pol} | {np.mean(a['ape_all']):.4f} | {np.mean(a['ape25']):.4f} | "
                         f"{np.mean(a['within_abs_at_25']):.0%} | {np.mean(a['within_rel_at_25']):.0%} | "
                         f"{np.mean(a['frac_abs']):.2f} | {np.mean(a['frac_rel']):.2f} |")
    text = "\n".join(lines)
    print(text)
    out_dir = args.results_dir or (bench.work_dir / "results")
    out_dir.mkdir(parents=True, exist_ok=True)
    doc = {"benchmark": "active querying vs exhaustive (SIMULATED VLM)", "simulated_vlm": acc.describe_noise(sim),
           "active_config": asdict(acfg), "bench": {k: str(v) for k, v in asdict(bench).items()},
           "live_check": live, "rows": rows, "seconds": time.time() - t0}
    (out_dir / "active_querying.json").write_text(json.dumps(doc, indent=1))
    print(f"\nwrote {out_dir / 'active_querying.json'} ({time.time() - t0:.0f}s)")
    return doc


if __name__ == "__main__":
    main(sys.argv[1:])
