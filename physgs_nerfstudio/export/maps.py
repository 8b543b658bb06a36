"""Property maps for chosen views: per-Gaussian values rendered as feature channels, saved as PNG figures.

Rendering goes through :func:`physgs_nerfstudio.render.rasterize` (gsplat on CUDA, the reference rasterizer
on CPU): the K material probabilities, every property mean and the density uncertainties are composited
like colours, then divided by the accumulated opacity, so a pixel shows the opacity-weighted average of
the Gaussians it sees (no background blending). Pixels with accumulation below ``min_alpha`` are blank.
Each view gives one PNG: RGB (degree-0 colour), material (legend colours, legend box), each property mean
(colour bar; density and Young's modulus on a log scale) and density aleatoric / epistemic / total
standard deviation.
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
def render_property_maps(
    pf: PropertyField, view: View, *, min_alpha: float = 0.2, backend: str = "auto"
) -> dict[str, np.ndarray]:
    """Maps of one view: ``rgb`` [H, W, 3], ``material`` [H, W] (index, -1 blank), ``alpha`` [H, W], and
    per property key ``<key>`` (mean) plus ``density_aleatoric_sd``/``_epistemic_sd``/``_total_sd`` [H, W]
    (NaN where blank)."""
    from ..render import rasterize

    dev = pf.device
    fields = pf.fields()
    pi = pf.pi().float()
    K = pf.num_materials
    cols = [pi, fields["mean"].float()]
    d = pf.property_index("density") if "density" in pf.property_keys else 0
    cols.append(torch.stack([fields[f][:, d] for f in ("aleatoric", "epistemic", "total")], -1).clamp_min(0).sqrt())
    dc = pf.sh_dc if pf.sh_dc is not None else torch.zeros(pf.num_gaussians, 3, device=dev)
    cols.append((dc.float() * _SH_C0 + 0.5).clamp(0, 1))
    feats = torch.cat(cols, -1)
    # normalise channels to O(1) so float32 compositing is accurate for Pa-sized values
    scale = feats.abs().amax(0).clamp_min(1e-12)
    render, alpha, _ = rasterize(
        pf.means, pf.quats / pf.quats.norm(dim=-1, keepdim=True), pf.scales, pf.opacities, feats / scale,
        view.viewmat[None].to(dev), view.K[None].to(dev), view.width, view.height, backend=backend,
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


def save_property_maps(
    pf: PropertyField,
    views: Sequence[View],
    out_dir: Path,
    *,
    min_alpha: float = 0.2,
    backend: str = "auto",
    dpi: int = 100,
    on_view: Callable[[str], None] | None = None,
) -> list[Path]:
    """One PNG per view under ``out_dir`` (``maps_<name>.png``) plus ``maps_<name>.npz`` with the raw maps;
    ``on_view(name)`` is called after each view (the caller's progress display)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap, LogNorm
    from matplotlib.patches import Patch

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    colors = np.asarray(pf.material_colors, dtype=np.float64) / 255.0
    for view in views:
        maps = render_property_maps(pf, view, min_alpha=min_alpha, backend=backend)
        panels = ["rgb", "material", *pf.property_keys, "density_aleatoric_sd", "density_epistemic_sd",
                  "density_total_sd"]  # fmt: skip
        ncol = 4
        nrow = int(np.ceil(len(panels) / ncol))
        fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.6 * nrow), squeeze=False)
        title = f"{view.name}" + ("  [SIMULATED VLM]" if pf.simulated else "")
        fig.suptitle(title)
        for ax in axes.ravel():
            ax.set_axis_off()
        for ax, name in zip(axes.ravel(), panels):
            if name == "rgb":
                ax.imshow(maps["rgb"])
                ax.set_title("colour (SH degree 0)")
                continue
            if name == "material":
                m = maps["material"]
                rgba = np.ones((*m.shape, 4))
                ok = m >= 0
                rgba[ok, :3] = colors[m[ok]]
                rgba[~ok, 3] = 0
                ax.imshow(rgba)
                present = [i for i in range(pf.num_materials) if (m == i).any()]
                ax.legend(handles=[Patch(color=colors[i], label=pf.material_names[i]) for i in present],
                          loc="lower right", fontsize=7, framealpha=0.8)  # fmt: skip
                ax.set_title("material (dominant)")
                continue
            v = maps[name]
            finite = v[np.isfinite(v)]
            key = name.split("_aleatoric")[0].split("_epistemic")[0].split("_total")[0]
            unit = PROPERTY_UNITS.get(key, "").split(" (")[0]
            lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
            if hi - lo <= 1e-6 * max(abs(hi), 1e-12):  # constant map: a readable colour bar around the value
                lo, hi = (lo * 0.99, hi * 1.01) if lo > 0 else (lo - 1, hi + 1)
            if name in _LOG_KEYS and lo > 0:
                norm = LogNorm(vmin=lo, vmax=hi)
            else:
                from matplotlib.colors import Normalize

                norm = Normalize(vmin=lo, vmax=hi)
            im = ax.imshow(v, cmap="viridis" if not name.endswith("_sd") else "magma", norm=norm)
            ax.set_title(f"{name} [{unit}]" if unit else name, fontsize=9)
            fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
        fig.tight_layout()
        path = out_dir / f"maps_{view.name}.png"
        fig.savefig(path, dpi=dpi)
        plt.close(fig)
        np.savez_compressed(out_dir / f"maps_{view.name}.npz", **{k: v for k, v in maps.items()})
        paths.append(path)
        if on_view is not None:
            on_view(view.name)
    _ = ListedColormap  # (kept for users who want a discrete material colormap)
    return paths
