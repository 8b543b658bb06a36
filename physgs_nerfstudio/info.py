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

    def main(self) -> None:
        import torch

        from physgs_nerfstudio import __version__

        rows = [("physgs-nerfstudio", __version__)]
        rows += [(d, _version(d)) for d in ("torch", "nerfstudio", "gsplat", "tyro", "segment-anything")]
        cuda = torch.cuda.is_available()
        rows.append(("CUDA available", str(cuda)))
        rows.append(("rasterizer", "gsplat (CUDA)" if cuda else "reference (pure torch, CPU)"))
        try:
            materials = importlib.import_module("physgs_nerfstudio.materials")
            for env in ("indoor", "outdoor"):
                rows.append((f"{env} library", f"{len(materials.load_library(env).materials)} materials"))
        except ImportError as err:  # pragma: no cover - only while the package is incomplete
            rows.append(("material libraries", f"unavailable ({err})"))
        width = max(len(k) for k, _ in rows)
        for key, value in rows:
            print(f"{key:<{width}}  {value}")


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
