"""The support plane (geometry/support.py): found under objects standing on a floor, never an object's own face."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from physgs_nerfstudio.geometry.support import (
    MAX_TOL_BANDS,
    RING_BAND,
    SupportConfig,
    align_to_plane,
    find_support,
    find_support_plane,
)

UP = np.array([0.0, 0.0, 1.0])


def _box_surface(rng: np.random.Generator, lo, hi, n: int) -> np.ndarray:
    """Points on the surface of an axis-aligned box, about uniform by area."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    ext = hi - lo
    areas = np.array([ext[1] * ext[2], ext[0] * ext[2], ext[0] * ext[1]])
    axis = rng.choice(3, size=n, p=areas / areas.sum())
    p = lo + rng.random((n, 3)) * ext
    side = rng.random(n) < 0.5
    p[np.arange(n), axis] = np.where(side, lo[axis], hi[axis])
    return p


def _floor(rng: np.random.Generator, half: float, n: int, z: float = 0.0, noise: float = 0.002) -> np.ndarray:
    xy = rng.uniform(-half, half, size=(n, 2))
    return np.column_stack([xy, z + rng.normal(0, noise, n)])


def _ring(n: int, radius: float, lo_deg: float, hi_deg: float) -> np.ndarray:
    """Camera centres on an orbit band between two elevations."""
    el = np.deg2rad(np.linspace(lo_deg, hi_deg, n))
    az = np.linspace(0, 2 * np.pi, n, endpoint=False) * 7.3
    return radius * np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def test_floor_under_objects_is_found_and_only_it_dropped() -> None:
    rng = np.random.default_rng(0)
    floor = _floor(rng, 1.6, 6000)
    objects = np.concatenate([_box_surface(rng, (-0.5, -0.3, 0.0), (0.5, 0.3, 0.75), 3000),
                              _box_surface(rng, (1.0, 0.5, 0.0), (1.3, 0.8, 0.25), 800)])  # fmt: skip
    floaters = rng.uniform(-4, 4, size=(300, 3)) - np.array([0, 0, 4.5])  # far below: another cluster
    pts = np.concatenate([floor, objects, floaters])
    plane = find_support_plane(pts, _ring(40, 3.0, 15, 60), UP)
    assert plane is not None
    assert abs(plane.normal @ UP) > 0.999 and abs(plane.offset) < 0.01
    assert plane.drops(floor).mean() > 0.98
    above = objects[:, 2] > 0.03  # the objects' bottom faces lie on the floor: those go with it
    assert not plane.drops(objects[above]).any()


@pytest.mark.parametrize("case", ["crate", "table", "cameras_below", "lamp"])
def test_an_objects_own_face_is_no_support(case: str) -> None:
    """A box's bottom face is its footprint, a table top has legs under it, a floor seen from below (an orbit
    down to -10 degrees) is not under the cameras, and a lamp's base has its shade overhanging it (the CPU lamp at
    seed 9696: with the session-27 test, which looked only over the base's footprint, the base was a support)."""
    rng = np.random.default_rng(1)
    cams = _ring(40, 3.0, 15, 60)
    if case == "crate":
        pts = _box_surface(rng, (-0.2, -0.15, 0.0), (0.2, 0.15, 0.25), 5000)
    elif case == "table":
        top = _box_surface(rng, (-0.5, -0.3, 0.72), (0.5, 0.3, 0.745), 5000)
        legs = [_box_surface(rng, (sx * 0.45 - 0.02, sy * 0.25 - 0.02, 0.0), (sx * 0.45 + 0.02, sy * 0.25 + 0.02, 0.72),
                             500) for sx in (-1, 1) for sy in (-1, 1)]  # fmt: skip
        pts = np.concatenate([top, *legs])
    elif case == "lamp":
        base = _box_surface(rng, (-0.09, -0.09, 0.0), (0.09, 0.09, 0.02), 3000)
        pole = _box_surface(rng, (-0.01, -0.01, 0.02), (0.01, 0.01, 0.42), 600)
        a = rng.uniform(0, 2 * np.pi, 4000)
        shade = np.column_stack([0.16 * np.cos(a), 0.16 * np.sin(a), rng.uniform(0.3, 0.5, len(a))])
        pts = np.concatenate([base[base[:, 2] > 1e-9], pole, shade])
        cams = _ring(40, 1.2, 15, 60)
    else:
        pts = np.concatenate([_floor(rng, 1.6, 6000), _box_surface(rng, (-0.5, -0.3, 0.0), (0.5, 0.3, 0.75), 3000)])
        cams = _ring(40, 3.0, -10, 60)
    assert find_support_plane(pts, cams, UP) is None


