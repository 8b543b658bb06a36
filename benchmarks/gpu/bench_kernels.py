"""GPU figures for the rendering-side pieces, measured side by side in one run on one CUDA device.

    python3 benchmarks/gpu/bench_kernels.py --out results.json

1. parity: the pure-torch reference rasterizer vs gsplat on the same Gaussians (max abs difference of
   colours, alphas, expected depth and of the gradients w.r.t. every input);
2. lifting: `lift_evidence` over all views (K material channels) vs one gsplat forward+backward of an RGB
   render per view, for 100k and 1M Gaussians (target: ratio <= 2).
Timings use CUDA events after warm-up; each figure is the median of repeats.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time

import torch

from physgs_nerfstudio.lifting import lift_evidence
from physgs_nerfstudio.render import rasterize


def random_gaussians(n: int, device: str, seed: int = 0, extent: float = 1.0):
    g = torch.Generator(device="cpu").manual_seed(seed)
    means = (torch.rand(n, 3, generator=g) - 0.5) * 2 * extent
    quats = torch.randn(n, 4, generator=g)
    # Mean spacing of n points in the cube, so neighbours overlap like a trained splat.
    spacing = 2 * extent / n ** (1 / 3)
    scales = spacing * torch.exp(0.3 * torch.randn(n, 3, generator=g)) * 0.6
    opacities = torch.rand(n, generator=g) * 0.9 + 0.05
    return [t.to(device) for t in (means, quats, scales, opacities)]


def orbit_cameras(v: int, width: int, height: int, device: str, radius: float = 3.0):
    viewmats, Ks = [], []
    f = 0.9 * width
    for i in range(v):
        theta = 2 * math.pi * i / v
        elev = 0.35 * math.sin(3 * theta)
        eye = torch.tensor([radius * math.cos(theta) * math.cos(elev), radius * math.sin(elev),
                            radius * math.sin(theta) * math.cos(elev)])
        fwd = -eye / eye.norm()
        right = torch.linalg.cross(fwd, torch.tensor([0.0, 1.0, 0.0]))
        right = right / right.norm()
        up = torch.linalg.cross(right, fwd)
        R = torch.stack([right, -up, fwd])  # OpenCV camera: x right, y down, z forward
        w2c = torch.eye(4)
        w2c[:3, :3] = R
        w2c[:3, 3] = -R @ eye
        viewmats.append(w2c)
        Ks.append(torch.tensor([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1.0]]))
    return torch.stack(viewmats).to(device), torch.stack(Ks).to(device)


def cuda_time(fn, repeats: int = 5, warmup: int = 2) -> float:
    for _ in range(warmup):
        fn()
    torch.cuda.synchronize()
    times = []
    for _ in range(repeats):
        start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
        start.record()
        fn()
        end.record()
        torch.cuda.synchronize()
        times.append(start.elapsed_time(end) / 1000.0)
    return statistics.median(times)


def parity(device: str, n: int = 3000, width: int = 96, height: int = 72) -> dict:
    """Reference vs gsplat on identical inputs: forward outputs and gradients."""
    means, quats, scales, opacities = random_gaussians(n, device, seed=1, extent=0.8)
    scales = scales * 2.0
    colors = torch.rand(n, 3, device=device)
    viewmats, Ks = orbit_cameras(2, width, height, device)
    out = {}
    results = {}
    for backend in ("reference", "gsplat"):
        leaves = [t.clone().requires_grad_(True) for t in (means, quats, scales, opacities, colors)]
        img, alpha, _ = rasterize(*leaves, viewmats, Ks, width, height, render_mode="RGB+ED",
                                  backend=backend)  # fmt: skip
        g = torch.Generator(device=device).manual_seed(3)
        w_img = torch.rand(img.shape, device=device, generator=g)
        w_alpha = torch.rand(alpha.shape, device=device, generator=g)
        (img * w_img).sum().add_((alpha * w_alpha).sum()).backward()
        results[backend] = dict(
            rgb=img[..., :3].detach(), depth=img[..., 3:].detach(), alpha=alpha.detach(),
            **{f"grad_{k}": leaf.grad.detach() for k, leaf in
               zip(("means", "quats", "scales", "opacities", "colors"), leaves)},
        )  # fmt: skip
    ref, gs = results["reference"], results["gsplat"]
    for key in ref:
        diff = (ref[key] - gs[key]).abs()
        scale = gs[key].abs().max().clamp_min(1e-12)
        out[key] = {"max_abs_diff": float(diff.max()), "max_abs_value": float(scale),
                    "mean_abs_diff": float(diff.mean())}  # fmt: skip
    out["setup"] = {"gaussians": n, "width": width, "height": height, "cameras": 2, "render_mode": "RGB+ED"}
    return out


def lifting(device: str, n: int, views: int, width: int, height: int, channels: int) -> dict:
    means, quats, scales, opacities = random_gaussians(n, device, seed=2)
    viewmats, Ks = orbit_cameras(views, width, height, device)
    g = torch.Generator(device=device).manual_seed(4)
    labels = torch.randint(0, channels, (views, height, width), device=device, generator=g)
    evidence = torch.nn.functional.one_hot(labels, channels).float()

    def lift():
        lift_evidence(means, quats, scales, opacities, viewmats, Ks, width, height, evidence)

    rgb = torch.rand(n, 3, device=device)

    def render_fwd_bwd():
        for v in range(views):
            leaves = [t.clone().requires_grad_(True) for t in (means, quats, scales, opacities, rgb)]
            img, _, _ = rasterize(*leaves, viewmats[v : v + 1], Ks[v : v + 1], width, height, backend="gsplat")
            img.sum().backward()

    t_lift = cuda_time(lift, repeats=3, warmup=1)
    t_render = cuda_time(render_fwd_bwd, repeats=3, warmup=1)
    return {"gaussians": n, "views": views, "width": width, "height": height, "channels": channels,
            "lift_all_views_s": t_lift, "rgb_fwd_bwd_all_views_s": t_render,
            "ratio": t_lift / t_render}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--width", type=int, default=800)
    ap.add_argument("--height", type=int, default=600)
    ap.add_argument("--channels", type=int, default=16)
    ap.add_argument("--sizes", type=int, nargs="+", default=[100_000, 1_000_000])
    args = ap.parse_args()
    assert torch.cuda.is_available(), "bench_kernels.py needs a CUDA device"
    results = {"device": torch.cuda.get_device_name(0), "torch": torch.__version__,
               "date": time.strftime("%Y-%m-%d %H:%M:%S %Z")}  # fmt: skip
    import gsplat

    results["gsplat"] = gsplat.__version__
    results["parity"] = parity("cuda")
    print(json.dumps(results["parity"], indent=1), flush=True)
    results["lifting"] = []
    for n in args.sizes:
        row = lifting("cuda", n, args.views, args.width, args.height, args.channels)
        print(row, flush=True)
        results["lifting"].append(row)
    with open(args.out, "w") as f:
        json.dump(results, f, indent=2)


if __name__ == "__main__":
    main()
