"""Time the mass of one object from a splat of N Gaussians: the object's geometry (selection, depth, carving, parts,
structure: ``geometry.reconstruct_object``) and the Monte Carlo (``mass.integrate_mass``), stage by stage.

    python benchmarks/gpu/mass_integration.py --gaussians 1000000 --views 54 --size 512   # GPU (issue 13: <= 2 s)
    python benchmarks/gpu/mass_integration.py --gaussians 20000 --views 12 --size 96      # CPU smoke run
    python benchmarks/gpu/mass_integration.py --gaussians 1000000 --views 24 --size 256 --reuse-rasterization  # CPU

The scene is generated here, so the figures need no trained run: a table (an oak top on four steel legs, flat
Gaussians on their surfaces, the way 3DGS places them) standing on a floor of other Gaussians (the background
that the selection must leave out), seen by rings of cameras; each view's object mask is the table's rendered
silhouette. N counts every Gaussian, floor included (a third of them). One untimed run first (CUDA context,
kernels, thread pools), then ``--repeats`` timed runs; the stages' times are medians, with the device synchronised
at each stage boundary. The mass itself is printed beside the table's true mass as a sanity check, not as an
accuracy figure (benchmarks/mass_suite.py measures accuracy). ``--reuse-rasterization``: the timed runs take the
untimed run's lifted masks and depth renders, so that on a CPU the stages time the work that a GPU run does on its
CPU and in small kernels, not the pure-torch rasterizer.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from physgs_nerfstudio.export.shapes import field_from
from physgs_nerfstudio.geometry import CaptureView, GeometryConfig, reconstruct_object
from physgs_nerfstudio.geometry.capture import viewmat_from_c2w
from physgs_nerfstudio.geometry.gaussians import render_depth
from physgs_nerfstudio.mass import MassConfig, integrate_mass

TOP = ((-0.5, -0.3, 0.70), (0.5, 0.3, 0.74))  # metres: an oak top 1.0 x 0.6 x 0.04
LEG = 0.04  # steel legs 4 cm square, under the top's corners
DENSITY = {"oak": 700.0, "steel": 7850.0, "concrete": 2400.0}


def _boxes() -> list[tuple[np.ndarray, np.ndarray, int]]:
    """(lo, hi, material) of the table's boxes: 0 = oak, 1 = steel."""
    (x0, y0, z0), (x1, y1, z1) = (np.array(p) for p in TOP)
    boxes = [(np.array([x0, y0, z0]), np.array([x1, y1, z1]), 0)]
    for sx in (x0 + 0.03, x1 - 0.03 - LEG):
        for sy in (y0 + 0.03, y1 - 0.03 - LEG):
            boxes.append((np.array([sx, sy, 0.0]), np.array([sx + LEG, sy + LEG, z0]), 1))
    return boxes


def _flat(points: np.ndarray, normals: np.ndarray, spacing: float) -> tuple[torch.Tensor, ...]:
    """Flat Gaussians tangent to the surface at ``points`` (quaternion turning +z onto the normal)."""
    n = torch.from_numpy(normals)
    axis = torch.cross(torch.tensor([0.0, 0.0, 1.0], dtype=n.dtype).expand_as(n), n, dim=-1)
    q = torch.cat([(1 + n[:, 2:3]), axis], -1)
    q[n[:, 2] < -1 + 1e-9] = torch.tensor([0.0, 1.0, 0.0, 0.0], dtype=n.dtype)
    q = q / q.norm(dim=-1, keepdim=True)
    scales = torch.tensor([spacing, spacing, spacing * 0.05]).expand(len(points), 3).clone()
    return torch.from_numpy(points).float(), scales, q.float()


