"""The viewer's property outputs: only what was measured gets a colour, on fixed scales.

Per Gaussian g (once per change of the lifted evidence, :class:`GaussianMaterials`):

* ``pi_g`` [K]: its material mixture weights (the model's ``material_weights`` rule: dominance probability or
  alpha / sum(alpha)), as every export writer uses them;
* ``measured_g``: it carries material evidence, i.e. lifting gave it evidence and at least
  ``min_labelled`` of its blending weight fell on pixels the material maps label. Gaussians of the
  environment that perception left unknown hold only the Dirichlet prior and are *not* measured.

The rasterizer composites ``measured_g * pi_g`` and ``measured_g`` (K + 1 channels) in the same pass as RGB.
Per pixel, ``coverage`` = the composited ``measured`` (the opacity of measured Gaussians) and the pixel's
material mixture ``pi = composited(measured * pi) / coverage``; the property mean, aleatoric and epistemic
variance come from that mixture and the materials' posteriors (law of total variance,
:func:`physgs_nerfstudio.bayes.mixture_fields`), exactly as the click query computes them for a ray
(:mod:`.query`). Pixels with ``coverage`` below ``min_coverage`` show dimmed RGB instead of a colour.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import torch
from jaxtyping import Bool, Float
from torch import Tensor

from ..bayes import NIG, mixture_fields
from ..bayes.mixture import material_mixture_weights
from .scales import DisplayScale, colourise, property_scales, uncertainty_scale

__all__ = ["GaussianMaterials", "PixelStatistics", "ViewerSettings", "display_outputs", "gaussian_channels",
           "gaussian_materials", "pixel_statistics", "prior_std", "viewer_outputs"]  # fmt: skip

UNCERTAINTY_KINDS = (("aleatoric", "aleatoric"), ("epistemic", "epistemic"), ("total_uncertainty", "total"))


@dataclass
class ViewerSettings:
    """What the property outputs show; the viewer panel (:mod:`.panel`) changes these while it runs."""

    uncertainty_property: str = "density"
    """property key whose aleatoric / epistemic / total standard deviations the uncertainty outputs show"""
    material_view: Literal["dominant", "probability"] = "dominant"
    """`material` output: the dominant material's legend colour, or the probability of ``material_index``"""
    material_index: int = 0
    min_coverage: float = 0.5
    """pixels whose measured Gaussians' opacity is below this show dimmed RGB"""
    min_labelled: float = 0.3
    """a Gaussian is measured if at least this share of its blending weight fell on labelled pixels"""
    dim: float = 0.3
    """brightness of the RGB shown where nothing was measured"""


@dataclass
class GaussianMaterials:
    """Per-Gaussian material weights and the measured flag (module doc)."""

    pi: Float[Tensor, "n k"]
    measured: Bool[Tensor, " n"]
    evidence: Float[Tensor, " n"]
    """total lifted Dirichlet evidence (confidence-weighted views with labels)"""
    views: Float[Tensor, " n"]
    """total per-view-normalised blending weight: the number of training views that saw the Gaussian"""
    labelled: Float[Tensor, " n"]
    """share of that weight on labelled pixels"""

    @classmethod
    def from_tensors(cls, alpha: Tensor, evidence: Tensor, views: Tensor, labelled: Tensor, *,
                     material_weights: str, min_labelled: float, lifted: bool) -> GaussianMaterials:  # fmt: skip
        pi = material_mixture_weights(alpha.detach().float(), material_weights)  # type: ignore[arg-type]
        ev = evidence.detach().float().reshape(-1)
        lab = labelled.detach().float().reshape(-1)
        measured = (ev > 0) & (lab >= min_labelled) & bool(lifted)
        return cls(pi, measured, ev, views.detach().float().reshape(-1), lab)


def gaussian_channels(gm: GaussianMaterials) -> Float[Tensor, "n k1"]:
    """Colours to composite: ``measured * pi`` (K) and ``measured`` (1)."""
    m = gm.measured.to(gm.pi.dtype)[:, None]
    return torch.cat([gm.pi * m, m], dim=-1)


@dataclass
class PixelStatistics:
    coverage: Float[Tensor, "h w 1"]
    """composited opacity of measured Gaussians"""
    shown: Bool[Tensor, "h w 1"]
    pi: Float[Tensor, "h w k"]
    """the pixel's material mixture (rows sum to 1 where covered)"""
    fields: dict[str, Float[Tensor, "h w p"]] = field(default_factory=dict)
    """mean, aleatoric, epistemic, total (variances), linear property units"""


def pixel_statistics(rendered: Float[Tensor, "h w k1"], nig: NIG, log_space: Sequence[bool],
                     min_coverage: float) -> PixelStatistics:  # fmt: skip
    """Per-pixel material mixture and property moments from the composited :func:`gaussian_channels`."""
    H, W, K1 = rendered.shape
    K = K1 - 1
    cov = rendered[..., K:].clamp_min(0)
    pi = rendered[..., :K].clamp_min(0) / cov.clamp_min(1e-10)
    pi = torch.where(cov > 1e-6, pi, torch.full_like(pi, 1.0 / K))
    pi = pi / pi.sum(-1, keepdim=True).clamp_min(1e-12)
    flat = mixture_fields(pi.reshape(-1, K).double(), nig.to(pi.device), log_space)
    fields = {k: v.reshape(H, W, -1).float() for k, v in flat.items()}
    return PixelStatistics(cov, cov > min_coverage, pi, fields)


