"""How much of a mask's hollow-or-solid call concerns each 3-D part (geometry/structure.py, "Evidence").

The shares of each mask's pixels per part are given directly (``fuse_structure(..., shares=...)``), so the
weights are checked against hand-computed values, with no rendering."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from physgs_nerfstudio.geometry import MaskObservation, StructureConfig
from physgs_nerfstudio.geometry.structure import fuse_structure

NAMES = ["paper", "cardboard", "leather", "natural_rubber"]
_MASK = np.ones((2, 2), bool)


def _fuse(observations, shares, mixture, evidence, lib=(0.0002, 0.004)):
    return fuse_structure(None, None, len(mixture), [], observations, list(lib), np.asarray(mixture, float), NAMES,
                          StructureConfig(evidence=evidence), shares=shares)  # fmt: skip


def _answer(view, mask_id, candidates, thickness):
    """One mask's candidates [(material, confidence)], all with one call: hollow at ``thickness`` or solid (None)."""
    return [MaskObservation(view, _MASK, m, p, thickness, mask_id=mask_id) for m, p in candidates]


def test_a_part_whose_material_the_views_split_hears_each_mask_that_shows_it():
    """The crate at CPU seed 16161: one part of the box is 0.63 paper and 0.28 cardboard, and its masks name
    cardboard first. Session 33 counted a mask on it at 0.7 x 0.28 + 0.3 x 0.63 = 0.385 of a view; the mask's one
    judgment counts whole where the mask is all this part."""
    mixture = [[0.63, 0.28, 0.09, 0.0], [0.0, 1.0, 0.0, 0.0]]
    obs, shares = [], []
    for v in range(6):
        for ob in _answer(f"v{v}", 0, [("cardboard", 0.7), ("paper", 0.3)], 0.004):
            shares.append((len(obs), np.array([1.0, 0.0])))
            obs.append(ob)
    old = _fuse(obs, shares, mixture, "material")
    new = _fuse(obs, shares, mixture, "mask")
    assert old.observations[0] == pytest.approx(6 * 0.385)
    assert new.observations[0] == pytest.approx(6.0)
    prior_a = 0.6  # the paper part's library thickness: hollow a priori with 0.6, one pseudo-observation
    assert new.hollow_a[0] == pytest.approx(prior_a + 6.0) and new.hollow_b[0] == pytest.approx(0.4)
    assert new.p_hollow[0] > old.p_hollow[0]
    assert new.observations[1] == 0 and new.hollow_a[1] == pytest.approx(0.6)
    # the thickness is an answer about one material: its weights are session 33's, and so is its posterior
    assert float(new.thickness.tau[0]) == pytest.approx(float(old.thickness.tau[0]))
    assert float(new.thickness.kappa[0]) == pytest.approx(float(old.thickness.kappa[0]))


def test_a_mask_that_spills_onto_a_part_of_another_material_says_little_about_it():
    """The shoe: a mask of the leather upper answered hollow, a fifth of its pixels on the rubber sole in the
    z-buffer. The sole is of no material it named, so the call counts there as far as the sole fills the mask:
    0.2 x 0.2 = 0.04 (its share alone would give 0.2)."""
    mixture = [[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
    obs = _answer("v0", 3, [("leather", 0.9), ("paper", 0.1)], 0.002)
    shares = [(0, np.array([0.8, 0.2])), (1, np.array([0.8, 0.2]))]
    s = _fuse(obs, shares, mixture, "mask", lib=(0.002, None))
    assert s.hollow_a[0] - 0.6 == pytest.approx(0.8)  # all of the mask's judgment that is the upper's
    assert s.hollow_a[1] - 0.3 == pytest.approx(0.04)
    assert s.hollow_b[1] == pytest.approx(0.7)  # the sole's prior, solid at 0.7, untouched


def test_candidates_that_call_it_differently_split_the_mask_by_how_well_they_fit():
    """A real VLM may call a part hollow as steel-like cardboard and solid as paper: the mask's weight on the
    part goes to each call as far as the candidate's material fits it (confidence x mixture weight)."""
    mixture = [[0.5, 0.5, 0.0, 0.0]]
    obs = [MaskObservation("v0", _MASK, "cardboard", 0.6, 0.004, mask_id=0),
           MaskObservation("v0", _MASK, "paper", 0.4, None, mask_id=0)]  # fmt: skip
    shares = [(0, np.array([1.0])), (1, np.array([1.0]))]
    s = _fuse(obs, shares, mixture, "mask", lib=(0.0002,))
    assert s.hollow_a[0] - 0.6 == pytest.approx(0.6) and s.hollow_b[0] - 0.4 == pytest.approx(0.4)


def test_masks_are_told_apart_by_their_ids_or_their_pixels():
    """Without ``mask_id`` (observations built by hand), candidates share a mask when they share its array."""
    mixture = [[1.0, 0.0, 0.0, 0.0]]
    a, b = np.ones((2, 2), bool), np.ones((2, 2), bool)
    obs = [MaskObservation("v0", a, "paper", 0.5, None), MaskObservation("v0", a, "cardboard", 0.5, None),
           MaskObservation("v0", b, "paper", 1.0, None)]  # fmt: skip
    shares = [(i, np.array([1.0])) for i in range(3)]
    assert _fuse(obs, shares, mixture, "mask", lib=(None,)).observations[0] == pytest.approx(2.0)


def test_the_setting_is_checked():
    with pytest.raises(ValueError, match="evidence"):
        StructureConfig(evidence="share")  # type: ignore[arg-type]


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_a_mask_counts_at_most_once_and_never_less_than_before(data):
    """Per mask and part, the call's weight is at most the part's share of the mask, and at least session 33's
    sum of confidence x share x mixture weight: sum_c p_c pi_sc <= (sum_c p_c)(sum_c pi_sc)."""
    n_parts = data.draw(st.integers(1, 3))
    rows = [data.draw(st.lists(st.floats(0, 1), min_size=4, max_size=4)) for _ in range(n_parts)]
    mixture = np.array([r if sum(r) > 0 else [1, 0, 0, 0] for r in rows], float)
    mixture /= mixture.sum(1, keepdims=True)
    share = np.array(data.draw(st.lists(st.floats(0.01, 1), min_size=n_parts, max_size=n_parts)))
    share /= share.sum()
    k = data.draw(st.integers(1, 4))
    mats = data.draw(st.permutations(NAMES))[:k]
    conf = np.array(data.draw(st.lists(st.floats(0.01, 1), min_size=k, max_size=k)))
    conf /= max(conf.sum(), 1.0)
    hollow = data.draw(st.lists(st.booleans(), min_size=k, max_size=k))
    obs = [MaskObservation("v0", _MASK, m, float(p), 0.003 if h else None, mask_id=0)
           for m, p, h in zip(mats, conf, hollow)]  # fmt: skip
    shares = [(i, share) for i in range(k)]
    new = _fuse(obs, shares, mixture, "mask", lib=[None] * n_parts)
    old = _fuse(obs, shares, mixture, "material", lib=[None] * n_parts)
    assert (new.observations <= share + 1e-9).all()
    assert (new.observations >= old.observations - 1e-9).all()
