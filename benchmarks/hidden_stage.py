"""The hidden-space stage of a trained run's geometry, kept for a look on any machine (issue 12).

    python benchmarks/hidden_stage.py --run DIR --out STAGE.npz [--resolution R]
    python benchmarks/hidden_stage.py --read STAGE.npz --object indoor_room --seed S [--views 60] [--emulate-seen]

The first form (on the machine that trained DIR, a folder whose runs/ holds its config.yml) runs the object's
geometry with the export's defaults (:func:`physgs_nerfstudio.export.run.object_geometry`) and saves what goes into
the hidden open space rule (:mod:`physgs_nerfstudio.geometry.hidden`): every carving variant's solid before and after
the rule, the space the polytope cut and the space below the support plane (the rays' enclosing space), the surface
Gaussians that sample the skin (means, scales, quaternions), the grid and nerfstudio's dataparser transform. A GPU
run's stage is a few hundred kB.

The second form rebuilds the generated layout from the object and seed alone and prints the nominal solid before and
after the rule against the truth (for `indoor_room`, its table): the carved volume over the true enclosed volume,
the false solid (in no part) and, for a table, where it lies (over the top, under it, elsewhere) and how much of it
is skin. With ``--emulate-seen`` it also runs the rule again with the axis ends of the skin's samples kept only where
a camera of the generated capture (``--views`` cameras, the synthesiser's orbit) sees them, judged from the nominal
solid itself: a sample is seen by a camera when the segment towards the camera's eye meets no solid voxel farther
from the sample than a voxel plus its Gaussian's smallest standard deviation. That is an estimate of
``GeometryConfig.hidden_skin_seen`` for a run whose views and renders are not at hand: the solid holds the hidden
space that the Gaussians' render does not, so it hides more than the rule's own test (the CPU demo room at seed
12626: 0.97x by the estimate, 1.07x by the rule itself).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def record(run_dir: Path, out: Path, resolution: int) -> None:
    """Run the geometry of ``run_dir`` and save its hidden-space stage into ``out`` (module doc)."""
    from geometry_diag import load_run_on_device

    import physgs_nerfstudio.geometry.reconstruct as R
    from physgs_nerfstudio.export.run import object_geometry

    store: dict[str, np.ndarray] = {}
    rule = R._without_hidden

    def wrapped(grid, solids, surface, beyond, plane, cfg, *args):  # type: ignore[no-untyped-def]
        store.update(
            origin=np.asarray(grid.origin, float), voxel=np.float64(grid.voxel_size), shape=np.asarray(grid.shape),
            solids=np.packbits(np.stack(solids), axis=-1),
            beyond=np.packbits(beyond if beyond is not None else np.zeros(grid.shape, bool), axis=-1),
            below=np.packbits(~plane.above_voxels(grid) if plane is not None else np.zeros(grid.shape, bool), axis=-1),
            s_means=surface.means.float().cpu().numpy(), s_scales=surface.scales.float().cpu().numpy(),
            s_quats=surface.quats.float().cpu().numpy(),
        )  # fmt: skip
        kept = rule(grid, solids, surface, beyond, plane, cfg, *args)
        store["after"] = np.packbits(np.stack(kept[0]), axis=-1)
        return kept

    R._without_hidden = wrapped
    cfg_path = next((run_dir / "runs").glob("**/config.yml"), None)
    if cfg_path is None:
        raise SystemExit(f"no trained run under {run_dir}/runs")
    run = load_run_on_device(cfg_path)
    geo = object_geometry(run, R.GeometryConfig(resolution=resolution))
    if "solids" not in store:
        raise SystemExit("the geometry ran no hidden-space rule (hidden_skin_voxels is None)")
    store.update(mpu=np.float64(run.field.metres_per_unit), variant_names=np.array(geo.variant_names),
                 transforms=np.array((cfg_path.parent / "dataparser_transforms.json").read_text()))  # fmt: skip
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out, **store)
    print(f"{out}: grid {tuple(store['shape'])}, {len(store['s_means'])} surface Gaussians, "
          f"{int(geo.solid.sum())} solid voxels after the rule")  # fmt: skip


def load(path: Path) -> dict:
    d = dict(np.load(path))
    shape = tuple(int(x) for x in d["shape"])
    for k in ("solids", "after", "beyond", "below"):
        d[k] = np.unpackbits(d[k], axis=-1)[..., : shape[-1]].astype(bool)
    t = json.loads(str(d["transforms"]))
    d["T"], d["s"], d["shape"] = np.asarray(t["transform"], float), float(t["scale"]), shape
    return d


def _eyes(obj: str, seed: int, views: int, d: dict) -> np.ndarray:
    """The generated capture's camera centres (the synthesiser's defaults: 50 degree field of view, 0.85 fill) in the
    run's scene coordinates."""
    from physgs_nerfstudio.synth.objects import build_layout
    from physgs_nerfstudio.synth.render import orbit_poses

    layout = build_layout(obj, seed)
    radius = layout.radius / (math.sin(math.radians(50.0) / 2) * 0.85)
    az0 = float(np.random.default_rng([seed, 17]).uniform(0, 360))
    e = orbit_poses(views, layout.center, radius, layout.elevation_deg, az0)[:, :3, 3]
    return d["s"] * (e @ d["T"][:3, :3].T + d["T"][:3, 3])


