"""`physgs export` wall times of two code trees side by side (before/after), plus a per-stage breakdown.

    python3 benchmarks/gpu/bench_export.py --config RUN/config.yml --tree main=/repo --tree perf=. \
        --views 10 --out export.json [--touch-gsplat]

Every case is one whole process (`python -m physgs_nerfstudio.cli export ...`, what a user runs), timed from
outside; the trees alternate case by case. Cases: ``load`` (import and load the run, write nothing: the fixed
cost of any export), ``ply``, ``maps1`` (one view), ``mapsN`` (``--views`` views; per view beyond the fixed
cost = (mapsN - maps1) / (N - 1)), ``mass``, ``all`` (the default outputs), ``mass_cold`` and ``all_cold`` (the same
with ``--no-geometry-cache`` in a tree that has the geometry cache: the geometry computed, not read from the run's
``physgs_cache/``; each row says whether its export read the geometry from there). Each process's gsplat build is
watched: a changed ``gsplat_cuda.so`` means that the process rebuilt it. ``--touch-gsplat`` then gives every
gsplat source the current time, as a reinstall of the wheel does, and times the last tree's ``maps1`` again
(the gsplat stamp must keep it from rebuilding; ninja's dry run says whether it would have). ``--breakdown``
(last, in this process, this tree) times each stage: loading, field on the device, material weights, PLY, geometry
steps, mass Monte Carlo, voxels, maps per view. ``--profile-load`` runs each tree's ``load`` once more under cProfile
and keeps the 30 entries of most cumulative time and -X importtime's 40 slowest imports (where the fixed cost
goes), before the cases.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

LOAD = ("import inspect,sys; from pathlib import Path; from physgs_nerfstudio.export.command import load_run; "
        "kw = {'capture': False} if 'capture' in inspect.signature(load_run).parameters else {}; "
        "r = load_run(Path(sys.argv[1]), **kw); print('gaussians', r.field.num_gaussians)")  # fmt: skip


def _gsplat_lib() -> Path | None:
    root = os.environ.get("TORCH_EXTENSIONS_DIR")
    return Path(root) / "gsplat_cuda" / "gsplat_cuda.so" if root else None


def _mtime(p: Path | None) -> float | None:
    return p.stat().st_mtime if p is not None and p.exists() else None


def _has_geometry_cache(tree: Path) -> bool:
    """Whether ``tree``'s export has the geometry cache (physgs_nerfstudio/export/geometry_cache.py)."""
    return (Path(tree) / "physgs_nerfstudio" / "export" / "geometry_cache.py").exists()


def _command(case: str, config: Path, out: Path, views: int, tree: Path | None = None) -> list[str]:
    if case == "load":
        return [sys.executable, "-c", LOAD, str(config)]
    cmd = [sys.executable, "-m", "physgs_nerfstudio.cli", "export", "--load-config", str(config), "--output-dir",
           str(out)]  # fmt: skip
    outputs = {"ply": ["ply"], "maps1": ["maps"], "mapsN": ["maps"], "mass": ["mass"], "mass_cold": ["mass"],
               "all": [], "all_cold": []}[case]  # fmt: skip
    if outputs:
        cmd += ["--outputs", *outputs]
    if case.endswith("_cold") and tree is not None and _has_geometry_cache(tree):
        cmd += ["--no-geometry-cache"]  # the geometry computed, whatever the run's cache holds
    if case == "mapsN":
        cmd += ["--views", *map(str, range(views))]
    return cmd


def run_case(tree: Path, case: str, config: Path, views: int) -> dict:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tree), os.environ.get("PYTHONPATH", "")]))
    lib = _gsplat_lib()
    before = _mtime(lib)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        proc = subprocess.run(_command(case, config, Path(tmp), views, tree), cwd=tree, env=env, capture_output=True,
                              text=True, check=False)  # fmt: skip
        wall = time.perf_counter() - t0
    after = _mtime(lib)
    row = {"case": case, "wall_s": round(wall, 3), "rc": proc.returncode,
           "gsplat_rebuilt": before is not None and after != before,
           "geometry_from_cache": "the run's geometry cache" in " ".join((proc.stdout + proc.stderr).split())}  # fmt: skip
    if proc.returncode != 0:
        row["tail"] = (proc.stdout + proc.stderr)[-1500:]
    return row


