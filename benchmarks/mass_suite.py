"""Mass over the generated families through the whole pipeline (synth -> perceive [SIMULATED VLM] -> train -> export).

    python benchmarks/mass_suite.py --seeds 70001 --out /tmp/mass_suite                     # every family, project renderer
    python benchmarks/mass_suite.py --seeds 70001 70002 70003 --renderers project mitsuba     # the full grid
    python benchmarks/mass_suite.py --families mug kettle --seeds 70001 --renderers mitsuba   # a subset, path traced
    python benchmarks/mass_suite.py --objects mug chair --seeds 101                           # today's fixed presets
    python benchmarks/mass_suite.py --seeds 70001 --export-args "--mass.geometry.resolution 128" --alt-name r128
    python benchmarks/mass_suite.py --merge A/mass_suite.json B/mass_suite_rows_baseline.jsonl merged.json  # one table
    python benchmarks/mass_suite.py --masks --families mug chair --seeds 71001 --renderers mitsuba  # the segmenter only
    python benchmarks/mass_suite.py --selection --seeds 71001 --renderers mitsuba --out OUT  # finished runs' selection

**The suite.** Every family of `physgs_nerfstudio.synth.families` (today's twelve presets as parametric families and
eleven new ones), each drawn from the seed (dimensions, part counts, walls, hollow or solid, each part's material and
its density inside the material's range), in one of the family's poses (standing, lying, on a small stand), on a
support (a floor or a table top with its own material and texture, seen by the cameras; ``--support none``: floating),
rendered by the project's ray caster (``project``) or path traced by Mitsuba 3 (``mitsuba``, ``--spp``; needs the
``pathtrace`` extra). The scene is written into OUT/FAMILY_sSEED_RENDERER/scene first, then ``physgs demo`` (its CPU
settings: 16 views at 96 px, 300 iterations, export at 96 voxels) runs on it, with its perception by the built-in
segmenter and the SIMULATED VLM. Runs are resumable (finished stages are skipped). Seeds that tests use (0-40, 101,
and the test files' own) should not be used here: the documented runs use 70001-70003.

**The split.** `families.DEVELOPMENT` (defaults of the method may be chosen on them) and `families.HELD_OUT` (all new
shapes; only measured): every summary shows both side by side, per renderer.

**Per object**: truth, predicted mean, 90% interval, covered, APE, and the error split exactly into three factors,
``pred / truth = volume x structure x density``:

* ``volume``: the carved envelope (the report's ``geometry.volume_m3``) over the true envelope (the object's parts'
  enclosed volumes: a shell with its cavity);
* ``structure``: the predicted material share of the envelope (solid parts whole, hollow parts their area x wall
  thickness, weighted by the hollow probability) over the true share (true material volume / true envelope);
* ``density``: the predicted mass per predicted material volume over the true mass per true material volume.

``support_kg``: the predicted mass inside the support or the stand: each export part's mass times the share of its
voxels' fill whose centres lie inside them (the export's voxels.npz mapped to the world by nerfstudio's dataparser
transform); the support is *counted* when that is more than 5% of the object's true mass.

**Per split** (and renderer, and method row): objects scored, median APE, coverage of the 90% interval, median
interval half-width relative to the mean, objects off by more than 2x, share of objects whose support was counted,
median absolute volume error, and failures (a run that crashed, with its last line). The first method row is
``baseline``: the method as it is (no export flags); ``--export-args`` adds a re-export of every finished run under
``--alt-name`` (``--trained``: score runs trained elsewhere, e.g. on a GPU, exported with the defaults). One
summary JSON (OUT/mass_suite[_NAME].json: the rows and the summary) and one printed table.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import statistics
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

OBJECTS = ("mug", "chair", "hammer", "bottle", "shoe", "table", "pan", "lamp", "crate", "stool", "dumbbell", "vase")
SUPPORT_COUNTED_SHARE = 0.05  # support mass above this share of the true mass: the support was counted in


def _demo_export_args(seed: int) -> list[str]:
    """The flags that make `physgs export` match the demo's own export (its grid resolution, samples and seed)."""
    from physgs_nerfstudio.demo import DemoCommand

    d = DemoCommand()
    return ["--mass.geometry.resolution", str(d.export_resolution), "--mass.n-samples", str(d.n_samples),
            "--mass.seed", str(seed)]  # fmt: skip


