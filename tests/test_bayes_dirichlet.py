"""Dirichlet-Categorical material fusion: hand-computed evidence, scipy oracles, guards."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from physgs_nerfstudio.bayes import (
    dirichlet_posterior,
    dirichlet_strength,
    dominance_probability,
    evidence_from_observations,
    expected_entropy,
    mutual_information,
    predictive,
    predictive_entropy,
    vacuity,
)


def test_evidence_hand_computed_with_and_without_weights():
    classes = torch.tensor([0, 2, 0, 1])
    conf = torch.tensor([0.5, 0.8, 0.25, 1.0])
    ev = evidence_from_observations(classes, conf, num_classes=3)
    assert ev.tolist() == pytest.approx([0.75, 1.0, 0.8])
    weights = torch.tensor([[1.0, 0.0, 1.0, 0.0], [0.5, 0.5, 0.0, 0.2]])
    ev = evidence_from_observations(classes, conf, 3, weights)
    # entity 0: 1*0.5 + 1*0.25 on class 0; entity 1: 0.5*0.5 on 0, 0.2*1.0 on 1, 0.5*0.8 on 2
    assert ev.shape == (2, 3)
    assert ev[0].tolist() == pytest.approx([0.75, 0.0, 0.0])
    assert ev[1].tolist() == pytest.approx([0.25, 0.2, 0.4])
    alpha = dirichlet_posterior(ev, alpha0=1.0, lam=2.0)
    assert alpha[1].tolist() == pytest.approx([1.5, 1.4, 1.8])
    alpha_vec = dirichlet_posterior(ev, alpha0=torch.tensor([0.5, 1.0, 2.0]), lam=1.0)
    assert alpha_vec[0].tolist() == pytest.approx([1.25, 1.0, 2.0])


@settings(max_examples=30, deadline=None)
@given(m=st.integers(1, 30), k=st.integers(1, 6), e=st.integers(1, 4), seed=st.integers(0, 10_000))
def test_evidence_matches_dense_onehot_oracle(m, k, e, seed):
    rng = np.random.default_rng(seed)
    classes = rng.integers(0, k, m)
    conf = rng.random(m)
    w = rng.random((e, m))
    onehot = np.eye(k)[classes]  # [M, K]
    expected = (w * conf) @ onehot
    for dtype in (torch.float32, torch.float64):
        got = evidence_from_observations(torch.tensor(classes), torch.tensor(conf, dtype=dtype), k,
                                         torch.tensor(w, dtype=dtype))
        assert got.dtype == dtype
        np.testing.assert_allclose(got.numpy(), expected, rtol=1e-5 if dtype == torch.float32 else 1e-12, atol=1e-6)


def test_predictive_matches_scipy_dirichlet_mean_and_helpers():
    rng = np.random.default_rng(0)
    alpha = rng.random((5, 4)) * 5 + 0.1
    pi = predictive(torch.tensor(alpha))
    for i in range(5):
        np.testing.assert_allclose(pi[i].numpy(), stats.dirichlet.mean(alpha[i]), rtol=1e-12)
    np.testing.assert_allclose(dirichlet_strength(torch.tensor(alpha)).numpy(), alpha.sum(1))
    np.testing.assert_allclose(vacuity(torch.tensor(alpha)).numpy(), 4 / alpha.sum(1))
    np.testing.assert_allclose(
        predictive_entropy(torch.tensor(alpha)).numpy(), [stats.entropy(a / a.sum()) for a in alpha], rtol=1e-12
    )


def test_expected_entropy_and_mutual_information_monte_carlo():
    rng = np.random.default_rng(1)
    alpha = np.array([[0.7, 2.0, 4.0], [10.0, 10.0, 10.0], [50.0, 1.0, 0.5]])
    ee = expected_entropy(torch.tensor(alpha)).numpy()
    mi = mutual_information(torch.tensor(alpha)).numpy()
    for i, a in enumerate(alpha):
        theta = np.clip(stats.dirichlet.rvs(a, size=200_000, random_state=rng), 1e-300, None)
        h = -(theta * np.log(theta)).sum(1)
        se = h.std() / np.sqrt(len(h))
        assert abs(ee[i] - h.mean()) < 5 * se + 1e-9
        assert mi[i] == pytest.approx(stats.entropy(a / a.sum()) - h.mean(), abs=5 * se + 1e-9)
        assert mi[i] >= 0


def test_more_evidence_sharpens_predictive():
    ev = evidence_from_observations(torch.tensor([1, 1, 1, 0]), torch.tensor([0.9, 0.8, 0.9, 0.3]), 3)
    a1 = dirichlet_posterior(ev, 1.0, 1.0)
    a2 = dirichlet_posterior(2 * ev, 1.0, 1.0)
    assert predictive(a2)[1] > predictive(a1)[1]
    assert predictive_entropy(a2) < predictive_entropy(a1)
    assert mutual_information(a2) < mutual_information(a1)


def test_guards_name_the_offending_index():
    cls = torch.tensor([0, 1, 2])
    with pytest.raises(ValueError, match=r"confidence outside \[0, 1\] at index 1"):
        evidence_from_observations(cls, torch.tensor([0.2, -0.1, 0.3]), 3)
    with pytest.raises(ValueError, match=r"non-finite value at index 2"):
        evidence_from_observations(cls, torch.tensor([0.2, 0.1, float("nan")]), 3)
    with pytest.raises(ValueError, match=r"class id out of range \[0, 3\) at index 2"):
        evidence_from_observations(torch.tensor([0, 1, 3]), torch.ones(3), 3)
    with pytest.raises(ValueError, match=r"class id out of range.*index 0"):
        evidence_from_observations(torch.tensor([-1, 1, 2]), torch.ones(3), 3)
    with pytest.raises(ValueError, match=r"weights.*>= 0 at index \(1, 0\)"):
        evidence_from_observations(cls, torch.ones(3), 3, torch.tensor([[1.0, 1, 1], [-1, 0, 0]]))
    with pytest.raises(ValueError, match=r"weights must have shape"):
        evidence_from_observations(cls, torch.ones(3), 3, torch.ones(2, 4))
    with pytest.raises(ValueError, match=r"one confidence per observation"):
        evidence_from_observations(cls, torch.ones(4), 3)
    with pytest.raises(ValueError, match=r"alpha0.*> 0"):
        dirichlet_posterior(torch.zeros(3), 0.0, 1.0)
    with pytest.raises(ValueError, match=r"lam"):
        dirichlet_posterior(torch.zeros(3), 1.0, -1.0)
    with pytest.raises(ValueError, match=r"predictive\(alpha\).*index \(0, 1\)"):
        predictive(torch.tensor([[1.0, 0.0, 1.0]]))


# ---------------------------------------------------------------------------------------------------------
# dominance probability P(theta_i = max_j theta_j)
# ---------------------------------------------------------------------------------------------------------


def test_dominance_two_classes_matches_regularised_beta():
    """K = 2: theta_1 ~ Beta(a1, a2), so P(theta_1 is max) = P(theta_1 > 1/2) = 1 - I_{1/2}(a1, a2)."""
    from scipy.special import betainc

    a = np.array([[2.0, 3.0], [0.05, 0.3], [0.5, 0.7], [100.0, 120.0], [1e4, 1.02e4], [7.0, 7.5], [30.0, 1.0]])
    got = dominance_probability(torch.tensor(a))
    np.testing.assert_allclose(got[:, 0].numpy(), 1 - betainc(a[:, 0], a[:, 1], 0.5), atol=1e-9)
    np.testing.assert_allclose(got.sum(-1).numpy(), 1.0, atol=1e-12)


def test_dominance_vs_monte_carlo_argmax_frequencies():
    rng = np.random.default_rng(0)
    alphas = np.array([
        [1.0, 1.0, 3.0, 0.5],
        [5.2, 4.8, 1.0, 1.0],
        [0.3, 0.1, 0.2, 0.05],  # all concentrations small (the coarsest regime)
        [40.0, 38.0, 35.0, 1.0],
        [1.0 + 4 * 6.0, 1.0 + 4 * 4.0, 1.0, 1.0],  # a 60/40 split after 10 observations
    ])
    got = dominance_probability(torch.tensor(alphas)).numpy()
    n = 200_000
    for a, p in zip(alphas, got):
        freq = np.bincount(np.argmax(rng.dirichlet(a, size=n), axis=1), minlength=len(a)) / n
        se = np.sqrt(np.maximum(p * (1 - p), 1e-12) / n)
        assert np.all(np.abs(freq - p) <= 5 * se + 1e-9), (a, freq, p)


def test_dominance_symmetric_is_uniform_and_evidence_concentrates():
    for k, a0 in ((3, 1.0), (20, 0.05), (7, 1000.0)):
        p = dominance_probability(torch.full((2, k), a0, dtype=torch.float64))
        torch.testing.assert_close(p, torch.full_like(p, 1.0 / k), rtol=0, atol=1e-12)
    # the predictive of a 60/40 split stays at 0.6; the dominance probability goes to 1
    n = torch.tensor([1.0, 10.0, 100.0, 1000.0], dtype=torch.float64)[:, None]
    alpha = 1.0 + n * torch.tensor([[0.6, 0.4, 0.0]], dtype=torch.float64)
    p0 = dominance_probability(alpha)[:, 0]
    assert torch.all(torch.diff(p0) > 0) and p0[-1] > 1 - 1e-9
    assert predictive(alpha)[-1, 0].item() == pytest.approx(0.6, abs=1e-3)


def test_dominance_shapes_dtypes_chunks_and_extremes():
    rng = np.random.default_rng(1)
    a = torch.tensor(np.exp(rng.uniform(np.log(0.05), np.log(1e4), (2, 5, 6))))
    ref = dominance_probability(a, num_nodes=1024)
    got = dominance_probability(a, chunk_elements=64 * 6 * 3)  # chunks of 3 entities
    assert got.shape == (2, 5, 6) and got.dtype == torch.float64
    torch.testing.assert_close(got, ref, rtol=0, atol=1e-6)
    rep = a.reshape(-1, 6)[torch.tensor([0, 3, 3, 0, 0, 7, 3, 3])]  # repeated rows are computed once
    torch.testing.assert_close(dominance_probability(rep), ref.reshape(-1, 6)[[0, 3, 3, 0, 0, 7, 3, 3]],
                               rtol=0, atol=1e-6)
    g32 = dominance_probability(a.float())
    assert g32.dtype == torch.float32
    torch.testing.assert_close(g32.double(), ref, rtol=0, atol=1e-5)
    # extreme concentrations stay finite and normalised
    ext = torch.tensor([[1e-12, 1e-12, 1.0], [1e6, 1e-3, 1e-3], [1e-3, 1e-3, 1e-3], [1e7, 1e7 + 1e4, 1.0]],
                       dtype=torch.float64)
    pe = dominance_probability(ext)
    assert torch.isfinite(pe).all() and torch.allclose(pe.sum(-1), torch.ones(4, dtype=torch.float64))
    from scipy.special import betainc

    assert pe[1, 0] > 1 - 1e-12
    assert pe[3, 1].item() == pytest.approx(betainc(1e7, 1e7 + 1e4, 0.5), abs=1e-6)  # class 2 (alpha 1) is negligible
    assert torch.allclose(pe[2], torch.full((3,), 1 / 3, dtype=torch.float64))
    assert dominance_probability(torch.tensor([[2.5]])).tolist() == [[1.0]]
    assert dominance_probability(torch.zeros(0, 4)).shape == (0, 4)
    with pytest.raises(ValueError, match="> 0"):
        dominance_probability(torch.tensor([[1.0, 0.0]]))


_alpha_st = st.lists(st.floats(0.05, 500.0), min_size=2, max_size=7)


@settings(max_examples=40, deadline=None)
@given(alpha=_alpha_st, perm_seed=st.integers(0, 10_000), i=st.integers(0, 6), bump=st.floats(0.05, 50.0))
def test_dominance_invariants(alpha, perm_seed, i, bump):
    a = torch.tensor([alpha], dtype=torch.float64)
    p = dominance_probability(a)
    assert torch.all(p >= 0) and abs(p.sum().item() - 1) < 1e-12
    perm = torch.as_tensor(np.random.default_rng(perm_seed).permutation(a.shape[1]))
    torch.testing.assert_close(dominance_probability(a[:, perm]), p[:, perm], rtol=0, atol=1e-9)
    i = i % a.shape[1]
    a2 = a.clone()
    a2[0, i] += bump
    p2 = dominance_probability(a2)
    assert p2[0, i] >= p[0, i] - 1e-9  # more evidence for i never makes i less likely to dominate
    others = torch.arange(a.shape[1]) != i
    assert torch.all(p2[0, others] <= p[0, others] + 1e-9)
