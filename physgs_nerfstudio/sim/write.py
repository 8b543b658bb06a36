"""Write the simulator-ready object (``--outputs sim``): meshes, MJCF, URDF, USD, MPM particles, samples, manifest.

Layout of ``<export>/sim/`` (docs/simulation.md)::

    manifest.json            every file, units, the frame and its pose in the scene, the values written
    object.xml, scene.xml    MuJoCo (:mod:`.mjcf`)
    object.urdf              URDF (:mod:`.urdf`)
    object.usda              USD with UsdPhysics (:mod:`.usd`)
    particles.npz, mpm_config.json   MPM particles (:mod:`.mpm`)
    meshes/part_<p>.obj, meshes/part_<p>_collision_<i>.obj
    samples/samples.json, samples/<iii>/object.{xml,urdf,usda}   with --sim.samples N (:mod:`.samples`)
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .body import element_masses
from .build import SimBuild, build_object
from .config import SimConfig
from .manifest import manifest
from .mjcf import mjcf_text, write_mjcf
from .mpm import poisson_ratio, write_mpm
from .samples import sample_bodies
from .urdf import urdf_text, write_urdf
from .usd import usd_available, write_usd, write_usd_sample

logger = logging.getLogger(__name__)

__all__ = ["write_sim"]


def _write_meshes(build: SimBuild, folder: Path) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for m in build.obj.meshes:
        out.append(folder / build.obj.mesh_file(m.part))
        m.trimesh().export(out[-1])
        for i, (v, f) in enumerate(m.collision):
            import trimesh

            out.append(folder / build.obj.mesh_file(m.part, i))
            trimesh.Trimesh(v, f, process=False).export(out[-1])
    return out


def _particles(pf: Any, build: SimBuild, geo: Any, folder: Path) -> list[Path]:
    shape = geo.grid.shape
    flat = np.zeros(int(np.prod(shape)))
    for e, m in ((build.solid_e, build.masses[0]), (build.wall_e, build.masses[1])):
        np.add.at(flat, np.ravel_multi_index(tuple(e.voxel.T), shape), element_masses(e, m, geo.num_parts))
    mix = np.zeros((flat.size, geo.mixture.shape[-1]))
    mix[np.ravel_multi_index(tuple(build.wall_e.voxel.T), shape)] = build.wall_e.weight  # a wall's voxels
    mix[np.ravel_multi_index(tuple(build.solid_e.voxel.T), shape)] = build.solid_e.weight  # every voxel with fill
    keep = np.flatnonzero(flat > 0)
    mix = mix[keep] / np.maximum(mix[keep].sum(1, keepdims=True), 1e-300)
    vox = np.stack(np.unravel_index(keep, shape), 1)
    fill = geo.fill().reshape(-1)[keep]
    fill = np.where(fill > 0, fill, 1.0)  # a solid voxel the volume counts at 0 that bounds a wall: a whole voxel
    E = pf.material_means()[:, pf.property_index("youngs_modulus")].cpu().numpy()
    nus = [poisson_ratio(n) for n in pf.material_names]
    nu = np.array([x for x, _ in nus])
    top = np.argmax(mix, 1)
    dominant = pf.material_names[int(np.argmax(build.masses.sum((0, 1))))]
    model = "metal" if "metal" in poisson_ratio(dominant)[1] else "jelly"
    return write_mpm(folder, build.frame.to_object(build.origin_m + (vox + 0.5) * build.voxel_m),
                     fill * build.voxel_m**3, flat[keep], mix @ E, mix @ nu, top, list(pf.material_names),
                     {n: s for n, (_, s) in zip(pf.material_names, nus)}, model)  # fmt: skip


def _write_samples(pf: Any, build: SimBuild, draws: Any, n: int, seed: int, folder: Path) -> tuple[list[Path], list]:
    rows, files = [], []
    for i, (body, mats, drawn) in enumerate(sample_bodies(pf, build, draws, n, seed)):
        d = folder / f"{i:03d}"
        d.mkdir(parents=True, exist_ok=True)
        obj = build.obj.variant(body, mats, "../../meshes")
        (d / "object.xml").write_text(mjcf_text(obj))
        (d / "object.urdf").write_text(urdf_text(obj))
        files += [d / "object.xml", d / "object.urdf"]
        if usd_available():
            files += write_usd_sample(obj, d, "../../object.usda")
        rows.append({"index": i, **body.to_dict(), "parts": {str(p): vars(m) for p, m in mats.items()}, **drawn})
    (folder / "samples.json").write_text(json.dumps({"count": n, "samples": rows}, indent=2))
    return [folder / "samples.json", *files], rows


def write_sim(pf: Any, geo: Any, draws: Any, report: Any, folder: Path, cfg: SimConfig | None = None, *,
              views: Sequence[Any] = (), data_dir: Path | None = None, seed: int = 0,
              dataparser: dict | None = None) -> list[Path]:  # fmt: skip
    """Write ``folder`` (module doc) from the export's field, geometry and Monte Carlo ``draws`` (the report's);
    raises :class:`.config.SimError` before writing anything when the input cannot make a body."""
    cfg = cfg or SimConfig()
    build = build_object(pf, geo, draws, cfg, views, data_dir)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    files = _write_meshes(build, folder / "meshes")
    files += write_mjcf(build.obj, folder) + write_urdf(build.obj, folder)
    if usd_available():
        files += write_usd(build.obj, folder)
    else:
        logger.warning("sim: object.usda not written: USD needs usd-core (pip install usd-core, or "
                       "physgs-nerfstudio[sim]); the MJCF, URDF and particles are written.")  # fmt: skip
    files += _particles(pf, build, geo, folder)
    rows: list = []
    if cfg.samples:
        more, rows = _write_samples(pf, build, draws, cfg.samples, seed, folder / "samples")
        files += more
    path = folder / "manifest.json"
    path.write_text(json.dumps(manifest(build, report, files, folder, rows, dataparser), indent=2))
    return [path, *files]
