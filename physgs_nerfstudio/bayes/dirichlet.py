"""Dirichlet-Categorical fusion of material observations (paper eq. dirichlet_update, supplement A.2).

Per entity e (a Gaussian, a region, a pixel) the material belief is Dirichlet(alpha_e) with

    alpha_e = alpha0 + lambda * sum_m w_em * p_m * onehot(c_m),

where c_m is the class of observation m, p_m in [0, 1] its confidence and w_em >= 0 how much observation m
concerns entity e (1 for the region itself, a rendering weight for a Gaussian). The posterior predictive
of the class is pi_e = alpha_e / sum_k alpha_ek. :func:`dominance_probability` is the posterior probability
that class i is the entity's DOMINANT class (its most frequent label, theta_i = max_j theta_j); unlike pi it
concentrates on one class as evidence accumulates.

All functions are batched over any leading dimensions; the class dimension is the last one.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
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
    "dominance_probability",
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


# ---------------------------------------------------------------------------------------------------------
# dominance probability P(theta_i = max_j theta_j | alpha)
# ---------------------------------------------------------------------------------------------------------


@lru_cache(maxsize=16)
def _gauss_legendre(n: int) -> tuple[np.ndarray, np.ndarray]:
    z, w = np.polynomial.legendre.leggauss(n)
    return z, w


def _gamma_tail_log_ratio(r: Tensor, upper: bool, iters: int = 60) -> Tensor:
    """Root s of ``exp(s) - 1 - s = r`` (r > 0) with s > 0 (``upper``) or s < 0.

    The Chernoff bound of G ~ Gamma(a, 1) is P(G <= x) resp. P(G >= x) <= exp(-a (e^s - 1 - s)) with
    s = log(x / a) on the matching side of 0, so x = a e^s with r = L / a bounds that tail by e^-L. h(s) =
    e^s - 1 - s is convex, so Newton from a start with h(s0) >= r converges monotonically.
    """
    if upper:  # h(s) >= s^2/2 and h(log1p(2r)) = 2r - log1p(2r) >= r for r >= 1.26
        s = torch.maximum(torch.sqrt(2 * r), torch.log1p(2 * r))
    else:  # h(-1 - r) = e^(-1-r) + r > r
        s = -1 - r
    for _ in range(iters):
        step = (torch.expm1(s) - s - r) / torch.expm1(s)
        step = torch.where(torch.isfinite(step), step, torch.zeros_like(step))
        s = s - step
        if bool((step.abs() <= 1e-12 * (1 + s.abs())).all()):
            break
    return s


def _dominance_chunk(alpha: Tensor, z: Tensor, w: Tensor, log_tail: float) -> Tensor:
    """[n, K] float64 alpha -> [n, K] unnormalised dominance integrals (see :func:`dominance_probability`)."""
    a_max = alpha.amax(-1)  # [n]
    r = log_tail / a_max
    log_a = torch.log(a_max)
    t_hi = log_a + _gamma_tail_log_ratio(r, upper=True)
    t_lo = log_a + _gamma_tail_log_ratio(r, upper=False)
    # P(max_j G_j < x) = prod_j F_j(x) <= prod_j x^a_j / Gamma(a_j + 1): a second lower bound, much tighter
    # than the largest class's own when all concentrations are small
    a_sum = alpha.sum(-1)
    t_prod = (torch.lgamma(alpha + 1).sum(-1) - log_tail) / a_sum
    t_lo = torch.maximum(t_lo, t_prod)
    t_hi = torch.maximum(t_hi, t_lo + 1e-6)
    half = 0.5 * (t_hi - t_lo)
    t = (0.5 * (t_hi + t_lo)).unsqueeze(-1) + half.unsqueeze(-1) * z  # [n, Q]
    x = torch.exp(t)
    a3 = alpha.unsqueeze(-1)  # [n, K, 1]
    log_f = torch.log(torch.special.gammainc(a3, x.unsqueeze(1))).clamp_min(-1e4)  # [n, K, Q]
    log_g = a3 * t.unsqueeze(1) - x.unsqueeze(1) - torch.lgamma(a3)  # log density of log G_i at t
    log_int = log_g + log_f.sum(1, keepdim=True) - log_f
    return (torch.exp(log_int) * w).sum(-1) * half.unsqueeze(-1)


def _unique_rows(flat: Tensor) -> tuple[Tensor, Tensor] | None:
    """``torch.unique(flat, dim=0, return_inverse=True)`` of float64 rows [N, K], or None when the distinct rows are
    more than 3/4 of them (little to gain). The rows are told apart first by a hash of their bits (a sort of N
    integers, where ``unique(dim=0)`` sorts N rows: 0.4 s at N = 650k, K = 3 on a CPU); only the distinct rows are
    then sorted as ``unique`` sorts them. Rows that share a hash but differ (a collision, checked) take the direct
    way."""
    bits = flat.contiguous().view(torch.int64)
    key = bits[:, 0].clone()
    for k in range(1, bits.shape[1]):
        key = (key * 1000003) ^ bits[:, k]
    keys, inverse = torch.unique(key, return_inverse=True)
    if keys.shape[0] * 4 > flat.shape[0] * 3:
        return None  # (a collision only lowers the count; the direct way would not go on either)
    first = torch.empty(keys.shape[0], dtype=torch.long, device=flat.device)
    first.scatter_(0, inverse, torch.arange(flat.shape[0], device=flat.device))
    rows = flat[first]
    if not bool((rows[inverse] == flat).all()):  # a collision: two different rows share a hash
        uniq, inv = torch.unique(flat, dim=0, return_inverse=True)
        return None if uniq.shape[0] * 4 > flat.shape[0] * 3 else (uniq, inv)
    uniq, order = torch.unique(rows, dim=0, return_inverse=True)  # the distinct rows, in unique's order
    return uniq, order[inverse]


def dominance_probability(
    alpha: Float[Tensor, "... k"],
    *,
    num_nodes: int = 64,
    tail: float = 1e-14,
    chunk_elements: int = 1 << 21,
) -> Float[Tensor, "... k"]:
    """Posterior probability that class i is the DOMINANT class: ``P(theta_i = max_j theta_j)``,
    theta ~ Dir(alpha).

    theta is the entity's label distribution (the frequencies with which observations of it would report
    each class), so this is the posterior of "the entity's material is i" read as "i is its most frequent
    label". The predictive ``alpha / sum(alpha)`` instead converges to the average label split: an entity
    whose observations say 60% ceramic / 40% porcelain keeps pi = (0.6, 0.4) however many observations
    arrive, while the dominance probability goes to (1, 0) (the epistemic part vanishes); with balanced
    evidence (alpha_i = alpha_j) it stays split equally. Symmetric alpha gives exactly 1/K.

    Computation (deterministic, vectorised): with theta_i = G_i / sum G, G_i ~ Gamma(alpha_i, 1)
    independent, ``P_i = int f_i(x) prod_{j != i} F_j(x) dx`` (f, F the Gamma(alpha, 1) density and
    regularised lower incomplete gamma ``torch.special.gammainc``). The integral is taken in t = log x by
    ``num_nodes``-point Gauss-Legendre quadrature on a per-entity window that holds all but ``~K * tail``
    of the law of max_j G_j: its ends are the Chernoff bounds of the largest-alpha Gamma (the largest-alpha
    class stochastically dominates the others, so max_j G_j rarely leaves its range), tightened below by
    ``P(max G < x) <= prod_j x^alpha_j / Gamma(alpha_j + 1)``. The integrals are normalised to sum to 1.
    Internally float64; the result has alpha's dtype. Accuracy (tests): <= ~1e-6 absolute against a
    2048-node reference for alpha in [0.05, 1e4]; coarser (~1e-3) when every alpha is well below 1 (the
    window then spans tens of e-folds).

    Cost: ``N * K * num_nodes`` incomplete-gamma evaluations (~0.17 us each in float64 on one CPU core:
    N = 1e6, K = 20 took 3 to 6 minutes), in chunks of about ``chunk_elements`` of them (memory ~ 6 x 8 bytes
    x chunk_elements). Rows of alpha that repeat exactly (pixels covered by the same masks) are computed once.

    Args:
        alpha: ``[..., K]`` concentrations > 0.
        num_nodes: quadrature nodes per entity.
        tail: probability mass of max G allowed outside the window (per class).
        chunk_elements: entities per chunk x K x num_nodes.

    Returns:
        ``[..., K]`` probabilities summing to 1 over the class axis, in alpha's dtype.
    """
    alpha = _check_alpha(alpha, "dominance_probability")
    if num_nodes < 2:
        raise ValueError(f"dominance_probability: num_nodes must be >= 2, got {num_nodes}.")
    if not 0 < tail < 1:
        raise ValueError(f"dominance_probability: tail must be in (0, 1), got {tail}.")
    shape = alpha.shape
    K = shape[-1]
    if K == 1:
        return torch.ones_like(alpha)
    flat = alpha.reshape(-1, K).to(torch.float64)
    inverse = None
    if flat.shape[0] > 1:  # entities with identical alpha (pixels under the same masks) are computed once
        found = _unique_rows(flat)
        if found is not None:
            flat, inverse = found
    n = flat.shape[0]
    zq, wq = _gauss_legendre(int(num_nodes))
    z = torch.as_tensor(zq, dtype=torch.float64, device=alpha.device)
    w = torch.as_tensor(wq, dtype=torch.float64, device=alpha.device)
    log_tail = -math.log(tail)
    rows = max(1, int(chunk_elements) // (K * int(num_nodes)))
    out = torch.empty_like(flat)
    for start in range(0, n, rows):
        a = flat[start : start + rows]
        p = _dominance_chunk(a, z, w, log_tail)
        total = p.sum(-1, keepdim=True)
        ok = torch.isfinite(total) & (total > 0)
        out[start : start + rows] = torch.where(ok, p / torch.where(ok, total, torch.ones_like(total)),
                                                a / a.sum(-1, keepdim=True))
    if inverse is not None:
        out = out[inverse]
    return out.reshape(shape).to(alpha.dtype)
