"""Time mass integration (solid and shell) for 100k and 1M random Gaussians, on CPU and, if present, CUDA.

    OMP_NUM_THREADS=2 python benchmarks/mass_integration.py [--sizes 100000 1000000] [--resolution 128]

Prints one row per (device, N, volume model): wall time of the opacity field + material mixture + surface +
Monte Carlo, and the number of (Gaussian, voxel) pairs evaluated.
"""

from __future__ import annotations

import argparse
import time

import torch

from physgs_nerfstudio.export.field import PropertyField
from physgs_nerfstudio.export.grid import gaussian_boxes, inverse_covariance6
from physgs_nerfstudio.export.mass import MassConfig, integrate_mass
from physgs_nerfstudio.export.occupancy import OccupancyConfig, compute_occupancy
from physgs_nerfstudio.export.shapes import KEYS, LOG_SPACE, material_nig, random_cloud


def make_field(n: int, device: str) -> PropertyField:
    means, scales, quats, opac, alpha = random_cloud(n, seed=0, k=4)
    scales = 0.5 * scales  # about one Gaussian per (2 sigma)^3: neighbours overlap, like a trained splat
    return PropertyField(
        means=means, quats=quats, scales=scales, opacities=opac, alpha=alpha,
        nig=material_nig([500.0, 1000.0, 2500.0, 7800.0], kappa=20, a=10, rel_sd=0.1),
        material_names=["a", "b", "c", "d"], material_colors=[(0, 0, 0)] * 4, log_space=LOG_SPACE,
        thickness_m=[0.004, 0.01, 0.003, 0.002], property_keys=KEYS,
    ).to(device)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[100_000, 1_000_000])
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--n-samples", type=int, default=4000)
    args = ap.parse_args()
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    print(f"threads={torch.get_num_threads()} resolution={args.resolution} n_samples={args.n_samples}")
    print(f"{'device':6} {'N':>9} {'model':6} {'pairs':>12} {'field s':>8} {'total s':>8} {'mass kg':>10}")
    for dev in devices:
        for n in args.sizes:
            pf = make_field(n, dev)
            occ_cfg = OccupancyConfig(resolution=args.resolution, progress=False)
            # pairs in the opacity pass (domain from a first occupancy run)
            if dev == "cuda":
                torch.cuda.synchronize()
            t0 = time.perf_counter()
            occ = compute_occupancy(pf, occ_cfg)
            if dev == "cuda":
                torch.cuda.synchronize()
            t_field = time.perf_counter() - t0
            _, cov = inverse_covariance6(pf.quats, pf.scales, occ.filter_sigma)
            pairs = int(gaussian_boxes(occ.grid, pf.means, cov, occ_cfg.cutoff_sigma)[2].sum())
            for model in ("solid", "shell"):
                cfg = MassConfig(occupancy=occ_cfg, volume_model=model, n_samples=args.n_samples)
                t0 = time.perf_counter()
                rep = integrate_mass(pf, cfg)
                if dev == "cuda":
                    torch.cuda.synchronize()
                dt = time.perf_counter() - t0
                print(f"{dev:6} {n:>9} {model:6} {pairs:>12} {t_field:>8.2f} {dt:>8.2f} {rep.mean_kg:>10.4g}",
                      flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