def prior_std(nig: NIG, log_space: Sequence[bool], alpha0: float, material_weights: str) -> Float[Tensor, " p"]:
    """Total standard deviation of each property for a Gaussian with no evidence (the scene's prior)."""
    K = nig.shape[0]
    pi = material_mixture_weights(torch.full((1, K), float(alpha0), dtype=torch.float64), material_weights)  # type: ignore[arg-type]
    return mixture_fields(pi, nig.to("cpu"), log_space)["total"][0].clamp_min(0).sqrt()


def display_outputs(
    stats: PixelStatistics,
    rgb: Float[Tensor, "h w 3"],
    property_keys: Sequence[str],
    viewer_names: dict[str, str],
    settings: ViewerSettings,
    uncertainty_top: Float[Tensor, " p"],
    scales: dict[str, DisplayScale] | None = None,
    as_std: bool = True,
) -> tuple[dict[str, Float[Tensor, "h w 3"]], dict[str, DisplayScale]]:
    """Coloured outputs (each [H, W, 3]): every property's mean under its viewer name, the chosen property's
    ``aleatoric``, ``epistemic`` and ``total_uncertainty`` (standard deviations), and ``material_probability``
    of ``settings.material_index``; dimmed RGB where ``stats.shown`` is False. Also returns the scale of each."""
    scales = scales if scales is not None else property_scales(property_keys)
    dimmed = rgb * settings.dim
    out: dict[str, Tensor] = {}
    used: dict[str, DisplayScale] = {}

    def put(name: str, values: Tensor, scale: DisplayScale) -> None:
        out[name] = torch.where(stats.shown, colourise(values, scale).to(rgb), dimmed)
        used[name] = scale

    for i, key in enumerate(property_keys):
        put(viewer_names.get(key, key), stats.fields["mean"][..., i : i + 1], scales[key])
    u = list(property_keys).index(settings.uncertainty_property)
    key = property_keys[u]
    top = float(uncertainty_top[u])
    for name, f in UNCERTAINTY_KINDS:
        var = stats.fields[f][..., u : u + 1].clamp_min(0)
        if as_std:
            put(name, var.sqrt(), uncertainty_scale(key, f, top))
        else:
            put(name, var, replace(uncertainty_scale(key, f, top**2), label=f"{key} {f} variance"))
    k = min(max(settings.material_index, 0), stats.pi.shape[-1] - 1)
    put("material_probability", stats.pi[..., k : k + 1], DisplayScale(key="probability", label="probability",
                                                                       lo=0.0, hi=1.0, log10=False, unit=""))
    return out, used


def _evidence_key(model: Any) -> tuple:
    t = [model.gauss_params[k] for k in ("dirichlet_evidence", "lifting_weight", "labelled_weight")]
    return (*[(x.data_ptr(), x._version, tuple(x.shape), str(x.device)) for x in t], int(model.lifted_views),
            float(model.alpha0), float(model.lam), model.config.material_weights, model.viewer_settings.min_labelled)


@torch.no_grad()
def gaussian_materials(model: Any) -> GaussianMaterials:
    """The model's :class:`GaussianMaterials`, cached until its lifted tensors change (the dominance
    probabilities cost a quadrature per Gaussian: too much for every frame)."""
    key = _evidence_key(model)
    cached = getattr(model, "_viewer_materials", None)
    if cached is None or cached[0] != key:
        gm = GaussianMaterials.from_tensors(
            model.dirichlet_alpha(), model.dirichlet_evidence.sum(-1), model.gauss_params["lifting_weight"],
            model.labelled_fraction(), material_weights=model.config.material_weights,
            min_labelled=model.viewer_settings.min_labelled, lifted=bool(model.lifted_views > 0),
        )  # fmt: skip
        top = prior_std(model.material_nig(), model.log_space, model.alpha0, model.config.material_weights)
        cached = (key, gm, top)
        model._viewer_materials = cached
    return cached[1]


@torch.no_grad()
def viewer_outputs(model: Any, composited: Float[Tensor, "h w k1"], rgb: Float[Tensor, "h w 3"],
                   viewer_names: dict[str, str]) -> dict[str, Tensor]:  # fmt: skip
    """A PhysGSModel's coloured property outputs from its composited :func:`gaussian_channels`; with the
    probability view, `material` shows the chosen material's probability. Tells the viewer panel (if any)
    which scales were drawn."""
    s: ViewerSettings = model.viewer_settings
    gaussian_materials(model)
    top = model._viewer_materials[2]
    stats = pixel_statistics(composited, model.material_nig(), model.log_space, s.min_coverage)
    outs, used = display_outputs(stats, rgb, model.property_keys, viewer_names, s, top,
                                 as_std=bool(getattr(model.config, "uncertainty_as_std", True)))  # fmt: skip
    prob = outs.pop("material_probability")
    if s.material_view == "probability":
        outs["material"] = prob
    panel = getattr(model, "physical_properties", None)
    if panel is not None:
        panel.note_scales(used)
    return outs
