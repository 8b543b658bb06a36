"""Hidden open space (physgs_nerfstudio.geometry.hidden): the pointer-doubling scan against a direct ray march,
a table top's hidden underside removed while the top, its legs and closed solids stay, and a table shot only from
above through the whole reconstruction."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch
from helpers.shapes import grown_skin, whole_voxel_volume
from hypothesis import given, settings
from hypothesis import strategies as st

from physgs_nerfstudio.geometry.hidden import (
    LATTICE_DIRECTIONS,
    gaussian_samples,
    hidden_open_rules,
    hidden_open_space,
    open_counts,
    open_fraction,
    skin_centred,
    without_hidden_space,
    without_hidden_space_many,
)


def _march_rays(solid: np.ndarray, skin: np.ndarray, closed: np.ndarray, v: tuple[int, int, int]
                ) -> dict[tuple[int, int, int], bool]:  # fmt: skip
    """Whether the ray from ``v`` in each lattice direction is open, one ray at a time (the module doc's definition,
    as a loop)."""
    out = {}
    shape = np.array(solid.shape)
    for d in LATTICE_DIRECTIONS:
        subs = [e for e in itertools.product(*[(0, s) if s else (0,) for s in d]) if any(e)]
        cur = np.array(v)
        while True:
            touched = [cur + np.array(e) for e in subs]
            if any(np.all((t >= 0) & (t < shape)) and skin[tuple(t)] for t in touched):
                out[d] = False  # the step crosses the skin: enclosed
                break
            nxt = cur + np.array(d)
            if not np.all((nxt >= 0) & (nxt < shape)):
                out[d] = True  # leaves the grid
                break
            if not solid[tuple(nxt)]:
                out[d] = not closed[tuple(nxt)]
                break
            cur = nxt
    return out


def _open_half(rays: dict[tuple[int, int, int], bool]) -> int:
    """The most open directions of one half whose 8 directions across it hold an open one (0 if none does)."""
    best = 0
    for axis in range(3):
        if any(o for d, o in rays.items() if d[axis] == 0):
            for s in (-1, 1):
                best = max(best, sum(o for d, o in rays.items() if d[axis] == s))
    return best


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), fill=st.floats(0.3, 0.9), skin_share=st.floats(0.0, 0.3))
def test_open_fraction_is_the_direct_ray_march(seed, fill, skin_share):
    rng = np.random.default_rng(seed)
    shape = (7, 6, 5)
    solid = rng.random(shape) < fill
    skin = rng.random(shape) < skin_share
    closed = rng.random(shape) < 0.3
    f = open_fraction(torch.from_numpy(solid), torch.from_numpy(skin), torch.from_numpy(closed)).numpy()
    total, half = open_counts(torch.from_numpy(solid), torch.from_numpy(skin), torch.from_numpy(closed))
    for v in map(tuple, np.argwhere(solid)):
        rays = _march_rays(solid, skin, closed, v)
        assert f[v] == pytest.approx(sum(rays.values()) / len(LATTICE_DIRECTIONS), abs=1e-6)
        assert int(total[v]) == sum(rays.values()) and int(half[v]) == _open_half(rays)


def _passes_by_march(solid: np.ndarray, skin: np.ndarray, closed: np.ndarray, frac: float, half: int, passes: int
                     ) -> tuple[np.ndarray, dict[str, int]]:  # fmt: skip
    """without_hidden_space as a loop over voxels and passes on the whole grid (the module doc's rules)."""
    solid = solid.copy()
    removed = {"majority": 0, "open_half": 0}
    for _ in range(passes):
        rule = np.zeros(solid.shape, np.uint8)
        for v in map(tuple, np.argwhere(solid & ~skin)):
            rays = _march_rays(solid, skin, closed, v)
            if sum(rays.values()) / len(LATTICE_DIRECTIONS) > frac:
                rule[v] = 1
            elif _open_half(rays) >= half:
                rule[v] = 2
        removed["majority"] += int((rule == 1).sum())
        removed["open_half"] += int((rule == 2).sum())
        if not rule.any():
            break
        solid &= rule == 0
    return solid, removed


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), chunk=st.sampled_from([1, 200, 2**25]))
def test_many_solids_at_once_are_each_alone_by_the_direct_ray_march(seed, chunk):
    # the carving's variants share the skin and run together on their common bounding box, in chunks: the same
    # voxels and counts as each alone on the whole grid, pass after pass
    rng = np.random.default_rng(seed)
    shape = (9, 8, 7)
    skin = rng.random(shape) < 0.15
    closed = rng.random(shape) < 0.2
    solids = []
    for _ in range(3):  # each in its own sub-box, some reaching the grid's edge
        lo = rng.integers(0, 3, 3)
        hi = lo + rng.integers(3, 7, 3)
        s = np.zeros(shape, bool)
        s[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] = rng.random(tuple(np.minimum(hi, shape) - lo)) < 0.8
        solids.append(s)
    kept, removed = without_hidden_space_many(torch.from_numpy(np.stack(solids)), torch.from_numpy(skin),
                                              torch.from_numpy(closed), 0.5, 9, 3, max_voxels=chunk)  # fmt: skip
    for i, s in enumerate(solids):
        want, counts = _passes_by_march(s, skin, closed, 0.5, 9, 3)
        assert np.array_equal(kept[i].numpy(), want) and removed[i] == counts, i


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), frac=st.floats(0.0, 0.95))
def test_hidden_space_lies_in_the_solid_off_the_skin_and_shrinks_with_the_skin(seed, frac):
    rng = np.random.default_rng(seed)
    shape = (9, 8, 7)
    solid = torch.from_numpy(rng.random(shape) < 0.7)
    skin = torch.from_numpy(rng.random(shape) < 0.1)
    more = skin | torch.from_numpy(rng.random(shape) < 0.1)
    h = hidden_open_space(solid, skin, None, frac)
    assert not bool((h & ~solid).any()) and not bool((h & skin).any())
    # more skin encloses more: every ray blocked before is blocked now
    assert not bool((hidden_open_space(solid, more, None, frac) & ~h).any())
    # a stricter majority removes less
    assert not bool((hidden_open_space(solid, skin, None, min(0.99, frac + 0.2)) & ~h).any())
    # the open half adds to the majority, and a looser half adds more
    h9 = hidden_open_space(solid, skin, None, frac, 9)
    assert not bool((h & ~h9).any()) and not bool((h9 & ~hidden_open_space(solid, skin, None, frac, 8)).any())
    assert not bool((h9 & skin).any())
    # the rules' grid: 1 where the majority removes, 2 where only the open half does
    rule = hidden_open_rules(solid, skin, None, frac, 9)
    assert torch.equal(rule == 1, h) and torch.equal(rule == 2, h9 & ~h)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 40), window=st.integers(0, 2), tol=st.floats(0.3, 2.0))