@settings(max_examples=25, deadline=None)
@given(tilt=st.floats(0, 20), seed=st.integers(0, 10_000))
def test_a_tilted_floor_is_found_along_its_own_normal(tilt: float, seed: int) -> None:
    """The plane's normal comes from its points (least squares on the inliers), not from the cameras' up."""
    rng = np.random.default_rng(seed)
    t = np.deg2rad(tilt)
    R = np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]])
    pts = np.concatenate([_floor(rng, 1.6, 5000), _box_surface(rng, (-0.4, -0.3, 0.0), (0.4, 0.3, 0.6), 2000)]) @ R.T
    plane = find_support_plane(pts, _ring(30, 3.0, 20, 60) @ R.T, UP, SupportConfig())
    assert plane is not None
    assert plane.normal @ (R @ UP) > np.cos(np.deg2rad(1.0))


@pytest.mark.parametrize("case", ["box", "table", "spill", "lying"])
def test_the_support_is_the_level_layer_in_the_ring_around_the_base(case: str) -> None:
    """:func:`find_support`: the object selected (with the floor around its base where its masks spilled onto it:
    "spill"), the floor and far background not; the plane is the floor, level, with a tolerance of at most
    ``MAX_TOL_BANDS`` bands however fuzzy the floor, never the object's own face (a table's top, a box's lid, a lying
    object's flat side), and an object with no floor under it, or one that covers a third of its ring, stands on
    nothing."""
    rng = np.random.default_rng(2)
    if case in ("box", "spill"):
        obj = _box_surface(rng, (-0.2, -0.15, 0.0), (0.2, 0.15, 0.25), 4000)
        obj = obj[obj[:, 2] > 1e-9]  # a splat has nothing on the face that rests on the floor: no view sees it
    elif case == "lying":  # a long flat object on its side: its base is its whole underside
        obj = _box_surface(rng, (-0.3, -0.04, 0.0), (0.3, 0.04, 0.03), 3000)
        obj = obj[obj[:, 2] > 1e-9]
    else:
        top = _box_surface(rng, (-0.5, -0.3, 0.72), (0.5, 0.3, 0.745), 5000)
        legs = [_box_surface(rng, (sx * 0.45 - 0.02, sy * 0.25 - 0.02, 0.0), (sx * 0.45 + 0.02, sy * 0.25 + 0.02, 0.72),
                             500) for sx in (-1, 1) for sy in (-1, 1)]  # fmt: skip
        obj = np.concatenate([top, *legs])
    noise = 0.012 if case == "spill" else 0.002  # a fuzzy floor: its tolerance is capped
    floor = _floor(rng, 3.0, 40000, z=-0.001, noise=noise)
    far = rng.uniform(-6, 6, size=(2000, 3)) + np.array([0, 0, 3.0])  # background around and above
    cams = _ring(40, 3.0, 15, 60)
    pts = np.concatenate([obj, floor, far])
    sel = np.zeros(len(pts), bool)
    sel[: len(obj)] = True
    if case == "spill":  # the floor within 5 cm of the box, taken in by the masks
        f = floor[:, :2]
        sel[len(obj) : len(obj) + len(floor)] = np.all(np.abs(f) <= [0.25, 0.2], 1)
    plane, why = find_support(pts, sel, cams, UP)
    assert plane is not None, why
    assert np.allclose(plane.normal, UP) and abs(plane.offset + 0.001) < 0.005
    size = float(np.max(np.quantile(obj, 0.98, 0) - np.quantile(obj, 0.02, 0)))
    assert plane.tol <= MAX_TOL_BANDS * RING_BAND * size * (1 + 1e-9)
    assert (case == "spill") == (plane.tol > 2.5 * RING_BAND * size)  # the fuzzy floor reaches the cap
    assert not plane.drops(obj[obj[:, 2] > 0.02]).any()
    assert find_support(np.concatenate([obj, far]), sel[: len(obj) + len(far)], cams, UP)[0] is None
    assert find_support(pts, sel, cams, UP, SupportConfig(enabled=False)) == (None, "off")
    one_side = np.concatenate([obj, floor[floor[:, 0] > 0.1], far])  # a ledge beside the object, not around it
    plane, why = find_support(one_side, sel[: len(one_side)] & (np.arange(len(one_side)) < len(obj)), cams, UP)
    assert plane is None and "of the ring around its base" in why