def write_scene(family: str, seed: int, renderer: str, support: str, scene_dir: Path, spp: int,
                mesh_dir: Path | None = None) -> float:  # fmt: skip
    """Generate the suite's scene (module doc) with the demo's views and resolution; seconds taken (0: it existed).
    ``mesh_dir``: the folder of bunny.obj and armadillo.obj (None: `physgs synth`'s default)."""
    from physgs_nerfstudio.demo import DemoCommand
    from physgs_nerfstudio.synth import SynthConfig, generate_scene

    if (scene_dir / "ground_truth.json").is_file():
        return 0.0
    d = DemoCommand()
    t0 = time.perf_counter()
    meshes = {"mesh_dir": mesh_dir} if mesh_dir is not None else {}
    generate_scene(SynthConfig(out=scene_dir, object=family, seed=seed, views=d.views, resolution=d.resolution,
                               shape="drawn", support=support, pose="drawn", renderer=renderer, spp=spp,
                               overwrite=True, **meshes))  # fmt: skip
    return time.perf_counter() - t0


def _tag(item: dict, support: str) -> str:
    """A run's folder name: FAMILY_sSEED_RENDERER (_float without a support; FAMILY_sSEED for a preset)."""
    fam, seed = item["family"], item["seed"]
    if item["preset"]:
        return f"{fam}_s{seed}"
    return f"{fam}_s{seed}_{item['renderer']}" + ("_float" if support == "none" else "")


def _scene_task(args: tuple) -> str:
    family, seed, renderer, support, scene_dir, spp, mesh_dir = args
    os.environ.update(OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    try:
        import torch

        torch.set_num_threads(1)
        s = write_scene(family, seed, renderer, support, Path(scene_dir), spp, mesh_dir)
        return f"{Path(scene_dir).parent.name}: {s:.1f} s"
    except Exception as err:  # noqa: BLE001 - a failed scene is reported; its run then fails with the same reason
        return f"{Path(scene_dir).parent.name}: failed: {type(err).__name__}: {err}"


def write_scenes(todo: list[dict], a: argparse.Namespace) -> None:
    """Every scene of the grid, ``--jobs`` processes at once (one thread each); one line per scene as it ends."""
    from concurrent.futures import ProcessPoolExecutor

    tasks = [(t["family"], t["seed"], t["renderer"], a.support,
              str(a.out / _tag(t, a.support) / "scene"), a.spp, a.mesh_dir)
             for t in todo if not t["preset"]]  # fmt: skip
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max(1, a.jobs)) as pool:
        for i, line in enumerate(pool.map(_scene_task, tasks), 1):
            print(f"[{i}/{len(tasks)} {time.perf_counter() - t0:.0f} s] {line}", flush=True)


def _to_world(x_scene: np.ndarray, transform: np.ndarray, scale: float) -> np.ndarray:
    """Dataset (world) coordinates of scene points: the inverse of nerfstudio's p_s = scale (R p + t)."""
    R, t = transform[:, :3], transform[:, 3]
    return (x_scene / scale - t) @ R


def support_mass(run_dir: Path, export: Path, layout_parts: list, rep_parts: list[dict]) -> float | None:
    """Predicted kg inside the support: each export part's mass (report.json) times the share of its voxels' fill
    (voxels.npz) whose world centres lie inside a ground part; a hollow part's mass lies in its wall, so its voxels
    share it by their fill, not by fill x density. Voxels of no part (the thin partial layer just outside the carving)
    are left out. None without the export's voxel grid or the run's dataparser transform."""
    from physgs_nerfstudio.export.voxel import load_voxel_grid

    vox, tf = export / "voxels.npz", next(iter((run_dir / "runs").glob("**/dataparser_transforms.json")), None)
    if not vox.is_file() or tf is None:
        return None
    vx = load_voxel_grid(vox)
    dp = json.loads(tf.read_text())
    fill = np.asarray(vx["fill"], float)
    idx = np.argwhere(fill > 0)
    if len(idx) == 0:
        return 0.0
    origin, h = np.asarray(vx["origin_scene"], float), float(vx["voxel_size_scene"])
    world = _to_world(origin + (idx + 0.5) * h, np.asarray(dp["transform"], float), float(dp["scale"]))
    ground = np.zeros(len(idx), bool)
    for part in layout_parts:
        if part.role == "ground":
            ground |= part.primitive.contains(part.to_local(world))
    pid, w = np.asarray(vx["part_id"])[tuple(idx.T)], fill[tuple(idx.T)]
    kg = 0.0
    for p, part in enumerate(rep_parts):
        mine = pid == p
        if w[mine].sum() > 0:
            kg += float(part["mass_mean_kg"]) * float(w[mine & ground].sum() / w[mine].sum())
    return kg