def test_centred_skin_is_the_windowed_centroid_rule(seed, n, window, tol):
    """Voxel by voxel, against a direct loop: skin when the voxel holds a point, or when the points in its window
    (``window`` voxels each way) have their centroid within ``tol`` voxels of its centre."""
    rng = np.random.default_rng(seed)
    shape = (6, 5, 7)
    pts = rng.uniform(-0.5, np.array(shape) + 0.5, (n, 3)) * 0.2  # some outside the grid; 0.2 scene units a voxel
    origin = np.zeros(3)
    skin = skin_centred(torch.from_numpy(pts), origin, 0.2, shape, window, tol).numpy()
    p = pts / 0.2
    ij = np.floor(p).astype(int)
    inside = np.all((ij >= 0) & (ij < shape), 1)
    p, ij = p[inside], ij[inside]
    for v in itertools.product(*map(range, shape)):
        near = np.all(np.abs(ij - v) <= window, 1)
        want = bool(np.all(ij == v, 1).any())
        if near.any():
            want |= bool(np.linalg.norm(p[near].mean(0) - (np.array(v) + 0.5)) <= tol)
        assert skin[v] == want, v


def test_centred_skin_closes_a_gappy_plane_without_growing_off_it_or_past_its_edge():
    """A plane z = 10.5 over x < 12, sampled at a third of its voxels (jittered within them): the centred skin covers
    nearly all of the plane, no thicker than 1 + 2 x 1.5 voxels across it, and stops within a voxel of its edge."""
    shape = (20, 20, 21)
    plane = np.zeros(shape, bool)
    plane[:12, :, 10] = True
    rng = np.random.default_rng(3)
    pts = _sparse_points(plane, 1 / 3, rng)
    pts = pts + torch.from_numpy(rng.uniform(-0.5, 0.5, pts.shape))
    skin = skin_centred(pts, np.zeros(3), 1.0, shape, 2, 1.5).numpy()
    assert skin[1:11, 1:19, 8:13].any(2).mean() > 0.95  # the gaps closed (away from the grid's border)
    assert not skin[:, :, :8].any() and not skin[:, :, 13:].any()
    assert not skin[13:].any()  # the edge at x = 12 did not move by more than a voxel


