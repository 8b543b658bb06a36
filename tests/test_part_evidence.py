"""A part's material from the views' answers about it (geometry/part_evidence.py)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from helpers.shapes import box_surface, ring_views

from physgs_nerfstudio.export.shapes import field_from
from physgs_nerfstudio.geometry import GeometryConfig, MaskObservation, SelectConfig, reconstruct_object
from physgs_nerfstudio.geometry.gaussians import render_depth
from physgs_nerfstudio.geometry.part_evidence import fuse_part_materials, observation_shares, part_maps
from physgs_nerfstudio.mass import MassConfig, integrate_mass

# a steel box and an oak box among eight distractor materials of other densities
NAMES = ["steel", "oak", "cast_iron", "pine", "glass", "abs", "cork", "wool", "granite", "eps"]
DENS = [7850.0, 700.0, 7200.0, 500.0, 2500.0, 1050.0, 240.0, 300.0, 2700.0, 20.0]


@pytest.fixture(scope="module")
def two_boxes():
    left = box_surface((0.2, 0.2, 0.2), 0.02, centre=(-0.3, 0.0, 0.0))
    right = box_surface((0.2, 0.2, 0.2), 0.02, centre=(0.3, 0.0, 0.0))
    means, scales, quats = (torch.cat([a, b]) for a, b in zip(left, right))
    labels = torch.cat([torch.zeros(len(left[0])), torch.ones(len(right[0]))]).long()
    # each Gaussian holds a sliver of one view's answer (evidence 0.3 on its material against a prior of 1 on each
    # of the 10): the per-Gaussian posteriors are near the prior, as after a short training with few views
    pf = field_from(means, scales, quats, densities=DENS, labels=labels, names=NAMES, confidence=0.3)
    views = ring_views(pf, (0, 0, 0), 1.6, n=8)
    lm = render_depth(field_from(*left, densities=DENS, names=NAMES), views, backend="reference")
    rm = render_depth(field_from(*right, densities=DENS, names=NAMES), views, backend="reference")
    obs = []
    for v, a, b in zip(views, lm, rm):
        lmask = (a.alpha > 0.5).numpy() & ~(b.alpha > 0.5).numpy()
        rmask = (b.alpha > 0.5).numpy() & ~(a.alpha > 0.5).numpy()
        obs += [MaskObservation(v.name, lmask, "steel", 0.7, None), MaskObservation(v.name, lmask, "cast_iron", 0.3, None),
                MaskObservation(v.name, rmask, "oak", 0.8, None), MaskObservation(v.name, rmask, "pine", 0.2, None)]  # fmt: skip
    return pf, views, obs


@pytest.fixture(scope="module")
def geos(two_boxes):
    """"observations": the parts' materials from the views' answers; "pooled": without observations, each part's
    Gaussians' pooled posterior (:func:`physgs_nerfstudio.geometry.parts.pooled_part_alpha`)."""
    pf, views, obs = two_boxes
    return {"observations": _reconstruct(pf, views, obs), "pooled": _reconstruct(pf, views, ())}


def _reconstruct(pf, views, obs):
    cfg = GeometryConfig(resolution=48, backend="reference", select=SelectConfig(bridge_cells=1, cluster_cells=4))
    return reconstruct_object(pf, pf.pi(), views, obs, [None] * len(NAMES), cfg, material_names=NAMES,
                              alpha=pf.alpha, dirichlet_prior=(1.0, 4.0))  # fmt: skip


def test_fused_evidence_equals_a_brute_force_count(two_boxes, geos):
    """alpha_s = alpha0 + lambda sum_o l_o p_o share_os onehot(c_o), counted pixel by pixel from the part maps."""
    pf, views, obs = two_boxes
    geo = geos["observations"]
    parts = np.where(geo.solid, geo.parts, -1)
    P = geo.num_parts
    weights = [1.0, 1.5, 0.5, 1.0] * len(views)
    obs_w = [
        MaskObservation(o.view, o.mask, o.material, o.confidence, None, weight=w)
        for o, w in zip(obs, weights)
    ]
    shares = observation_shares(geo.grid, parts, P, views, obs_w)
    alpha, seen = fuse_part_materials(shares, obs_w, NAMES, P, 1.0, 4.0)
    expect = np.ones((P, len(NAMES)))
    by_view = {v.name: v for v in views}
    for o in obs_w:
        h, w = o.mask.shape
        ids = part_maps(geo.grid, parts, by_view[o.view], w, h)[o.mask]
        ids = ids[ids >= 0]
        for s in range(P):
            if len(ids):
                expect[s, NAMES.index(o.material)] += (
                    4.0 * o.weight * o.confidence * float((ids == s).sum()) / len(ids)
                )
    np.testing.assert_allclose(alpha, expect, rtol=1e-12)
    np.testing.assert_allclose(seen, (expect - 1.0).sum(1) / 4.0, rtol=1e-12)


