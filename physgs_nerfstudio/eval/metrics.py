"""Evaluation metrics: the paper's point metrics and calibration of the predictive distributions.

Point metrics (paper sec. 4, m = ground truth, m_hat = estimate; all per item, aggregate = mean):
    ADE   |m - m_hat|                    ALDE  |ln m - ln m_hat|
    APE   |m - m_hat| / m                MnRE  min(m / m_hat, m_hat / m)   (higher is better)

Calibration of per-item Gaussian mixtures (weights, means, stds, each [n, K]; 1-D [n] = one Gaussian):
central-interval coverage (via the PIT), negative log-likelihood, CRPS (closed form for a Gaussian,
exact pairwise formula for a mixture, empirical formula for Monte Carlo samples).

Inputs may be numpy arrays, torch tensors (detached, moved to CPU), sequences or scalars; outputs are
numpy float64 arrays (per item) or floats (aggregates). Self-contained: numpy + scipy only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from scipy import special

__all__ = [
    "POINT_METRICS",
    "ade",
    "alde",
    "ape",
    "central_coverage",
    "coverage_curve",
    "crps_gaussian",
    "crps_mixture",
    "crps_samples",
    "gaussian_mixture_nll",
    "interval_coverage",
    "mixture_cdf",
    "mnre",
    "pit",
    "point_metrics",
    "summarize",
]


def _arr(x: Any, name: str, where: str) -> np.ndarray:
    if hasattr(x, "detach") and hasattr(x, "cpu"):  # torch tensor, without importing torch
        x = x.detach().cpu().numpy()
    a = np.asarray(x, dtype=np.float64)
    bad = ~np.isfinite(a)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ValueError(
            f"{where}: non-finite {name} at index {idx if len(idx) != 1 else idx[0]} (value {a[bad].flat[0]!r};"
            f" {int(bad.sum())} offending). Drop or repair those items before evaluating."
        )
    return a


def _check_positive(a: np.ndarray, name: str, where: str, why: str) -> None:
    bad = a <= 0
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ValueError(
            f"{where}: {name} must be > 0 ({why}), got {a[bad].flat[0]!r} at index "
            f"{idx if len(idx) != 1 else idx[0]} ({int(bad.sum())} offending). "
            "Log/ratio metrics are defined for positive quantities only (mass, friction, hardness, modulus)."
        )


def _pair(target: Any, pred: Any, where: str, positive_target: bool, positive_pred: bool):
    t = _arr(target, "target", where)
    p = _arr(pred, "pred", where)
    try:
        t, p = np.broadcast_arrays(t, p)
    except ValueError as err:
        raise ValueError(f"{where}: target shape {t.shape} and pred shape {p.shape} do not match.") from err
    if positive_target:
        _check_positive(t, "target", where, f"{where} divides by or takes the log of it")
    if positive_pred:
        _check_positive(p, "pred", where, f"{where} divides by or takes the log of it")
    return t, p


def ade(target: Any, pred: Any) -> np.ndarray:
    """Absolute difference error |m - m_hat| per item."""
    t, p = _pair(target, pred, "ade", False, False)
    return np.abs(t - p)


def alde(target: Any, pred: Any) -> np.ndarray:
    """Absolute log difference error |ln m - ln m_hat| per item (both must be > 0)."""
    t, p = _pair(target, pred, "alde", True, True)
    return np.abs(np.log(t) - np.log(p))


def ape(target: Any, pred: Any) -> np.ndarray:
    """Absolute percentage error |(m - m_hat) / m| per item (target must be > 0), as a fraction."""
    t, p = _pair(target, pred, "ape", True, False)
    return np.abs((t - p) / t)


def mnre(target: Any, pred: Any) -> np.ndarray:
    """Minimum ratio error min(m / m_hat, m_hat / m) per item, in (0, 1], higher is better (both > 0)."""
    t, p = _pair(target, pred, "mnre", True, True)
    return np.minimum(t / p, p / t)


POINT_METRICS = {"ADE": ade, "ALDE": alde, "APE": ape, "MnRE": mnre}


def point_metrics(target: Any, pred: Any, names: Sequence[str] = tuple(POINT_METRICS)) -> dict[str, np.ndarray]:
    """Per-item arrays of the requested point metrics (default all four)."""
    unknown = [n for n in names if n not in POINT_METRICS]
    if unknown:
        raise ValueError(f"point_metrics: unknown metric(s) {unknown}; choose from {list(POINT_METRICS)}.")
    return {n: POINT_METRICS[n](target, pred) for n in names}


# ---------------------------------------------------------------------------------------------------
# calibration
# ---------------------------------------------------------------------------------------------------
def interval_coverage(target: Any, lo: Any, hi: Any) -> np.ndarray:
    """Per item: does [lo, hi] contain the target (bool array)."""
    t = _arr(target, "target", "interval_coverage")
    lo_a = _arr(lo, "lo", "interval_coverage")
    hi_a = _arr(hi, "hi", "interval_coverage")
    t, lo_a, hi_a = np.broadcast_arrays(t, lo_a, hi_a)
    bad = lo_a > hi_a
    if bad.any():
        i = int(np.argwhere(bad.reshape(-1))[0, 0])
        raise ValueError(f"interval_coverage: lo > hi at item {i} ({lo_a.flat[i]} > {hi_a.flat[i]}).")
    return (t >= lo_a) & (t <= hi_a)


def _mixture(weights: Any, means: Any, stds: Any, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    mu = _arr(means, "means", where)
    sd = _arr(stds, "stds", where)
    w = np.ones_like(mu) if weights is None else _arr(weights, "weights", where)
    w, mu, sd = np.broadcast_arrays(w, mu, sd)
    if mu.ndim == 1:  # one Gaussian per item
        w, mu, sd = w[:, None], mu[:, None], sd[:, None]
    elif mu.ndim == 0:
        w, mu, sd = w.reshape(1, 1), mu.reshape(1, 1), sd.reshape(1, 1)
    if mu.ndim != 2:
        raise ValueError(f"{where}: mixture arrays must be [n, K] (or [n] for one Gaussian), got {mu.shape}.")
    _check_positive(sd, "stds", where, "component standard deviations")
    if (w < 0).any():
        i = tuple(int(j) for j in np.argwhere(w < 0)[0])
        raise ValueError(f"{where}: negative mixture weight at {i}; weights must be >= 0.")
    tot = w.sum(-1, keepdims=True)
    if (tot <= 0).any():
        i = int(np.argwhere(tot[:, 0] <= 0)[0, 0])
        raise ValueError(f"{where}: mixture weights of item {i} sum to 0.")
    return w / tot, mu, sd


def _target_for(target: Any, n: int, where: str) -> np.ndarray:
    t = _arr(target, "target", where).reshape(-1)
    if t.shape[0] == 1 and n != 1:
        t = np.broadcast_to(t, (n,))
    if t.shape[0] != n:
        raise ValueError(f"{where}: {t.shape[0]} targets but {n} predictive distributions.")
    return t


def mixture_cdf(target: Any, weights: Any, means: Any, stds: Any) -> np.ndarray:
    """Per-item CDF of the Gaussian mixture at the target."""
    w, mu, sd = _mixture(weights, means, stds, "mixture_cdf")
    t = _target_for(target, mu.shape[0], "mixture_cdf")
    return (w * special.ndtr((t[:, None] - mu) / sd)).sum(-1)


pit = mixture_cdf  # probability integral transform: uniform on [0, 1] for a calibrated model


def central_coverage(target: Any, weights: Any, means: Any, stds: Any, level: float = 0.9) -> np.ndarray:
    """Per item: is the target inside the central ``level`` interval of its mixture (|PIT - 1/2| <= level/2)."""
    if not 0 < level < 1:
        raise ValueError(f"central_coverage: level must be in (0, 1), got {level}.")
    u = mixture_cdf(target, weights, means, stds)
    return np.abs(u - 0.5) <= level / 2


def coverage_curve(
    target: Any, weights: Any, means: Any, stds: Any, levels: Sequence[float] = (0.5, 0.8, 0.9, 0.95)
) -> dict[float, float]:
    """Observed coverage fraction for each nominal central-interval level (reliability diagram data)."""
    u = mixture_cdf(target, weights, means, stds)
    return {float(lv): float(np.mean(np.abs(u - 0.5) <= lv / 2)) for lv in levels}


def gaussian_mixture_nll(target: Any, weights: Any, means: Any, stds: Any) -> np.ndarray:
    """Per-item negative log-likelihood -log sum_k w_k N(y | mu_k, sd_k^2) (logsumexp)."""
    w, mu, sd = _mixture(weights, means, stds, "gaussian_mixture_nll")
    t = _target_for(target, mu.shape[0], "gaussian_mixture_nll")
    z = (t[:, None] - mu) / sd
    with np.errstate(divide="ignore"):
        logw = np.log(w)
    lp = logw - 0.5 * z * z - np.log(sd) - 0.5 * math.log(2 * math.pi)
    return -special.logsumexp(lp, axis=-1)


def _a_fn(mu: np.ndarray, var: np.ndarray) -> np.ndarray:
    """E|X| for X ~ N(mu, var): mu (2 Phi(mu/s) - 1) + 2 s phi(mu/s)."""
    s = np.sqrt(var)
    z = mu / s
    return mu * (2 * special.ndtr(z) - 1) + 2 * s * np.exp(-0.5 * z * z) / math.sqrt(2 * math.pi)


def crps_gaussian(target: Any, mean: Any, std: Any) -> np.ndarray:
    """Closed-form CRPS of N(mean, std^2) at the target: std [z (2 Phi(z) - 1) + 2 phi(z) - 1/sqrt(pi)]."""
    t = _arr(target, "target", "crps_gaussian")
    mu = _arr(mean, "mean", "crps_gaussian")
    sd = _arr(std, "std", "crps_gaussian")
    t, mu, sd = np.broadcast_arrays(t, mu, sd)
    _check_positive(sd, "std", "crps_gaussian", "standard deviation")
    z = (t - mu) / sd
    return sd * (z * (2 * special.ndtr(z) - 1) + 2 * np.exp(-0.5 * z * z) / math.sqrt(2 * math.pi) - 1 / math.sqrt(math.pi))


def crps_mixture(target: Any, weights: Any, means: Any, stds: Any) -> np.ndarray:
    """Exact CRPS of a Gaussian mixture: E|X - y| - E|X - X'| / 2, with E|N(m, v)| in closed form.

    sum_i w_i A(y - mu_i, s_i^2) - 1/2 sum_ij w_i w_j A(mu_i - mu_j, s_i^2 + s_j^2), A(m, v) = E|N(m, v)|.
    O(n K^2).
    """
    w, mu, sd = _mixture(weights, means, stds, "crps_mixture")
    t = _target_for(target, mu.shape[0], "crps_mixture")
    var = sd * sd
    term1 = (w * _a_fn(t[:, None] - mu, var)).sum(-1)
    dmu = mu[:, :, None] - mu[:, None, :]
    dvar = var[:, :, None] + var[:, None, :]
    term2 = (w[:, :, None] * w[:, None, :] * _a_fn(dmu, dvar)).sum((-1, -2))
    return term1 - 0.5 * term2


def crps_samples(target: Any, samples: Any) -> np.ndarray:
    """CRPS of the empirical distribution of ``samples`` [n, S] (e.g. Monte Carlo mass draws) per item.

    Exact for the empirical distribution: mean|x_i - y| - sum_i (2i - S - 1) x_(i) / S^2 (sorted x).
    """
    x = _arr(samples, "samples", "crps_samples")
    if x.ndim == 1:
        x = x[None, :]
    t = _target_for(target, x.shape[0], "crps_samples")
    s = x.shape[1]
    xs = np.sort(x, axis=1)
    coef = 2 * np.arange(1, s + 1) - s - 1
    half_mean_abs_diff = (xs * coef).sum(1) / (s * s)
    return np.abs(x - t[:, None]).mean(1) - half_mean_abs_diff


def summarize(
    target: Any,
    pred: Any | None = None,
    *,
    lo: Any | None = None,
    hi: Any | None = None,
    mixture: Mapping[str, Any] | None = None,
    samples: Any | None = None,
    levels: Sequence[float] = (0.5, 0.9),
    point_names: Sequence[str] = tuple(POINT_METRICS),
) -> dict[str, float]:
    """One flat dict of aggregate numbers for a report.

    Args:
        target: ground truth [n].
        pred: point estimates [n]; if omitted, the mixture mean is used.
        lo, hi: an explicit interval per item -> ``coverage_interval``.
        mixture: ``{"weights", "means", "stds"}`` per item ([n, K] or [n]) -> ``nll``, ``crps``,
            ``coverage@<level>`` for each of ``levels``.
        samples: Monte Carlo draws [n, S] -> ``crps_samples``.
        point_names: which of ADE/ALDE/APE/MnRE to report (drop ALDE/MnRE for signed quantities).

    Returns:
        ``{"n", "ADE", "ALDE", "APE", "MnRE", ...}``, means over items (floats).
    """
    out: dict[str, float] = {}
    t = _arr(target, "target", "summarize").reshape(-1)
    out["n"] = float(t.shape[0])
    if pred is None:
        if mixture is None:
            raise ValueError("summarize: give pred, or a mixture whose mean serves as the estimate.")
        w, mu, _ = _mixture(mixture.get("weights"), mixture["means"], mixture["stds"], "summarize")
        pred = (w * mu).sum(-1)
    for name, vals in point_metrics(t, pred, point_names).items():
        out[name] = float(np.mean(vals))
    if lo is not None or hi is not None:
        if lo is None or hi is None:
            raise ValueError("summarize: give both lo and hi for interval coverage.")
        out["coverage_interval"] = float(np.mean(interval_coverage(t, lo, hi)))
    if mixture is not None:
        w_, m_, s_ = mixture.get("weights"), mixture["means"], mixture["stds"]
        out["nll"] = float(np.mean(gaussian_mixture_nll(t, w_, m_, s_)))
        out["crps"] = float(np.mean(crps_mixture(t, w_, m_, s_)))
        for lv, cov in coverage_curve(t, w_, m_, s_, levels).items():
            out[f"coverage@{lv:g}"] = cov
    if samples is not None:
        out["crps_samples"] = float(np.mean(crps_samples(t, samples)))
    return out
