"""MPM particles: ``particles.npz`` (one particle per voxel that carries mass) and ``mpm_config.json`` in the
shape of PhysGaussian's scene configs.

Each particle is a voxel of the export's grid with mass: its volume ``fill x voxel^3`` (a whole voxel where the
volume counts it at 0 but a wall's face bounds it), its mass the share of the
body's part masses that lies on it (:func:`.body.element_masses`: a solid part's voxels, a hollow part's wall
faces, whose mass goes to the voxel they bound), its density mass / volume (a wall thinner than a voxel is
smeared over its voxels: the density is the wall's mass over the voxel's volume). The particles' total mass is
the body's (the report's mean). Young's modulus: the voxel's material mixture of the fused per-material means.
Poisson's ratio: the material library has none; :data:`POISSON_BY_CATEGORY` gives a handbook value per library
category (isotropic; wood is orthotropic and gets a representative 0.35), the voxel's mixture of those.
Positions in the object frame, metres.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

__all__ = ["POISSON_BY_CATEGORY", "poisson_ratio", "write_mpm"]

POISSON_BY_CATEGORY = {"wood": 0.35, "metal": 0.30, "plastic": 0.38, "rubber": 0.49, "foam": 0.25, "glass": 0.22,
                       "ceramic": 0.22, "stone": 0.25, "paper": 0.30, "fabric": 0.30, "flooring": 0.35,
                       "pavement": 0.25, "terrain": 0.30}  # fmt: skip
"""typical isotropic Poisson's ratios (Engineering ToolBox / MatWeb handbook values) per library category"""
DEFAULT_POISSON = 0.30


def poisson_ratio(name: str) -> tuple[float, str]:
    """(Poisson's ratio, where it comes from) for a library material ``name``."""
    from ..materials.library import load_library

    for env in ("indoor", "outdoor"):
        lib = load_library(env)
        mat = next((m for m in lib.materials if m.name == name), None)
        if mat is not None and mat.category in POISSON_BY_CATEGORY:
            return POISSON_BY_CATEGORY[mat.category], f"category {mat.category} (physgs_nerfstudio.sim.mpm)"
    return DEFAULT_POISSON, "default (no category value)"


def write_mpm(folder: Path, position_m: np.ndarray, volume_m3: np.ndarray, mass_kg: np.ndarray,
              youngs_pa: np.ndarray, poisson: np.ndarray, material: np.ndarray, names: list[str],
              nu_source: dict[str, str], model: str = "jelly") -> list[Path]:  # fmt: skip
    """``particles.npz`` and ``mpm_config.json`` (module doc); ``material``: each particle's dominant material;
    ``model``: PhysGaussian's constitutive model ("metal" for a mostly metal object, else "jelly": elastic)."""
    folder = Path(folder)
    density = mass_kg / volume_m3
    np.savez_compressed(folder / "particles.npz", position_m=position_m.astype(np.float32),
                        volume_m3=volume_m3.astype(np.float64), mass_kg=mass_kg.astype(np.float64),
                        density_kg_m3=density.astype(np.float32), youngs_modulus_pa=youngs_pa.astype(np.float32),
                        poisson_ratio=poisson.astype(np.float32), material_index=material.astype(np.int16),
                        material_names=np.array(names))  # fmt: skip
    M = float(mass_kg.sum())
    E = float(np.exp((mass_kg * np.log(youngs_pa)).sum() / M))
    nu = float((mass_kg * poisson).sum() / M)
    lo, hi = position_m.min(0), position_m.max(0)
    pad = 0.5 * float((hi - lo).max())
    config = {
        "material": model, "E": E, "nu": nu, "density": M / float(volume_m3.sum()),
        "g": [0.0, 0.0, -9.81], "substep_dt": 1e-4, "frame_dt": 4e-2, "frame_num": 50, "n_grid": 100,
        "grid_v_damping_scale": 0.9999, "rpic_damping": 0.0,
        "sim_area": [float(lo[0] - pad), float(hi[0] + pad), float(lo[1] - pad), float(hi[1] + pad), 0.0,
                     float(hi[2] + pad)],
        "mpm_space_vertical_upward_axis": [0, 0, 1],
        "boundary_conditions": [{"type": "surface_collider", "point": [0.0, 0.0, 0.0], "normal": [0.0, 0.0, 1.0],
                                 "surface": "slip", "friction": 0.0, "start_time": 0.0, "end_time": 1e3}],
        "physgs": {"particles": "particles.npz", "units": {"position_m": "m", "volume_m3": "m^3", "mass_kg": "kg",
                                                          "density_kg_m3": "kg/m^3", "youngs_modulus_pa": "Pa"},
                   "scalar_values": "E: mass-weighted geometric mean, nu and density: mass-weighted means of the "
                                    "per-particle values in particles.npz",
                   "poisson_source": nu_source, "total_mass_kg": M, "num_particles": len(mass_kg)},
    }  # fmt: skip
    (folder / "mpm_config.json").write_text(json.dumps(config, indent=2))
    return [folder / "particles.npz", folder / "mpm_config.json"]