def _box_surface(lo: np.ndarray, hi: np.ndarray, n: int, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    size = hi - lo
    faces = [(ax, s) for ax in range(3) for s in (0, 1)]
    areas = np.array([np.prod(np.delete(size, ax)) for ax, _ in faces])
    which = rng.choice(len(faces), size=n, p=areas / areas.sum())
    pts = lo + rng.random((n, 3)) * size
    nrm = np.zeros((n, 3))
    for f, (ax, s) in enumerate(faces):
        sel = which == f
        pts[sel, ax] = hi[ax] if s else lo[ax]
        nrm[sel, ax] = 1.0 if s else -1.0
    return pts, nrm


def make_scene(n: int, views: int, size: int, device: str, seed: int = 0):
    """(field, capture views with masks, true mass kg) of the table on its floor (module doc)."""
    rng = np.random.default_rng(seed)
    boxes = _boxes()
    areas = np.array([2 * (np.prod((h - lo)[:2]) + np.prod((h - lo)[1:]) + (h - lo)[0] * (h - lo)[2])
                      for lo, h, _ in boxes])  # fmt: skip
    n_floor = n // 3
    counts = np.floor((n - n_floor) * areas / areas.sum()).astype(int)
    counts[0] += n - n_floor - counts.sum()
    pts, nrm, lab = [], [], []
    for (lo, hi, m), c in zip(boxes, counts):
        p, q = _box_surface(lo, hi, int(c), rng)
        pts.append(p), nrm.append(q), lab.append(np.full(int(c), m))
    spacing = math.sqrt(areas.sum() / (n - n_floor)) * 1.5
    floor = np.column_stack([rng.uniform(-1.5, 1.5, (n_floor, 2)), np.zeros(n_floor)])
    floor = floor[~((np.abs(floor[:, 0]) < 0.52) & (np.abs(floor[:, 1]) < 0.32))]  # not under the table's top
    pts.append(floor), nrm.append(np.tile([0.0, 0.0, 1.0], (len(floor), 1))), lab.append(np.full(len(floor), 2))
    means, scales, quats = _flat(np.concatenate(pts), np.concatenate(nrm), spacing)
    labels = torch.from_numpy(np.concatenate(lab))
    names = ["oak", "steel", "concrete"]
    pf = field_from(means, scales, quats, densities=[DENSITY[k] for k in names], labels=labels, names=names,
                    thickness_m=[None, None, None]).to(device)  # fmt: skip
    table = field_from(means[labels < 2], scales[labels < 2], quats[labels < 2], densities=[700.0]).to(device)
    f = size / (2 * math.tan(math.radians(45.0) / 2))
    K = torch.tensor([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1.0]])
    centre = np.array([0.0, 0.0, 0.4])
    cams = []
    for i in range(views):
        el = math.radians((0.0, 20.0, 50.0)[i % 3])  # the lowest ring sees under the top
        az = 2 * math.pi * i / views
        pos = centre + 2.2 * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        fwd = (centre - pos) / np.linalg.norm(centre - pos)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        c2w = torch.from_numpy(np.stack([right, up, -fwd, pos], 1)).float()  # OpenGL axes, as nerfstudio's
        cams.append(CaptureView(viewmat_from_c2w(c2w), K, size, size, torch.zeros(size, size, dtype=torch.bool),
                                name=f"v{i:03d}"))  # fmt: skip
    for v, r in zip(cams, render_depth(table, cams, surface=False)):
        v.mask = (r.alpha > 0.5).cpu()
    true_kg = sum(DENSITY["oak" if m == 0 else "steel"] * float(np.prod(h - lo)) for lo, h, m in boxes)
    return pf, cams, true_kg


def run_once(pf, views, device: str, cfg: GeometryConfig | None = None) -> tuple[dict[str, float], float]:
    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
    marks: list[tuple[str, float]] = []

    def step(name: str) -> None:
        sync()
        marks.append((name, time.perf_counter()))

    pf._pi = None  # as in a fresh export: nothing cached
    sync()
    t0 = time.perf_counter()
    geo = reconstruct_object(pf, pf.pi_rows, views, (), [None] * pf.num_materials, cfg or GeometryConfig(),
                             material_names=pf.material_names, alpha=pf.alpha, material_weights=pf.material_weights,
                             progress=step)  # fmt: skip
    step("mass Monte Carlo")
    report = integrate_mass(pf, geo, MassConfig())
    step("end")
    times = {"total": marks[-1][1] - t0}
    for (name, t), (_, t_next) in itertools.pairwise(marks):
        times[name] = t_next - t
    times["geometry"] = marks[-2][1] - t0
    return times, float(report.mean_kg)


_RASTER: dict[str, object] = {}


def _record_rasterization() -> None:
    """Keep the outputs of the geometry's two rasterizing steps (lifting the masks, rendering the object's depth)."""
    from physgs_nerfstudio.geometry import reconstruct, select

    lift, render = select.lift_masks, reconstruct.render_depth

    def lift_kept(*a, **k):
        _RASTER["lift"] = lift(*a, **k)
        return _RASTER["lift"]

    def render_kept(*a, **k):
        _RASTER["render"] = render(*a, **k)
        return _RASTER["render"]

    select.lift_masks, reconstruct.render_depth = lift_kept, render_kept


