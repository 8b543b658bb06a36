"""Timing of the pure-torch reference rasterizer on this CPU.

Prints one table of forward and forward+backward times (median of a few runs) for 64x64 and 128x128 images with
1k, 5k and 20k random Gaussians in front of the camera, each covering a few to tens of pixels; or, with
``--checkpoint``, for a trained splat's Gaussians (a nerfstudio checkpoint, such as `physgs demo`'s) seen by
8 cameras around them in one call (trained splats have larger, overlapping, semi-transparent Gaussians than
the random scene, and the compositing does more of the work). Writes the rows to one summary JSON (``--out``).

    python benchmarks/reference_rasterizer.py [--repeats 5] [--sizes 64 128] [--counts 1000 5000 20000]
    python benchmarks/reference_rasterizer.py --checkpoint demo_output/runs/demo/physgs-lite/demo/\
nerfstudio_models/step-000000299.ckpt --sizes 96
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import format_table, write_summary

from physgs_nerfstudio.render import reference_rasterization


def random_scene(n: int, size: int, seed: int = 0) -> dict[str, torch.Tensor]:
    """Gaussians in a frustum 2..4 m in front of an identity camera with a 60 degree field of view."""
    g = torch.Generator().manual_seed(seed)
    focal = 0.5 * size / torch.tan(torch.tensor(torch.pi / 6)).item()
    z = 2.0 + 2.0 * torch.rand(n, generator=g)
    xy = (torch.rand(n, 2, generator=g) - 0.5) * 2 * (0.5 * size / focal) * z[:, None]
    means = torch.cat([xy, z[:, None]], 1)
    # pixel footprint sigma ~ 0.5..3 px at the image scale -> 3-sigma radius of 2..9 px
    sigma_px = 0.5 + 2.5 * torch.rand(n, 3, generator=g)
    scales = sigma_px * z[:, None] / focal
    quats = torch.randn(n, 4, generator=g)
    opacities = 0.1 + 0.8 * torch.rand(n, generator=g)
    colors = torch.rand(n, 3, generator=g)
    viewmats = torch.eye(4)[None]
    Ks = torch.tensor([[focal, 0, size / 2], [0, focal, size / 2], [0, 0, 1.0]])[None]
    return {"means": means, "quats": quats, "scales": scales, "opacities": opacities, "colors": colors,
                "viewmats": viewmats, "Ks": Ks}  # fmt: skip


def checkpoint_scene(path: str, size: int, views: int = 8) -> dict[str, torch.Tensor]:
    """A trained splat's Gaussians (activated) and `views` cameras on a ring 30 degrees above them, at 2.5
    times the radius holding 90% of the Gaussians, with a 50 degree field of view."""
    state = torch.load(path, map_location="cpu", weights_only=False)["pipeline"]
    g = {k.rsplit(".", 1)[-1]: v.float() for k, v in state.items() if ".gauss_params." in k}
    means = g["means"]
    centre = means.median(0).values
    dist = 2.5 * float((means - centre).norm(dim=-1).quantile(0.9))
    viewmats = []
    for i in range(views):
        th, el = 2 * math.pi * i / views, math.radians(30)
        eye = centre + dist * torch.tensor(
            [math.cos(th) * math.cos(el), math.sin(th) * math.cos(el), math.sin(el)]
        )
        fwd = (centre - eye) / (centre - eye).norm()
        right = torch.linalg.cross(fwd, torch.tensor([0.0, 0.0, 1.0]))
        right = right / right.norm()
        rot = torch.stack([right, torch.linalg.cross(fwd, right), fwd])  # OpenCV: x right, y down, z forward
        vm = torch.eye(4)
        vm[:3, :3], vm[:3, 3] = rot, -rot @ eye
        viewmats.append(vm)
    focal = 0.5 * size / math.tan(math.radians(25))
    K = torch.tensor([[focal, 0, size / 2], [0, focal, size / 2], [0, 0, 1.0]])
    return {"means": means, "quats": g["quats"], "scales": g["scales"].exp(),
            "opacities": torch.sigmoid(g["opacities"][:, 0]),
            "colors": torch.cat([g["features_dc"][:, None], g["features_rest"]], 1),
            "viewmats": torch.stack(viewmats), "Ks": K[None].expand(views, 3, 3).contiguous()}  # fmt: skip


def _sh_degree(scene: dict[str, torch.Tensor]) -> int | None:
    return None if scene["colors"].dim() == 2 else math.isqrt(scene["colors"].shape[1]) - 1


def time_once(scene: dict[str, torch.Tensor], size: int, backward: bool) -> tuple[float, float]:
    """(wall, process CPU) seconds of one render (and backward)."""
    params = {k: v.clone().requires_grad_(backward and k not in ("viewmats", "Ks")) for k, v in scene.items()}
    t0, c0 = time.perf_counter(), time.process_time()
    with torch.set_grad_enabled(backward):
        img, alpha, meta = reference_rasterization(
            **params, width=size, height=size, packed=False, sh_degree=_sh_degree(scene)
        )
        if backward:
            meta["means2d"].retain_grad()
            (img.sum() + alpha.sum()).backward()
    return time.perf_counter() - t0, time.process_time() - c0


def median_times(
    scene: dict[str, torch.Tensor], size: int, backward: bool, repeats: int
) -> tuple[float, float]:
    runs = [time_once(scene, size, backward) for _ in range(repeats)]
    return statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 128])
    parser.add_argument("--counts", type=int, nargs="+", default=[1000, 5000, 20000])
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's choice)")
    parser.add_argument(
        "--checkpoint",
        default=None,
        help="a nerfstudio checkpoint: its Gaussians from 8 cameras, not --counts",
    )
    parser.add_argument("--out", type=Path, default=Path("reference_rasterizer.json"), help="the summary JSON")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    rows = []
    for size in args.sizes:
        for n in [None] if args.checkpoint else args.counts:
            scene = checkpoint_scene(args.checkpoint, size) if n is None else random_scene(n, size)
            with torch.no_grad():
                _, _, meta = reference_rasterization(
                    **scene, width=size, height=size, packed=False, sh_degree=_sh_degree(scene)
                )
            time_once(scene, size, True)  # warm-up
            fwd = median_times(scene, size, False, args.repeats)
            both = median_times(scene, size, True, args.repeats)
            rows.append({"image": size, "gaussians": len(scene["means"]),
                         "visible": int((meta["radii"] > 0).sum()),  # summed over the cameras
                         "forward_wall_s": fwd[0], "forward_cpu_s": fwd[1],
                         "forward_backward_wall_s": both[0], "forward_backward_cpu_s": both[1]})  # fmt: skip
    write_summary(args.out, {"torch": torch.__version__, "threads": torch.get_num_threads(),
                             "repeats": args.repeats, "checkpoint": args.checkpoint, "rows": rows})  # fmt: skip
    print(f"torch {torch.__version__}, threads {torch.get_num_threads()}; wall and process-CPU seconds, median")
    print(format_table(
        ("image", "gaussians", "visible", "fwd wall", "fwd cpu", "f+b wall", "f+b cpu"),
        [(f"{r['image']}x{r['image']}", r["gaussians"], r["visible"], r["forward_wall_s"], r["forward_cpu_s"],
          r["forward_backward_wall_s"], r["forward_backward_cpu_s"]) for r in rows],
    ))  # fmt: skip

if __name__ == "__main__":
    main()