def error_split(gt: dict, rep: dict) -> dict:
    """The exact split pred / truth = volume x structure x density (module doc) and the structure calls."""
    obj = [p for p in gt["parts"] if p.get("role", "object") == "object"]
    truth = sum(p["mass_kg"] for p in obj)
    true_mat = sum(p["volume_m3"] for p in obj)
    true_env = sum(p.get("enclosed_volume_m3", p["volume_m3"]) for p in obj)
    pred_env = float(rep["geometry"].get("volume_m3", rep.get("volume_m3", 0.0)))
    pred_mat = sum(p["volume_m3"] * (1 - p["structure"]["p_hollow"]) + min(p["volume_m3"], p["area_m2"] *
                   p["structure"]["thickness_m"]) * p["structure"]["p_hollow"] for p in rep["parts"])  # fmt: skip
    pred = float(rep["mean_kg"])
    ok = pred_env > 0 and pred_mat > 0 and true_env > 0
    shells = {p["material"] for p in obj if p["volume_model"] == "shell"}
    solids = {p["material"] for p in obj if p["volume_model"] == "solid"}
    right = [(p["structure"]["p_hollow"] > 0.5) == (p["material"] in shells) for p in rep["parts"]
             if p["material"] in shells | solids]  # fmt: skip
    return {
        "volume": pred_env / true_env if ok else None,
        "structure": (pred_mat / pred_env) / (true_mat / true_env) if ok else None,
        "density": (pred / pred_mat) / (truth / true_mat) if ok else None,
        "volume_ratio": pred_mat / true_mat if true_mat > 0 else None,  # material volume (the earlier suite's figure)
        "structure_right": (sum(right) / len(right)) if right else None,
    }


def score(family: str, seed: int, renderer: str, run_dir: Path, export: Path, support: str,
          mesh_dir: Path | None = None) -> dict:  # fmt: skip
    """One object's row (module doc) from its ground_truth.json and its export's report.json (and voxels.npz);
    ``mesh_dir``: the figurine family's meshes (None: `physgs synth`'s default folder)."""
    from physgs_nerfstudio.synth.families import split_of
    from physgs_nerfstudio.synth.objects import build_layout
    from physgs_nerfstudio.synth.support import suite_layout

    gt = json.loads((run_dir / "scene" / "ground_truth.json").read_text())
    rep = json.loads((export / "report.json").read_text())["mass"]
    truth, pred = float(gt["total_mass_kg"]), float(rep["mean_kg"])
    lo, hi = rep["interval_kg"]
    if gt["parameters"].get("shape", "canonical") == "drawn":
        meshes = {"mesh_dir": mesh_dir} if mesh_dir is not None else {}
        parts = suite_layout(family, seed, shape="drawn", support=support, pose="drawn", **meshes).parts
    else:
        parts = build_layout(family, seed, *([mesh_dir] if mesh_dir is not None else [])).parts
    sup = support_mass(run_dir, export, parts, rep["parts"])
    return {
        "family": family, "split": split_of(family), "seed": seed, "renderer": renderer, "layout": gt.get("layout"),
        "truth_kg": truth, "pred_kg": pred, "interval_kg": [lo, hi], "covered": lo <= truth <= hi,
        "ape": abs(pred - truth) / truth, "half_width_rel": (hi - lo) / 2 / pred if pred > 0 else None,
        "off_2x": pred > 2 * truth or pred < truth / 2, "error": error_split(gt, rep),
        "support_kg": sup, "support_counted": None if sup is None else sup > SUPPORT_COUNTED_SHARE * truth,
        "support": next((p["material"] for p in gt["parts"] if p["object"] in ("floor", "tabletop")), None),
        "true_parts": [{k: p[k] for k in ("name", "material", "volume_model", "thickness_m", "volume_m3",
                                          "enclosed_volume_m3", "density_kg_m3", "mass_kg", "role") if k in p}
                       for p in gt["parts"]],
        "rests_on_plane": rep["geometry"].get("rests_on_plane"),
        "support_plane_in_masks": rep["geometry"].get("support_plane_in_masks"),
        "parts": [{"material": p["material"], "volume_m3": p["volume_m3"], "area_m2": p["area_m2"],
                   "p_hollow": p["structure"]["p_hollow"], "thickness_m": p["structure"]["thickness_m"],
                   "mass_mean_kg": p["mass_mean_kg"]} for p in rep["parts"]],
        "density_mean": {m["name"]: m["density_mean"] for m in rep["materials"]},
        "volume_by_variant_m3": rep["geometry"].get("volume_by_variant_m3"),
    }  # fmt: skip