def _replay_rasterization() -> None:
    """Answer those two steps with the kept outputs (--reuse-rasterization)."""
    from physgs_nerfstudio.geometry import reconstruct, select

    select.lift_masks = lambda *a, **k: tuple(t.clone() for t in _RASTER["lift"])  # type: ignore[attr-defined]
    reconstruct.render_depth = lambda *a, **k: _RASTER["render"]


_FUNCTIONS = {
    "select": ["lift_masks", "band_labels", "split_close", "support_plane_or_reason"],
    "reconstruct": ["drop_outside_hull", "_object_views", "voxel_mixture", "part_labels", "observation_shares",
                    "concavities", "pooled_part_alpha", "material_quantiles", "part_areas", "fuse_structure"],
    "solid": ["mask_hull", "carve_votes_many", "solid_from_votes", "support_excess"],
}  # fmt: skip
_FUNC_TIMES: dict[str, list[float]] = {}


def _time_functions(device: str) -> None:
    """Time the geometry's functions (--functions): each call wrapped with a device sync on both sides; the
    variants' areas run on a thread pool, so their times overlap and add up to more than the stage's."""
    from physgs_nerfstudio.geometry import reconstruct, select, solid

    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
    for mod, names in ((select, _FUNCTIONS["select"]), (reconstruct, _FUNCTIONS["reconstruct"]),
                       (solid, _FUNCTIONS["solid"])):
        for name in names:
            f = getattr(mod, name)

            def timed(*a, _f=f, _name=name, **k):
                sync()
                t = time.perf_counter()
                out = _f(*a, **k)
                sync()
                _FUNC_TIMES.setdefault(_name, []).append(time.perf_counter() - t)
                return out

            setattr(mod, name, timed)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--gaussians", type=int, default=1_000_000)
    ap.add_argument("--views", type=int, default=54)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"])
    ap.add_argument("--reuse-rasterization", action="store_true",
                    help="the timed runs reuse the untimed run's lifted masks and depth renders (the same inputs "
                         "give the same outputs): the stages then time the rest, which a GPU run pays on its CPU; "
                         "for CPU comparisons, where the pure-torch rasterizer would hide it")  # fmt: skip
    ap.add_argument("--functions", action="store_true",
                    help="also time the geometry's functions, summed per timed run (median over the runs)")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    device = ("cuda" if torch.cuda.is_available() else "cpu") if args.device == "auto" else args.device
    t = time.perf_counter()
    pf, views, true_kg = make_scene(args.gaussians, args.views, args.size, device)
    print(f"scene: {pf.num_gaussians} Gaussians, {len(views)} views at {args.size} px on {device} "
          f"({time.perf_counter() - t:.1f} s to make)")  # fmt: skip
    cfg = GeometryConfig()
    if args.reuse_rasterization:
        _record_rasterization()
    run_once(pf, views, device, cfg)  # untimed: CUDA context, kernels, thread pools
    if args.reuse_rasterization:
        _replay_rasterization()
    if args.functions:
        _time_functions(device)
    runs, per_run = [], []
    for _ in range(args.repeats):
        _FUNC_TIMES.clear()
        runs.append(run_once(pf, views, device, cfg))
        per_run.append({k: sum(v) for k, v in _FUNC_TIMES.items()})
    med = {k: statistics.median(r[0][k] for r in runs) for k in runs[0][0]}
    print(f"{'stage':<24}{'median s':>10}")
    for k, v in med.items():
        print(f"{k:<24}{v:>10.3f}")
    functions = {k: statistics.median(r.get(k, 0.0) for r in per_run) for k in per_run[0]} if args.functions else {}
    for k, v in sorted(functions.items(), key=lambda kv: -kv[1]):
        print(f"  {k:<22}{v:>10.3f}")
    print(f"mass {runs[-1][1]:.2f} kg (the table's true mass {true_kg:.2f} kg; a sanity check, not an accuracy figure)")
    if args.out:
        args.out.write_text(json.dumps({"gaussians": pf.num_gaussians, "views": len(views), "size": args.size,
                                        "device": device,
                                        "reuse_rasterization": args.reuse_rasterization, "gpu": torch.cuda.get_device_name() if device == "cuda"
                                        else None, "repeats": args.repeats, "median_s": med,
                                        "runs_s": [r[0] for r in runs], "functions_s": functions, "mass_kg": runs[-1][1],
                                        "true_kg": true_kg}, indent=2))  # fmt: skip


if __name__ == "__main__":
    main()
