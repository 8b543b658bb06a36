"""Dirichlet-Categorical fusion of material observations (paper eq. dirichlet_update, supplement A.2).

Per entity e (a Gaussian, a region, a pixel) the material belief is Dirichlet(alpha_e) with

    alpha_e = alpha0 + lambda * sum_m w_em * p_m * onehot(c_m),

where c_m is the class of observation m, p_m in [0, 1] its confidence and w_em >= 0 how much observation m
concerns entity e (1 for the region itself, a rendering weight for a Gaussian). The posterior predictive
of the class is pi_e = alpha_e / sum_k alpha_ek.

All functions are batched over any leading dimensions; the class dimension is the last one.
"""

from __future__ import annotations

import torch
from jaxtyping import Float, Int
from torch import Tensor

from ._checks import (
    as_float_tensor,
    check_class_indices,
    check_finite,
    check_nonnegative,
    check_positive,
    raise_if,
    result_dtype,
)

__all__ = [
    "dirichlet_posterior",
    "dirichlet_strength",
    "evidence_from_observations",
    "expected_entropy",
    "mutual_information",
    "predictive",
    "predictive_entropy",
    "vacuity",
]


def evidence_from_observations(
    classes: Int[Tensor, "m"],  # noqa: F821, UP037
    confidence: Float[Tensor, "m"],  # noqa: F821, UP037
    num_classes: int,
    weights: Float[Tensor, "e m"] | Float[Tensor, "m"] | None = None,  # noqa: F821, UP037
) -> Float[Tensor, "e k"] | Float[Tensor, "k"]:  # noqa: F821, UP037
    """Confidence-weighted class evidence ``sum_m w_em p_m onehot(c_m)``.

    Args:
        classes: ``[M]`` integer class ids in ``[0, num_classes)``.
        confidence: ``[M]`` VLM confidences p_m in ``[0, 1]``.
        num_classes: K.
        weights: optional ``[E, M]`` per-entity weights w_em >= 0 (or ``[M]`` for one entity).

    Returns:
        ``[E, K]`` evidence if ``weights`` is 2-D; ``[K]`` if ``weights`` is ``None`` (every observation
        concerns the single entity with weight 1) or 1-D. Dtype: the floating dtype of
        ``confidence``/``weights`` (default dtype for integer inputs).
    """
    where = "evidence_from_observations"
    classes_t = torch.as_tensor(classes)
    classes_t = check_class_indices(classes_t, num_classes, where=f"{where}(classes)")
    dtype = result_dtype(confidence, weights)
    conf = as_float_tensor(confidence, dtype=dtype).to(classes_t.device)
    if conf.shape != classes_t.shape:
        raise ValueError(
            f"{where}: confidence has shape {tuple(conf.shape)} but classes has {tuple(classes_t.shape)}; "
            "pass one confidence per observation."
        )
    check_finite(conf, where=f"{where}(confidence)")
    raise_if(
        (conf < 0) | (conf > 1),
        conf,
        where=f"{where}(confidence)",
        what="confidence outside [0, 1]",
        fix="VLM confidences must be probabilities; clip or renormalise them before fusion.",
    )
    if weights is None:
        out = torch.zeros(num_classes, dtype=dtype, device=conf.device)
        return out.index_add_(0, classes_t, conf)
    w = as_float_tensor(weights, dtype=dtype).to(conf.device)
    if w.dim() not in (1, 2) or w.shape[-1] != conf.shape[0]:
        raise ValueError(
            f"{where}: weights must have shape [E, M] or [M] with M={conf.shape[0]}, got {tuple(w.shape)}."
        )
    check_nonnegative(w, where=f"{where}(weights)", fix="Entity weights w_em must be >= 0.")
    contrib = w * conf
    out = torch.zeros(*w.shape[:-1], num_classes, dtype=dtype, device=conf.device)
    return out.index_add_(out.dim() - 1, classes_t, contrib)


def dirichlet_posterior(
    evidence: Float[Tensor, "... k"], alpha0: float | Tensor, lam: float
) -> Float[Tensor, "... k"]:
    """Posterior concentration ``alpha = alpha0 + lam * evidence``.

    Args:
        evidence: ``[..., K]`` non-negative evidence (see :func:`evidence_from_observations`).
        alpha0: prior concentration, scalar or broadcastable to ``[..., K]`` (e.g. ``[K]``), all > 0.
        lam: evidence strength lambda >= 0.
    """
    where = "dirichlet_posterior"
    ev = as_float_tensor(evidence)
    check_nonnegative(ev, where=f"{where}(evidence)", fix="Evidence is a sum of weights x confidences, >= 0.")
    a0 = as_float_tensor(alpha0, like=ev)
    check_positive(a0, where=f"{where}(alpha0)", fix="The Dirichlet prior needs alpha0 > 0 (e.g. 1.0).")
    lam_t = as_float_tensor(lam, like=ev)
    check_nonnegative(lam_t, where=f"{where}(lam)", fix="lambda scales evidence and must be >= 0.")
    return a0 + lam_t * ev


def _check_alpha(alpha: Tensor, where: str) -> Tensor:
    alpha = as_float_tensor(alpha)
    if alpha.dim() < 1:
        raise ValueError(f"{where}: alpha must have a class dimension [..., K], got a scalar.")
    check_positive(alpha, where=f"{where}(alpha)", fix="Dirichlet concentrations must be > 0 and finite.")
    return alpha


def predictive(alpha: Float[Tensor, "... k"]) -> Float[Tensor, "... k"]:
    """Posterior predictive class probabilities ``pi = alpha / sum(alpha)`` (paper eq. posterior_class)."""
    alpha = _check_alpha(alpha, "predictive")
    return alpha / alpha.sum(-1, keepdim=True)


def dirichlet_strength(alpha: Float[Tensor, "... k"]) -> Float[Tensor, ...]:
    """Dirichlet strength ``S = sum_k alpha_k`` (total pseudo-count)."""
    return _check_alpha(alpha, "dirichlet_strength").sum(-1)


def vacuity(alpha: Float[Tensor, "... k"]) -> Float[Tensor, ...]:
    """Subjective-logic vacuity ``K / S`` in (0, 1]: 1 under a uniform unit prior, -> 0 with evidence."""
    alpha = _check_alpha(alpha, "vacuity")
    return alpha.shape[-1] / alpha.sum(-1)


def predictive_entropy(alpha: Float[Tensor, "... k"]) -> Float[Tensor, ...]:
    """Entropy (nats) of the predictive categorical ``H[pi]`` (total material uncertainty)."""
    pi = predictive(alpha)
    return -(pi * torch.log(pi)).sum(-1)


def expected_entropy(alpha: Float[Tensor, "... k"]) -> Float[Tensor, ...]:
    """``E_{theta ~ Dir(alpha)} H[Cat(theta)] = -sum_k (alpha_k/S) (digamma(alpha_k+1) - digamma(S+1))``.

    The aleatoric part of the material uncertainty.
    """
    alpha = _check_alpha(alpha, "expected_entropy")
    s = alpha.sum(-1, keepdim=True)
    return -((alpha / s) * (torch.digamma(alpha + 1) - torch.digamma(s + 1))).sum(-1)


def mutual_information(alpha: Float[Tensor, "... k"]) -> Float[Tensor, ...]:
    """Mutual information between class and theta, ``H[pi] - E H[Cat(theta)]`` >= 0 (epistemic part)."""
    return (predictive_entropy(alpha) - expected_entropy(alpha)).clamp_min(0)
