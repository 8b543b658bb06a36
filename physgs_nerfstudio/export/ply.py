"""PLY point cloud of Gaussian centres with material posteriors, property fields and uncertainty.

The file is also a standard 3D Gaussian Splatting PLY (opens in splat viewers): it carries the splat
attributes with the usual names, then the PhysGS attributes. One vertex per Gaussian, all float32 unless
noted. Positions and scales are in scene units (multiply by ``metres_per_unit``, stored in the header, for
metres).

Splat attributes (3DGS convention):
  ``x, y, z``; ``nx, ny, nz`` (zeros); ``f_dc_0..2`` (degree-0 SH); ``f_rest_0..`` (higher SH, channel-major:
  ``f_rest_{c * R + j}`` = coefficient j of colour channel c); ``opacity`` (logit); ``scale_0..2`` (log of
  the standard deviations); ``rot_0..3`` (quaternion w, x, y, z).

PhysGS attributes:
  ``material_id`` (uint8: materials.json id, 1..K), ``material_index`` (uint8: 0..K-1 into the legend),
  ``material_prob`` (weight of the most probable material), ``material_top{j}`` (uint8 index, j = 0..top_k-1) and
  ``material_top{j}_prob``, ``material_entropy`` (nats), ``alpha_sum`` (Dirichlet strength), and per property
  key ``<key>_mean`` (units below) and ``<key>_aleatoric``, ``<key>_epistemic``, ``<key>_total``
  (variances of the per-Gaussian mixture predictive, units squared). Every material and property column
  uses the same per-Gaussian weights, ``PropertyField.pi()`` (``material_weights`` in the header).

Header: ``comment physgs <json>`` holds the legend (id, index, name, colour, thickness_m), property keys,
units, metres_per_unit, scale_source and ``simulated``; the same JSON is in ``obj_info``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import torch
from plyfile import PlyData, PlyElement

from .field import PropertyField

__all__ = ["PROPERTY_UNITS", "read_ply_legend", "write_property_ply"]

PROPERTY_UNITS = {
    "density": "kg/m^3",
    "kinetic_friction": "1",
    "shore_hardness": "canonical Shore hardness (materials/hardness.py)",
    "youngs_modulus": "Pa",
}


def _header_meta(pf: PropertyField, top_k: int) -> dict[str, Any]:
    return {
        "format": "physgs-ply/1",
        "legend": pf.legend(),
        "property_keys": list(pf.property_keys),
        "units": {k: PROPERTY_UNITS.get(k, "?") for k in pf.property_keys},
        "uncertainty": "aleatoric/epistemic/total are variances (units^2)",
        "positions": "scene units; metres = value * metres_per_unit",
        "metres_per_unit": pf.metres_per_unit,
        "scale_source": pf.scale_source,
        "simulated": pf.simulated,
        "top_k": top_k,
        "material_weights": pf.material_weights,
    }


def write_property_ply(pf: PropertyField, path: Path, *, top_k: int = 3, chunk: int = 1 << 18) -> Path:
    """Write ``pf`` as a PLY (module doc); returns the path. ``chunk`` Gaussians at a time for the fields."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    n, K = pf.num_gaussians, pf.num_materials
    if K > 255:
        raise ValueError(f"PLY export stores material indices as uint8: at most 255 materials, got {K}.")
    top_k = max(1, min(top_k, K))
    cols: dict[str, tuple[np.ndarray, str]] = {}

    def put(name: str, arr: torch.Tensor | np.ndarray, dtype: str = "f4") -> None:
        a = arr.detach().cpu().numpy() if isinstance(arr, torch.Tensor) else np.asarray(arr)
        cols[name] = (a.reshape(n), dtype)

    means = pf.means.float()
    for i, c in enumerate("xyz"):
        put(c, means[:, i])
    for c in ("nx", "ny", "nz"):
        put(c, np.zeros(n, np.float32))
    dc = pf.sh_dc if pf.sh_dc is not None else torch.zeros(n, 3)
    for i in range(3):
        put(f"f_dc_{i}", dc[:, i])
    if pf.sh_rest is not None and pf.sh_rest.shape[1] > 0:
        rest = pf.sh_rest.float().transpose(1, 2).reshape(n, -1)  # [N, 3, R] channel-major
        for i in range(rest.shape[1]):
            put(f"f_rest_{i}", rest[:, i])
    put("opacity", torch.logit(pf.opacities.float().clamp(1e-6, 1 - 1e-6)))
    log_s = torch.log(pf.scales.float().clamp_min(1e-12))
    for i in range(3):
        put(f"scale_{i}", log_s[:, i])
    q = pf.quats.float() / pf.quats.float().norm(dim=-1, keepdim=True).clamp_min(1e-12)
    for i in range(4):
        put(f"rot_{i}", q[:, i])

    # material posterior and property fields, in chunks of Gaussians
    P = len(pf.property_keys)
    top_i = np.zeros((n, top_k), np.uint8)
    top_p = np.zeros((n, top_k), np.float32)
    entropy = np.zeros(n, np.float32)
    fields = {f: np.zeros((n, P), np.float32) for f in ("mean", "aleatoric", "epistemic", "total")}
    weights = pf.pi()  # the one weighting of the file: material columns and property columns alike
    for s in range(0, n, chunk):
        pi = weights[s : s + chunk]
        p, i = torch.topk(pi, top_k, dim=-1)
        top_i[s : s + chunk] = i.cpu().numpy().astype(np.uint8)
        top_p[s : s + chunk] = p.cpu().numpy()
        entropy[s : s + chunk] = (-(pi * torch.log(pi.clamp_min(1e-30))).sum(-1)).cpu().numpy()
        for f, v in pf.fields(slice(s, s + chunk)).items():
            fields[f][s : s + chunk] = v.cpu().numpy()
    put("material_id", top_i[:, 0] + 1, "u1")
    put("material_index", top_i[:, 0], "u1")
    put("material_prob", top_p[:, 0])
    for j in range(top_k):
        put(f"material_top{j}", top_i[:, j], "u1")
        put(f"material_top{j}_prob", top_p[:, j])
    put("material_entropy", entropy)
    put("alpha_sum", pf.alpha.sum(-1).float())
    for pi_, key in enumerate(pf.property_keys):
        for f in ("mean", "aleatoric", "epistemic", "total"):
            put(f"{key}_{f}", fields[f][:, pi_])

    dtype = [(name, dt) for name, (_, dt) in cols.items()]
    data = np.empty(n, dtype=dtype)
    for name, (arr, dt) in cols.items():
        data[name] = arr.astype(dt, copy=False)
    meta = json.dumps(_header_meta(pf, top_k), separators=(",", ":"))
    el = PlyElement.describe(data, "vertex")
    PlyData([el], text=False, comments=[f"physgs {meta}"], obj_info=[f"physgs {meta}"]).write(str(path))
    return path


def read_ply_legend(path: Path) -> dict[str, Any]:
    """The ``physgs`` JSON of a PLY written by :func:`write_property_ply`."""
    ply = PlyData.read(str(path))
    for line in list(ply.comments) + list(ply.obj_info):
        if line.startswith("physgs "):
            return json.loads(line[len("physgs ") :])
    raise ValueError(f"{path}: no `comment physgs {{...}}` header line; not written by physgs export.")
