"""Scene-level property fusion: per material, a NIG posterior for each property (docs/architecture.md, "`bayes/`").

Observations (records of ``observations.jsonl``) of material i contribute their property values with
weight = confidence; NaN (or a missing key) means "not reported" and leaves that property's statistics
alone. Priors come from the material library (``MaterialLibrary.nig_prior``); log-space properties
(``PriorConfig.log_space``) are fused as natural logs, both for the prior and the observations.

Wall thickness (``thickness_m``, not one of the fused properties) per material: if the observations that
report it as a shell (non-null) carry at least half of the material's confidence weight, the
confidence-weighted geometric mean of their values; if observations exist but mostly say "solid" (null),
None; with no observation the library's ``thickness_m``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from ..bayes import NIG, Moments, nig_posterior
from ..materials import PROPERTY_KEYS, MaterialLibrary, PriorConfig, log_space_flags

logger = logging.getLogger(__name__)


@dataclass
class PropertyPosteriors:
    names: list[str]
    """K canonical material names; index i <-> material id i + 1 in the label maps."""
    prior: NIG
    """[K, P] in the fused space (log for log-space properties)."""
    posterior: NIG
    """[K, P] in the fused space."""
    moments: Moments
    num_observations: list[int]
    """Observation records per material."""
    weight: list[float]
    """Sum of confidences per material."""
    thickness_m: list[float | None]
    log_space: tuple[bool, ...]


def legend_names(observations: Sequence[dict], library: MaterialLibrary, mode: str = "observed") -> list[str]:
    """Materials of the legend in library order: ``observed`` (at least one observation with positive
    confidence) or ``library`` (all of them)."""
    if mode == "library":
        return list(library.names)
    if mode != "observed":
        raise ValueError(f"unknown legend mode {mode!r}; choose 'observed' or 'library'")
    seen = {o.get("material") for o in observations if _finite_pos(o.get("confidence"))}
    return [n for n in library.names if n in seen]


def _finite_pos(v) -> bool:
    try:
        return math.isfinite(float(v)) and float(v) > 0
    except (TypeError, ValueError):
        return False


def property_row(props: dict, log_space: Sequence[bool]) -> list[float]:
    """One record's ``properties`` as a row over PROPERTY_KEYS in the fused space: log for log-space
    properties; NaN where missing, not a finite number, or not positive in log space."""
    row = []
    for key, use_log in zip(PROPERTY_KEYS, log_space):
        try:
            v = float(props.get(key, math.nan))
        except (TypeError, ValueError):
            v = math.nan
        if not math.isfinite(v) or (use_log and v <= 0):
            v = math.nan
        elif use_log:
            v = math.log(v)
        row.append(v)
    return row


def observation_arrays(
    observations: Sequence[dict], names: Sequence[str], log_space: Sequence[bool]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[float | None]]:
    """classes [M] (index into names), confidence [M], values [M, P] in the fused space (NaN = missing),
    thickness per record. Records of materials outside ``names`` or with bad confidence are skipped."""
    index = {n: i for i, n in enumerate(names)}
    cls, conf, vals, thick = [], [], [], []
    skipped = 0
    for o in observations:
        i = index.get(o.get("material"))
        if i is None or not _finite_pos(o.get("confidence")):
            skipped += 1
            continue
        props = o.get("properties") or {}
        cls.append(i)
        conf.append(min(1.0, float(o["confidence"])))
        vals.append(property_row(props, log_space))
        t = props.get("thickness_m")
        thick.append(
            float(t)
            if isinstance(t, (int, float)) and not isinstance(t, bool) and math.isfinite(t) and t > 0
            else None
        )
    if skipped:
        logger.debug(
            "property fusion skipped %d records (material not in the legend or confidence <= 0)", skipped
        )
    P = len(PROPERTY_KEYS)
    return (
        np.asarray(cls, dtype=np.int64),
        np.asarray(conf, dtype=np.float64),
        np.asarray(vals, dtype=np.float64).reshape(-1, P),
        thick,
    )


def fuse_properties(
    observations: Sequence[dict],
    library: MaterialLibrary,
    names: Sequence[str] | None = None,
    prior_config: PriorConfig | None = None,
) -> PropertyPosteriors:
    """Per-material NIG posteriors [K, P] from all observations (module docstring)."""
    prior_config = prior_config or PriorConfig()
    names = list(names) if names is not None else legend_names(observations, library)
    flags = log_space_flags(prior_config)
    K, P = len(names), len(PROPERTY_KEYS)
    if K == 0:
        empty = torch.zeros(0, P, dtype=torch.float64)
        prior = NIG(empty, empty + 1, empty + 2, empty + 1)
        return PropertyPosteriors([], prior, prior, Moments(empty, empty, empty), [], [], [], flags)
    prior = library.nig_prior(names, prior_config)
    cls, conf, vals, thick = observation_arrays(observations, names, flags)
    moments = Moments.from_observations(
        torch.as_tensor(cls), torch.as_tensor(conf), torch.as_tensor(vals).reshape(-1, P), K
    )
    posterior = nig_posterior(prior, moments)
    counts = np.bincount(cls, minlength=K).tolist()
    weight = np.bincount(cls, weights=conf, minlength=K).tolist()
    thickness = _thickness(names, library, cls, conf, thick)
    return PropertyPosteriors(names, prior, posterior, moments, counts, weight, thickness, flags)


def _thickness(names, library, cls, conf, thick) -> list[float | None]:
    out: list[float | None] = []
    for i, name in enumerate(names):
        sel = np.flatnonzero(cls == i)
        if len(sel) == 0:
            out.append(library[name].thickness_m)
            continue
        shell = [(conf[j], thick[j]) for j in sel if thick[j] is not None]
        w_shell = sum(w for w, _ in shell)
        if w_shell >= 0.5 * conf[sel].sum() and w_shell > 0:
            out.append(float(math.exp(sum(w * math.log(t) for w, t in shell) / w_shell)))
        else:
            out.append(None)
    return out


def posterior_means(post: PropertyPosteriors) -> dict[str, np.ndarray]:
    """MMSE estimate per material in linear units: {key: [K]} (log-space properties exponentiated; the
    mean of the log is the median of a log-normal, which is what the fused tau estimates)."""
    tau = post.posterior.tau.detach().cpu().numpy()
    out = {}
    for p, (key, use_log) in enumerate(zip(PROPERTY_KEYS, post.log_space)):
        out[key] = np.exp(tau[:, p]) if use_log else tau[:, p]
    return out