def test_a_closed_solid_sampled_with_gaps_keeps_its_inside_with_the_centred_skin():
    """The gappy cube of the test below, with the default skin: its inside stays."""
    shape = (20, 20, 20)
    solid = np.zeros(shape, bool)
    solid[3:17, 3:17, 1:15] = True
    shell = solid & ~np.pad(np.ones((12, 12, 13), bool), ((4, 4), (4, 4), (1, 6)))
    shell[:, :, 1] &= False
    closed = np.zeros(shape, bool)
    closed[:, :, :1] = True
    rng = np.random.default_rng(1)
    pts = _sparse_points(shell, 1 / 3, rng)
    pts = pts + torch.from_numpy(rng.uniform(-0.5, 0.5, pts.shape))
    skin = skin_centred(pts, np.zeros(3), 1.0, shape, 2, 1.5)
    assert not hidden_open_space(torch.from_numpy(solid), skin, torch.from_numpy(closed)).any()
    assert not hidden_open_space(torch.from_numpy(solid), skin, torch.from_numpy(closed), 0.5, 9).any()  # open half
    kept, removed = without_hidden_space(torch.from_numpy(solid), skin, torch.from_numpy(closed), 0.5, 9, 8)
    assert torch.equal(kept, torch.from_numpy(solid)) and removed == {"majority": 0, "open_half": 0}  # passes


def test_gaussian_samples_are_the_means_and_their_axes_ends():
    means = torch.tensor([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]], dtype=torch.float64)
    scales = torch.tensor([[0.1, 0.2, 0.3], [1.0, 1.0, 0.01]], dtype=torch.float64)
    quats = torch.nn.functional.normalize(torch.tensor([[1.0, 0.2, -0.3, 0.4], [0.3, 0.1, 0.9, -0.2]],
                                                       dtype=torch.float64), dim=1)  # fmt: skip
    s = gaussian_samples(means, scales, quats, 2.0)
    assert s.shape == (14, 3) and torch.equal(s[:2], means)
    ends = s[2:].reshape(2, 6, 3) - means[:, None]
    # six ends per Gaussian, in +- pairs, at 2 sigma along three orthogonal axes
    assert torch.allclose(ends[:, :3], -ends[:, 3:])
    assert torch.allclose(ends[:, :3].norm(dim=-1), 2 * scales)
    gram = ends[:, :3] @ ends[:, :3].transpose(1, 2)
    assert torch.allclose(gram - torch.diag_embed(torch.diagonal(gram, dim1=1, dim2=2)), torch.zeros_like(gram),
                          atol=1e-12)  # fmt: skip