def _run(cmd: list[str], env: dict, log: Path) -> str | None:
    proc = subprocess.run(cmd, check=False, capture_output=True, text=True, env=env)
    log.write_text(proc.stdout[-20000:] + proc.stderr[-20000:])
    if proc.returncode != 0:
        return (proc.stderr.strip().splitlines() or ["failed"])[-1]
    return None


def run_one(item: dict, a: argparse.Namespace) -> dict:
    """Scene, demo and (with --export-args) the re-export of one (family, seed, renderer); its scored row."""
    fam, seed, renderer = item["family"], item["seed"], item["renderer"]
    tag = _tag(item, a.support)
    d = a.out / tag
    env = dict(os.environ, **({"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"} if a.jobs > 1 else {}))
    row = {"family": fam, "seed": seed, "renderer": renderer}
    t0 = time.perf_counter()
    try:
        scene_s = 0.0 if item["preset"] else write_scene(fam, seed, renderer, a.support, d / "scene", a.spp,
                                                         a.mesh_dir)  # fmt: skip
    except Exception as err:  # noqa: BLE001 - a failed scene is a failed row, reported with its reason
        return {**row, "failed": f"scene: {type(err).__name__}: {err}"}
    demo = [sys.executable, "-m", "physgs_nerfstudio.cli", "demo", "--object", fam, "--seed", str(seed),
            "--output-dir", str(d), *(["--mesh-dir", str(a.mesh_dir)] if a.mesh_dir else []), *a.demo_args]  # fmt: skip
    finished = a.trained or (d / "demo_summary.json").is_file()
    if not finished and (err := _run(demo, env, a.out / f"{tag}.log")):
        return {**row, "failed": f"demo: {err}"}
    export = d / "export"
    if a.export_args is not None or a.trained:
        cfg = next((d / "runs").glob("**/config.yml"))
        export = d / f"export_{a.alt_name}"
        cmd = [sys.executable, "-m", "physgs_nerfstudio.cli", "export", "--load-config", str(cfg), "--output-dir",
               str(export), "--outputs", "mass", "voxels", "--overwrite",
               *([] if a.trained else _demo_export_args(seed)), *(a.export_args or [])]  # fmt: skip
        if err := _run(cmd, env, a.out / f"{tag}_{a.alt_name}.log"):
            return {**row, "failed": f"export: {err}"}
    try:
        out = score(fam, seed, renderer, d, export, a.support, a.mesh_dir)
    except Exception as err:  # noqa: BLE001 - e.g. an export without a mass (its report says why)
        return {**row, "failed": f"score: {type(err).__name__}: {err}"}
    return {**out, "scene_s": scene_s, "wall_s": time.perf_counter() - t0}


def mask_scores(scene_dir: Path, segmenter=None) -> dict:
    """The built-in segmenter's whole-object masks on one scene against its label maps (``--masks``): the union of a
    view's ``whole`` masks (what the geometry carves from) summed over the views; ``iou`` with the object's parts,
    ``support_share`` of the masks on the support or stand (role ``ground``), ``views_without_object``."""
    from PIL import Image

    from physgs_nerfstudio.perception.segment_builtin import BuiltinSegmenterConfig

    seg = segmenter or BuiltinSegmenterConfig().setup()
    gt = json.loads((scene_dir / "ground_truth.json").read_text())
    obj_ids = [p["id"] for p in gt["parts"] if p["role"] == "object"]
    sup_ids = [p["id"] for p in gt["parts"] if p["role"] != "object"]
    inter = union = masked = on_support = empty = 0
    for fr in gt["frames"]:
        part = np.asarray(Image.open(scene_dir / fr["part_path"]))
        obj, sup = np.isin(part, obj_ids), np.isin(part, sup_ids)
        whole = [m.segmentation for m in seg.segment(np.asarray(Image.open(scene_dir / fr["file_path"]).convert("RGB")))
                 if m.level == "whole"]  # fmt: skip
        u = np.any(whole, 0) if whole else np.zeros_like(obj)
        empty += not u.any()
        inter, union = inter + int((u & obj).sum()), union + int((u | obj).sum())
        masked, on_support = masked + int(u.sum()), on_support + int((u & sup).sum())
    return {"iou": inter / max(union, 1), "support_share": on_support / max(masked, 1), "views_without_object": empty,
            "views": len(gt["frames"])}  # fmt: skip