def test_the_grid_is_placed_with_a_layer_of_voxel_faces_on_the_plane() -> None:
    """:func:`align_to_plane`: the grid moves down by less than a voxel, grows a voxel, and a face layer lies on the
    plane; no plane, no change."""
    from physgs_nerfstudio.geometry.grid import VoxelGrid
    from physgs_nerfstudio.geometry.support import SupportPlane

    grid = VoxelGrid((0.013, -0.2, -0.0737), 0.01, (20, 30, 25))
    plane = SupportPlane(UP.copy(), 0.0042, 0.001, 0.5)
    got = align_to_plane(grid, plane)
    assert got.shape == (20, 30, 26) and got.origin[:2] == grid.origin[:2] and got.voxel_size == grid.voxel_size
    k = (plane.offset - got.origin[2]) / got.voxel_size
    assert abs(k - round(k)) < 1e-9 and 0 <= grid.origin[2] - got.origin[2] < got.voxel_size
    centres = got.origin[2] + (np.arange(got.shape[2]) + 0.5) * got.voxel_size
    assert np.abs(centres - plane.offset).min() == pytest.approx(0.5 * got.voxel_size)
    assert align_to_plane(grid, None) is grid


def _views(cams: np.ndarray, size: int = 64, mask: bool = True) -> list:
    """Pinhole views at ``cams`` looking at the origin (60 degree field), with all-foreground (or empty) masks."""
    import torch

    from physgs_nerfstudio.geometry.capture import CaptureView

    out = []
    for c in cams:
        f = -c / np.linalg.norm(c)  # camera z: forward
        r = np.cross(f, UP)
        r /= np.linalg.norm(r)
        d = np.cross(f, r)  # camera y: down
        R = np.stack([r, d, f])  # world -> camera rows
        vm = np.eye(4)
        vm[:3, :3], vm[:3, 3] = R, -R @ c
        k = size / 2 / np.tan(np.deg2rad(30))
        K = torch.tensor([[k, 0, size / 2], [0, k, size / 2], [0, 0, 1]], dtype=torch.float32)
        out.append(CaptureView(torch.tensor(vm, dtype=torch.float32), K, size, size,
                               torch.full((size, size), mask, dtype=torch.bool)))  # fmt: skip
    return out