def _table(thickness: int = 2):
    """A 24 x 24 x 26 grid: a floor below z = 1; a top (``thickness`` voxels under z = 20) on four 2 x 2 legs; the
    carving kept the space under the top from z 10 (no view saw past it); the skin is the top's upper face and
    sides and the legs' outsides, where the views saw the surface."""
    shape = (24, 24, 26)
    under = 20 - thickness
    top = np.zeros(shape, bool)
    top[2:22, 2:22, under:20] = True
    legs = np.zeros(shape, bool)
    for x, y in [(2, 2), (20, 2), (2, 20), (20, 20)]:
        legs[x:x + 2, y:y + 2, 1:under] = True
    hidden = np.zeros(shape, bool)
    hidden[5:19, 5:19, 10:under] = True  # grazing rays from the sides carved the rest
    solid = top | legs | hidden
    closed = np.zeros(shape, bool)
    closed[:, :, :1] = True  # below the support plane
    surface = legs.copy()  # 2 x 2 legs: every voxel is on their outside
    surface[2:22, 2:22, 19] = True
    surface[[2, 21], 2:22, under:20] = True
    surface[2:22, [2, 21], under:20] = True
    return solid, top, legs, hidden, closed, surface


def _sparse_points(mask: np.ndarray, keep: float, rng: np.random.Generator) -> torch.Tensor:
    """Points at the centres of a random ``keep`` share of ``mask``'s voxels (a grid of unit voxels at the origin):
    the Gaussians sample the seen surface with gaps."""
    ijk = np.argwhere(mask)
    ijk = ijk[rng.random(len(ijk)) < keep]
    return torch.from_numpy(ijk + 0.5)


def test_hidden_space_under_a_top_goes_and_the_table_stays():
    solid, top, legs, hidden, closed, surface = _table()
    rng = np.random.default_rng(0)
    skin = grown_skin(_sparse_points(surface, 0.5, rng), np.zeros(3), 1.0, solid.shape, 2)
    h = hidden_open_space(torch.from_numpy(solid), skin, torch.from_numpy(closed)).numpy()
    assert not (h & (top | legs)).any()
    # all of the hidden block more than the skin's reach (2 steps) under the top's upper face is gone
    below = hidden.copy()
    below[:, :, 17:] = False
    assert h[below].all()
    assert h[hidden].mean() > 0.85


def test_the_open_half_removes_the_layer_that_stray_skin_encloses_sideways():
    """Stray skin a voxel and a half under the top (the Gaussians of its underside that the lowest views see near
    its edges, placed low: the CPU demo room's table at seed 3131 had skin on 19% and 9% of the voxels 1.5 and 2.5
    cm under its top). At that height the majority keeps the layer: the top encloses it upwards, the stray skin
    sideways. Its downward half is open, and some direction across it, so the open half removes much of it; the
    top and the legs stay."""
    solid, top, legs, _hidden, closed, surface = _table()
    rng = np.random.default_rng(0)
    skin = surface | top  # the top's skin covers its two voxels
    layer = np.zeros(solid.shape, bool)
    layer[5:19, 5:19, 15] = True
    skin |= layer & (rng.random(solid.shape) < 0.15)
    t = torch.from_numpy
    majority = hidden_open_space(t(solid), t(skin), t(closed), 0.5).numpy()
    half = hidden_open_space(t(solid), t(skin), t(closed), 0.5, 9).numpy()
    assert not (half & (top | legs)).any() and not (majority & ~half).any()
    stray = layer & ~skin
    kept_majority, kept_half = (stray & ~majority).sum(), (stray & ~half).sum()
    print("layer voxels kept: majority", kept_majority, "open half", kept_half, "of", stray.sum())
    assert kept_majority > 0.5 * stray.sum() and kept_half <= 0.8 * kept_majority