def masks_mode(todo: list[dict], a: argparse.Namespace) -> None:
    """``--masks``: write the scenes, score the built-in segmenter's whole masks on each (:func:`mask_scores`), print
    one line per scene and the medians, and write OUT/mask_iou.json."""
    write_scenes(todo, a)
    rows = []
    for t in todo:
        r = {"family": t["family"], "seed": t["seed"], "renderer": t["renderer"],
             **mask_scores(a.out / _tag(t, a.support) / "scene")}  # fmt: skip
        rows.append(r)
        print(f"{r['family']:10s} {r['seed']} {r['renderer']:8s} IoU {r['iou']:.2f}  support share "
              f"{r['support_share']:.2f}  views without object {r['views_without_object']}/{r['views']}", flush=True)
    if rows:
        print(f"median IoU {_median([r['iou'] for r in rows]):.3f}  median support share "
              f"{_median([r['support_share'] for r in rows]):.3f}  ({len(rows)} scenes)")
    (a.out / "mask_iou.json").write_text(json.dumps({"seeds": a.seeds, "support": a.support, "rows": rows}, indent=2))


def selection_share(run_dir: Path, family: str, seed: int, mesh_dir: Path | None) -> dict:
    """How much of the object the selection holds on a finished run (``--selection``): the trained splat's Gaussians
    (opacity > 0.1) whose centres lie inside the object's true envelope (its parts' outer shapes), their median
    foreground probability (the masks lifted onto the Gaussians) and the share of them that
    ``geometry.select.select_object`` selects with the export's defaults. The solid ends at the selected Gaussians'
    polytope, so what the selection lacks is not carved."""
    from physgs_nerfstudio.export.run import load_run
    from physgs_nerfstudio.geometry.config import GeometryConfig
    from physgs_nerfstudio.geometry.select import select_object
    from physgs_nerfstudio.synth.support import suite_layout

    run = load_run(next((run_dir / "runs").glob("**/config.yml")))
    dp = json.loads(next((run_dir / "runs").glob("**/dataparser_transforms.json")).read_text())
    cfg = GeometryConfig()
    g = run.field
    sel = select_object(g, list(run.views), cfg.select, backend=cfg.backend)
    world = _to_world(g.means.double().cpu().numpy(), np.asarray(dp["transform"], float), float(dp["scale"]))
    meshes = {"mesh_dir": mesh_dir} if mesh_dir is not None else {}
    inside = np.zeros(len(world), bool)
    for p in suite_layout(family, seed, shape="drawn", support="drawn", pose="drawn", **meshes).parts:
        if p.role != "ground":
            inside |= p.outer().contains(p.to_local(world))
    obj = inside & (g.opacities.reshape(-1).cpu().numpy() > 0.1)
    prob, selected = sel.prob.cpu().numpy()[obj], sel.selected.cpu().numpy()[obj]
    return {"gaussians": int(obj.sum()), "median_prob": float(np.median(prob)) if obj.any() else None,
            "selected_share": float(selected.mean()) if obj.any() else None}  # fmt: skip


def selection_mode(todo: list[dict], a: argparse.Namespace) -> None:
    """``--selection``: score every finished run's selection (:func:`selection_share`), print one line per run and
    the median share, and write OUT/selection_share.json."""
    rows = []
    for t in todo:
        d = a.out / _tag(t, a.support)
        if not (d / "demo_summary.json").is_file():
            continue
        r = {"family": t["family"], "seed": t["seed"], "renderer": t["renderer"],
             **selection_share(d, t["family"], t["seed"], a.mesh_dir)}  # fmt: skip
        rows.append(r)
        print(f"{r['family']:10s} {r['seed']} {r['renderer']:8s} object Gaussians {r['gaussians']:5d}  median "
              f"probability {r['median_prob']:.2f}  selected {r['selected_share']:.2f}", flush=True)
    if rows:
        print(f"median selected share {_median([r['selected_share'] for r in rows]):.2f}  ({len(rows)} runs)")
    (a.out / "selection_share.json").write_text(json.dumps({"seeds": a.seeds, "rows": rows}, indent=2))


