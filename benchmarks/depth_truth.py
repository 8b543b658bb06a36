"""The depth that carves against the generator's true depth, per part and by the angle at which the view sees it.

    python benchmarks/depth_truth.py --load-config RUN/config.yml [--out F.json] [--voxel-m 0.0103]

For a trained run on a generated scene (`physgs synth` writes the true z-depth and part of every pixel in
``gt/depth`` and ``gt/part``): the object's Gaussians are selected and rendered as `physgs export` renders them
for carving (expected depth, median depth, along-ray extent), and on each true part's pixels (away from its edge in
the image by ``--inset-px``, opaque in the render) the rendered depth is compared with the true one. The error is
reported as the offset along the surface's normal, ``(rendered - true) x cos(incidence)`` (positive: the rendered
surface lies *inside* the part, under its face), in millimetres and in voxels, for the carving's depth (expected
minus the front extent, the GPU default; and the median, the CPU default) and by the incidence angle (from the true
depth map's normals). A positive offset of about a voxel on both faces of a plate carves a layer off each.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from geometry_diag import _transform, load_run_on_device

from physgs_nerfstudio.geometry import reconstruct
from physgs_nerfstudio.geometry.gaussians import render_depth
from physgs_nerfstudio.geometry.select import select_object

BINS = (0.0, 0.25, 0.5, 0.75, 1.0001)
"""cos(incidence) bins: grazing ... head-on"""


def true_normals(depth: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(float [H, W, 3] unit normals of the true depth map in camera axes, turned to face the camera; float [H, W]
    |cos| of the angle between each pixel's ray and its normal): from the back-projected points' central
    differences; NaN where the pixel or a neighbour is background."""
    H, W = depth.shape
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    x = (u + 0.5 - K[0, 2]) / K[0, 0]
    y = (v + 0.5 - K[1, 2]) / K[1, 1]
    P = np.stack([x * depth, y * depth, depth], -1)
    du = np.full_like(P, np.nan)
    dv = np.full_like(P, np.nan)
    du[:, 1:-1] = P[:, 2:] - P[:, :-2]
    dv[1:-1] = P[2:] - P[:-2]
    n = np.cross(du, dv)
    n /= np.linalg.norm(n, axis=-1, keepdims=True) + 1e-30
    ray = np.stack([x, y, np.ones_like(x)], -1)
    dot = (n * ray).sum(-1)
    n *= np.where(dot > 0, -1.0, 1.0)[..., None]  # facing the camera
    c = np.abs(dot) / np.linalg.norm(ray, axis=-1)
    bad = (depth <= 0) | np.isnan(c)
    bad[:, 1:-1] |= (depth[:, 2:] <= 0) | (depth[:, :-2] <= 0)
    bad[1:-1] |= (depth[2:] <= 0) | (depth[:-2] <= 0)
    c[bad] = np.nan
    n[bad] = np.nan
    return n, c


