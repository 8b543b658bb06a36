"""Dense per-pixel material and property maps of one image from its masks and VLM observations.

Fusion over the image (docs/architecture.md, "`bayes/`", with the image as the scene and pixels as entities):

* properties: per material, one NIG posterior per property from ALL observations of the image
  (``fusion.properties.fuse_properties`` over the whole library, so unobserved materials keep their prior);
* materials: per pixel, a Dirichlet over the image's legend (the materials observed in it) whose evidence
  is the level-weighted confidence of every observation of every mask covering the pixel
  (``fusion.maps.fuse_view``: finer levels weigh more); alpha = alpha0 + lambda * evidence;
* per pixel, the mixture over materials gives the property mean and the variance split
  (``bayes.property_fields``): aleatoric, epistemic (material ambiguity included), total. The mixture
  weights are ``property_fields``' default: the posterior probability that the material is the pixel's
  DOMINANT label under its Dirichlet (``bayes.dominance_probability``), which concentrates on one material
  as evidence accumulates; the label and ``material_confidence`` stay the argmax / max of the Dirichlet
  predictive alpha / sum(alpha) (``fusion.maps.fuse_view``; the argmax of both is the same material).

A pixel is ``covered`` when some mask with a usable observation covers it. Other pixels (no mask, or only
masks whose answer was empty or rejected) carry no evidence, so they get the prior: with
``uncovered="library"`` (default) a flat Dirichlet over the WHOLE material library (the material could be
anything) with each material's posterior (observed) or prior (unobserved) property NIG, which makes their
uncertainty maximal; with ``"legend"`` a flat Dirichlet over the image's legend.

Hardness is reported on the Shore scale the user picks: each material's NIG is moved to that scale
(``nig_in_scale``: its estimate converted with ``materials.from_canonical``, its variances by the delta
method around it) before the per-pixel mixture, so the spread between materials is computed on the target
scale. (Shore hardness must not be fused in log space for this; it is not by default.)
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from ..bayes import NIG, dirichlet_posterior, property_fields
from ..fusion.maps import MapFusionConfig, fuse_view
from ..fusion.properties import PropertyPosteriors, fuse_properties, legend_names
from ..materials import PROPERTY_KEYS, MaterialLibrary, PriorConfig, from_canonical, log_space_flags

logger = logging.getLogger(__name__)

STATS = ("mean", "aleatoric", "epistemic", "total")
LOG10_STATS = ("log10_mean", "log10_aleatoric", "log10_epistemic", "log10_total")
_LN10 = math.log(10.0)
HARDNESS_SCALES = ("A", "D", "00", "A_eq")
PROPERTY_ALIASES = {
    "friction": "kinetic_friction",
    "hardness": "shore_hardness",
    "shore": "shore_hardness",
    "stiffness": "youngs_modulus",
    "young": "youngs_modulus",
    "youngs": "youngs_modulus",
    "e": "youngs_modulus",
}
LABELS = {
    "density": "density",
    "kinetic_friction": "kinetic friction",
    "shore_hardness": "Shore hardness",
    "youngs_modulus": "Young's modulus",
}

#: maps.npz keys (H x W arrays unless noted) and their meaning; ``<key>`` is a property key.
NPZ_KEYS: dict[str, str] = {
    "rgb": "uint8 [H, W, 3]: the working image (EXIF-rotated, downscaled to --max-side)",
    "material": "uint8 [H, W]: material id, index into legend_names (0 = unknown: no usable observation)",
    "material_confidence": "float32 [H, W]: predictive probability of that material (flat prior 1/L where unknown)",
    "covered": "bool [H, W]: covered by at least one mask with a usable VLM observation",
    "mask_count": "uint16 [H, W]: number of masks covering the pixel (answered or not)",
    "evidence": "float32 [H, W, K]: sum over covering observations of level weight x confidence, per legend material",
    "legend_names": "str [K + 1]: 'unknown', then the K legend materials (ids 1..K)",
    "legend_colors": "uint8 [K + 1, 3]: legend colours (row 0 = unknown)",
    "<key>_mean": "float32 [H, W]: mean of property <key> under the pixel's material mixture (weights: P(material is the pixel's dominant label)), in units[<key>]",
    "<key>_aleatoric": "float32 [H, W]: aleatoric variance (E[sigma^2] mixed over materials), units[<key>]^2",
    "<key>_epistemic": "float32 [H, W]: epistemic variance (Var[mu] + between-material spread), units[<key>]^2",
    "<key>_total": "float32 [H, W]: total variance = aleatoric + epistemic, units[<key>]^2",
    "<key>_log10_<stat>": "float32 [H, W], only for properties fused in log space (density, youngs_modulus by "
    "default): mean of log10(value) and its aleatoric / epistemic / total variance in decades^2 (the mixture "
    "in log space: an uncertainty that compares across materials of any magnitude; the figures show it)",
    "properties": "str [P]: the property keys mapped",
    "units": "str [P]: unit of each mapped property (variances are in unit^2)",
    "meta_json": "str: JSON with hardness_scale, log_space, alpha0, lambda, level_weights, uncovered prior, view",
}


def normalize_properties(names: Sequence[str]) -> tuple[str, ...]:
    """Property keys from keys or viewer names (friction, hardness, stiffness), in PROPERTY_KEYS order."""
    out = []
    for n in names:
        key = PROPERTY_ALIASES.get(n.strip().lower(), n.strip().lower())
        if key not in PROPERTY_KEYS:
            raise ValueError(f"unknown property {n!r}; choose from {', '.join(PROPERTY_KEYS)} (or friction, hardness, stiffness)")
        out.append(key)
    if not out:
        raise ValueError("map at least one property")
    return tuple(k for k in PROPERTY_KEYS if k in out)


def unit_of(key: str, hardness_scale: str) -> str:
    if key == "density":
        return "kg/m^3"
    if key == "kinetic_friction":
        return "1"
    if key == "youngs_modulus":
        return "Pa"
    if key == "shore_hardness":
        return "Shore A-equivalent (A_eq)" if hardness_scale == "A_eq" else f"Shore {hardness_scale}"
    raise KeyError(key)


@dataclass
class ImageMaps:
    """Per-pixel results of one image (see NPZ_KEYS)."""

    names: list[str]
    colors: np.ndarray
    material: np.ndarray
    confidence: np.ndarray
    covered: np.ndarray
    mask_count: np.ndarray
    evidence: np.ndarray
    properties: tuple[str, ...]
    fields: dict[str, dict[str, np.ndarray]]
    units: dict[str, str]
    hardness_scale: str
    log_space: dict[str, bool]
    per_material: list[dict] = field(default_factory=list)
    unknown: dict[str, dict[str, float]] = field(default_factory=dict)
    """Mean and variances of an uncovered pixel (the prior), per property."""
    uncovered_prior: str = "library"

    @property
    def shape(self) -> tuple[int, int]:
        return self.material.shape  # type: ignore[return-value]


def nig_in_scale(nig: NIG, scale: str) -> NIG:
    """The NIG [K, P] with its shore_hardness column moved from A_eq to Shore ``scale``, per material:
    tau -> f(tau) and b -> b f'(tau)^2 (so aleatoric and epistemic scale by the squared local slope of the
    piecewise-linear conversion f, the delta method around each material's own estimate). Mixing then
    happens on the target scale, so the spread between materials is exact there."""
    if scale == "A_eq":
        return nig
    p = PROPERTY_KEYS.index("shore_hardness")
    tau = nig.tau[:, p].detach().cpu().double().numpy()
    d = 0.01
    slope = (np.asarray(from_canonical(tau + d, scale)) - np.asarray(from_canonical(tau - d, scale))) / (2 * d)
    new_tau, new_b = nig.tau.clone(), nig.b.clone()
    new_tau[:, p] = torch.as_tensor(np.asarray(from_canonical(tau, scale)), dtype=nig.tau.dtype)
    new_b[:, p] = nig.b[:, p] * torch.as_tensor(slope * slope, dtype=nig.b.dtype)
    return NIG(new_tau, nig.kappa, nig.a, new_b)


def _fields(alpha: torch.Tensor, nig: NIG, flags: Sequence[bool], hardness_scale: str) -> dict[str, torch.Tensor]:
    """Linear-unit mean and variance split [N, P] (STATS), plus for every property the same moments of
    log10(value) (LOG10_STATS: the mixture taken in the fused log space; meaningful for the log-space
    properties only, where an uncertainty in decades compares across materials of any magnitude)."""
    nig = nig_in_scale(nig, hardness_scale)
    out = dict(property_fields(alpha, nig, flags))
    logs = property_fields(alpha, nig, [False] * len(flags))  # moments of ln(value) for log-space columns
    out["log10_mean"] = logs["mean"] / _LN10
    for s in ("aleatoric", "epistemic", "total"):
        out[f"log10_{s}"] = logs[s] / _LN10**2
    return out


def _stat_dict(fields: dict[str, torch.Tensor], key: str, flags: Sequence[bool]) -> dict[str, float]:
    p = PROPERTY_KEYS.index(key)
    return {s: float(fields[s][0, p]) for s in STATS + (LOG10_STATS if flags[p] else ())}


def _nig_json(nig: NIG, i: int) -> dict[str, dict[str, float]]:
    return {key: {f: float(getattr(nig, f)[i, p]) for f in ("tau", "kappa", "a", "b")} for p, key in enumerate(PROPERTY_KEYS)}


def usable_records(records: Sequence[dict], names: Sequence[str], num_masks: int) -> tuple[list[int], list[int], list[float]]:
    """(mask ids, legend indices, confidences) of the records that can carry evidence."""
    index = {n: i for i, n in enumerate(names)}
    om, oc, op = [], [], []
    stale = 0
    for r in records:
        k = index.get(r.get("material"))
        try:
            p, m = float(r.get("confidence")), int(r.get("mask_id"))
        except (TypeError, ValueError):
            continue
        if k is None or not (0 < p <= 1):
            continue
        if not 0 <= m < num_masks:
            stale += 1
            continue
        om.append(m)
        oc.append(k)
        op.append(p)
    if stale:
        logger.warning("%d observations name masks that do not exist (stale workspace?); ignored", stale)
    return om, oc, op


def compute_image_maps(
    masks: np.ndarray,
    levels: Sequence[str],
    records: Sequence[dict],
    library: MaterialLibrary,
    *,
    properties: Sequence[str] = PROPERTY_KEYS,
    hardness_scale: str = "D",
    map_config: MapFusionConfig | None = None,
    prior_config: PriorConfig | None = None,
    legend: Literal["observed", "library"] = "observed",
    uncovered: Literal["library", "legend"] = "library",
) -> ImageMaps:
    """masks: bool [M, H, W] with their levels; records: the image's observations (observations.jsonl)."""
    map_config = map_config or MapFusionConfig()
    prior_config = prior_config or PriorConfig()
    if hardness_scale not in HARDNESS_SCALES:
        raise ValueError(f"unknown hardness scale {hardness_scale!r}; choose one of {', '.join(HARDNESS_SCALES)}")
    properties = normalize_properties(properties)
    masks = np.asarray(masks, dtype=bool)
    if masks.ndim != 3:
        raise ValueError(f"masks must be [M, H, W], got {masks.shape}")
    M, H, W = masks.shape
    names = legend_names(records, library, legend)
    K, L = len(names), len(library.names)
    post: PropertyPosteriors = fuse_properties(records, library, library.names, prior_config)
    flags = log_space_flags(prior_config)
    if flags[PROPERTY_KEYS.index("shore_hardness")] and hardness_scale != "A_eq":
        raise ValueError("shore_hardness fused in log space can only be reported as A_eq; set --hardness-scale A_eq")
    lidx = torch.as_tensor([library.index(n) for n in names], dtype=torch.long)
    om, oc, op = usable_records(records, names, M)
    vm = fuse_view(masks, list(levels), om, oc, op, K, map_config)
    evidence = vm.evidence.reshape(H * W, K)
    covered = evidence.sum(-1) > 0 if K else np.zeros(H * W, bool)

    # the prior of an uncovered pixel: flat Dirichlet over the library (or the legend)
    if uncovered == "legend" and K > 0:
        u_alpha, u_nig, u_conf = torch.full((1, K), float(map_config.alpha0), dtype=torch.float64), post.posterior[lidx], 1.0 / K
    elif uncovered in ("library", "legend"):
        u_alpha, u_nig, u_conf = torch.full((1, L), float(map_config.alpha0), dtype=torch.float64), post.posterior, 1.0 / L
    else:
        raise ValueError(f"unknown uncovered prior {uncovered!r}; choose 'library' or 'legend'")
    u_fields = _fields(u_alpha, u_nig, flags, hardness_scale)
    full = {s: u_fields[s].expand(H * W, -1).clone() for s in STATS + LOG10_STATS}
    if covered.any():
        alpha = dirichlet_posterior(torch.from_numpy(evidence[covered].astype(np.float64)), float(map_config.alpha0), float(map_config.lam))
        c_fields = _fields(alpha, post.posterior[lidx], flags, hardness_scale)
        sel = torch.from_numpy(covered)
        for s in STATS + LOG10_STATS:
            full[s][sel] = c_fields[s]

    fields = {}
    for key in properties:
        p = PROPERTY_KEYS.index(key)
        stats = STATS + (LOG10_STATS if flags[p] else ())
        fields[key] = {s: full[s][:, p].reshape(H, W).numpy().astype(np.float32) for s in stats}
    cov2 = covered.reshape(H, W)
    material = np.where(cov2, vm.labels, 0).astype(np.uint8)
    confidence = np.where(cov2, vm.confidence, np.float32(u_conf)).astype(np.float32)
    colors = np.concatenate([np.full((1, 3), 40, np.uint8), np.asarray([library[n].color for n in names], np.uint8).reshape(-1, 3)])

    per_material = []
    counts = np.bincount(material.reshape(-1), minlength=K + 1)
    for i, name in enumerate(names):
        li = int(lidx[i])
        one = _fields(torch.ones(1, 1, dtype=torch.float64), post.posterior[[li]], flags, hardness_scale)
        per_material.append(
            {
                "id": i + 1,
                "name": name,
                "color": [int(c) for c in library[name].color],
                "pixels": int(counts[i + 1]),
                "pixel_fraction": float(counts[i + 1] / (H * W)),
                "num_observations": int(post.num_observations[li]),
                "observation_weight": float(post.weight[li]),
                "estimate": {key: _stat_dict(one, key, flags) for key in properties},
                "posterior": _nig_json(post.posterior, li),
                "prior": _nig_json(post.prior, li),
            }
        )
    unknown = {key: _stat_dict(u_fields, key, flags) for key in properties}
    return ImageMaps(
        names=names,
        colors=colors,
        material=material,
        confidence=confidence,
        covered=cov2,
        mask_count=masks.sum(0).astype(np.uint16) if M else np.zeros((H, W), np.uint16),
        evidence=vm.evidence.astype(np.float32),
        properties=properties,
        fields=fields,
        units={k: unit_of(k, hardness_scale) for k in properties},
        hardness_scale=hardness_scale,
        log_space={k: bool(f) for k, f in zip(PROPERTY_KEYS, flags)},
        per_material=per_material,
        unknown=unknown,
        uncovered_prior=uncovered if (uncovered == "library" or K > 0) else "library",
    )


