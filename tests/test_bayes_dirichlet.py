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