def _median(xs: list) -> float | None:
    xs = [x for x in xs if x is not None and math.isfinite(x)]
    return statistics.median(xs) if xs else None


def summarize(rows: list[dict]) -> list[dict]:
    """Per (renderer, split): the module doc's figures."""
    from physgs_nerfstudio.synth.families import split_of

    out = []
    for renderer in sorted({r["renderer"] for r in rows}):
        for split in ("development", "held_out"):
            group = [r for r in rows if r["renderer"] == renderer and split_of(r["family"]) == split]
            ok = [r for r in group if "failed" not in r]
            if not group:
                continue
            counted = [r["support_counted"] for r in ok if r.get("support_counted") is not None]
            out.append({
                "renderer": renderer, "split": split, "objects": len(ok), "failed": len(group) - len(ok),
                "median_ape": _median([r["ape"] for r in ok]),
                "coverage": sum(r["covered"] for r in ok) / len(ok) if ok else None,
                "median_half_width_rel": _median([r["half_width_rel"] for r in ok]),
                "off_2x": sum(r["off_2x"] for r in ok),
                "support_counted_share": sum(counted) / len(counted) if counted else None,
                "median_volume_error": _median([abs(r["error"]["volume"] - 1) for r in ok
                                                if r["error"]["volume"] is not None]),
            })  # fmt: skip
    return out


def table(summary: list[dict], method: str) -> str:
    def f(x, fmt):
        return "-" if x is None else format(x, fmt)

    head = ("method", "renderer", "split", "n", "failed", "median APE", "90% coverage", "median half-width/mean",
            ">2x off", "support counted", "median |vol err|")
    lines = [" | ".join(head), " | ".join("---" for _ in head)]
    for s in summary:
        lines.append(" | ".join([method, s["renderer"], s["split"], str(s["objects"]), str(s["failed"]),
                                 f(s["median_ape"], ".3f"), f(s["coverage"], ".0%"),
                                 f(s["median_half_width_rel"], ".2f"), str(s["off_2x"]),
                                 f(s["support_counted_share"], ".0%"), f(s["median_volume_error"], ".3f")]))
    return "\n".join(lines)


def _args(argv: list[str] | None = None) -> argparse.Namespace:
    from physgs_nerfstudio.synth.families import FAMILIES

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--families", nargs="*", default=list(FAMILIES), help="families of the suite (default: all)")
    ap.add_argument("--objects", nargs="*", default=None,
                    help="today's fixed presets instead (canonical, floating, project renderer: the earlier suite)")
    ap.add_argument("--seeds", nargs="*", type=int, default=[70001])
    ap.add_argument("--renderers", nargs="*", default=["project"], choices=["project", "mitsuba"])
    ap.add_argument("--support", default="drawn", choices=["drawn", "floor", "table", "none"])
    ap.add_argument("--spp", type=int, default=64, help="samples per pixel of the mitsuba renderer")
    ap.add_argument("--mesh-dir", type=Path, default=None,
                    help="folder of bunny.obj and armadillo.obj for the figurine family (default: physgs synth's)")
    ap.add_argument("--out", type=Path, default=Path("/tmp/physgs_mass_suite"))
    ap.add_argument("--demo-args", type=shlex.split, default=[],
                    help='extra `physgs demo` flags (one quoted string), e.g. "--device cuda": train on a GPU')
    ap.add_argument("--scenes-only", action="store_true",
                    help="write the scenes (--jobs processes at once) and stop: a GPU machine renders them on its CPUs "
                         "before the runs")
    ap.add_argument("--masks", action="store_true",
                    help="write the scenes and score the built-in segmenter's whole-object masks against their label "
                         "maps (IoU, share on the support; OUT/mask_iou.json) instead of running the pipeline")
    ap.add_argument("--selection", action="store_true",
                    help="score the finished runs' selection: the share of each object's Gaussians it holds "
                         "(OUT/selection_share.json) instead of running the pipeline")
    ap.add_argument("--export-args", type=shlex.split, default=None,
                    help="re-export every finished demo with these extra `physgs export` flags (one quoted string) into "
                         "export_NAME/ and score that: a method row beside the baseline")  # fmt: skip
    ap.add_argument("--alt-name", default="alt", help="name of the re-export (export_NAME/, mass_suite_NAME.json)")
    ap.add_argument("--jobs", type=int, default=1, help="runs at once (each limited to one thread)")
    ap.add_argument("--trained", action="store_true",
                    help="score runs trained elsewhere (the GPU suite: OUT/TAG/scene and runs/**/config.yml): "
                         "`physgs export --outputs mass voxels` with its defaults (plus --export-args) into export_NAME/")
    return ap.parse_args(argv)