def test_passes_remove_what_the_first_pass_left_open_and_keep_the_table():
    """The stray-skin layer of the test above, with the rules run again on what they leave: the space a pass removed
    is open to the next, so the layer and the space between it and the top go too; the top and the legs stay, more
    passes remove a superset, and one pass is :func:`hidden_open_space`."""
    solid, top, legs, hidden, closed, surface = _table()
    rng = np.random.default_rng(0)
    skin = surface | top
    layer = np.zeros(solid.shape, bool)
    layer[5:19, 5:19, 15] = True
    skin |= layer & (rng.random(solid.shape) < 0.15)
    t = torch.from_numpy
    one, removed = without_hidden_space(t(solid), t(skin), t(closed), 0.5, 9, 1)
    assert torch.equal(one, t(solid) & ~hidden_open_space(t(solid), t(skin), t(closed), 0.5, 9))
    assert removed["majority"] + removed["open_half"] == int(solid.sum() - one.sum())
    many, removed8 = without_hidden_space(t(solid), t(skin), t(closed), 0.5, 9, 8)
    one, many = one.numpy(), many.numpy()
    assert not (many & ~one).any() and not ((top | legs) & ~many).any()
    assert removed8["majority"] + removed8["open_half"] == int(solid.sum() - many.sum())
    between = hidden & ~skin
    between[:, :, :15] = False  # the layer and the space between it and the top
    print("kept between the top and below the stray skin: one pass", (between & one).sum(), "eight",
          (between & many).sum(), "of", between.sum())
    assert (between & many).sum() <= 0.25 * (between & one).sum()


def test_a_thick_top_closed_all_round_by_its_seen_sides_keeps_its_unseen_lower_part():
    """A top 5 voxels thick whose upper face's skin reaches 2 voxels into it and whose sides were seen whole: its
    lower 3 voxels are no skin and their downward half is open, but no direction across is (the sides enclose
    them), so the open half keeps them, as the majority does."""
    solid, top, legs, hidden, closed, surface = _table(thickness=5)
    skin = surface.copy()
    skin[:, :, 18] |= top[:, :, 18]
    t = torch.from_numpy
    for half in (None, 9, 8):
        h = hidden_open_space(t(solid), t(skin), t(closed), 0.5, half).numpy()
        assert not (h & (top | legs)).any() and h[hidden].all(), half


def test_a_closed_solid_sampled_with_gaps_keeps_its_inside():
    """A 14-voxel cube on the floor, its five seen faces sampled at a third of their voxels: the skin of 2 steps
    closes the gaps and nothing is removed; without growing it, rays leak out through them."""
    shape = (20, 20, 20)
    solid = np.zeros(shape, bool)
    solid[3:17, 3:17, 1:15] = True
    shell = solid & ~np.pad(np.ones((12, 12, 13), bool), ((4, 4), (4, 4), (1, 6)))  # the faces, bottom included
    shell[:, :, 1] &= False  # the bottom face on the floor is never seen
    closed = np.zeros(shape, bool)
    closed[:, :, :1] = True
    pts = _sparse_points(shell, 1 / 3, np.random.default_rng(1))
    t_solid, t_closed = torch.from_numpy(solid), torch.from_numpy(closed)
    assert not hidden_open_space(t_solid, grown_skin(pts, np.zeros(3), 1.0, shape, 2), t_closed).any()
    assert hidden_open_space(t_solid, grown_skin(pts, np.zeros(3), 1.0, shape, 0), t_closed).any()


def test_the_support_plane_encloses_an_unseen_bottom():
    """A flat slab lying on the floor, seen only from above: its upper face is the only skin; rays down end on the
    floor (enclosed), so its inside stays even though its sides' skin is missing for half the directions."""
    shape = (16, 16, 10)
    solid = np.zeros(shape, bool)
    solid[2:14, 2:14, 1:7] = True
    surface = np.zeros(shape, bool)
    surface[2:14, 2:14, 6] = True
    surface[[2, 13], 2:14, 1:7] = True
    surface[2:14, [2, 13], 1:7] = True
    closed = np.zeros(shape, bool)
    closed[:, :, :1] = True
    skin = grown_skin(torch.from_numpy(np.argwhere(surface) + 0.5), np.zeros(3), 1.0, shape, 2)
    assert not hidden_open_space(torch.from_numpy(solid), skin, torch.from_numpy(closed)).any()
    # without the floor, the rays down leave the solid: a majority of directions are open at its bottom middle
    assert hidden_open_space(torch.from_numpy(solid), grown_skin(
        torch.from_numpy(np.argwhere(surface[:, :, 6:]) + [0.5, 0.5, 6.5]), np.zeros(3), 1.0, shape, 1)).any()