def test_parts_take_their_material_from_the_views_not_the_diluted_gaussians(two_boxes, geos):
    pf, views, obs = two_boxes
    geo, pooled = geos["observations"], geos["pooled"]
    assert geo.num_parts == 2
    xs = [float(np.argwhere(geo.parts == p)[:, 0].mean()) for p in range(2)]
    left, right = (0, 1) if xs[0] < xs[1] else (1, 0)
    # the views' answers, counted once per view: steel on the left (against cast iron), oak on the right
    assert geo.part_mixture[left, NAMES.index("steel")] > 0.95
    assert geo.part_mixture[right, NAMES.index("oak")] > 0.95
    # the mean of the Gaussians' posteriors keeps most of the weight on materials no view named
    assert pooled.part_mixture[left, NAMES.index("steel")] < 0.5
    # and the mass follows: the boxes' solid volumes (each sample draws one geometry variant) at steel's and oak's
    # densities
    rep = integrate_mass(pf, geo, MassConfig(n_samples=4000, structure="solid"))
    v = geo.volumes.mean(0)
    expect = DENS[0] * v[left] + DENS[1] * v[right]
    assert rep.mean_kg == pytest.approx(expect, rel=0.05)


def test_a_part_no_view_answers_keeps_its_gaussians_posterior(two_boxes, geos):
    pf, views, obs = two_boxes
    only_left = [o for o in obs if o.material in ("steel", "cast_iron")]
    geo = _reconstruct(pf, views, only_left)
    pooled = geos["pooled"]
    xs = [float(np.argwhere(geo.parts == p)[:, 0].mean()) for p in range(2)]
    right = 1 if xs[0] < xs[1] else 0
    np.testing.assert_allclose(geo.part_mixture[right], pooled.part_mixture[right])


def _brute_absorb(parts, observed):
    """Oracle for absorb_unobserved: per unobserved voxel, a loop over every observed voxel of the solid, giving the
    set of old part ids at the nearest (Euclidean) distance, or None where the voxel's 26-connected piece holds no
    observed voxel (it keeps its part)."""
    from scipy import ndimage

    piece, _ = ndimage.label(parts >= 0, structure=np.ones((3, 3, 3), bool))
    seen = np.argwhere((parts >= 0) & observed[np.maximum(parts, 0)])
    reached = set(piece[tuple(seen.T)].tolist())
    out = {}
    for ijk in np.argwhere((parts >= 0) & ~observed[np.maximum(parts, 0)]):
        if piece[tuple(ijk)] in reached:
            d = ((seen - ijk) ** 2).sum(1)
            out[tuple(ijk)] = set(parts[tuple(seen[d == d.min()].T)].tolist())
        else:
            out[tuple(ijk)] = None
    return out


def test_unobserved_parts_join_the_nearest_observed_part():
    """A closed box (observed wall, part 0) whose filled inside split into two unobserved parts (1, 2) and a lid of
    another observed material (3); a separate unobserved speck (4) is kept. Checked against a brute-force nearest
    search (any of the parts tied at the nearest distance); the speck keeps its own part, renumbered."""
    from physgs_nerfstudio.geometry.part_evidence import absorb_unobserved

    parts = np.full((14, 12, 12), -1, np.int64)
    parts[1:11, 1:11, 1:11] = 0
    parts[3:6, 2:10, 2:10] = 1
    parts[6:9, 2:10, 2:10] = 2
    parts[1:11, 1:11, 10] = 3
    parts[12:14, 0:2, 0:2] = 4
    observed = np.array([True, False, False, True, False])
    out = absorb_unobserved(parts, observed)
    old_of_new = {0: 0, 1: 3, 2: 4}  # kept parts in their old order
    assert set(np.unique(out[out >= 0]).tolist()) == set(old_of_new)
    for ijk, near in _brute_absorb(parts, observed).items():
        assert old_of_new[int(out[ijk])] in (near if near is not None else {int(parts[ijk])}), ijk
    keep = observed[np.maximum(parts, 0)] & (parts >= 0)
    assert np.array_equal(np.vectorize(old_of_new.get)(out[keep]), parts[keep])  # observed voxels stay
    assert (out[3:9, 2:10, 2:5] == 0).all() and (out[4:8, 4:8, 9] == 1).all()  # walls below, the lid above
    assert np.array_equal(out >= 0, parts >= 0)  # no voxel gained or lost
    assert absorb_unobserved(parts, np.ones(5, bool)) is parts  # nothing to absorb: the same grid


def test_touching_parts_of_one_material_merge():
    """Two cardboard parts that touch merge (numbered by their first old part); a third cardboard part separated from
    them by an oak part does not; negative materials (parts that must stay alone) never merge."""
    from physgs_nerfstudio.geometry.part_evidence import merge_same_material

    parts = np.full((12, 6, 6), -1, np.int64)
    parts[0:3, 1:4, 1:4] = 0
    parts[3:5, 1:4, 1:4] = 1  # oak between
    parts[5:7, 1:4, 1:4] = 2
    parts[7:9, 1:4, 1:4] = 3  # touches 2
    parts[9:11, 1:4, 1:4] = 4  # touches 3, must stay alone
    out, old_to_new = merge_same_material(parts, np.array([0, 1, 0, 0, -5]))
    assert old_to_new.tolist() == [0, 1, 2, 2, 3]
    assert np.array_equal(out, np.where(parts >= 0, old_to_new[np.maximum(parts, 0)], -1))
    same, ident = merge_same_material(parts, np.array([0, 1, 2, 3, 4]))
    assert same is parts and ident.tolist() == [0, 1, 2, 3, 4]
