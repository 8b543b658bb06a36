"""Evaluation metrics: hand-computed point metrics, calibration vs Monte Carlo and scipy."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import stats

from physgs_nerfstudio.eval.metrics import (
    ade,
    alde,
    ape,
    central_coverage,
    coverage_curve,
    crps_gaussian,
    crps_mixture,
    crps_samples,
    gaussian_mixture_nll,
    interval_coverage,
    mnre,
    pit,
    point_metrics,
    summarize,
)


def test_point_metrics_hand_computed():
    m = [2.0, 10.0, 0.5]  # ground truth
    m_hat = [1.0, 12.0, 0.5]
    np.testing.assert_allclose(ade(m, m_hat), [1.0, 2.0, 0.0])
    np.testing.assert_allclose(alde(m, m_hat), [math.log(2), math.log(1.2), 0.0])
    np.testing.assert_allclose(ape(m, m_hat), [0.5, 0.2, 0.0])
    np.testing.assert_allclose(mnre(m, m_hat), [0.5, 10 / 12, 1.0])
    # symmetric metrics are symmetric, APE is not (divides by the ground truth)
    np.testing.assert_allclose(mnre(m_hat, m), mnre(m, m_hat))
    assert ape(m_hat, m)[0] == pytest.approx(1.0)
    s = summarize(torch.tensor(m), torch.tensor(m_hat, dtype=torch.float64))
    assert s["n"] == 3 and s["ADE"] == pytest.approx(1.0) and s["APE"] == pytest.approx(0.7 / 3)
    assert s["MnRE"] == pytest.approx((0.5 + 10 / 12 + 1) / 3)
    assert set(point_metrics(m, m_hat)) == {"ADE", "ALDE", "APE", "MnRE"}


def test_point_metric_guards():
    with pytest.raises(ValueError, match=r"alde: target must be > 0.*index 1"):
        alde([1.0, 0.0], [1.0, 1.0])
    with pytest.raises(ValueError, match=r"mnre: pred must be > 0.*index 0"):
        mnre([1.0, 2.0], [-1.0, 1.0])
    with pytest.raises(ValueError, match=r"ape: target must be > 0"):
        ape([-1.0], [1.0])
    with pytest.raises(ValueError, match=r"non-finite pred at index 2"):
        ade([1.0, 2.0, 3.0], [1.0, 2.0, float("nan")])
    with pytest.raises(ValueError, match=r"do not match"):
        ade([1.0, 2.0, 3.0], [1.0, 2.0])
    with pytest.raises(ValueError, match=r"unknown metric"):
        point_metrics([1.0], [1.0], ["RMSE"])
    assert ade([-1.0], [1.0])[0] == 2.0  # ADE is fine with signed values
    with pytest.raises(ValueError, match=r"lo > hi"):
        interval_coverage([1.0], [2.0], [0.0])


def test_coverage_of_correct_model_is_nominal():
    rng = np.random.default_rng(0)
    n, k = 20_000, 3
    w = rng.dirichlet(np.ones(k), n)
    mu = rng.normal(0, 5, (n, k))
    sd = rng.random((n, k)) + 0.2
    comp = (w.cumsum(1) > rng.random((n, 1))).argmax(1)
    y = mu[np.arange(n), comp] + sd[np.arange(n), comp] * rng.standard_normal(n)
    u = pit(y, w, mu, sd)
    assert stats.kstest(u, "uniform").pvalue > 1e-3
    for level, cov in coverage_curve(y, w, mu, sd, (0.5, 0.9, 0.95)).items():
        assert abs(cov - level) < 4 * math.sqrt(level * (1 - level) / n)
    # an over-confident model (stds / 3) under-covers
    assert central_coverage(y, w, mu, sd / 3, 0.9).mean() < 0.75
    # explicit intervals: a single Gaussian's central 90% interval
    lo, hi = stats.norm.interval(0.9, mu[:, 0], sd[:, 0])
    y0 = mu[:, 0] + sd[:, 0] * rng.standard_normal(n)
    assert abs(interval_coverage(y0, lo, hi).mean() - 0.9) < 4 * math.sqrt(0.09 / n)


def test_nll_matches_scipy():
    rng = np.random.default_rng(1)
    w = rng.dirichlet(np.ones(4), 10)
    mu = rng.normal(0, 2, (10, 4))
    sd = rng.random((10, 4)) + 0.1
    y = rng.normal(0, 3, 10)
    ref = -np.log((w * stats.norm.pdf(y[:, None], mu, sd)).sum(1))
    np.testing.assert_allclose(gaussian_mixture_nll(y, w, mu, sd), ref, rtol=1e-12)
    np.testing.assert_allclose(gaussian_mixture_nll(y, None, mu[:, 0], sd[:, 0]),
                               -stats.norm.logpdf(y, mu[:, 0], sd[:, 0]), rtol=1e-12)
    assert np.isfinite(gaussian_mixture_nll([1e3], None, [0.0], [1.0])).all()  # far tail, no underflow


def test_crps_closed_forms_vs_monte_carlo():
    rng = np.random.default_rng(2)
    y = np.array([0.3, -2.0, 5.0])
    mu, sd = np.array([0.0, 1.0, 4.0]), np.array([1.0, 0.5, 2.0])
    n_mc = 400_000
    g = crps_gaussian(y, mu, sd)
    for i in range(3):
        x = mu[i] + sd[i] * rng.standard_normal(n_mc)
        x2 = mu[i] + sd[i] * rng.standard_normal(n_mc)
        mc = np.abs(x - y[i]).mean() - 0.5 * np.abs(x - x2).mean()
        assert g[i] == pytest.approx(mc, abs=0.01 * sd[i])
    np.testing.assert_allclose(crps_mixture(y, None, mu, sd), g, rtol=1e-12)
    # mixture: exact pairwise formula vs Monte Carlo
    w = np.array([[0.2, 0.5, 0.3], [0.6, 0.1, 0.3]])
    m = np.array([[-3.0, 0.0, 4.0], [1.0, 1.5, -2.0]])
    s = np.array([[0.5, 1.0, 2.0], [0.3, 3.0, 1.0]])
    yy = np.array([1.0, -1.0])
    got = crps_mixture(yy, w, m, s)
    for i in range(2):
        def draw(i=i):
            c = rng.choice(3, n_mc, p=w[i])
            return m[i, c] + s[i, c] * rng.standard_normal(n_mc)
        x, x2 = draw(), draw()
        mc = np.abs(x - yy[i]).mean() - 0.5 * np.abs(x - x2).mean()
        assert got[i] == pytest.approx(mc, abs=0.02)
        # and the empirical-sample CRPS of those draws approaches it too
        assert crps_samples(yy[i:i + 1], x[None, :20_000])[0] == pytest.approx(got[i], abs=0.05)


def test_crps_samples_equals_bruteforce_pairwise():
    rng = np.random.default_rng(3)
    x = rng.normal(size=(3, 40))
    y = rng.normal(size=3)
    brute = np.abs(x - y[:, None]).mean(1) - 0.5 * np.abs(x[:, :, None] - x[:, None, :]).mean((1, 2))
    np.testing.assert_allclose(crps_samples(y, x), brute, rtol=1e-12)


def test_summarize_with_calibration():
    rng = np.random.default_rng(4)
    n = 2_000
    mu = rng.uniform(1, 10, n)
    sd = 0.1 * mu
    y = mu + sd * rng.standard_normal(n)
    s = summarize(y, mixture={"weights": None, "means": mu, "stds": sd}, lo=mu - 3 * sd, hi=mu + 3 * sd,
                  samples=mu[:, None] + sd[:, None] * rng.standard_normal((n, 200)))
    assert s["ADE"] == pytest.approx(np.abs(y - mu).mean())
    assert abs(s["coverage@0.9"] - 0.9) < 0.03 and abs(s["coverage@0.5"] - 0.5) < 0.05
    assert s["coverage_interval"] > 0.99
    assert s["nll"] == pytest.approx(-stats.norm.logpdf(y, mu, sd).mean())
    assert s["crps"] == pytest.approx(crps_gaussian(y, mu, sd).mean())
    assert s["crps_samples"] == pytest.approx(s["crps"], rel=0.05)
    with pytest.raises(ValueError, match=r"give pred"):
        summarize(y)
