"""Property maps for chosen views: per-Gaussian values rendered as feature channels, saved as PNG sheets.

Rendering goes through :func:`physgs_nerfstudio.render.rasterize` (gsplat on CUDA, the reference rasterizer
on CPU): the K material probabilities, every property mean and the density uncertainties are composited
like colours, then divided by the accumulated opacity, so a pixel shows the opacity-weighted average of
the Gaussians it sees (no background blending). Pixels with accumulation below ``min_alpha`` are blank.
Each view gives one PNG sheet (:mod:`.sheet`): RGB (degree-0 colour), material (legend colours, legend), each
property mean (colour bar; density and Young's modulus on a log scale) and density aleatoric / epistemic /
total standard deviation; the per-Gaussian channels are computed once for all views (:func:`map_features`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor

from .field import PropertyField
from .ply import PROPERTY_UNITS

__all__ = ["View", "render_property_maps", "save_property_maps"]

_SH_C0 = 0.28209479177387814
_LOG_KEYS = ("density", "youngs_modulus")


@dataclass
class View:
    viewmat: Float[Tensor, "4 4"]
    """world-to-camera, OpenCV axes (x right, y down, z forward), as gsplat"""
    K: Float[Tensor, "3 3"]
    width: int
    height: int
    name: str = "view"


@torch.no_grad()
def map_features(pf: PropertyField) -> tuple[Float[Tensor, "n c"], Float[Tensor, " c"]]:
    """The per-Gaussian channels the maps composite (material weights, property means, density's three standard
    deviations, degree-0 colour), each scaled to O(1), and the scales: computed once for all views."""
    dev = pf.device
    fields = pf.fields()
    cols = [pf.pi().float(), fields["mean"].float()]
    d = pf.property_index("density") if "density" in pf.property_keys else 0
    cols.append(torch.stack([fields[f][:, d] for f in ("aleatoric", "epistemic", "total")], -1).clamp_min(0).sqrt())
    dc = pf.sh_dc if pf.sh_dc is not None else torch.zeros(pf.num_gaussians, 3, device=dev)
    cols.append((dc.float() * _SH_C0 + 0.5).clamp(0, 1))
    feats = torch.cat(cols, -1)
    # normalise channels to O(1) so float32 compositing is accurate for Pa-sized values
    scale = feats.abs().amax(0).clamp_min(1e-12)
    return feats / scale, scale


@torch.no_grad()
def render_property_maps(
    pf: PropertyField, view: View, *, min_alpha: float = 0.2, backend: str = "auto",
    features: tuple[Tensor, Tensor] | None = None,
) -> dict[str, np.ndarray]:  # fmt: skip
    """Maps of one view: ``rgb`` [H, W, 3], ``material`` [H, W] (index, -1 blank), ``alpha`` [H, W], and
    per property key ``<key>`` (mean) plus ``density_aleatoric_sd``/``_epistemic_sd``/``_total_sd`` [H, W]
    (NaN where blank). ``features``: :func:`map_features` of ``pf`` (computed here when None)."""
    from ..render import rasterize

    feats, scale = map_features(pf) if features is None else features
    K = pf.num_materials
    render, alpha, _ = rasterize(
        pf.means, pf.quats / pf.quats.norm(dim=-1, keepdim=True), pf.scales, pf.opacities, feats,
        view.viewmat[None].to(pf.device), view.K[None].to(pf.device), view.width, view.height, backend=backend,
    )  # fmt: skip
    img = (render[0] * scale).cpu().numpy()
    a = alpha[0, ..., 0].cpu().numpy()
    blank = a < min_alpha
    avg = img / np.maximum(a, 1e-6)[..., None]
    out: dict[str, np.ndarray] = {"alpha": a}
    P = len(pf.property_keys)
    mat = np.argmax(avg[..., :K], -1).astype(np.int64)
    mat[blank] = -1
    out["material"] = mat
    for p, key in enumerate(pf.property_keys):
        v = avg[..., K + p].copy()
        v[blank] = np.nan
        out[key] = v
    for j, f in enumerate(("aleatoric", "epistemic", "total")):
        v = avg[..., K + P + j].copy()
        v[blank] = np.nan
        out[f"density_{f}_sd"] = v
    out["rgb"] = np.clip(img[..., K + P + 3 :], 0, 1)  # premultiplied on black
    return out


def _sheet(pf: PropertyField, maps: dict[str, np.ndarray], name: str) -> np.ndarray:
    """The PNG sheet of one view's maps (:mod:`.sheet`): colour, material with its legend, each property's mean,
    density's standard deviations."""
    from .sheet import colorize, compose_sheet

    colors = np.asarray(pf.material_colors, dtype=np.uint8).reshape(-1, 3)
    m = maps["material"]
    mat = np.full((*m.shape, 3), 255, np.uint8)
    mat[m >= 0] = colors[m[m >= 0]]
    panels: list[tuple[str, np.ndarray, str | None]] = [
        ("colour (SH degree 0)", (np.clip(maps["rgb"], 0, 1) * 255).round().astype(np.uint8), None),
        ("material (dominant)", mat, None),
    ]
    for key in [*pf.property_keys, "density_aleatoric_sd", "density_epistemic_sd", "density_total_sd"]:
        cmap = "magma" if key.endswith("_sd") else "viridis"
        rgb, lo, hi, log = colorize(maps[key], cmap, log=key in _LOG_KEYS)
        base = key.split("_aleatoric")[0].split("_epistemic")[0].split("_total")[0]
        unit = PROPERTY_UNITS.get(base, "").split(" (")[0]
        panels.append((f"{key} [{unit}]" if unit else key, rgb, f"{cmap}|{lo}|{hi}|{int(log)}"))
    present = [i for i in range(pf.num_materials) if (m == i).any()]
    legend = [(pf.material_names[i], tuple(colors[i])) for i in present]
    header = name + ("  [SIMULATED VLM]" if pf.simulated else "")
    return compose_sheet(panels, header=header, legend=legend)


def save_property_maps(
    pf: PropertyField,
    views: Sequence[View],
    out_dir: Path,
    *,
    min_alpha: float = 0.2,
    backend: str = "auto",
    on_view: Callable[[str], None] | None = None,
) -> list[Path]:
    """One PNG sheet per view under ``out_dir`` (``maps_<name>.png``) plus ``maps_<name>.npz`` with the raw maps;
    ``on_view(name)`` is called after each view (the caller's progress display)."""
    from PIL import Image

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    features = map_features(pf)
    paths = []
    for view in views:
        maps = render_property_maps(pf, view, min_alpha=min_alpha, backend=backend, features=features)
        path = out_dir / f"maps_{view.name}.png"
        Image.fromarray(_sheet(pf, maps, view.name)).save(path, compress_level=1)
        np.savez(out_dir / f"maps_{view.name}.npz", **maps)  # uncompressed: deflating float maps cost 0.65 s a view
        paths.append(path)
        if on_view is not None:
            on_view(view.name)
    return paths