def _room_with_reflections(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A floor with a table-sized box on it, and under the floor, within its footprint, the diffuse cloud of
    Gaussians with which a splat draws a shiny floor's reflections: half the points, the lowest of them all."""
    floor = _floor(rng, 3.0, 6000)
    box = _box_surface(rng, (-0.5, -0.3, 0.0), (0.5, 0.3, 0.75), 3000)
    mirror = np.column_stack([rng.uniform(-1.0, 1.0, (9000, 2)), -rng.uniform(0.05, 0.6, 9000)])
    return floor, box, mirror


def test_reflections_under_a_floor_are_seen_only_through_it() -> None:
    """The cloud under the floor is the lowest third, so the first search draws its planes there and finds no thin
    layer; the search over all the points finds the floor. No camera sees the cloud past the floor (every ray to it
    crosses the floor), so it does not count as "below" where the views are given, and the floor is accepted;
    counted (no views), it rejects the floor."""
    from physgs_nerfstudio.geometry.support import support_plane_or_reason

    rng = np.random.default_rng(3)
    floor, box, mirror = _room_with_reflections(rng)
    pts = np.concatenate([floor, box, mirror])
    cams = _ring(30, 2.5, 35, 70)
    views = _views(cams)
    plane, why = support_plane_or_reason(pts, cams, UP, SupportConfig(), views)
    assert plane is not None, why
    assert abs(plane.offset) < 0.01 and plane.drops(floor).mean() > 0.98 and plane.drops(mirror).all()
    assert not plane.drops(box[box[:, 2] > 0.03]).any()
    plane, why = support_plane_or_reason(pts, cams, UP, SupportConfig(), None)
    assert plane is None and "lies below it" in why and "no thin layer" in why
    assert why.startswith("lowest 33%: no thin layer")


def test_a_table_top_stays_no_support_with_views() -> None:
    """Its legs stand under its footprint, and the low views see them past the top's edge, on their masks; with
    empty masks the same legs are background and do not count."""
    from physgs_nerfstudio.geometry.support import _in_plane, seen_under_plane, support_plane_or_reason

    rng = np.random.default_rng(4)
    top = _box_surface(rng, (-0.5, -0.3, 0.72), (0.5, 0.3, 0.745), 5000)
    legs = np.concatenate([_box_surface(rng, (sx * 0.45 - 0.02, sy * 0.25 - 0.02, 0.0),
                                        (sx * 0.45 + 0.02, sy * 0.25 + 0.02, 0.72), 500)
                           for sx in (-1, 1) for sy in (-1, 1)])  # fmt: skip
    mug = _box_surface(rng, (-0.05, -0.05, 0.745), (0.05, 0.05, 0.85), 300)
    cams = _ring(40, 3.0, 15, 60)
    pts = np.concatenate([top, legs, mug])
    plane, why = support_plane_or_reason(pts, cams, UP, SupportConfig(), _views(cams))
    assert plane is None and "below" in why
    uv = top @ _in_plane(UP)
    seen = seen_under_plane(legs, uv, UP, 0.73, 0.01, _views(cams))
    assert seen.mean() > 0.9
    assert not seen_under_plane(legs, uv, UP, 0.73, 0.01, _views(cams, mask=False)).any()


def test_points_under_a_wide_floor_are_hidden_from_cameras_above() -> None:
    """Brute force: a point counts as seen past the plane exactly when, for some view that has it in frame, the
    segment from the camera crosses the plane outside the footprint (here a square)."""
    from physgs_nerfstudio.geometry.support import _in_plane, seen_under_plane

    rng = np.random.default_rng(5)
    floor = _floor(rng, 1.0, 20000, noise=0.0)
    pts = np.column_stack([rng.uniform(-2.0, 2.0, (400, 2)), -rng.uniform(0.05, 1.5, 400)])
    cams = _ring(12, 3.0, 30, 60)
    views = _views(cams, size=256)
    got = seen_under_plane(pts, floor @ _in_plane(UP), UP, 0.0, 0.005, views, cells=64)
    cell = 2.0 / 64
    n_past = np.zeros(len(pts), int)
    for c in cams:
        t = c[2] / (c[2] - pts[:, 2])
        x = c + t[:, None] * (pts - c)
        past = np.abs(x[:, :2]).max(1) > 1.0 + cell  # (the footprint is grown by a cell)
        n_past += past
    clear_in = n_past >= 2  # all-foreground masks: "on the mask" wherever in frame
    clear_out = n_past == 0
    assert got[clear_out].sum() == 0
    # where several views see past the floor, in frame (the views look at the origin from 3 m: points within 2 m
    # of it are in most frames), the point counts
    assert got[clear_in].mean() > 0.8


def test_contact_band_keeps_neighbours_joined_near_the_floor_apart(monkeypatch) -> None:
    """Two objects on a floor, 0.4 m apart, joined by a chain of clutter a few centimetres above the floor (what the
    GPU room's floor Gaussians did): clustered as one without the band (``contact_band`` 0); with ``contact_band``
    (the default) the clusters are cut above it, the central object alone is selected, and its own points in the band
    (its legs' feet) join it. A low object wholly inside the band (a mat on the floor, at the capture's centre) is
    still found."""
    import types

    import torch

    import physgs_nerfstudio.geometry.select as sel

    rng = np.random.default_rng(6)
    floor = _floor(rng, 2.0, 8000)
    table = _box_surface(rng, (-0.4, -0.3, 0.0), (0.4, 0.3, 0.75), 4000)
    crate = _box_surface(rng, (0.8, -0.2, 0.0), (1.2, 0.2, 0.4), 2000)
    chain = np.column_stack([rng.uniform(0.35, 0.85, 600), rng.uniform(-0.05, 0.05, 600), rng.uniform(0.01, 0.025, 600)])
    pts = np.concatenate([floor, table, crate, chain])
    cams = _ring(30, 3.0, 30, 60)
    g = types.SimpleNamespace(means=torch.from_numpy(pts).float(), opacities=torch.ones(len(pts)))
    ones = torch.ones(len(pts), dtype=torch.float64)
    monkeypatch.setattr(sel, "lift_masks", lambda *a, **k: (10 * ones, 0 * ones))  # all foreground
    views = _views(cams)
    n_t, n_c = len(floor), len(floor) + len(table)
    up_t, up_c = table[:, 2] > 0.03, crate[:, 2] > 0.03  # (the bottom faces go with the floor)
    base = sel.select_object(g, views, sel.SelectConfig(contact_band=0.0)).selected.numpy()
    assert base[n_t:n_c][up_t].mean() > 0.99 and base[n_c : n_c + len(crate)][up_c].mean() > 0.99  # joined
    assert not base[: len(floor)].any()  # the floor is the support plane
    cut = sel.select_object(g, views, sel.SelectConfig()).selected.numpy()
    assert not cut[n_c : n_c + len(crate)].any()
    feet = table[:, 2] < 0.05
    assert cut[n_t:n_c][~feet].mean() > 0.99 and cut[n_t:n_c][feet & (table[:, 2] > 0.02)].mean() > 0.9
    # the same scene with the table moved 1.2 m away and a 4 cm mat at the centre: the mat is its own cluster
    mat = _box_surface(rng, (-0.3, -0.2, 0.0), (0.3, 0.2, 0.04), 1500)
    pts2 = np.concatenate([floor, table + [-1.2, 0, 0], crate, mat])
    g2 = types.SimpleNamespace(means=torch.from_numpy(pts2).float(), opacities=torch.ones(len(pts2)))
    ones2 = torch.ones(len(pts2), dtype=torch.float64)
    monkeypatch.setattr(sel, "lift_masks", lambda *a, **k: (10 * ones2, 0 * ones2))
    got = sel.select_object(g2, views, sel.SelectConfig()).selected.numpy()
    n_m = len(pts2) - len(mat)
    assert got[n_m:][mat[:, 2] > 0.02].mean() > 0.99 and not got[:n_m].any()
    with pytest.raises(ValueError, match="contact_band"):
        sel.SelectConfig(contact_band=-0.5)


def _table_and_chair(rng: np.random.Generator, gap: float) -> tuple[np.ndarray, np.ndarray]:
    """Surface points of a 1.2 x 0.8 m table (top at 0.72-0.76 m, four legs) and of a chair whose seat begins ``gap``
    from the table's edge along +x (the generated `indoor_room`'s layout), standing on z = 0."""

    def _solid(boxes: list, n: int) -> np.ndarray:
        vol = np.array([np.prod(np.subtract(hi, lo)) ** (2 / 3) for lo, hi in boxes])
        counts = np.maximum((n * vol / vol.sum()).astype(int), 200)
        return np.concatenate([_box_surface(rng, lo, hi, k) for (lo, hi), k in zip(boxes, counts)])

    legs = [((x - 0.03, y - 0.03, 0.0), (x + 0.03, y + 0.03, 0.72)) for x in (-0.55, 0.55) for y in (-0.35, 0.35)]
    table = _solid([((-0.6, -0.4, 0.72), (0.6, 0.4, 0.76)), *legs], 12000)
    cx = 0.6 + gap + 0.2
    chair_legs = [((x - 0.02, y - 0.02, 0.0), (x + 0.02, y + 0.02, 0.45)) for x in (cx - 0.18, cx + 0.18)
                  for y in (-0.18, 0.18)]  # fmt: skip
    chair = _solid([((cx - 0.2, -0.2, 0.45), (cx + 0.2, 0.2, 0.49)), ((cx + 0.17, -0.2, 0.49), (cx + 0.2, 0.2, 0.9)),
                    *chair_legs], 6000)  # fmt: skip
    return table, chair


def _coarse_selection(monkeypatch, g, views) -> np.ndarray:
    """The selection's coarse cluster alone (without the split over the support plane)."""
    import physgs_nerfstudio.geometry.select as sel

    with monkeypatch.context() as m:
        m.setattr(sel, "split_close", lambda _m, chosen, *a, **k: chosen)
        return sel.select_object(g, views, sel.SelectConfig()).selected.numpy()


def test_object_standing_close_to_another_on_a_floor_is_split_from_it(monkeypatch) -> None:
    """A table and a chair 15 cm from its edge on a floor (the generated `indoor_room`'s layout): the clusters' cells
    are a share of the floor's size and join them (the coarse selection: :func:`.clusters.split_close` left out); the
    split over the support plane splits the chosen cluster again at the table's own resolution and keeps the table
    whole, legs included, and none of the chair."""
    import types

    import torch

    import physgs_nerfstudio.geometry.select as sel

    rng = np.random.default_rng(8)
    table, chair = _table_and_chair(rng, 0.15)  # the chair's seat begins 15 cm from the table's edge
    floor = _floor(rng, 2.5, 20000)
    pts = np.concatenate([floor, table, chair])
    g = types.SimpleNamespace(means=torch.from_numpy(pts).float(), opacities=torch.ones(len(pts)))
    ones = torch.ones(len(pts), dtype=torch.float64)
    monkeypatch.setattr(sel, "lift_masks", lambda *a, **k: (10 * ones, 0 * ones))  # all foreground
    views = _views(_ring(30, 3.5, 30, 60))
    n_t = len(floor)
    t_up, c_up = table[:, 2] > 0.03, chair[:, 2] > 0.03
    coarse = _coarse_selection(monkeypatch, g, views)
    assert coarse[n_t : n_t + len(table)][t_up].mean() > 0.99 and coarse[n_t + len(table) :][c_up].mean() > 0.99
    chosen = sel.select_object(g, views, sel.SelectConfig())
    got = chosen.selected.numpy()
    assert got[n_t : n_t + len(table)][t_up].mean() > 0.99
    assert not got[n_t + len(table) :].any() and not got[:n_t].any()
    assert chosen.split_from == int(coarse.sum()) > chosen.num_selected


@pytest.mark.xfail(strict=True, reason="known limitation: with the views' exact up (support.views_up) the floor's fit "
                   "takes the dense floaters 2-6 cm over it into its layer, whose tolerance grows to 4.5 cm, and the "
                   "table's feet below that go with the floor (98.7% of the table above 3 cm kept; the mean image up, "
                   "2.2 degrees off here, spread that layer and kept them)")
def test_floaters_near_the_floor_do_not_link_a_chair_to_the_table_in_the_split(monkeypatch) -> None:
    """The table and chair of the test above, with a layer of floaters 2-6 cm over the floor (within the band) between them and
    around them (what linked the GPU `indoor_room`'s table to its chair and lamp at seed 21414): the split links its
    parts only above the contact band at its own reach, so the chair goes and the table stays whole, its legs' feet
    in the band included."""
    import types

    import torch

    import physgs_nerfstudio.geometry.select as sel

    rng = np.random.default_rng(21)
    table, chair = _table_and_chair(rng, 0.19)  # the chair's seat begins 19 cm from the table's edge
    cx = 0.6 + 0.19 + 0.2
    floaters = np.column_stack([rng.uniform(-0.9, cx + 0.4, 8000), rng.uniform(-0.6, 0.6, 8000),
                                rng.uniform(0.02, 0.06, 8000)])  # fmt: skip
    floor = _floor(rng, 2.5, 20000)
    pts = np.concatenate([floor, table, chair, floaters]) - [0.0, 0.0, 0.74]  # the cameras look at the table's top
    g = types.SimpleNamespace(means=torch.from_numpy(pts).float(), opacities=torch.ones(len(pts)))
    ones = torch.ones(len(pts), dtype=torch.float64)
    monkeypatch.setattr(sel, "lift_masks", lambda *a, **k: (10 * ones, 0 * ones))  # all foreground
    views = _views(_ring(30, 3.5, 30, 60))
    t0, c0, f0 = len(floor), len(floor) + len(table), len(floor) + len(table) + len(chair)
    got = sel.select_object(g, views, sel.SelectConfig()).selected.numpy()
    up = table[:, 2] > 0.03  # (the plane's tolerance drops the feet's lowest millimetres)
    assert got[t0:c0][up].mean() > 0.99
    coarse = _coarse_selection(monkeypatch, g, views)
    assert coarse[c0:f0][chair[:, 2] > 0.2].mean() > 0.99  # the coarse clusters join them
    assert not (coarse[t0:c0] & ~got[t0:c0]).any()  # the split keeps every point of the table they had, feet too
    assert not got[c0:f0].any() and not got[:t0].any()


def test_clusters_grid_stays_bounded_for_a_fine_cell_over_a_wide_spread(monkeypatch) -> None:
    """A cell far finer than the points' spread (a small support plane's size over 48, among strays metres away)
    asked for tens of GB of labels; the grid is coarsened to fit (here a cap of 2M cells, not the default's 1,000M)
    and the two clumps stay two clusters."""
    import torch

    import physgs_nerfstudio.geometry.clusters as cl
    import physgs_nerfstudio.geometry.select as sel

    monkeypatch.setattr(cl, "MAX_CELLS", 2e6)

    rng = np.random.default_rng(9)
    a = rng.normal(0, 0.01, (2000, 3))
    b = rng.normal(0, 0.01, (2000, 3)) + [5.0, 4.0, 3.0]
    strays = rng.uniform(-8, 8, (20, 3))
    m = torch.from_numpy(np.concatenate([a, b, strays]))
    lab, _, cell, ids = cl.cluster_labels(m, sel.SelectConfig(), extent=0.01)
    q = np.quantile(m.numpy(), (0.002, 0.998), axis=0)  # the grid's box: strays past it are no cluster
    assert float(np.prod((q[1] - q[0]) / cell + 5)) <= cl.MAX_CELLS
    la, lb = lab[:2000].numpy(), lab[2000:4000].numpy()
    assert (la == la[0]).mean() > 0.99 and (lb == lb[0]).mean() > 0.99 and la[0] != lb[0] and la[0] > 0


def _look_at(c: np.ndarray, target: np.ndarray, up: np.ndarray, roll_deg: float = 0.0) -> np.ndarray:
    """World -> camera rotation (OpenCV rows: right, down, forward) of a camera at ``c`` looking at ``target``,
    held upright with respect to ``up`` and then rolled about its axis."""
    f = (target - c) / np.linalg.norm(target - c)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    d = np.cross(f, r)
    a = np.deg2rad(roll_deg)
    r, d = np.cos(a) * r + np.sin(a) * d, -np.sin(a) * r + np.cos(a) * d
    return np.stack([r, d, f])


@pytest.mark.parametrize("arc_deg", [90.0, 200.0, 360.0])
def test_the_views_up_is_perpendicular_to_every_cameras_level_x_axis(arc_deg: float) -> None:
    """Cameras on part of an orbit, looking down at an object: their mean image up leans towards the object side the
    arc covers, while the normal of their image x axes is the world's up exactly (and close under a small roll)."""
    import torch

    from physgs_nerfstudio.geometry.capture import CaptureView
    from physgs_nerfstudio.geometry.support import views_up

    rng = np.random.default_rng(3)
    up = np.array([0.05, -0.03, 1.0]) / np.linalg.norm([0.05, -0.03, 1.0])  # a world whose up is not the z axis
    az = np.deg2rad(np.linspace(0, arc_deg, 16, endpoint=arc_deg < 360))
    el = np.deg2rad(rng.uniform(20, 50, 16))
    basis = np.linalg.qr(np.column_stack([up, [1.0, 0, 0], [0, 1.0, 0]]))[0]
    h1, h2 = basis[:, 1], basis[:, 2]
    cams = 2.0 * (np.cos(el)[:, None] * (np.cos(az)[:, None] * h1 + np.sin(az)[:, None] * h2) + np.sin(el)[:, None] * up)
    K = torch.eye(3)

    def views(roll: np.ndarray) -> list:
        out = []
        for c, rr in zip(cams, roll):
            R = _look_at(c, np.zeros(3), up, rr)
            vm = np.eye(4)
            vm[:3, :3], vm[:3, 3] = R, -R @ c
            out.append(CaptureView(torch.tensor(vm, dtype=torch.float64), K, 8, 8, torch.ones(8, 8, dtype=torch.bool)))
        return out

    def angle(a: np.ndarray) -> float:
        return float(np.degrees(np.arccos(np.clip(a @ up, -1, 1))))

    level = views(np.zeros(16))
    mean_up = np.mean([-v.viewmat[1, :3].numpy() for v in level], 0)
    assert angle(views_up(level)) < 1e-4  # arccos resolves about 1e-6 degree
    if arc_deg < 360:  # the oracle's point: the mean image up is off where the arc is partial
        assert angle(mean_up / np.linalg.norm(mean_up)) > 2.0
    assert angle(views_up(views(rng.normal(0, 1.0, 16)))) < 1.0  # a hand-held roll of about a degree
