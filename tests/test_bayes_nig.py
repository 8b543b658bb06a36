"""NIG fusion: closed form vs brute-force integration, sequential (A.5) == batched, merge laws, guards."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from physgs_nerfstudio.bayes import NIG, Moments, nig_posterior, nig_update

F64 = torch.float64


def _scalar_nig(tau0, k0, a0, b0, dtype=F64) -> NIG:
    return NIG(*(torch.tensor(v, dtype=dtype) for v in (tau0, k0, a0, b0)))


def _grid_posterior(prior, psi, w):
    """Brute force: prior x prod_m N(psi_m | mu, s2)^{w_m} on a (mu, log s2) grid; returns grids and weights."""
    tau0, k0, a0, b0 = prior
    mu = np.linspace(psi.mean() - 12.0, psi.mean() + 12.0, 1601)
    ls = np.linspace(-7.0, 7.0, 1401)
    MU, LS = np.meshgrid(mu, ls, indexing="ij")
    S2 = np.exp(LS)
    logp = (
        stats.norm.logpdf(MU, tau0, np.sqrt(S2 / k0))
        + stats.invgamma.logpdf(S2, a0, scale=b0)
        + LS  # Jacobian d s2 = s2 d log s2
    )
    for p, x in zip(w, psi):
        logp = logp + p * stats.norm.logpdf(x, MU, np.sqrt(S2))
    dens = np.exp(logp - logp.max())
    dmu, dls = mu[1] - mu[0], ls[1] - ls[0]
    dens /= dens.sum() * dmu * dls
    return MU, S2, dens, dmu * dls


@pytest.mark.parametrize("weights", [[1.0, 2.0, 1.0, 3.0, 1.0], [0.9, 0.35, 0.6, 0.15, 0.8]])
def test_closed_form_matches_brute_force_integration(weights):
    rng = np.random.default_rng(3)
    psi = rng.normal(2.0, 1.5, size=len(weights))
    w = np.asarray(weights)
    prior = (0.5, 0.7, 3.0, 2.0)
    if w.max() > 1:  # integer weights: the weighted likelihood equals repeated observations
        reps = w.astype(int)
        obs, conf = np.repeat(psi, reps), np.ones(reps.sum())
    else:  # fractional weights: confidences p_m, likelihood^p_m
        obs, conf = psi, w
    m = Moments.from_observations(torch.zeros(len(obs), dtype=torch.long), torch.tensor(conf), torch.tensor(obs), 1)
    post = nig_posterior(_scalar_nig(*prior), m[0])
    MU, S2, dens, da = _grid_posterior(prior, psi, w)
    e_mu = (MU * dens).sum() * da
    e_s2 = (S2 * dens).sum() * da
    var_mu = ((MU - e_mu) ** 2 * dens).sum() * da
    assert post.mean().item() == pytest.approx(e_mu, rel=1e-5, abs=1e-6)
    assert post.aleatoric().item() == pytest.approx(e_s2, rel=1e-4)
    assert post.epistemic().item() == pytest.approx(var_mu, rel=1e-4)
    # Student-t predictive vs integrating N(x | mu, s2) over the brute-force posterior
    df, loc, scale = (t.item() for t in post.student_t())
    for x in (loc - 3 * scale, loc - 0.5 * scale, loc + 1.7 * scale):
        pred = (stats.norm.pdf(x, MU, np.sqrt(S2)) * dens).sum() * da
        assert stats.t.pdf(x, df, loc, scale) == pytest.approx(pred, rel=1e-4)
        assert post.predictive_logpdf(torch.tensor(x, dtype=F64)).item() == pytest.approx(
            stats.t.logpdf(x, df, loc, scale), rel=1e-10
        )
    # variance of the Student-t predictive = aleatoric + epistemic
    assert post.variance().item() == pytest.approx(stats.t.var(df, loc, scale), rel=1e-10)


def test_moments_scatter_with_missing_values_matches_brute_force():
    classes = torch.tensor([0, 2, 0, 1, 2, 2])
    conf = torch.tensor([0.5, 1.0, 0.25, 0.75, 0.5, 0.1], dtype=F64)
    vals = torch.tensor(
        [[1.0, 10.0], [2.0, float("nan")], [3.0, 30.0], [float("nan"), float("nan")], [5.0, 50.0], [6.0, 60.0]],
        dtype=F64,
    )
    m = Moments.from_observations(classes, conf, vals, num_classes=4)
    assert m.shape == (4, 2)
    for k in range(4):
        for p in range(2):
            sel = [i for i in range(6) if classes[i] == k and not math.isnan(vals[i, p])]
            W = sum(conf[i].item() for i in sel)
            S = sum(conf[i].item() * vals[i, p].item() for i in sel)
            Q = sum(conf[i].item() * vals[i, p].item() ** 2 for i in sel)
            assert m.W[k, p].item() == pytest.approx(W) and m.S[k, p].item() == pytest.approx(S)
            assert m.Q[k, p].item() == pytest.approx(Q)
    prior = NIG(torch.zeros(4, 2, dtype=F64), torch.ones(4, 2, dtype=F64), 3 * torch.ones(4, 2, dtype=F64),
                torch.ones(4, 2, dtype=F64))
    post = nig_posterior(prior, m)
    # class 3 has no observations at all, class 1 only a NaN: exact prior (b = b0 where W = 0)
    for k in (1, 3):
        for f in ("tau", "kappa", "a", "b"):
            assert torch.equal(getattr(post, f)[k], getattr(prior, f)[k])


def _sequential(prior: NIG, psi, w) -> NIG:
    post = prior
    for x, p in zip(psi, w):
        post = nig_update(post, x, p)
    return post


obs_strategy = st.lists(
    st.tuples(st.floats(-50, 50, allow_nan=False), st.floats(0.0, 1.0)), min_size=1, max_size=12
)


@settings(max_examples=60, deadline=None)
@given(obs=obs_strategy, perm_seed=st.integers(0, 10_000), split=st.integers(0, 12),
       tau0=st.floats(-10, 10), k0=st.floats(0.05, 5), a0=st.floats(1.1, 6), b0=st.floats(0.05, 20))
def test_sequential_equals_batched_any_order_and_split(obs, perm_seed, split, tau0, k0, a0, b0):
    psi = np.array([o[0] for o in obs])
    w = np.array([o[1] for o in obs])
    prior = _scalar_nig(tau0, k0, a0, b0)
    cls = torch.zeros(len(psi), dtype=torch.long)
    m_all = Moments.from_observations(cls, torch.tensor(w), torch.tensor(psi), 1)[0]
    batched = nig_posterior(prior, m_all)
    order = np.random.default_rng(perm_seed).permutation(len(psi))
    seq = _sequential(prior, psi[order], w[order])
    s = min(split, len(psi))
    m1 = Moments.from_observations(cls[:s], torch.tensor(w[:s]), torch.tensor(psi[:s]), 1)[0]
    m2 = Moments.from_observations(cls[s:], torch.tensor(w[s:]), torch.tensor(psi[s:]), 1)[0]
    chained = nig_posterior(nig_posterior(prior, m1), m2)
    merged = nig_posterior(prior, m1.merge(m2))
    for other in (seq, chained, merged):
        for f in ("tau", "kappa", "a"):
            assert getattr(other, f).item() == pytest.approx(getattr(batched, f).item(), rel=1e-9, abs=1e-9)
        # b: absolute error scale of the scatter terms (cancellation in Q - S^2/W)
        scale_b = b0 + (w * (psi - tau0) ** 2).sum() + (w * psi**2).sum()
        assert other.b.item() == pytest.approx(batched.b.item(), rel=1e-9, abs=1e-12 * scale_b)
    # float32: same posterior to float32 accuracy
    seq32 = _sequential(_scalar_nig(tau0, k0, a0, b0, torch.float32), psi[order], w[order])
    b32 = nig_posterior(prior.to(torch.float32), m_all.to(torch.float32))
    assert seq32.dtype == torch.float32 and b32.dtype == torch.float32
    for other in (seq32, b32):
        assert other.tau.item() == pytest.approx(batched.tau.item(), rel=1e-4, abs=1e-4 * (1 + abs(psi).max()))
        assert other.kappa.item() == pytest.approx(batched.kappa.item(), rel=1e-5)
        assert other.b.item() == pytest.approx(batched.b.item(), rel=2e-3, abs=1e-5 * scale_b)


moment_strategy = st.tuples(st.floats(0, 10), st.floats(-100, 100), st.floats(0, 1000))


@settings(max_examples=40, deadline=None)
@given(x=moment_strategy, y=moment_strategy, z=moment_strategy)
def test_moments_merge_commutative_associative(x, y, z):
    mx, my, mz = (Moments(*(torch.tensor(v, dtype=F64) for v in t)) for t in (x, y, z))
    ab = mx.merge(my)
    ba = my + mx
    assert all(torch.equal(getattr(ab, f), getattr(ba, f)) for f in "WSQ")
    left = (mx + my) + mz
    right = mx + (my + mz)
    for f in "WSQ":
        assert torch.allclose(getattr(left, f), getattr(right, f), rtol=1e-12, atol=1e-12)


def test_batched_shapes_and_dtypes():
    for dtype in (torch.float32, F64):
        K, P = 5, 4
        g = torch.Generator().manual_seed(0)
        prior = NIG(torch.randn(K, P, generator=g, dtype=dtype), torch.rand(K, P, generator=g, dtype=dtype) + 0.1,
                    torch.full((K, P), 2.0, dtype=dtype), torch.rand(K, P, generator=g, dtype=dtype) + 0.1)
        cls = torch.randint(0, K, (200,), generator=g)
        m_conf = torch.rand(200, generator=g, dtype=dtype)
        m_vals = torch.randn(200, P, generator=g, dtype=dtype)
        m = Moments.from_observations(cls, m_conf, m_vals, K)
        post = nig_posterior(prior, m)
        assert post.shape == (K, P) and post.dtype == dtype
        # equals sequential A.5 updates, observation by observation, routed to its class by the weight
        seq = prior
        for i in range(200):
            w_i = (torch.arange(K) == cls[i]).to(dtype)[:, None] * m_conf[i]
            seq = nig_update(seq, m_vals[i].expand(K, P), w_i.expand(K, P))
        tol = {"rtol": 1e-4, "atol": 1e-4} if dtype == torch.float32 else {"rtol": 1e-10, "atol": 1e-10}
        for f in ("tau", "kappa", "a", "b"):
            torch.testing.assert_close(getattr(seq, f), getattr(post, f), **tol)
        assert torch.all(post.kappa >= prior.kappa) and torch.all(post.b >= prior.b)


def test_nig_update_vectorised_matches_scalar_loop():
    g = torch.Generator().manual_seed(1)
    prior = NIG(torch.randn(3, 2, generator=g, dtype=F64), torch.rand(3, 2, generator=g, dtype=F64) + 0.1,
                torch.full((3, 2), 2.5, dtype=F64), torch.rand(3, 2, generator=g, dtype=F64) + 0.1)
    value = torch.randn(3, 2, generator=g, dtype=F64)
    value[1, 0] = float("nan")  # missing: that entry unchanged
    weight = torch.rand(3, 2, generator=g, dtype=F64)
    post = nig_update(prior, value, weight)
    for i in range(3):
        for j in range(2):
            if i == 1 and j == 0:
                assert post[i, j].to_dict() == prior[i, j].to_dict()
                continue
            k, t, a, b = (getattr(prior, f)[i, j].item() for f in ("kappa", "tau", "a", "b"))
            p, x = weight[i, j].item(), value[i, j].item()
            assert post.kappa[i, j].item() == pytest.approx(k + p)
            assert post.tau[i, j].item() == pytest.approx((k * t + p * x) / (k + p))
            assert post.a[i, j].item() == pytest.approx(a + p / 2)
            assert post.b[i, j].item() == pytest.approx(b + p * k * (x - t) ** 2 / (2 * (k + p)))


def test_json_roundtrip_and_student_t():
    nig = NIG(torch.tensor([[1.0, 2.0]], dtype=F64), torch.tensor([[0.5, 3.0]], dtype=F64),
              torch.tensor([[2.0, 7.5]], dtype=F64), torch.tensor([[1.5, 0.2]], dtype=F64))
    back = NIG.from_dict(json.loads(json.dumps(nig.to_dict())), dtype=F64)
    assert all(torch.equal(getattr(back, f), getattr(nig, f)) for f in ("tau", "kappa", "a", "b"))
    scalar = nig[0, 1]
    d = scalar.to_dict()
    assert isinstance(d["tau"], float) and set(d) == {"tau", "kappa", "a", "b"}
    df, loc, scale = scalar.student_t()
    assert df.item() == 15.0 and loc.item() == 2.0
    assert scale.item() == pytest.approx(math.sqrt(0.2 * 4.0 / (7.5 * 3.0)))
    with pytest.raises(KeyError, match="kappa"):
        NIG.from_dict({"tau": 1.0, "a": 2.0, "b": 1.0})
    m = Moments.from_dict(Moments(torch.tensor(1.0), torch.tensor(2.0), torch.tensor(5.0)).to_dict())
    assert m.Q.item() == 5.0


def test_guards():
    nig = NIG(torch.tensor([0.0, 1.0]), torch.tensor([1.0, 1.0]), torch.tensor([3.0, 0.8]), torch.tensor([1.0, 1.0]))
    with pytest.raises(ValueError, match=r"a <= 1.*index 1.*a0 > 1"):
        nig.aleatoric()
    with pytest.raises(ValueError, match=r"a <= 1"):
        nig.epistemic()
    with pytest.raises(ValueError, match=r"NIG\(tau\): non-finite value at index 1"):
        NIG(torch.tensor([0.0, float("nan")]), 1.0, 2.0, 1.0)
    with pytest.raises(ValueError, match=r"NIG\(kappa\).*> 0"):
        NIG(0.0, 0.0, 2.0, 1.0)
    with pytest.raises(ValueError, match=r"NIG\(b\)"):
        NIG(0.0, 1.0, 2.0, -1.0)
    with pytest.raises(ValueError, match="do not broadcast"):
        NIG(torch.zeros(3), torch.ones(2), 2.0, 1.0)
    cls = torch.tensor([0, 1, 0])
    with pytest.raises(ValueError, match=r"confidence.*index 2"):
        Moments.from_observations(cls, torch.tensor([0.5, 0.5, -0.1]), torch.zeros(3, 2), 2)
    with pytest.raises(ValueError, match=r"class id out of range.*index 1"):
        Moments.from_observations(torch.tensor([0, 5, 0]), torch.ones(3), torch.zeros(3), 2)
    with pytest.raises(ValueError, match=r"infinite property value at index \(2, 1\)"):
        Moments.from_observations(cls, torch.ones(3), torch.tensor([[0.0, 0], [0, 0], [0, float("inf")]]), 2)
    with pytest.raises(ValueError, match=r"integer"):
        Moments.from_observations(cls.float(), torch.ones(3), torch.zeros(3), 2)
    with pytest.raises(ValueError, match=r"nig_update\(weight\).*>= 0"):
        nig_update(NIG(0.0, 1.0, 2.0, 1.0), 1.0, -0.5)
    with pytest.raises(ValueError, match=r"nig_update\(value\)"):
        nig_update(NIG(0.0, 1.0, 2.0, 1.0), float("inf"), 0.5)
    with pytest.raises(ValueError, match=r"Moments\(W\)"):
        Moments(torch.tensor(-1.0), 0.0, 0.0)


def test_zero_weight_and_empty_moments_keep_prior():
    prior = NIG(torch.tensor([1.0, -2.0], dtype=F64), torch.tensor([0.3, 2.0], dtype=F64),
                torch.tensor([2.0, 4.0], dtype=F64), torch.tensor([0.7, 1.1], dtype=F64))
    post = nig_posterior(prior, Moments.zeros((2,), dtype=F64))
    assert all(torch.equal(getattr(post, f), getattr(prior, f)) for f in ("tau", "kappa", "a", "b"))
    post = nig_update(prior, torch.tensor([100.0, -100.0], dtype=F64), 0.0)
    assert all(torch.equal(getattr(post, f), getattr(prior, f)) for f in ("tau", "kappa", "a", "b"))


def test_scatter_cancellation_is_clamped_and_accurate():
    # large values with tiny spread: Q - S^2/W cancels; identical values must give exactly zero scatter
    psi = torch.full((50,), 7850.0, dtype=torch.float32)
    cls = torch.zeros(50, dtype=torch.long)
    m = Moments.from_observations(cls, torch.full((50,), 0.3), psi, 1)
    prior = NIG(torch.tensor([7850.0]), torch.tensor([1.0]), torch.tensor([2.0]), torch.tensor([1.0]))
    post = nig_posterior(prior, m)
    assert post.b.item() >= 1.0 and post.b.item() == pytest.approx(1.0, abs=1e-2)
    assert post.tau.item() == pytest.approx(7850.0)


def test_empirical_matches_paper_A3():
    m = Moments.from_observations(torch.tensor([0, 0, 1]), torch.tensor([0.5, 1.0, 1.0], dtype=F64),
                                  torch.tensor([1.0, 4.0, 2.0], dtype=F64), 3)
    mu, var = m.empirical(eps=1e-6)
    assert mu[0].item() == pytest.approx(3.0) and var[0].item() == pytest.approx((0.5 + 16) / 1.5 - 9)
    assert var[1].item() == pytest.approx(1e-6) and math.isnan(mu[2].item())