def _seen_by_solid(d: dict, points: np.ndarray, thick: np.ndarray, eyes: np.ndarray) -> np.ndarray:
    """bool [N]: a camera sees the point past the nominal solid (module doc's estimate), in half-voxel steps."""
    solid, h = d["solids"][0], float(d["voxel"])
    shape = np.array(solid.shape)
    p = (points - d["origin"]) / h
    start = 1.0 + thick / h
    seen = np.zeros(len(p), bool)
    for eye in eyes:
        v = (eye - d["origin"]) / h - p
        length = np.linalg.norm(v, axis=1)
        u = v / length[:, None]
        hit = np.zeros(len(p), bool)
        for t in np.arange(0.5, 2.0 * float(shape.max()), 0.5):
            ij = np.floor(p + u * t).astype(int)
            inside = np.all((ij >= 0) & (ij < shape), axis=1)
            if not inside.any():
                break
            idx = np.nonzero(inside & (t > start) & (t < length))[0]
            hit[idx] |= solid[ij[idx, 0], ij[idx, 1], ij[idx, 2]]
        seen |= ~hit
    return seen


def read(path: Path, obj: str, seed: int, views: int, emulate_seen: bool) -> dict:
    import torch
    from geometry_diag import _to_world

    from physgs_nerfstudio.geometry.hidden import gaussian_samples, skin_centred, without_hidden_space
    from physgs_nerfstudio.geometry.reconstruct import GeometryConfig
    from physgs_nerfstudio.synth.objects import build_layout

    d = load(path)
    shape, h = d["shape"], float(d["voxel"])
    world = _to_world(d["origin"] + (np.indices(shape).reshape(3, -1).T + 0.5) * h, d["T"], d["s"])
    parts = list(build_layout(obj, seed).parts)
    if obj == "indoor_room":
        parts = [p for p in parts if p.object == "table"]
    inside = [p.outer().contains(p.to_local(world)) for p in parts]
    any_part = np.logical_or.reduce(inside)
    true_m3 = sum(p.enclosed_volume() for p in parts)
    cell = (h * float(d["mpu"])) ** 3
    top = next((p for p in parts if p.name == "top"), None)
    cfg = GeometryConfig()
    closed = torch.from_numpy(d["beyond"] | d["below"])

    def summary(solid: np.ndarray, skin: np.ndarray | None) -> dict:
        s = solid.ravel()
        false = s & ~any_part
        row = {
            "volume_ratio": float(s.sum() * cell / true_m3),
            "false_solid_m3": float(false.sum() * cell),
            "kept_share": {
                p.name: float((s & e).sum() / max(int(e.sum()), 1)) for p, e in zip(parts, inside)
            },
        }
        if top is not None:
            loc = top.to_local(world)
            half = np.asarray(top.outer().size) / 2
            over_fp = np.all(np.abs(loc[:, :2]) <= half[:2], axis=1)
            row["false_over_top_m3"] = float((false & over_fp & (loc[:, 2] > 0)).sum() * cell)
            row["false_under_top_m3"] = float((false & over_fp & (loc[:, 2] < 0)).sum() * cell)
            if skin is not None:
                row["false_under_top_skin_m3"] = float(
                    (false & over_fp & (loc[:, 2] < 0) & skin.ravel()).sum() * cell
                )
        return row  # fmt: skip

    m, sc, q = (torch.from_numpy(d[k]).double() for k in ("s_means", "s_scales", "s_quats"))
    samples = gaussian_samples(m, sc, q, cfg.hidden_skin_sigmas)
    n = len(m)

    def rule(samples: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
        skin = skin_centred(
            samples, d["origin"], h, shape, cfg.hidden_skin_voxels or 0, cfg.hidden_skin_tolerance
        )
        kept = without_hidden_space(torch.from_numpy(d["solids"][0]), skin, closed, cfg.hidden_min_open_fraction,
                                    cfg.hidden_min_open_half, cfg.hidden_passes)[0]  # fmt: skip
        return kept.numpy(), skin.numpy()

    every, skin = rule(samples)
    out = {"stage": str(path), "object": obj, "seed": seed, "voxel_m": h * float(d["mpu"]), "true_m3": true_m3,
           "before_rule": summary(d["solids"][0], None), "after_rule": summary(d["after"][0], None),
           "every_axis_end": summary(every, skin)}  # fmt: skip
    if emulate_seen and len(samples) > n:
        thick = np.repeat(d["s_scales"].min(1) * cfg.hidden_skin_sigmas, 6)
        keep = _seen_by_solid(d, samples[n:].numpy(), thick, _eyes(obj, seed, views, d))
        kept, skin = rule(torch.cat([samples[:n], samples[n:][torch.from_numpy(keep)]]))
        out["seen_axis_ends_estimate"] = {**summary(kept, skin), "axis_ends_dropped": int((~keep).sum()),
                                          "axis_ends": len(keep)}  # fmt: skip
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--run", type=Path, default=None, help="record this trained run's stage (a folder with runs/)"
    )
    ap.add_argument(
        "--out", type=Path, default=None, help="--run: the .npz to write; --read: a JSON to write"
    )
    ap.add_argument(
        "--resolution", type=int, default=128, help="--run: the geometry's grid (the export's default)"
    )
    ap.add_argument(
        "--read", type=Path, default=None, help="a recorded stage (.npz) to compare with the truth"
    )
    ap.add_argument("--object", default="indoor_room")
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("--views", type=int, default=60, help="--emulate-seen: the capture's camera count")
    ap.add_argument("--emulate-seen", action="store_true", help="estimate hidden_skin_seen (module doc)")
    a = ap.parse_args()
    if (a.run is None) == (a.read is None):
        raise SystemExit("give --run RUN --out STAGE.npz, or --read STAGE.npz --object O --seed S")
    if a.run is not None:
        if a.out is None:
            raise SystemExit("--run needs --out STAGE.npz")
        record(a.run, a.out, a.resolution)
        return
    if a.seed is None:
        raise SystemExit("--read needs --seed (the generated scene's)")
    res = read(a.read, a.object, a.seed, a.views, a.emulate_seen)
    text = json.dumps(res, indent=1)
    print(text)
    if a.out is not None:
        a.out.write_text(text)


if __name__ == "__main__":
    main()