def profile_load(tree: Path, config: Path, top: int = 30) -> str:
    """The ``load`` case of ``tree`` under cProfile: its ``top`` entries by cumulative time, as text."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tree), os.environ.get("PYTHONPATH", "")]))
    with tempfile.TemporaryDirectory() as tmp:
        script, stats = Path(tmp) / "load.py", Path(tmp) / "load.prof"
        script.write_text(LOAD.replace("; ", "\n"))
        subprocess.run([sys.executable, "-m", "cProfile", "-o", str(stats), str(script), str(config)], cwd=tree,
                       env=env, capture_output=True, text=True, check=False)  # fmt: skip
        code = (f"import pstats, io; s = io.StringIO(); pstats.Stats({str(stats)!r}, stream=s)"
                f".sort_stats('cumulative').print_stats({top}); print(s.getvalue())")  # fmt: skip
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
        imports = subprocess.run([sys.executable, "-X", "importtime", str(script), str(config)], cwd=tree, env=env,
                                 capture_output=True, text=True, check=False).stderr  # fmt: skip
    rows = []  # (cumulative us, module) of -X importtime's lines
    for line in imports.splitlines():
        parts = line.removeprefix("import time:").split("|")
        if len(parts) == 3 and parts[1].strip().isdigit():
            rows.append((int(parts[1]), parts[2].rstrip()))
    top = "\n".join(f"{us / 1e6:8.3f} s {name}" for us, name in sorted(rows, reverse=True)[:40])
    return proc.stdout[-8000:] + "\nimports by cumulative time (-X importtime):\n" + top


def ninja_would_rebuild() -> int | None:
    """How many build steps ninja would run for the gsplat build (a dry run), or None."""
    lib = _gsplat_lib()
    if lib is None or not lib.parent.exists():
        return None
    proc = subprocess.run(["ninja", "-C", str(lib.parent), "-n"], capture_output=True, text=True, check=False)
    return sum(1 for line in proc.stdout.splitlines() if line.startswith("["))


def touch_gsplat_sources() -> int:
    import gsplat

    now = time.time()
    files = [p for p in (Path(gsplat.__file__).parent / "cuda" / "csrc").rglob("*") if p.is_file()]
    for p in files:
        os.utime(p, (now, now))
    return len(files)


def _sync() -> None:
    import torch

    if torch.cuda.is_available():
        torch.cuda.synchronize()


def breakdown(config: Path, views: int) -> dict:
    """Per-stage seconds of one export in this process (this tree's code)."""
    t: dict[str, float] = {}
    t0 = time.perf_counter()
    import torch

    from physgs_nerfstudio.export.command import load_run, object_geometry, views_from_cameras
    from physgs_nerfstudio.export.maps import save_property_maps
    from physgs_nerfstudio.export.ply import write_property_ply
    from physgs_nerfstudio.export.voxel import write_voxel_grid
    from physgs_nerfstudio.mass import MassConfig, integrate_mass

    t["import"] = time.perf_counter() - t0
    mark = time.perf_counter()

    def lap(name: str) -> None:
        nonlocal mark
        _sync()
        now = time.perf_counter()
        t[name] = now - mark
        mark = now

    load_run(config, capture=False)
    lap("load_run without masks (ply, maps)")
    run = load_run(config, capture=True)
    lap("load_run again, with masks (mass, voxels)")
    device = "cuda" if torch.cuda.is_available() else "cpu"
    run.field = run.field.to(device)
    lap("field to device")
    run.field.pi()
    lap("material weights (pi)")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        write_property_ply(run.field, out / "p.ply")
        lap("ply")
        steps: list[tuple[str, float]] = []
        geo = object_geometry(run, MassConfig().geometry,
                              progress=lambda s: (_sync(), steps.append((s, time.perf_counter()))))
        lap("geometry")
        names = [s for s, _ in steps] + ["end"]
        times = [x for _, x in steps] + [mark]
        t.update({f"geometry: {names[i]}": times[i + 1] - times[i] for i in range(len(steps))})
        integrate_mass(run.field, geo, MassConfig())
        lap("mass Monte Carlo")
        write_voxel_grid(run.field, out / "v.npz", geo)
        lap("voxels")
        vs = views_from_cameras(run.cameras, list(range(views)))
        stamps: list[float] = []
        save_property_maps(run.field, vs, out / "maps",
                           on_view=lambda _n: (_sync(), stamps.append(time.perf_counter())))
        lap(f"maps ({views} views)")
        per = [b - a for a, b in itertools.pairwise(stamps)]
        t["maps per view after the first (median)"] = statistics.median(per) if per else float("nan")
        t.update(_one_view_parts(run.field, vs[-1], out))
    return {"stages_s": {k: round(v, 3) for k, v in t.items()}, "num_gaussians": run.field.num_gaussians,
            "views": len(run.views), "device": device}  # fmt: skip


def _one_view_parts(field, view, out: Path) -> dict[str, float]:
    """One view's maps, part by part: channels, render, sheet, PNG, npz (what a view beyond the first costs)."""
    import numpy as np
    from PIL import Image

    from physgs_nerfstudio.export import maps as M

    t: dict[str, float] = {}
    mark = time.perf_counter()

    def lap(name: str) -> None:
        nonlocal mark
        _sync()
        now = time.perf_counter()
        t[f"one view: {name}"] = now - mark
        mark = now

    feats = M.map_features(field)
    lap("channels (once for all views)")
    maps = M.render_property_maps(field, view, features=feats)
    lap("render and read back")
    if hasattr(M, "_sheet"):
        sheet = M._sheet(field, maps, view.name)
        lap("sheet")
        Image.fromarray(sheet).save(out / "v.png", compress_level=1)
        lap("png")
    np.savez(out / "v.npz", **maps)
    lap("npz")
    return t


def summarise(rows: list[dict], trees: list[str], views: int) -> dict:
    out: dict[str, dict] = {}
    for name in trees:
        med = {}
        for case in ("load", "ply", "maps1", "mapsN", "mass", "all", "mass_cold", "all_cold"):
            w = [r["wall_s"] for r in rows if r["tree"] == name and r["case"] == case and r["rc"] == 0]
            if w:
                med[case] = statistics.median(w)
        if "maps1" in med and "mapsN" in med and views > 1:
            med["maps_per_view_beyond_fixed"] = (med["mapsN"] - med["maps1"]) / (views - 1)
        out[name] = med
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", type=Path, required=True)
    ap.add_argument("--tree", action="append", default=[], help="NAME=PATH of a checkout (first = baseline)")
    ap.add_argument("--cases", nargs="+", default=["load", "all", "mass", "maps1", "mapsN", "ply"])
    ap.add_argument("--views", type=int, default=10)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--budget-s", type=float, default=1e9, help="start no new case after this many seconds")
    ap.add_argument("--touch-gsplat", action="store_true")
    ap.add_argument("--breakdown", action="store_true")
    ap.add_argument("--profile-load", action="store_true")
    ap.add_argument("--warmup", action="store_true", help="one untimed load per tree first (bytecode caches written)")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    trees = [(n, Path(p).resolve()) for n, p in (t.split("=", 1) for t in args.tree)]
    result: dict = {"config": str(args.config), "views": args.views, "trees": {n: str(p) for n, p in trees},
                    "rows": []}  # fmt: skip
    start = time.perf_counter()

    def save() -> None:
        result["summary"] = summarise(result["rows"], [n for n, _ in trees], args.views)
        args.out.write_text(json.dumps(result, indent=1))

    if args.warmup:
        result["warmup"] = [{"tree": name, **run_case(path, "load", args.config, args.views)} for name, path in trees]
    if args.profile_load:  # first: where the fixed cost goes, whatever the budget leaves for the cases
        result["profile_load"] = {name: profile_load(path, args.config) for name, path in trees}
        save()
    for _ in range(args.repeats):
        for case in args.cases:
            for name, path in trees:
                if time.perf_counter() - start > args.budget_s:
                    break
                row = {"tree": name, **run_case(path, case, args.config, args.views)}
                result["rows"].append(row)
                print(json.dumps(row), flush=True)
                save()
    if args.touch_gsplat and trees:
        result["touched_gsplat_sources"] = touch_gsplat_sources()
        result["ninja_steps_after_touch"] = ninja_would_rebuild()
        name, path = trees[-1]
        row = {"tree": name, **run_case(path, "maps1", args.config, args.views), "after_touch": True}
        result["rows"].append(row)
        print(json.dumps(row), flush=True)
    if args.breakdown and time.perf_counter() - start < args.budget_s:
        result["breakdown"] = breakdown(args.config, args.views)
        print("breakdown", json.dumps(result["breakdown"]), flush=True)
    save()
    print(json.dumps(result["summary"], indent=1))


if __name__ == "__main__":
    main()
