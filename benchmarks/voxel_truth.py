"""An export's voxel grid against the generator's exact parts: where the object's volume went, part by part.

    physgs export --load-config RUN/config.yml --outputs mass voxels --output-dir EXPORT
    python benchmarks/voxel_truth.py EXPORT --object shoe --seed 5050 [--transforms RUN/dataparser_transforms.json]
        [--profile sole] [--out truth.json]

For a run of a generated scene (`physgs synth --object OBJECT --seed SEED`), reads EXPORT/voxels.npz (the nominal
carving and each voxel's part, :mod:`physgs_nerfstudio.export.voxel`) and nerfstudio's dataparser transform (by
default EXPORT/dataparser_transforms.json, else --transforms), rebuilds the layout from the object and seed alone (no
images), and reports per true part: its enclosed volume on the grid (voxel centres inside its outer surface), the
share of those voxels the carving kept, and which of the export's parts they went to; then the carved voxels inside
no part (false solid). ``--profile PART`` also prints the kept share of that part along each of its local axes (ten
bins), which tells a face carved away from a seam misplaced. Needs only the export's files: a GPU run's export can be
copied back and read here.

The counts above judge each voxel by its centre and count it whole, but the volume that the mass uses is the export's
``fill``: each voxel's counted share (boundary voxels measured at the rendered surface, the unseen boundary at half;
:mod:`physgs_nerfstudio.geometry.partial`). ``--volume`` accounts for that volume against the truth voxel by voxel
(:func:`volume_account`): each voxel's true share of the parts from ``--subsamples``^3 points inside it; its fill up to
that share is the parts' (a boundary voxel half in a part and counted half is no error), the rest is *false fill*.
Per part, its fill against its true volume; the false fill with its fill-weighted heights and, with ``--relative-to
PART`` (e.g. ``top``), split into the space above that part's upper face, under its lower face (over its footprint)
and beside it.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from geometry_diag import _to_world

from physgs_nerfstudio.export.voxel import load_voxel_grid
from physgs_nerfstudio.synth.objects import build_layout


def voxel_centres_world(vx: dict, transform: np.ndarray, scale: float, shape: tuple[int, ...] | None = None
                        ) -> np.ndarray:  # fmt: skip
    """[X*Y*Z, 3] the world coordinates of every voxel centre of a loaded grid (:func:`load_voxel_grid`; ``shape``:
    its occupancy's by default), in C order, through nerfstudio's dataparser ``transform`` [3, 4] and ``scale``."""
    origin, h = np.asarray(vx["origin_scene"], float), float(vx["voxel_size_scene"])
    index = np.indices(shape if shape is not None else vx["occupancy"].shape).reshape(3, -1).T
    return _to_world(origin + (index + 0.5) * h, transform, scale)


def voxel_truth(vx: dict, transform: np.ndarray, scale: float, parts: list, profile: str | None = None) -> dict:
    """The comparison (module doc) of a loaded voxel grid (:func:`load_voxel_grid`) with the layout's ``parts``, the
    grid's scene coordinates mapped to the world by nerfstudio's dataparser ``transform`` [3, 4] and ``scale``."""
    occ = vx["occupancy"].astype(bool)
    pid = vx["part_id"]
    h = float(vx["voxel_size_scene"])
    mpu = float(vx["metres_per_unit"])
    world = voxel_centres_world(vx, transform, scale)
    cell = (h * mpu) ** 3
    flat_occ, flat_pid = occ.ravel(), pid.ravel()
    in_any = np.zeros(len(world), bool)
    rows = []
    for p in parts:
        local = p.to_local(world)
        enclosed = p.outer().contains(local)
        in_any |= enclosed
        kept = enclosed & flat_occ
        ids = flat_pid[kept]
        to = np.bincount(ids[ids >= 0], minlength=int(pid.max()) + 1)
        row = {"part": p.name, "material": p.material, "volume_model": p.volume_model,
               "enclosed_on_grid_m3": float(enclosed.sum() * cell), "enclosed_m3": float(p.enclosed_volume()),
               "kept_share": float(kept.sum() / max(int(enclosed.sum()), 1)),
               "to_export_parts": {int(i): int(c) for i, c in enumerate(to) if c}}  # fmt: skip
        if profile == p.name:
            prof = []
            for ax in range(3):
                edges = np.linspace(local[enclosed, ax].min(), local[enclosed, ax].max(), 11)
                a = np.histogram(local[kept, ax], edges)[0]
                b = np.histogram(local[enclosed, ax], edges)[0]
                prof.append([round(float(x), 3) for x in a / np.maximum(b, 1)])
            row["kept_share_along_local_axes"] = prof
        rows.append(row)
    false = flat_occ & ~in_any
    export_parts = vx["meta"].get("parts", [])
    false_by_part = {}
    for k in sorted(set(flat_pid[false].tolist())):
        m = false & (flat_pid == k)
        false_by_part[int(k)] = {"voxels": int(m.sum()),
                                 "world_z_m_5_50_95": [round(float(z), 4) for z in np.percentile(world[m, 2], [5, 50, 95])]}
    return {
        "voxel_size_m": h * mpu, "solid_m3": float(flat_occ.sum() * cell), "parts": rows,
        "false_solid_m3": float(false.sum() * cell), "false_share": float(false.sum() / max(int(flat_occ.sum()), 1)),
        "false_by_export_part": false_by_part,
        "export_parts": [{"voxels": int((pid == i).sum()), "p_hollow": q.get("p_hollow"), "thickness_m": q.get("thickness_m")}
                         for i, q in enumerate(export_parts)],
    }  # fmt: skip


def volume_account(vx: dict, fill: np.ndarray, transform: np.ndarray, scale: float, parts: list,
                   relative_to: str | None = None, subsamples: int = 4, chunk: int = 20000) -> dict:
    """The export's counted volume (``fill`` [X, Y, Z], scene voxels of a loaded grid, :func:`load_voxel_grid`)
    against ``parts`` (module doc, ``--volume``), in m^3: per part its true volume and the fill inside it; the false
    fill (in no part) in all and, with ``relative_to`` (a part's name), above, under and beside that part."""
    h = float(vx["voxel_size_scene"])
    mpu = float(vx["metres_per_unit"])
    cell = (h * mpu) ** 3
    origin = np.asarray(vx["origin_scene"], float)
    shape = fill.shape
    idx = np.indices(shape).reshape(3, -1).T
    world = voxel_centres_world(vx, transform, scale, shape)
    flat = fill.reshape(-1).astype(np.float64)
    # the voxels that hold fill or may hold a part: centre within a voxel's diagonal of a part's box
    reach = np.sqrt(3) * h * mpu
    near = flat > 0
    for p in parts:
        lo, hi = p.world_bounds()
        near |= np.all((world >= np.asarray(lo) - reach) & (world <= np.asarray(hi) + reach), axis=1)
    rows = np.nonzero(near)[0]
    t = (np.arange(subsamples) + 0.5) / subsamples - 0.5
    offsets = np.stack(np.meshgrid(t, t, t, indexing="ij"), -1).reshape(-1, 3)
    ref = next((p for p in parts if p.name == relative_to), None) if relative_to else None
    if relative_to and ref is None:
        raise ValueError(f"--relative-to {relative_to!r}: no such part ({', '.join(p.name for p in parts)})")
    share = np.zeros((len(rows), len(parts)))
    region = np.zeros((len(rows), 3))  # of the sub-points in no part: above, under, beside ``ref``
    for a in range(0, len(rows), chunk):
        r = rows[a:a + chunk]
        pts = _to_world((origin + (idx[r, None, :] + 0.5 + offsets[None]) * h).reshape(-1, 3), transform, scale)
        ins = np.stack([p.outer().contains(p.to_local(pts)) for p in parts], 1)
        share[a:a + chunk] = ins.reshape(len(r), len(offsets), len(parts)).mean(1)
        if ref is not None:
            free = ~ins.any(1)
            loc = ref.to_local(pts)
            half = ref.outer().half_extents()
            over = np.all(np.abs(loc[:, :2]) <= half[:2], axis=1)
            cls = np.stack([free & over & (loc[:, 2] > half[2]), free & over & (loc[:, 2] < -half[2]), free & ~over], 1)
            region[a:a + chunk] = cls.reshape(len(r), len(offsets), 3).mean(1)
    f = flat[rows]
    in_any = np.clip(share.sum(1), 0, 1)
    # a voxel's fill up to its true share is the parts' (split in proportion to their shares), the rest is false
    inside = np.minimum(f, in_any)
    per_part = share * (inside / np.maximum(share.sum(1), 1e-12))[:, None]
    w = f - inside
    out = {
        "fill_m3": float(flat.sum() * cell),
        "parts": [{"object": p.object, "part": p.name, "true_m3": float(p.enclosed_volume()),
                   "true_on_grid_m3": float(share[:, i].sum() * cell), "fill_in_part_m3": float(per_part[:, i].sum() * cell)}
                  for i, p in enumerate(parts)],
        "false_fill_m3": float(w.sum() * cell),
    }
    if w.sum() > 0:
        z = world[rows, 2]
        order = np.argsort(z)
        cum = np.cumsum(w[order]) / w.sum()
        out["false_fill_world_z_m_5_50_95"] = [round(float(z[order][min(np.searchsorted(cum, q), len(z) - 1)]), 4)
                                               for q in (0.05, 0.5, 0.95)]  # fmt: skip
    if ref is not None:
        spread = region / np.maximum(1 - in_any, 1e-12)[:, None]  # the false fill over the voxel's free space
        out["false_fill_relative_to"] = {"part": ref.name, **{k: float((w * spread[:, j]).sum() * cell)
                                         for j, k in enumerate(("above_m3", "under_m3", "beside_m3"))}}  # fmt: skip
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("export", type=Path, help="a `physgs export --outputs ... voxels` folder")
    ap.add_argument("--object", required=True, help="the generated object (layout) name")
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--transforms", type=Path, default=None,
                    help="the run's dataparser_transforms.json (default: EXPORT/dataparser_transforms.json)")
    ap.add_argument("--profile", default=None, help="a true part's name: its kept share along its local axes")
    ap.add_argument("--volume", action="store_true", help="account for the export's counted volume (fill) per voxel")
    ap.add_argument("--relative-to", default=None, help="with --volume: split the false fill about this true part")
    ap.add_argument("--subsamples", type=int, default=4, help="with --volume: points per voxel and axis")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    tf_path = a.transforms or a.export / "dataparser_transforms.json"
    if not tf_path.is_file():
        raise SystemExit(f"{tf_path}: no dataparser transform; pass --transforms RUN/dataparser_transforms.json")
    if not (a.export / "voxels.npz").is_file():
        raise SystemExit(f"{a.export}/voxels.npz not found: export with --outputs mass voxels")
    tf = json.loads(tf_path.read_text())
    parts = [p for p in build_layout(a.object, a.seed).parts if p.role != "ground"]
    res = {"object": a.object, "seed": a.seed,
           **voxel_truth(load_voxel_grid(a.export / "voxels.npz"), np.asarray(tf["transform"], float),
                         float(tf["scale"]), parts, a.profile)}  # fmt: skip
    if a.volume:
        grid = load_voxel_grid(a.export / "voxels.npz")
        if "fill" not in grid:
            raise SystemExit(f"{a.export}/voxels.npz has no fill (an export before session 38): --volume needs it")
        res["volume"] = volume_account(grid, np.asarray(grid["fill"]), np.asarray(tf["transform"], float),
                                       float(tf["scale"]), parts, a.relative_to, a.subsamples)  # fmt: skip
    if a.out:
        a.out.write_text(json.dumps(res, indent=1))
    print(f"{a.object} seed {a.seed}: voxel {1000 * res['voxel_size_m']:.2f} mm, solid {res['solid_m3'] * 1e6:.0f} cm^3, "
          f"false solid {100 * res['false_share']:.1f}%")  # fmt: skip
    for r in res["parts"]:
        print(f"  {r['part']:10s} {r['material']:15s} {r['volume_model']:5s} enclosed {r['enclosed_on_grid_m3'] * 1e6:9.1f} "
              f"cm^3  kept {r['kept_share']:.3f}  -> export parts (voxels) {r['to_export_parts']}")  # fmt: skip
        for ax, prof in enumerate(r.get("kept_share_along_local_axes", [])):
            print(f"    kept along local axis {ax}: {prof}")
    for i, q in enumerate(res["export_parts"]):
        print(f"  export part {i}: {q}")
    for k, f in res["false_by_export_part"].items():
        print(f"  false solid in export part {k}: {f['voxels']} voxels, world height 5/50/95%: {f['world_z_m_5_50_95']} m")
    if "volume" in res:
        v = res["volume"]
        print(f"  counted volume (fill) {v['fill_m3'] * 1e6:.0f} cm^3; false fill {v['false_fill_m3'] * 1e6:.0f} cm^3, "
              f"world height 5/50/95%: {v.get('false_fill_world_z_m_5_50_95')} m")  # fmt: skip
        for r in v["parts"]:
            print(f"    {r['object']:8s} {r['part']:10s} true {r['true_m3'] * 1e6:9.1f} cm^3 (on the grid "
                  f"{r['true_on_grid_m3'] * 1e6:9.1f})  fill inside {r['fill_in_part_m3'] * 1e6:9.1f}")  # fmt: skip
        if "false_fill_relative_to" in v:
            rr = v["false_fill_relative_to"]
            print(f"    false fill about {rr['part']}: above {rr['above_m3'] * 1e6:.0f}, under {rr['under_m3'] * 1e6:.0f}, "
                  f"beside {rr['beside_m3'] * 1e6:.0f} cm^3")  # fmt: skip


if __name__ == "__main__":
    main()
