"""Time of `physgs export --outputs sim` on a trained run (the demo's, on the CPU) and its share of the export.

    python benchmarks/sim_export.py --load-config RUN/config.yml [--resolution 96] [--n-samples 4000]
        [--collision hull coacd] [--samples 32] [--json F]
    MUJOCO_GL=egl python benchmarks/sim_export.py --render EXPORT/sim --png docs/sim_mujoco.png

In one process: the run is loaded once; the export's usual outputs (ply, voxels, maps of view 0, mass) are written
with the object's geometry computed (no geometry cache: a cold export), then `--outputs sim` is written on that
geometry once per collision method. Printed: each step's wall seconds (the sim's own steps: meshes, collision,
carriers, writers, samples) and the sim's share of an export that writes everything, sim / (usual + sim).
`--render` drops an exported object onto a floor in MuJoCo and renders it at rest (the README's picture).
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

STEPS = {"physgs_nerfstudio.sim.build": ["part_meshes", "collision_pieces", "elements", "mass_carriers"],
         "physgs_nerfstudio.sim.write": ["build_object", "_write_meshes", "write_mjcf", "write_urdf", "write_usd",
                                         "_particles", "_write_samples"]}  # fmt: skip


def _timers() -> dict[str, float]:
    import importlib

    spent: dict[str, float] = {}
    for modname, names in STEPS.items():
        mod = importlib.import_module(modname)
        for name in names:
            f = getattr(mod, name)

            @functools.wraps(f)
            def timed(*a, _f=f, _n=name, **k):
                t = time.perf_counter()
                try:
                    return _f(*a, **k)
                finally:
                    spent[_n] = spent.get(_n, 0.0) + time.perf_counter() - t

            setattr(mod, name, timed)
    return spent


def render_at_rest(sim_dir: Path, out: Path, drop: float = 0.05, seconds: float = 1.5,
                   size: tuple[int, int] = (480, 640)) -> None:  # fmt: skip
    """Drop an exported object (``scene.xml``: the object on a floor) from ``drop`` metres, simulate ``seconds`` and
    render its resting state off-screen to ``out``; prints the lowest collision point's height (0 = on the floor),
    the tilt of its z axis and its largest speed. Needs an OpenGL that MuJoCo opens without a display
    (``MUJOCO_GL=egl``, Mesa's EGL works on CPU machines, or ``osmesa``)."""
    import mujoco
    import numpy as np
    from PIL import Image


    model = mujoco.MjModel.from_xml_path(str(sim_dir / "scene.xml"))
    data = mujoco.MjData(model)
    data.qpos[2] = drop
    for _ in range(int(seconds / model.opt.timestep)):
        mujoco.mj_step(model, data)
    man = json.loads((sim_dir / "manifest.json").read_text())
    extent = 2.0 * float(np.max(np.abs(model.geom_rbound[1:])))
    cam = mujoco.MjvCamera()
    cam.lookat[:] = data.xipos[1]
    cam.distance, cam.azimuth, cam.elevation = 2.2 * extent, 135.0, -25.0
    renderer = mujoco.Renderer(model, *size)
    renderer.update_scene(data, camera=cam)
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(renderer.render()).save(out)
    geoms = [i for i in range(model.ngeom) if "collision" in model.geom(i).name]
    low = min(float((data.geom_xpos[i] + model.mesh_vert[model.mesh_vertadr[j]:model.mesh_vertadr[j]
                                                         + model.mesh_vertnum[j]] @ data.geom_xmat[i].reshape(3, 3).T
                     )[:, 2].min()) for i, j in ((i, model.geom_dataid[i]) for i in geoms))  # fmt: skip
    tilt = np.degrees(np.arccos(np.clip(data.xmat[1].reshape(3, 3)[2, 2], -1, 1)))
    print(f"{out}: {man['object']} ({man['body']['mass_kg']:.4g} kg) at rest after {seconds} s: lowest "
          f"collision point {low * 1000:.3f} mm, tilted {tilt:.2f} deg, largest speed {np.abs(data.qvel).max():.2e}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--load-config", type=Path)
    ap.add_argument("--render", type=Path, metavar="SIM_DIR",
                    help="instead: render an export's sim/ folder at rest in MuJoCo to --png (the README's picture)")
    ap.add_argument("--png", type=Path, default=Path("docs/sim_mujoco.png"))
    ap.add_argument("--resolution", type=int, default=96, help="voxels along the longest side (the demo's 96)")
    ap.add_argument("--n-samples", type=int, default=4000)
    ap.add_argument("--collision", nargs="+", default=["hull", "coacd"])
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    if args.render is not None:
        render_at_rest(args.render, args.png)
        return 0
    if args.load_config is None:
        ap.error("--load-config is required (or --render SIM_DIR)")

    import torch

    from physgs_nerfstudio.export.command import load_run, views_from_cameras, write_export
    from physgs_nerfstudio.geometry import GeometryConfig
    from physgs_nerfstudio.mass import MassConfig
    from physgs_nerfstudio.sim import SimConfig

    torch.set_num_threads(max(1, torch.get_num_threads()))
    spent = _timers()
    t = time.perf_counter()
    run = load_run(args.load_config)
    t_load = time.perf_counter() - t
    mass = MassConfig(geometry=GeometryConfig(resolution=args.resolution), n_samples=args.n_samples)
    views = views_from_cameras(run.cameras, (0,), 480) if run.cameras is not None else []
    out = Path(tempfile.mkdtemp(prefix="sim_bench_"))
    t = time.perf_counter()
    res = write_export(run, out / "usual", mass=mass, views=views, quiet=True)
    t_usual = time.perf_counter() - t
    rows = {}
    for method in args.collision:
        spent.clear()
        t = time.perf_counter()
        sim = write_export(run, out / f"sim_{method}", mass=mass, outputs=("sim",), quiet=True, geometry=res.geometry,
                           sim=SimConfig(collision=method, samples=args.samples))  # fmt: skip
        total = time.perf_counter() - t
        man = json.loads((out / f"sim_{method}" / "sim" / "manifest.json").read_text())
        rows[method] = {"seconds": total, "share_of_export": total / (t_usual + total), "steps": dict(spent),
                        "collision": man["collision"], "files": len(sim.files["sim"]),
                        "pieces": {p: v["collision_pieces"] for p, v in man["parts"].items()},
                        "triangles": sum(v["triangles"] for v in man["parts"].values())}  # fmt: skip
    result = {"load_config": str(args.load_config), "resolution": args.resolution, "n_samples": args.n_samples,
              "samples": args.samples, "solid_voxels": int(res.geometry.solid.sum()), "load_s": t_load,
              "usual_export_s": t_usual, "sim": rows, "mass_kg": res.mass.mean_kg}  # fmt: skip
    print(f"load {t_load:.1f} s; usual outputs (ply voxels maps mass, geometry computed) {t_usual:.1f} s; "
          f"{result['solid_voxels']} solid voxels")
    for method, r in rows.items():
        steps = ", ".join(f"{k} {v:.2f}" for k, v in r["steps"].items())
        print(f"--outputs sim, collision {method} ({r['collision']}): {r['seconds']:.1f} s = "
              f"{100 * r['share_of_export']:.0f}% of the export with it; {steps}")
    if args.json:
        args.json.write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
