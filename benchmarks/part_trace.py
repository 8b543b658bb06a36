"""How the mass export splits an object's solid into parts, stage by stage, for a look against the truth.

    python benchmarks/part_trace.py --load-config RUN/config.yml --out DIR [-- EXPORT FLAGS...]
    python benchmarks/part_trace.py --read DIR --object shoe --seed 5353 --part sole

The first form runs ``physgs export --outputs mass voxels --no-geometry-cache`` into DIR/export with the geometry's
part steps (:mod:`physgs_nerfstudio.geometry.reconstruct`) wrapped, and writes DIR/part_trace.npz: the grid, the
union solid, the voxels whose own Gaussians give a material (the evidence of
:func:`physgs_nerfstudio.geometry.parts.voxel_mixture`), each solid voxel's dominant material, and the part grid
after the colour-by-material split (``part_labels``), after unobserved parts are absorbed and after touching parts
of one material merge. The second form reads that file on any machine and prints, per height bin of the true part
PART (the generator's exact shape), the share of its voxels at each stage by the part they end in, and the
dominant material of the evidence voxels on its surface: whether a seam is misplaced by the labels the views gave
the surface or by the steps that carry them inside.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def _record(out: Path) -> None:
    """Wrap the part steps of the reconstruction so that each saves its result into ``out``/part_trace.npz."""
    import torch

    import physgs_nerfstudio.geometry.reconstruct as R

    rec: dict[str, np.ndarray] = {}

    def save() -> None:
        np.savez_compressed(out / "part_trace.npz", **rec)

    vm, pl, au, mm = R.voxel_mixture, R.part_labels, R.absorb_unobserved, R.merge_same_material

    def voxel_mixture(grid, solid, means, opacities, pi, observed=None, *, min_evidence=0.5, up_weight=1.0):
        mix = vm(grid, solid, means, opacities, pi, observed, min_evidence=min_evidence, up_weight=up_weight)
        idx = grid.index_of(means.float())
        ok = ((idx >= 0) & (idx < torch.as_tensor(grid.shape, device=idx.device))).all(1)
        _, Y, Z = grid.shape
        flat = ((idx[:, 0] * Y + idx[:, 1]) * Z + idx[:, 2])[ok].cpu().numpy()
        conf = opacities.double().reshape(-1)
        if observed is not None:
            conf = conf * observed.double().reshape(-1).clamp(0.0, 1.0)
        occ, row = np.unique(flat, return_inverse=True)  # the occupied voxels, as voxel_mixture sums them
        strength = np.zeros(grid.num_voxels)
        strength[occ] = np.bincount(row, conf[ok].cpu().numpy(), minlength=len(occ))
        own = np.zeros((len(occ), pi.shape[1]))
        np.add.at(own, row, (conf[:, None] * pi.double())[ok].cpu().numpy())
        material = np.full(grid.num_voxels, -1, np.int16)
        material[occ] = np.argmax(own, -1)
        evidence = (strength >= min_evidence).reshape(grid.shape)
        rec.update(origin=np.asarray(grid.origin, float), voxel_size=np.float64(grid.voxel_size),
                   union=solid.astype(bool), evidence=evidence, up_weight=np.float64(up_weight),
                   dominant=np.where(solid, np.argmax(mix, -1), -1).astype(np.int16),
                   evidence_material=np.where(evidence, material.reshape(grid.shape), -1).astype(np.int16))
        save()
        return mix

    def part_labels(solid, mixture, min_part_fraction=2e-3):
        parts = pl(solid, mixture, min_part_fraction)
        rec["parts_split"] = parts.astype(np.int16)
        save()
        return parts

    def absorb_unobserved(parts, observed):
        merged = au(parts, observed)
        rec["parts_absorbed"] = merged.astype(np.int16)
        rec["observed_split"] = np.asarray(observed, bool)
        save()
        return merged

    def merge_same_material(parts, material):
        merged, old_to_new = mm(parts, material)
        rec["parts_merged"] = merged.astype(np.int16)
        rec["merge_material"] = np.asarray(material)
        save()
        return merged, old_to_new

    R.voxel_mixture, R.part_labels = voxel_mixture, part_labels
    R.absorb_unobserved, R.merge_same_material = absorb_unobserved, merge_same_material


def _read(a: argparse.Namespace) -> None:
    from geometry_diag import _to_world

    from physgs_nerfstudio.export.voxel import load_voxel_grid
    from physgs_nerfstudio.synth.objects import build_layout

    t = dict(np.load(a.read / "part_trace.npz"))
    vx = load_voxel_grid(a.read / "export" / "voxels.npz")
    tr = json.loads(a.transforms.read_text()) if a.transforms else json.loads(
        (a.read / "export" / "dataparser_transforms.json").read_text())  # fmt: skip
    T, s = np.asarray(tr["transform"], float), float(tr["scale"])
    legend = ", ".join(f"{m['index']} {m['name']}" for m in vx["meta"].get("legend", []))
    union = t["union"]
    shape = union.shape
    centres = t["origin"] + (np.indices(shape).reshape(3, -1).T + 0.5) * float(t["voxel_size"])
    world = _to_world(centres, T, s)
    part = {p.name: p for p in build_layout(a.object, a.seed).parts}[a.part]
    inside = part.outer().contains(part.to_local(world)).reshape(shape)
    z = world[:, 2].reshape(shape)
    sel = inside & union
    zs = z[sel]
    edges = np.quantile(zs, np.linspace(0, 1, a.bins + 1))
    print(f"{a.object} seed {a.seed}, part {a.part}: {int(inside.sum())} voxels inside, {int(sel.sum())} solid; "
          f"up weight {float(t['up_weight']):g}; materials {legend}")
    final = vx["part_id"]
    stages = [(k, t[k]) for k in ("parts_split", "parts_absorbed", "parts_merged") if k in t] + [("final", final)]
    shell = np.zeros(shape, bool)  # the part's solid voxels with an empty 6-neighbour: its surface
    pad = np.pad(union, 1)
    for ax in range(3):
        for d in (-1, 1):
            shell |= ~np.roll(pad, d, ax)[1:-1, 1:-1, 1:-1]
    shell &= sel
    for i in range(a.bins):
        m = sel & (z >= edges[i]) & (z <= edges[i + 1])
        row = [f"z {1000 * edges[i]:7.1f}..{1000 * edges[i + 1]:6.1f} mm n {int(m.sum()):6d}"]
        for name, g in stages:
            ids, cnt = np.unique(g[m], return_counts=True)
            row.append(name.removeprefix("parts_"))
            row.append(" ".join(f"{int(k)}:{c / m.sum():.2f}" for k, c in zip(ids, cnt)))
        dom, cnt = np.unique(t["dominant"][m], return_counts=True)
        row.append("dominant " + " ".join(f"{int(k)}:{c / m.sum():.2f}" for k, c in zip(dom, cnt)))
        e = m & t["evidence"]
        em, ec = np.unique(t["evidence_material"][e], return_counts=True)
        row.append(f"evidence n {int(e.sum())} " + " ".join(f"{int(k)}:{c / max(1, e.sum()):.2f}" for k, c in zip(em, ec)))
        sh = m & shell
        row.append(f"surface n {int(sh.sum())} evid {float((sh & t['evidence']).sum()) / max(1, sh.sum()):.2f}")
        print(" | ".join(row))
    # where the evidence lies around the part: a band of voxels around it (the part's own surface may hold none)
    near = np.zeros(shape, bool)
    from scipy import ndimage

    near = ndimage.binary_dilation(inside, iterations=2) & ~ndimage.binary_erosion(inside, iterations=2)
    e = near & t["evidence"]
    print("evidence within 2 voxels of its surface, by height bin and dominant material:")
    for i in range(a.bins):
        m = e & (z >= edges[i]) & (z <= edges[i + 1])
        em, ec = np.unique(t["evidence_material"][m], return_counts=True)
        print(f"  z {1000 * edges[i]:7.1f}..{1000 * edges[i + 1]:6.1f} mm n {int(m.sum()):5d} "
              + " ".join(f"{int(k)}:{c / max(1, m.sum()):.2f}" for k, c in zip(em, ec)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--load-config", type=Path)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--read", type=Path)
    ap.add_argument("--object")
    ap.add_argument("--seed", type=int)
    ap.add_argument("--part")
    ap.add_argument("--bins", type=int, default=10)
    ap.add_argument("--transforms", type=Path)
    a, rest = ap.parse_known_args()
    if a.read:
        _read(a)
        return
    if a.load_config is None or a.out is None:
        ap.error("--load-config and --out (or --read)")
    a.out.mkdir(parents=True, exist_ok=True)
    _record(a.out)
    from physgs_nerfstudio.cli import main as cli

    rest = [r for r in rest if r != "--"]
    sys.argv = ["physgs", "export", "--load-config", str(a.load_config), "--output-dir", str(a.out / "export"),
                "--outputs", "mass", "voxels", "--overwrite", "--no-geometry-cache", *rest]
    cli()


if __name__ == "__main__":
    main()