def save_npz(path: Path, maps: ImageMaps, rgb: np.ndarray, meta: dict) -> Path:
    """Write maps.npz (compressed; keys in NPZ_KEYS) atomically."""
    import json
    import os

    arrays: dict[str, np.ndarray] = {
        "rgb": np.asarray(rgb, np.uint8),
        "material": maps.material,
        "material_confidence": maps.confidence,
        "covered": maps.covered,
        "mask_count": maps.mask_count,
        "evidence": maps.evidence,
        "legend_names": np.asarray(["unknown", *maps.names]),
        "legend_colors": maps.colors,
        "properties": np.asarray(list(maps.properties)),
        "units": np.asarray([maps.units[k] for k in maps.properties]),
        "meta_json": np.asarray(json.dumps(meta, sort_keys=True)),
    }
    for key, stats in maps.fields.items():
        for s, arr in stats.items():
            arrays[f"{key}_{s}"] = arr
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp.npz")
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, path)
    return path


def finite_summary(arr: np.ndarray, where: np.ndarray | None = None) -> dict[str, float]:
    """min / median / mean / max of the finite values (optionally inside a mask)."""
    v = arr[where] if where is not None else arr.reshape(-1)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"min": math.nan, "median": math.nan, "mean": math.nan, "max": math.nan}
    return {"min": float(v.min()), "median": float(np.median(v)), "mean": float(v.mean()), "max": float(v.max())}
