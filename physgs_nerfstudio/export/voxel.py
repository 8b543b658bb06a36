"""Dense voxel grid of occupancy, material and property fields (``.npz``).

Arrays are indexed ``[i, j, k]`` = ``[x, y, z]`` (C order); voxel (i, j, k) has its centre at
``origin + (index + 0.5) * voxel_size``. ``origin_scene``/``voxel_size_scene`` are in scene units,
``origin_m``/``voxel_size_m`` in metres (scene units x ``metres_per_unit``; the origin is the scene
origin scaled, nerfstudio's dataparser transform is not undone). Contents:

* ``occupancy`` uint8: 1 inside the object's carved solid (the nominal carving, :mod:`physgs_nerfstudio.geometry`)
* ``fill`` float32: the share of each voxel that the object's volume and mass count: 1 inside, the share behind
  the rendered surface on the voxels that it cuts (the solid's boundary and, with ``occupancy`` 0 and ``part_id``
  -1, the voxels just outside it: :mod:`physgs_nerfstudio.geometry.partial`), halved on the boundary with hidden
  open space (a top's unseen underside: :mod:`physgs_nerfstudio.geometry.hidden`), 0 elsewhere;
  ``sum(fill) x voxel_size_m^3`` is the nominal volume of the report
* ``part_id`` int32: the voxel's 3-D part (index into ``meta["parts"]``, solid or hollow per part), -1 outside
* ``material_index`` int16: dominant material (legend index 0..K-1), -1 outside
* ``material_prob`` float32 [X, Y, Z, K]: per-voxel material mixture (0 outside)
* ``<key>_mean`` and ``<key>_total`` float32 per property key: mixture mean and total variance (units^2)
  of the per-voxel predictive (``bayes.mixture_fields`` with the voxel's mixture), NaN outside
* ``meta`` (JSON string): axis order, units, legend, property keys, metres_per_unit, scale_source, simulated,
  the geometry's settings and per part its structure posterior (hollow probability, wall thickness)
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..bayes import mixture_fields
from ..geometry import ObjectGeometry
from .field import PropertyField
from .ply import PROPERTY_UNITS

__all__ = ["load_voxel_grid", "write_voxel_grid"]


def write_voxel_grid(pf: PropertyField, path: Path, geo: ObjectGeometry) -> Path:
    """Write the object's carved voxel grid (module doc) from :func:`physgs_nerfstudio.geometry.reconstruct_object`."""
    shape = geo.grid.shape
    K = pf.num_materials
    idx = np.nonzero(geo.solid)
    pi = geo.mixture[idx]  # [M, K]
    out: dict[str, Any] = {}
    out["occupancy"] = geo.solid.astype(np.uint8)
    out["fill"] = geo.fill()
    out["part_id"] = np.where(geo.solid, geo.parts, -1).astype(np.int32)
    mat = np.full(shape, -1, dtype=np.int16)
    mat[idx] = np.argmax(pi, axis=1).astype(np.int16)
    out["material_index"] = mat
    prob = np.zeros((*shape, K), dtype=np.float32)
    prob[idx] = pi
    out["material_prob"] = prob
    nig = pf.nig.to(torch.float64)
    fields = mixture_fields(torch.from_numpy(pi), nig, pf.log_space)  # the voxel's mixture of pf.pi()
    for p, key in enumerate(pf.property_keys):
        for f in ("mean", "total"):
            arr = np.full(shape, np.nan, dtype=np.float32)
            arr[idx] = fields[f][:, p].numpy()
            out[f"{key}_{f}"] = arr
    mpu = pf.metres_per_unit
    origin = np.asarray(geo.grid.origin, dtype=np.float64)
    out["origin_scene"] = origin
    out["voxel_size_scene"] = np.float64(geo.grid.voxel_size)
    out["origin_m"] = origin * mpu
    out["voxel_size_m"] = np.float64(geo.grid.voxel_size * mpu)
    out["metres_per_unit"] = np.float64(mpu)
    meta = {
        "format": "physgs-voxels/2",
        "axis_order": "xyz",
        "index": "array[i, j, k] = voxel at x, y, z index; centre = origin + (index + 0.5) * voxel_size",
        "units": {**{k: PROPERTY_UNITS.get(k, "?") for k in pf.property_keys}, "origin_m": "m",
                  "voxel_size_m": "m", "origin_scene": "scene units", "voxel_size_scene": "scene units",
                  "<key>_total": "variance, units^2"},  # fmt: skip
        "property_keys": list(pf.property_keys),
        "legend": pf.legend(),
        "metres_per_unit": mpu,
        "scale_source": pf.scale_source,
        "simulated": pf.simulated,
        "geometry": geo.summary(),
        "parts": geo.structure.to_list(),
    }  # fmt: skip
    out["meta"] = np.array(json.dumps(meta))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **out)
    return path


def load_voxel_grid(path: Path) -> dict[str, Any]:
    """Arrays of a grid written by :func:`write_voxel_grid`, with ``meta`` parsed."""
    with np.load(path, allow_pickle=False) as z:
        d = {k: z[k] for k in z.files}
    d["meta"] = json.loads(str(d["meta"]))
    return d
