"""Which object perception names each part (physgs_nerfstudio.geometry.select, perception's ``object`` answer): a
box standing on a larger one, masked together at the ``whole`` level and apart at the ``part`` level, keeps the
large box's Gaussians and drops the small one's; a wrong answer or two does not drop anything."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from helpers.shapes import box_surface, ring_views

from physgs_nerfstudio.export.shapes import field_from
from physgs_nerfstudio.geometry import GeometryConfig, MaskObservation, SelectConfig, reconstruct_object
from physgs_nerfstudio.geometry.gaussians import render_depth
from physgs_nerfstudio.geometry.select import object_labels, other_object
from physgs_nerfstudio.perception.validate import Validator, object_name


def test_object_names_are_normalised():
    assert object_name("The Table.") == "table"
    assert object_name("  a   Coffee-Mug ") == "coffee-mug"
    assert object_name("") is None and object_name(None) is None and object_name(3) is None
    assert object_name("x" * 61) is None


def test_the_validated_answer_carries_the_object():
    from physgs_nerfstudio.materials import load_library

    check = Validator(load_library("indoor"))
    ans = check('{"caption": "a mug", "object": "Mug", "candidates": [{"material": "ceramic", "confidence": 1}]}')
    assert ans.object == "mug" and ans.candidates
    assert check('{"caption": "x", "candidates": [{"material": "ceramic", "confidence": 1}]}').object is None


def test_the_finest_mask_names_its_pixels():
    from physgs_nerfstudio.geometry import CaptureView

    v = CaptureView(torch.eye(4), torch.eye(3), 4, 2, torch.ones(2, 4, dtype=torch.bool), name="v0")
    whole = np.ones((2, 4), bool)
    part = np.zeros((2, 4), bool)
    part[:, 3] = True
    obs = [MaskObservation("v0", part, "ceramic", 1.0, None, level="part", mask_id=1, object="mug"),
           MaskObservation("v0", whole, "oak", 1.0, None, level="whole", mask_id=0, object="table"),
           MaskObservation("v9", whole, "oak", 1.0, None, level="whole", mask_id=0, object="chair")]  # fmt: skip
    lab = object_labels([v], obs)
    assert lab.names == ["mug", "table", "chair"]
    assert lab.maps[0].tolist() == [[1, 1, 1, 0], [1, 1, 1, 0]]


def test_one_other_name_must_outweigh_the_objects_own_by_the_prior():
    counts = torch.tensor([[5.0, 0.0], [2.0, 2.5], [1.0, 3.5], [0.0, 0.5], [9.0, 9.0]], dtype=torch.float64)
    sel = torch.tensor([True, True, True, True, False])
    k, drop = other_object(counts, sel, 1.0)
    assert k == 0 and drop.tolist() == [False, False, True, False, False]
    _, drop0 = other_object(counts, sel, 0.0)
    assert drop0.tolist() == [False, True, True, True, False]


@pytest.fixture(scope="module")
def mug_on_table():
    """An oak 'table' box (0.5 x 0.4 x 0.2 m) with a ceramic 'mug' box (0.08 m) standing on its top: the field,
    the views (masks: both together), and per view the part mask of each."""
    table = box_surface((0.5, 0.4, 0.2), 0.02)
    mug = box_surface((0.08, 0.08, 0.08), 0.01, centre=(0.1, 0.05, 0.141))
    means, scales, quats = (torch.cat([a, b]) for a, b in zip(table, mug))
    labels = torch.cat([torch.zeros(len(table[0])), torch.ones(len(mug[0]))]).long()
    pf = field_from(means, scales, quats, densities=[700.0, 2400.0], labels=labels, names=["oak", "ceramic"],
                    thickness_m=[None, None])  # fmt: skip
    views = ring_views(pf, (0, 0, 0.02), 1.5, elevations=(20.0, 55.0), n=12, size=64)
    parts = []
    for name, part in (("table", table), ("mug", mug)):
        alone = render_depth(field_from(*part, densities=[1.0], names=["x"]), views, backend="reference")
        parts.append((name, [r for r in alone]))
    full = render_depth(pf, views, backend="reference")
    masks = {}
    for i, v in enumerate(views):
        table_front = parts[0][1][i].depth <= parts[1][1][i].depth + 1e-6
        mug_px = (parts[1][1][i].alpha > 0.5) & ~((parts[0][1][i].alpha > 0.5) & table_front)
        masks[v.name] = {"whole": (full[i].alpha > 0.5).numpy(), "mug": mug_px.numpy(),
                         "table": ((parts[0][1][i].alpha > 0.5) & ~mug_px).numpy()}  # fmt: skip
    return pf, views, masks, len(table[0])


def _observations(views, masks, wrong: set[str] = frozenset()):
    obs = []
    for v in views:
        m = masks[v.name]
        obs.append(MaskObservation(v.name, m["whole"], "oak", 1.0, None, level="whole", mask_id=0, object="table"))
        obs.append(MaskObservation(v.name, m["table"], "oak", 1.0, None, level="part", mask_id=1,
                                   object="mug" if v.name in wrong else "table"))  # fmt: skip
        obs.append(MaskObservation(v.name, m["mug"], "ceramic", 1.0, None, level="part", mask_id=2, object="mug"))
    return obs


def _reconstruct(pf, views, obs, names: float | None):
    cfg = GeometryConfig(resolution=32, backend="reference", variants=False, select=SelectConfig(object_names=names))
    return reconstruct_object(pf, pf.pi(), views, obs, [None, None], cfg, material_names=pf.material_names)


def test_the_object_standing_on_the_chosen_one_is_dropped(mug_on_table):
    pf, views, masks, n_table = mug_on_table
    obs = _observations(views, masks)
    off = _reconstruct(pf, views, obs, None)
    on = _reconstruct(pf, views, obs, 1.0)
    assert off.selection.selected[n_table:].float().mean() > 0.9  # without the names the mug is the table's
    sel = on.selection.selected
    assert on.selection.object_name == "table" and on.selection.other_object > 0
    # the mug's bottom face (a sixth of its Gaussians) lies on the top, where no view sees it: no evidence either way
    assert sel[:n_table].float().mean() > 0.99 and sel[n_table:].float().mean() < 0.2, (
        float(sel[:n_table].float().mean()), float(sel[n_table:].float().mean()))
    assert on.summary()["object_name"] == "table"
    table_m3, mug_m3 = 0.5 * 0.4 * 0.2, 0.08**3
    assert off.volumes[0].sum() - on.volumes[0].sum() > 0.5 * mug_m3
    assert on.volumes[0].sum() == pytest.approx(table_m3, rel=0.25)


def test_one_wrong_answer_drops_nothing(mug_on_table):
    pf, views, masks, n_table = mug_on_table
    right = _reconstruct(pf, views, _observations(views, masks), 1.0).selection.selected[:n_table]
    wrong = {views[0].name}  # one view calls the table's part mask "mug"
    once = _reconstruct(pf, views, _observations(views, masks, wrong), 1.0).selection.selected[:n_table]
    # every table Gaussian that the right answers keep is kept, but for a few at the mug's foot, where the mug's
    # pixels cover the top's edge and the wrong view tips the balance (the footprint grown by 3 cm)
    away = ((pf.means[:n_table, :2] - torch.tensor([0.1, 0.05])).abs() > 0.04 + 0.03).any(1)
    assert bool((once | ~right | ~away).all()) and int((right & ~once).sum()) <= 0.01 * int(right.sum())