def true_normals_cos(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """float [H, W]: the |cos| of :func:`true_normals`."""
    return true_normals(depth, K)[1]


def face_of(n_world: np.ndarray) -> np.ndarray:
    """str [N]: "up" / "down" where the generator-world normal is within 45 degrees of +z / -z, else "side"."""
    z = n_world[..., 2]
    return np.where(z > np.sqrt(0.5), "up", np.where(z < -np.sqrt(0.5), "down", "side"))


def _erode(m: np.ndarray, r: int) -> np.ndarray:
    from scipy import ndimage

    return ndimage.binary_erosion(m, iterations=r) if r > 0 else m


def _stats(x: np.ndarray) -> dict:
    if len(x) == 0:
        return {"n": 0}
    q = np.percentile(x, [10, 50, 90])
    return {"n": len(x), "p10": round(float(q[0]), 3), "median": round(float(q[1]), 3),
            "p90": round(float(q[2]), 3)}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--load-config", type=Path, required=True)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--inset-px", type=int, default=2, help="pixels kept away from each part's edge in the image")
    ap.add_argument("--voxel-m", type=float, default=None, help="voxel size (m) to express the offsets in voxels")
    ap.add_argument("--max-view-width", type=int, default=640)
    a = ap.parse_args()
    from PIL import Image

    run = load_run_on_device(a.load_config, max_view_width=a.max_view_width)
    pf, views, data_dir = run.field, run.views, run.data_dir
    T, s = _transform(a.load_config.parent)
    R_T = T[:, :3]  # scene = s (R_T world + t)
    truth = json.loads((data_dir / "ground_truth.json").read_text())
    names = [p["name"] for p in truth["parts"]]
    by_name = {f["file_path"]: f for f in truth.get("frames", [])}
    cfg = reconstruct.GeometryConfig()
    sel = select_object(pf, views, cfg.select, backend=cfg.backend)
    sub = reconstruct._Subset(pf, sel.selected)
    renders = render_depth(sub, views, backend=cfg.backend, depth="both", extent=True)
    k = replace(cfg.carve, depth_render="expected").extent_multiple()  # gsplat's multiple
    rows: dict[str, dict[str, list]] = {n: {"front": [], "expected": [], "median": [], "cos": [], "face": []}
                                      for n in names}  # fmt: skip
    for v, r in zip(views, renders):
        f = by_name.get(v.name)
        if f is None:
            continue
        depth_true = np.load(data_dir / f["depth_path"]).astype(np.float64)
        part = np.asarray(Image.open(data_dir / f["part_path"]))
        if part.ndim == 3:
            part = part[..., 0]
        if depth_true.shape != (v.height, v.width):
            continue  # only views at the dataset's own size (no rescaled views)
        K = v.K.double().cpu().numpy()
        normal, cos = true_normals(depth_true, K)
        R_view = v.viewmat[:3, :3].double().cpu().numpy()
        face = face_of(normal @ R_view @ R_T)  # camera -> scene -> generator world
        alpha = r.alpha.double().cpu().numpy()
        exp_d = r.depth.double().cpu().numpy() / s
        med = (r.median if r.median is not None else r.depth).double().cpu().numpy() / s
        ext = r.extent.double().cpu().numpy() / s if r.extent is not None else np.zeros_like(exp_d)
        for i, n in enumerate(names):
            m = _erode(part == i + 1, a.inset_px) & (alpha >= 0.5) & np.isfinite(cos) & np.isfinite(exp_d)
            if not m.any():
                continue
            c = cos[m]
            rows[n]["cos"].append(c)
            rows[n]["face"].append(face[m])
            rows[n]["expected"].append((exp_d[m] - depth_true[m]) * c)
            rows[n]["front"].append((exp_d[m] - k * ext[m] - depth_true[m]) * c)
            rows[n]["median"].append((med[m] - depth_true[m]) * c)
    out: dict = {"config": str(a.load_config), "front_extent_multiple": k, "voxel_m": a.voxel_m,
                 "unit": "mm along the normal, + = inside the part", "parts": {}}  # fmt: skip
    for n, d in rows.items():
        if not d["cos"]:
            continue
        c = np.concatenate(d["cos"])
        res: dict = {}
        for key in ("front", "expected", "median"):
            x = np.concatenate(d[key]) * 1000
            res[key] = {f"cos {lo:.2f}-{min(hi, 1):.2f}": _stats(x[(c >= lo) & (c < hi)])
                        for lo, hi in itertools.pairwise(BINS)}
            res[key]["all"] = _stats(x)
            fc = np.concatenate(d["face"])
            res[key]["by_face"] = {f: _stats(x[fc == f]) for f in ("up", "down", "side")}
        out["parts"][n] = res
        for key in ("front", "expected", "median"):
            f = res[key]["all"]
            vox = f" ({f['median'] / 1000 / a.voxel_m:+.2f} voxel)" if a.voxel_m and f.get("n") else ""
            print(f"{n:10s} {key:8s} median {f.get('median')} mm{vox}; by cos: "
                  + ", ".join(f"{b[4:]}: {res[key][b].get('median')} (n={res[key][b]['n']})"
                              for b in res[key] if b not in ("all", "by_face"))
                  + "; by face: " + ", ".join(f"{f}: {st.get('median')} (n={st['n']})"
                                               for f, st in res[key]["by_face"].items()))
    if a.out:
        a.out.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
