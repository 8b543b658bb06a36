"""The simulator object of an export: checks, frame, carriers, meshes and materials (:func:`build_object`)."""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .body import Elements, MassCarriers, body_from_masses, elements, mass_carriers, mean_masses
from .config import SimConfig, SimError
from .frame import ObjectFrame, capture_up, object_frame
from .mesh import collision_pieces, part_meshes
from .simobject import PartMaterial, SimObject

__all__ = ["SimBuild", "build_object", "check_metric_scale", "part_materials"]

KNOWN_SCALES = ("known_length", "user_scale", "given")
FRICTION_KEY = "kinetic_friction"


def check_metric_scale(scale_source: str, data_dir: Path | None) -> None:
    """Refuse a scale that was assumed, not known: ``metric_dataset`` counts as known only for a `physgs synth`
    scene (its ground_truth.json gives lengths in metres)."""
    if scale_source in KNOWN_SCALES:
        return
    if scale_source == "metric_dataset" and data_dir is not None:
        gt = Path(data_dir) / "ground_truth.json"
        try:
            if json.loads(gt.read_text()).get("units", {}).get("length") == "m":
                return
        except (OSError, ValueError, AttributeError):
            pass
    raise SimError(f"sim: the run's metric scale is assumed, not known (scale source {scale_source!r}): a body's "
                   "mass and inertia need it; pass --scale (metres per dataset unit, 1 for a Polycam, Record3D or "
                   "ARKit capture) or --known-length.")  # fmt: skip


@dataclass
class SimBuild:
    """An object ready to write, with what its samples and particles are made from."""

    obj: SimObject
    frame: ObjectFrame
    up_source: str
    carriers: MassCarriers
    solid_e: Elements
    wall_e: Elements
    masses: np.ndarray
    """[2, P, K] the mean body's part masses (solid, wall)"""
    voxel_m: float
    origin_m: np.ndarray


def part_materials(pf: Any, share: np.ndarray, friction: np.ndarray, mass: np.ndarray, volume: np.ndarray
                   ) -> dict[int, PartMaterial]:  # fmt: skip
    """Per part: its dominant material, friction ``share [P, K] @ friction [K]`` and density mass / volume."""
    mu = np.clip(share @ friction, 0.0, 2.0)
    rho = np.divide(mass, volume, out=np.zeros_like(mass), where=volume > 0)
    top = [int(np.argmax(share[p])) for p in range(share.shape[0])]
    return {p: PartMaterial(pf.material_names[k], float(mu[p]), float(rho[p]), tuple(map(int, pf.material_colors[k])))
            for p, k in enumerate(top)}  # fmt: skip


def _check_object(geo: Any, cfg: SimConfig) -> None:
    n = int(geo.solid.sum())
    if n == 0:
        raise SimError("sim: the object has no solid voxels (an empty object): nothing to simulate; check the "
                       "object's selection (--mass.geometry.select) or the masks.")  # fmt: skip
    if n < cfg.min_voxels:
        raise SimError(f"sim: the object is {n} solid voxel{'s' if n > 1 else ''}, fewer than {cfg.min_voxels}: "
                       "too coarse for a body's inertia and meshes; raise --mass.geometry.resolution.")  # fmt: skip


def build_object(pf: Any, geo: Any, draws: Any, cfg: SimConfig, views: Sequence[Any] = (),
                 data_dir: Path | None = None) -> SimBuild:  # fmt: skip
    """Check the input (metric scale, a solid of at least ``cfg.min_voxels`` voxels) and build the mean body
    (:mod:`.body`), its meshes (:mod:`.mesh`) and its parts' materials. Raises :class:`SimError` (one line)."""
    check_metric_scale(pf.scale_source, data_dir)
    _check_object(geo, cfg)
    mpu = pf.metres_per_unit
    a = geo.grid.voxel_size * mpu
    origin = np.asarray(geo.grid.origin, dtype=np.float64) * mpu
    fill = geo.fill()
    up, up_source = capture_up(geo, views)
    frame = object_frame(geo.solid, fill, origin, a, up)
    parts = np.where(geo.solid, geo.parts, -1)
    meshes = part_meshes(geo.solid, parts, fill, origin, a, frame, cfg.max_triangles)
    if meshes:  # the object rests on z = 0: its meshes' lowest point, not its voxels'
        low = min(float(m.vertices[:, 2].min()) for m in meshes)
        frame = ObjectFrame(frame.rotation, frame.origin_m + low * frame.rotation[:, 2])
        for m in meshes:
            m.vertices[:, 2] -= low
    solid_e, wall_e = elements(geo.solid, parts, geo.mixture, fill, origin, a, frame)
    carriers = mass_carriers(solid_e, wall_e, geo.num_parts)
    masses = mean_masses(draws.part_mass_kg, draws.hollow)
    try:
        body = body_from_masses(masses, carriers)
    except ValueError as err:
        raise SimError(f"sim: {err}: nothing to simulate; see report.json's parts.") from None
    if not meshes:
        raise SimError("sim: the object's volume makes no surface (no voxel is more than half filled): nothing to "
                       "simulate; raise --mass.geometry.resolution.")  # fmt: skip
    method = "hull"
    for m in meshes:
        m.collision, method = collision_pieces(m, cfg.collision, cfg.coacd_threshold, cfg.max_pieces)
    friction = pf.material_means()[:, pf.property_index(FRICTION_KEY)].cpu().numpy()
    mats = part_materials(pf, geo.part_mixture, friction, masses.sum((0, 2)), draws.volume_m3.mean(0))
    obj = SimObject("object", body, meshes, mats, collision_method=method)
    return SimBuild(obj, frame, up_source, carriers, solid_e, wall_e, masses, a, origin)