def test_a_table_shot_from_above_loses_the_space_under_its_top(monkeypatch):
    """Every camera looks down on the top (elevations 35-75 degrees), so no view sees past the space under it: the
    carving alone keeps it as solid; the hidden-space rule removes it and keeps the top and the legs."""
    from helpers.shapes import geometry_of, ring_views, table_on_floor

    pf, only_obj = table_on_floor()
    views = ring_views(pf, (0, 0, 0.3), 2.2, n=18, elevations=(35.0, 55.0, 75.0), mask_pf=only_obj)
    truth = 0.8 * 0.5 * 0.04 + 4 * 0.04 * 0.04 * 0.5
    geo = geometry_of(pf, views, resolution=64)
    from physgs_nerfstudio.geometry import solid

    def carving_alone(*args, **_kw):
        solids = args[6]
        return solids, {"majority": 0, "open_half": 0}, [np.zeros_like(s) for s in solids]

    monkeypatch.setattr(solid, "_without_hidden", carving_alone)
    kept = geometry_of(pf, views, resolution=64).volumes[0].sum()
    v = geo.volumes[0].sum()
    print("truth", truth, "carving alone", kept, "without hidden space", v, geo.hidden_removed,
          geo.summary()["hidden_boundary_voxels"])
    assert kept > 3.0 * truth  # the hidden space the rule is for
    # the report says what each rule removed: the voxels of the nominal solid the rule took away
    removed = geo.summary()["hidden_open_voxels"]
    assert removed["majority"] > 0 and removed["open_half"] >= 0
    # and the kept voxels on the boundary with that space count half a voxel each (module doc, "The boundary with
    # hidden open space")
    edge = geo.summary()["hidden_boundary_voxels"]
    assert edge > 0
    assert (kept - v) / geo.grid.voxel_size**3 == pytest.approx(removed["majority"] + removed["open_half"] + edge / 2,
                                                                rel=0.05)
    # most of it goes; what stays is the skin's reach under the 4 cm top (about a voxel, 1.6 cm here) and the legs'
    # visual hull (module doc)
    assert 0.8 * truth <= v <= 0.45 * kept
    # the top itself stays: the solid's voxels at the top's height cover its footprint
    z = np.asarray(geo.grid.origin)[2] + (np.arange(geo.grid.shape[2]) + 0.5) * geo.grid.voxel_size
    at_top = geo.solid[:, :, np.abs(z - 0.52) < 0.01].any(2)
    assert at_top.sum() * geo.grid.voxel_size**2 >= 0.9 * 0.4
    legs = geo.solid[:, :, np.abs(z - 0.25) < 0.01].any(2)
    assert legs.sum() * geo.grid.voxel_size**2 >= 0.9 * 4 * 0.04**2


def _with(pf, means: torch.Tensor, scales: torch.Tensor, quats: torch.Tensor):
    """``pf`` with more Gaussians of its first Gaussian's opacity and material evidence."""
    from dataclasses import replace

    n = len(means)
    return replace(pf, means=torch.cat([pf.means, means.float()]),
                   scales=torch.cat([pf.scales, scales.float()]), quats=torch.cat([pf.quats, quats.float()]),
                   opacities=torch.cat([pf.opacities, pf.opacities[:1].expand(n)]),
                   alpha=torch.cat([pf.alpha, pf.alpha[:1].expand(n, -1)]),
                   sh_dc=torch.cat([pf.sh_dc, torch.zeros(n, 3)]))


