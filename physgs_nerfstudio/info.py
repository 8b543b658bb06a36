"""`physgs info`: what this installation can do (versions, rasterizer backends, libraries)."""

from __future__ import annotations

import importlib
import importlib.metadata as md
from dataclasses import dataclass


def _version(dist: str) -> str:
    try:
        return md.version(dist)
    except md.PackageNotFoundError:
        return "not installed"


@dataclass
class InfoCommand:
    """Print versions, the rasterizer backend that will be used, and the material libraries."""

    build_gsplat: bool = False
    """Compile gsplat's CUDA code now, once after installing gsplat, so that no training or export pays for it."""

    def main(self) -> None:
        import torch

        from physgs_nerfstudio import __version__

        rows = [("physgs-nerfstudio", __version__)]
        rows += [(d, _version(d)) for d in ("torch", "nerfstudio", "gsplat", "tyro", "segment-anything")]
        cuda = torch.cuda.is_available()
        rows.append(("CUDA available", str(cuda)))
        rows.append(("rasterizer", "gsplat (CUDA)" if cuda else "reference (pure torch, CPU)"))
        if cuda:
            rows.append(("gsplat CUDA build", self._gsplat_build()))
        try:
            materials = importlib.import_module("physgs_nerfstudio.materials")
            for env in ("indoor", "outdoor"):
                rows.append((f"{env} library", f"{len(materials.load_library(env).materials)} materials"))
        except ImportError as err:  # pragma: no cover - only while the package is incomplete
            rows.append(("material libraries", f"unavailable ({err})"))
        width = max(len(k) for k, _ in rows)
        for key, value in rows:
            print(f"{key:<{width}}  {value}")


    def _gsplat_build(self) -> str:
        from physgs_nerfstudio.render.gsplat_build import build_status

        status, reason = build_status()
        if not self.build_gsplat or status in ("precompiled", "unavailable"):
            return f"{status}: {reason}"
        import time

        import torch

        from physgs_nerfstudio.render import rasterize

        t0 = time.perf_counter()
        d = torch.device("cuda")
        one = torch.ones(1, device=d)
        rasterize(torch.tensor([[0.0, 0.0, 2.0]], device=d), torch.tensor([[1.0, 0, 0, 0]], device=d),
                  0.1 * torch.ones(1, 3, device=d), 0.5 * one, one[:, None].expand(1, 3).contiguous(),
                  torch.eye(4, device=d)[None], torch.tensor([[[8.0, 0, 4], [0, 8, 4], [0, 0, 1]]], device=d), 8, 8)
        torch.cuda.synchronize()
        status, reason = build_status()
        return f"{status} after {time.perf_counter() - t0:.0f} s: {reason}"


@dataclass
class MaterialsCommand:
    """List a material library with the typical value and range of every property."""

    env: str = "indoor"
    """Library to list: "indoor", "outdoor", or a path to a YAML file of your own."""
    extra_files: tuple[str, ...] = ()
    """Extra YAML files merged into the library (same schema as the shipped ones)."""

    def main(self) -> None:
        from pathlib import Path

        from rich.console import Console
        from rich.table import Table

        from physgs_nerfstudio.materials import PROPERTY_KEYS, load_library

        library = load_library(self.env, extra_files=[Path(f) for f in self.extra_files])
        table = Table(title=f"{library.env} material library ({len(library.materials)} materials)")
        table.add_column("name")
        for key in PROPERTY_KEYS:
            table.add_column(f"{key} typical [low, high]")
        for material in library.materials:
            cells = [material.name]
            for key in PROPERTY_KEYS:
                r = material.properties[key]
                cells.append(f"{r.typical:.4g} [{r.low:.3g}, {r.high:.3g}]")
            table.add_row(*cells)
        Console().print(table)