def merge(files: list[Path], out: Path) -> None:
    """One summary and table of the rows of several saved suite JSONs, or of the rows files (.jsonl) that runs write
    as they go (runs split over processes or machines, or stopped early); a (family, seed, renderer) seen twice
    keeps its last row."""
    runs = []
    for f in files:
        if str(f).endswith(".jsonl"):
            lines = [json.loads(x) for x in Path(f).read_text().splitlines() if x.strip()]
            for m in sorted({x["method"] for x in lines}):
                runs.append({"method": m, "rows": list({(x["family"], x["seed"], x["renderer"]): x for x in lines
                                                        if x["method"] == m}.values())})  # fmt: skip
        else:
            runs.append(json.loads(Path(f).read_text()))
    methods = sorted({r["method"] for r in runs})
    merged = {"merged_from": [str(f) for f in files], "summary": {}, "rows": {}}
    for method in methods:
        rows = [row for r in runs if r["method"] == method for row in r["rows"]]
        merged["summary"][method] = summarize(rows)
        merged["rows"][method] = rows
        print(table(merged["summary"][method], method))
    out.write_text(json.dumps(merged, indent=2))


def main(argv: list[str] | None = None) -> None:
    if argv is None and sys.argv[1:2] == ["--merge"]:
        files = sys.argv[2:]
        return merge([Path(f) for f in files[:-1]], Path(files[-1]))
    a = _args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    if a.objects is not None:
        todo = [{"family": o, "seed": s, "renderer": "project", "preset": True} for s in a.seeds for o in a.objects]
    else:
        todo = [{"family": f, "seed": s, "renderer": r, "preset": False}
                for r in a.renderers for s in a.seeds for f in a.families]  # fmt: skip

    if a.scenes_only:
        return write_scenes(todo, a)
    if a.masks:
        return masks_mode(todo, a)
    if a.selection:
        return selection_mode(todo, a)
    method = "baseline" if a.export_args is None else a.alt_name
    partial = a.out / f"mass_suite_rows_{method}.jsonl"  # every finished row at once: a run stopped early keeps them

    def one(item: dict) -> dict:
        row = run_one(item, a)
        keep = ("family", "seed", "renderer", "truth_kg", "pred_kg", "interval_kg", "covered", "ape", "support_kg",
                "failed", "wall_s", "scene_s")  # fmt: skip
        print(json.dumps({k: row[k] for k in keep if k in row}), flush=True)
        with partial.open("a") as f:
            f.write(json.dumps({"method": method, **row}) + "\n")
        return row

    # the scenes first, in processes: a renderer's module (Mitsuba's) imported by several threads at once comes
    # out half-initialised in some of them
    missing = [t for t in todo if not t["preset"] and not (a.out / _tag(t, a.support) / "scene" /
                                                            "ground_truth.json").is_file()]  # fmt: skip
    if missing:
        write_scenes(missing, a)
    with ThreadPoolExecutor(max(1, a.jobs)) as pool:
        rows = list(pool.map(one, todo))
    summary = summarize(rows)
    print(table(summary, method))
    name = "mass_suite.json" if a.export_args is None and not a.trained else f"mass_suite_{a.alt_name}.json"
    (a.out / name).write_text(json.dumps({"method": method, "export_args": a.export_args, "seeds": a.seeds,
                                          "support": a.support, "spp": a.spp, "summary": summary, "rows": rows},
                                         indent=2))  # fmt: skip


if __name__ == "__main__":
    main()
