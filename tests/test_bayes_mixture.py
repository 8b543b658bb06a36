"""Mixture predictive: moments, quantiles, log-pdf, sampling and property fields vs scipy / Monte Carlo."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate, optimize, stats

from physgs_nerfstudio.bayes import (
    NIG,
    component_scale,
    material_mixture_weights,
    mixture_cdf,
    mixture_interval,
    mixture_logpdf,
    mixture_moments,
    mixture_quantile,
    mixture_sample,
    predictive,
    property_fields,
    property_intervals,
)

F64 = torch.float64


def _random_mixture(rng, n=4, k=3):
    pi = rng.random((n, k)) + 0.05
    pi /= pi.sum(1, keepdims=True)
    loc = rng.normal(0, 3, (n, k))
    scale = rng.random((n, k)) + 0.3
    return pi, loc, scale


def test_mixture_moments_law_of_total_variance_vs_integration():
    rng = np.random.default_rng(0)
    pi, tau, _ = _random_mixture(rng)
    ale = rng.random((4, 3)) + 0.1
    epi = rng.random((4, 3)) * 0.5
    mean, a_e, e_e, tot = (t.numpy() for t in mixture_moments(*(torch.tensor(x) for x in (pi, tau, ale, epi))))
    for i in range(4):
        sd = np.sqrt(ale[i] + epi[i])

        def pdf(x, i=i, sd=sd):
            return (pi[i] * stats.norm.pdf(x, tau[i], sd)).sum()

        m1 = integrate.quad(lambda x: x * pdf(x), -60, 60, limit=200)[0]
        m2 = integrate.quad(lambda x, m1=m1: (x - m1) ** 2 * pdf(x), -60, 60, limit=200)[0]
        assert mean[i] == pytest.approx(m1, abs=1e-8)
        assert tot[i] == pytest.approx(m2, rel=1e-7)
        assert a_e[i] == pytest.approx((pi[i] * ale[i]).sum())
        between = (pi[i] * tau[i] ** 2).sum() - m1**2
        assert e_e[i] == pytest.approx((pi[i] * epi[i]).sum() + between, rel=1e-10)
    # one certain material: no between-material term
    mean, a_e, e_e, tot = mixture_moments(torch.tensor([[0.0, 1.0]]), torch.tensor([3.0, 5.0]),
                                          torch.tensor([1.0, 2.0]), torch.tensor([0.1, 0.2]))
    assert mean.item() == 5.0 and a_e.item() == 2.0 and e_e.item() == pytest.approx(0.2)


@pytest.mark.parametrize("df", [None, "t"])
def test_quantiles_cdf_logpdf_vs_scipy(df):
    rng = np.random.default_rng(1)
    pi, loc, scale = _random_mixture(rng, n=5, k=3)
    dfs = np.array([1.5, 4.0, 30.0]) if df else None
    comp = (lambda x, i: stats.t(dfs, loc[i], scale[i])) if df else (lambda x, i: stats.norm(loc[i], scale[i]))

    def cdf_np(x, i):
        return (pi[i] * comp(x, i).cdf(x)).sum()

    args = [torch.tensor(a) for a in (pi, loc, scale)]
    dft = torch.tensor(dfs) if df else None
    for q in (0.02, 0.3, 0.5, 0.9, 0.999):
        got = mixture_quantile(*args, q, dft).numpy()
        for i in range(5):
            ref = optimize.brentq(lambda x, i=i, q=q: cdf_np(x, i) - q, -1e4, 1e4, xtol=1e-13, rtol=1e-14)
            assert got[i] == pytest.approx(ref, rel=1e-8, abs=1e-8)
    x = rng.normal(0, 4, 5)
    lp = mixture_logpdf(torch.tensor(x), *args, dft).numpy()
    cd = mixture_cdf(torch.tensor(x), *args, dft).numpy()
    for i in range(5):
        assert lp[i] == pytest.approx(np.log((pi[i] * comp(x[i], i).pdf(x[i])).sum()), rel=1e-10)
        assert cd[i] == pytest.approx(cdf_np(x[i], i), abs=1e-12)
    # float32 path agrees to float32 accuracy
    got32 = mixture_quantile(*(a.float() for a in args), 0.9, dft.float() if df else None)
    assert got32.dtype == torch.float32
    np.testing.assert_allclose(got32.numpy(), mixture_quantile(*args, 0.9, dft).numpy(), rtol=1e-4, atol=1e-4)


def test_single_component_quantile_and_interval_exact():
    loc, scale = torch.tensor([[2.0]], dtype=F64), torch.tensor([[0.5]], dtype=F64)
    pi = torch.ones(1, 1, dtype=F64)
    lo, hi = mixture_interval(pi, loc, scale, 0.9)
    assert lo.item() == pytest.approx(stats.norm.ppf(0.05, 2, 0.5), rel=1e-12)
    assert hi.item() == pytest.approx(stats.norm.ppf(0.95, 2, 0.5), rel=1e-12)
    q = mixture_quantile(pi, loc, scale, 0.995, torch.tensor([[3.0]], dtype=F64))
    assert q.item() == pytest.approx(stats.t.ppf(0.995, 3, 2, 0.5), rel=1e-10)
    with pytest.raises(ValueError, match=r"quantile level outside"):
        mixture_quantile(pi, loc, scale, 1.0)
    with pytest.raises(ValueError, match=r"scale.*> 0"):
        mixture_quantile(pi, loc, torch.zeros(1, 1), 0.5)
    with pytest.raises(ValueError, match=r"sum to 0"):
        mixture_quantile(torch.zeros(1, 2), torch.zeros(2), torch.ones(2), 0.5)


@pytest.mark.parametrize("use_t", [False, True])
def test_sampling_matches_cdf(use_t):
    rng = np.random.default_rng(2)
    pi, loc, scale = _random_mixture(rng, n=3, k=3)
    args = [torch.tensor(a) for a in (pi, loc, scale)]
    df = torch.tensor([3.0, 8.0, 50.0], dtype=F64) if use_t else None
    torch.manual_seed(0)
    s = mixture_sample(*args, 20_000, df, generator=torch.Generator().manual_seed(0))
    assert s.shape == (20_000, 3)
    for i in range(3):
        res = stats.kstest(s[:, i].numpy(), lambda x, i=i: mixture_cdf(torch.tensor(x), args[0][i], args[1][i],
                                                                          args[2][i], df).numpy())
        assert res.pvalue > 1e-3


def _random_nig(rng, k, p, log_tau=None):
    tau = rng.normal(0, 1, (k, p)) if log_tau is None else log_tau + 0.3 * rng.normal(size=(k, p))
    return NIG(torch.tensor(tau), torch.tensor(rng.random((k, p)) * 3 + 0.5), torch.tensor(rng.random((k, p)) * 4 + 3.0),
               torch.tensor(rng.random((k, p)) * 0.2 + 0.02))


def test_property_fields_linear_matches_mixture_moments():
    rng = np.random.default_rng(3)
    K, P, N = 6, 3, 50
    nig = _random_nig(rng, K, P)
    nig = NIG(nig.tau * 100 + 1000, nig.kappa, nig.a, nig.b * 1e4)  # large offset: cancellation check
    alpha = torch.tensor(rng.random((N, K)) * 3 + 0.01)
    alpha[0] = torch.tensor([1e6] + [1e-3] * (K - 1), dtype=F64)  # near-certain entity
    for weights in ("dominant", "predictive"):
        pi = material_mixture_weights(alpha, weights)
        ref = mixture_moments(pi[:, None, :], nig.tau.T, nig.aleatoric().T, nig.epistemic().T)
        for dtype in (F64, torch.float32):
            out = property_fields(alpha.to(dtype), nig, [False] * P, material_weights=weights)
            tol = {"rtol": 1e-10, "atol": 1e-8} if dtype == F64 else {"rtol": 1e-5, "atol": 2e-2}
            for name, r in zip(("mean", "aleatoric", "epistemic", "total"), ref):
                assert out[name].shape == (N, P) and out[name].dtype == dtype
                torch.testing.assert_close(out[name].double(), r, **tol)
    # weights: "predictive" is alpha / sum; the default (positional call) is "dominant", which differs
    torch.testing.assert_close(material_mixture_weights(alpha, "predictive"), predictive(alpha))
    default = property_fields(alpha, nig, [False] * P)["mean"]
    torch.testing.assert_close(default, property_fields(alpha, nig, [False] * P, material_weights="dominant")["mean"])
    assert (default - property_fields(alpha, nig, [False] * P, material_weights="predictive")["mean"]).abs().max() > 1
    with pytest.raises(ValueError, match="material_weights"):
        property_fields(alpha, nig, [False] * P, material_weights="argmax")


def test_dominant_weights_concentrate_with_evidence_predictive_do_not():
    """An entity whose observations split 60/40 between two materials: with growing evidence the dominant
    mixture's mean goes to the majority material's and its material-ambiguity (between) variance to 0; the
    predictive mixture stays at the 60/40 blend. Balanced evidence keeps the dominant mixture split."""
    nig = NIG(torch.tensor([[0.0], [10.0], [-5.0]], dtype=F64), torch.full((3, 1), 50.0, dtype=F64),
              torch.full((3, 1), 30.0, dtype=F64), torch.full((3, 1), 1.0, dtype=F64))
    n = torch.tensor([1.0, 4.0, 16.0, 64.0, 256.0], dtype=F64)[:, None]
    alpha = 1.0 + 4.0 * n * torch.tensor([[0.6, 0.4, 0.0]], dtype=F64)
    dom = property_fields(alpha, nig, [False], material_weights="dominant")
    pred = property_fields(alpha, nig, [False], material_weights="predictive")
    ale_epi = (nig.aleatoric() + nig.epistemic())[0, 0].item()  # within-material variance of material 0
    between_dom = dom["total"][:, 0] - (material_mixture_weights(alpha) * (nig.aleatoric() + nig.epistemic())[:, 0]).sum(-1)
    assert torch.all(torch.diff(dom["mean"][:, 0]) < 0)  # moves monotonically towards material 0 (tau 0)
    assert dom["mean"][-1, 0].abs() < 1e-6 and between_dom[-1] < 1e-6
    assert dom["total"][-1, 0].item() == pytest.approx(ale_epi, rel=1e-4)
    # predictive: the mean goes to the 60/40 blend (~4), the between-material variance to 0.24 * 100 = 24
    assert pred["mean"][-1, 0].item() == pytest.approx(0.6 * 0 + 0.4 * 10, abs=0.05)
    assert pred["epistemic"][-1, 0].item() > 20
    balanced = 1.0 + 4.0 * 256.0 * torch.tensor([[0.5, 0.5, 0.0]], dtype=F64)
    wb = material_mixture_weights(balanced)
    assert wb[0, 0].item() == pytest.approx(0.5, abs=1e-9) and wb[0, 1].item() == pytest.approx(0.5, abs=1e-9)


def test_property_fields_log_space_vs_monte_carlo():
    rng = np.random.default_rng(4)
    K, P, N = 4, 2, 3
    nig = _random_nig(rng, K, P, log_tau=np.array([7.0, 20.0]))  # density ~1e3, modulus ~5e8
    alpha = torch.tensor(rng.random((N, K)) * 2 + 0.2)
    out = property_fields(alpha, nig, [True, False])
    pi = material_mixture_weights(alpha).numpy()
    sd = np.sqrt((nig.aleatoric() + nig.epistemic()).numpy())
    tau = nig.tau.numpy()
    n_mc = 400_000
    for e in range(N):
        comp = rng.choice(K, size=n_mc, p=pi[e])
        x = np.exp(tau[comp, 0] + sd[comp, 0] * rng.standard_normal(n_mc))  # log-space property 0
        se_mean = x.std() / np.sqrt(n_mc)
        assert out["mean"][e, 0].item() == pytest.approx(x.mean(), abs=5 * se_mean)
        assert out["total"][e, 0].item() == pytest.approx(x.var(), rel=0.03)
        y = tau[comp, 1] + sd[comp, 1] * rng.standard_normal(n_mc)  # linear property 1
        assert out["total"][e, 1].item() == pytest.approx(y.var(), rel=0.02)
    # the documented split rule: one certain material -> aleatoric/total equals the log-space fraction
    a1 = torch.tensor([[1e9, 1e-6, 1e-6, 1e-6]], dtype=F64)
    o1 = property_fields(a1, nig, [True, False])
    ale, epi = nig.aleatoric()[0, 0].item(), nig.epistemic()[0, 0].item()
    assert (o1["aleatoric"] / o1["total"])[0, 0].item() == pytest.approx(ale / (ale + epi), rel=1e-6)
    v = ale + epi
    lin_var = np.expm1(v) * np.exp(2 * tau[0, 0] + v)
    assert o1["total"][0, 0].item() == pytest.approx(lin_var, rel=1e-5)


def test_property_intervals_cover_nominal_mass():
    rng = np.random.default_rng(5)
    K, P, N = 3, 2, 4
    nig = _random_nig(rng, K, P)
    alpha = torch.tensor(rng.random((N, K)) * 2 + 0.2)
    for student_t in (False, True):
        lo, hi = property_intervals(alpha, nig, [True, False], 0.8, student_t=student_t, chunk_size=3)
        assert lo.shape == (N, P) and torch.all(lo < hi)
        pi = material_mixture_weights(alpha)  # the default weights ("dominant")
        scale, df = component_scale(nig, student_t)
        for p in range(P):
            s = mixture_sample(pi, nig.tau[:, p], scale[:, p], 50_000, None if df is None else df[:, p],
                               generator=torch.Generator().manual_seed(p))
            if p == 0:
                s = torch.exp(s)
            frac = ((s >= lo[:, p]) & (s <= hi[:, p])).double().mean(0)
            assert torch.all((frac - 0.8).abs() < 0.01), frac


def test_property_fields_shape_errors_and_speed():
    import time

    nig = NIG(torch.zeros(4, 2), torch.ones(4, 2), torch.full((4, 2), 3.0), torch.ones(4, 2))
    with pytest.raises(ValueError, match=r"same K"):
        property_fields(torch.ones(5, 3), nig, [False, False])
    with pytest.raises(ValueError, match=r"log_space has 1"):
        property_fields(torch.ones(5, 4), nig, [False])
    with pytest.raises(ValueError, match=r"a <= 1"):
        property_fields(torch.ones(5, 4), NIG(torch.zeros(4, 2), 1.0, 1.0, 1.0), [False, False])
    K, P, N = 20, 4, 200_000
    nig = NIG(torch.randn(K, P), torch.rand(K, P) + 1, torch.rand(K, P) + 2, torch.rand(K, P) + 0.1)
    alpha = torch.rand(N, K) + 0.1
    t0 = time.perf_counter()  # the matrix products (the dominance weights are timed in benchmarks)
    out = property_fields(alpha, nig, [True, False, False, True], material_weights="predictive")
    assert time.perf_counter() - t0 < 5.0
    assert all(torch.isfinite(v).all() for v in out.values())


@settings(max_examples=200, deadline=None)
@given(st.lists(st.lists(st.integers(1, 4), max_size=4), min_size=1, max_size=4),
       st.lists(st.integers(0, 3), max_size=4))  # fmt: skip
def test_broadcast_shapes_matches_torch(shapes, ones):
    """The module's broadcast_shapes (no sympy import) equals torch.broadcast_shapes, errors included."""
    from physgs_nerfstudio.bayes.mixture import broadcast_shapes

    shapes = [list(s) for s in shapes]
    for k, i in enumerate(ones):  # some dimensions of size 1, which broadcast
        s = shapes[k % len(shapes)]
        if s:
            s[i % len(s)] = 1
    try:
        want = torch.broadcast_shapes(*shapes)
    except RuntimeError:
        with pytest.raises(RuntimeError):
            broadcast_shapes(*shapes)
        return
    assert broadcast_shapes(*shapes) == want