@pytest.mark.xfail(strict=True, reason="known regression: at the surface depth (SURFACE_TRANSMITTANCE 0.8) the table "
                   "alone keeps 1.58x its volume (1.31x at the median depth), so the needles' layer is no "
                   "longer the test's contrast")
def test_axis_ends_that_no_view_sees_do_not_sample_the_skin():
    """Long thin Gaussians lie on the table's top face tilted 60 degrees below it, as a GPU splat's needles
    do: the end of each one's long axis pokes 2 cm under the 4 cm top, where no view sees, and with every axis
    end as a skin sample that skin encloses the hidden space under the top. Counting only the ends that some
    view sees on its rendered surface (``hidden_skin_seen``, within a voxel plus the Gaussian's own
    thickness), the table keeps the volume it has without the needles."""
    from helpers.shapes import geometry_of, ring_views, table_on_floor

    pf, only_obj = table_on_floor()
    g = torch.arange(-0.36, 0.37, 0.06)
    X, Y = torch.meshgrid(g, torch.arange(-0.21, 0.22, 0.06), indexing="ij")
    means = torch.stack([X.reshape(-1), Y.reshape(-1), torch.full((X.numel(),), 0.54)], 1)
    half = math.radians(60.0) / 2  # about y: the long x axis turns to (cos 60, 0, -sin 60)
    quats = torch.tensor([math.cos(half), 0.0, math.sin(half), 0.0]).expand(len(means), 4)
    scales = torch.tensor([0.07, 1e-3, 1e-3]).expand(len(means), 3)
    needled, only_needled = _with(pf, means, scales, quats), _with(only_obj, means, scales, quats)
    truth = 0.8 * 0.5 * 0.04 + 4 * 0.04 * 0.04 * 0.5

    rendered = {}  # each field's views rendered once (the rules below read the same renders)

    def volume(field, mask_field, **kw):
        if id(field) not in rendered:
            rendered[id(field)] = ring_views(field, (0, 0, 0.3), 2.2, n=18, elevations=(35.0, 55.0, 75.0),
                                             mask_pf=mask_field)
        # (whole voxels: the skin rules compared, without partial volume's shares)
        return whole_voxel_volume(geometry_of(field, rendered[id(field)], resolution=64, **kw)) / truth

    # the means' band of session 33 (a whole voxel), where the rule was measured; the default's below
    plain = volume(pf, only_obj, hidden_skin_band=1.0)
    every_end = volume(needled, only_needled, hidden_skin_seen=1e6, hidden_skin_band=1.0)  # every end counts
    seen_ends = volume(needled, only_needled, hidden_skin_band=1.0)
    print("plain", plain, "every axis end", every_end, "seen axis ends", seen_ends)
    assert every_end > 1.25 * plain  # the needles' ends enclose a layer under the top
    assert seen_ends == pytest.approx(plain, rel=0.02)
    # at the default band (half a voxel: fewer of the top's own centres sample the skin, so the needles' seen ends
    # weigh a little more) the layer under the top still goes
    plain_d, seen_d = volume(pf, only_obj), volume(needled, only_needled)
    print("default band: plain", plain_d, "seen axis ends", seen_d)
    assert seen_d < plain_d + 0.25 * (every_end - plain)


@pytest.mark.parametrize("bad", [{"hidden_skin_tolerance": 0.0}, {"hidden_skin_voxels": -1},
                                 {"hidden_min_open_half": 0},
                                 {"hidden_min_open_half": 10},
                                 {"hidden_skin_seen": -1.0}])  # fmt: skip
def test_hidden_space_settings_are_checked(bad):
    from physgs_nerfstudio.geometry.reconstruct import GeometryConfig

    with pytest.raises(ValueError, match=next(iter(bad))):
        GeometryConfig(**bad)
