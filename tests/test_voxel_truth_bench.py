"""benchmarks/voxel_truth.py on grids built from the generator's own parts, with known answers."""

from __future__ import annotations

import numpy as np
import pytest
from bench_modules import load_benchmark

from physgs_nerfstudio.synth.objects import build_layout


@pytest.fixture(scope="module")
def vt():
    return load_benchmark("voxel_truth.py", "physgs_bench_voxel_truth")


def _grid(parts, h: float, keep):
    """A voxel dict over the parts' box (scene = world: identity transform, scale 1): occupied where ``keep(part index,
    local point)`` holds inside a part, part_id = that part's index; and the voxel centres (world)."""
    lo = np.array([-0.5, -0.5, -0.05])
    shape = (int(1.0 / h), int(1.0 / h), int(1.0 / h))
    idx = np.indices(shape).reshape(3, -1).T
    world = lo + (idx + 0.5) * h
    occ = np.zeros(len(world), bool)
    pid = np.full(len(world), -1, np.int32)
    for i, p in enumerate(parts):
        local = p.to_local(world)
        inside = p.primitive.contains(local) & keep(i, local)
        occ |= inside
        pid[inside] = i
    return {"occupancy": occ.reshape(shape).astype(np.uint8), "part_id": pid.reshape(shape), "origin_scene": lo,
            "voxel_size_scene": np.float64(h), "metres_per_unit": np.float64(1.0),
            "meta": {"parts": [{"p_hollow": 0.0, "thickness_m": None} for _ in parts]}}, world  # fmt: skip


def test_exact_solid_is_kept_whole_and_an_eroded_face_shows_in_the_profile(vt):
    parts = [p for p in build_layout("stool", 0).parts if p.role != "ground"]
    T = np.hstack([np.eye(3), np.zeros((3, 1))])
    whole, world = _grid(parts, 0.01, lambda i, x: np.ones(len(x), bool))
    exact = vt.voxel_truth(whole, T, 1.0, parts)
    for row in exact["parts"]:
        assert row["kept_share"] == pytest.approx(1.0, abs=1e-9)
        assert set(row["to_export_parts"]) <= set(range(len(parts)))
    assert exact["false_solid_m3"] == 0.0
    seat = next(i for i, p in enumerate(parts) if p.name == "seat")
    # the seat without the upper tenth of its local z range: the kept share is the voxels below that, the profile's
    # last bin along z is empty, its first whole, and along x every bin keeps the same share
    local = parts[seat].to_local(world)
    z = local[parts[seat].primitive.contains(local), 2]
    top = z.max() - 0.1 * (z.max() - z.min())
    cut = vt.voxel_truth(_grid(parts, 0.01, lambda i, x: (i != seat) | (x[:, 2] < top))[0], T, 1.0, parts,
                         profile="seat")  # fmt: skip
    row = next(r for r in cut["parts"] if r["part"] == "seat")
    assert row["kept_share"] == pytest.approx(float(np.mean(z < top)), abs=1e-9)  # counted voxel by voxel above
    assert 0 < row["kept_share"] < 1
    assert row["kept_share_along_local_axes"][2][-1] == 0.0
    assert row["kept_share_along_local_axes"][2][0] == pytest.approx(1.0)
    assert row["kept_share_along_local_axes"][0] == pytest.approx([row["kept_share"]] * 10, abs=0.05)


def test_volume_account_counts_shares_not_centres(vt):
    """A box whose faces lie on voxel boundaries, filled exactly: its fill is its volume and nothing is false. A layer
    counted at half over it (a voxel thick) and a column beside it are false fill, found above and beside it; a
    boundary voxel half inside the box and counted at half is no error."""
    from physgs_nerfstudio.synth.geometry import Box
    from physgs_nerfstudio.synth.objects import Part

    h = 0.01
    box = Part("top", Box((0.2, 0.1, 0.02)), "oak", translation=np.array([0.0, 0.0, 0.05]), object="table")
    lo = np.array([-0.15, -0.1, 0.0])
    shape = (30, 20, 10)
    idx = np.indices(shape).reshape(3, -1).T
    world = lo + (idx + 0.5) * h
    inside = box.primitive.contains(box.to_local(world)).reshape(shape)
    assert inside.sum() == 20 * 10 * 2
    vx = {"origin_scene": lo, "voxel_size_scene": np.float64(h), "metres_per_unit": np.float64(1.0)}
    T = np.hstack([np.eye(3), np.zeros((3, 1))])
    fill = inside.astype(np.float32)
    exact = vt.volume_account(vx, fill, T, 1.0, [box], relative_to="top", subsamples=4)
    assert exact["parts"][0]["true_on_grid_m3"] == pytest.approx(box.enclosed_volume(), rel=1e-9)
    assert exact["parts"][0]["fill_in_part_m3"] == pytest.approx(box.enclosed_volume(), rel=1e-9)
    assert exact["false_fill_m3"] == pytest.approx(0.0, abs=1e-12)
    over = fill.copy()
    k = np.nonzero(inside.any((0, 1)))[0].max() + 1  # the layer just over the box
    over[:, :, k] = np.where(inside[:, :, k - 1], 0.5, 0.0)
    over[0, 0, :] = 1.0  # a column beside it
    acc = vt.volume_account(vx, over, T, 1.0, [box], relative_to="top", subsamples=4)
    rel = acc["false_fill_relative_to"]
    assert rel["above_m3"] == pytest.approx(0.5 * 200 * h**3, rel=1e-9)
    assert rel["beside_m3"] == pytest.approx(10 * h**3, rel=1e-9)
    assert rel["under_m3"] == pytest.approx(0.0, abs=1e-12)
    assert acc["false_fill_m3"] == pytest.approx(rel["above_m3"] + rel["beside_m3"], rel=1e-9)
    # a grid shifted by half a voxel: the box's faces cut voxels in half; filled with the true shares, no false fill
    shifted = {**vx, "origin_scene": lo + h / 2}
    w2 = lo + h / 2 + (idx[:, None, :] + 0.5 + (np.stack(np.meshgrid(*[(np.arange(8) + 0.5) / 8 - 0.5] * 3,
                                                                    indexing="ij"), -1).reshape(-1, 3))[None]) * h
    share = box.primitive.contains(box.to_local(w2.reshape(-1, 3))).reshape(len(idx), -1).mean(1).reshape(shape)
    acc2 = vt.volume_account(shifted, share.astype(np.float32), T, 1.0, [box], relative_to="top", subsamples=8)
    assert acc2["false_fill_m3"] == pytest.approx(0.0, abs=1e-12)
    assert acc2["parts"][0]["fill_in_part_m3"] == pytest.approx(acc2["parts"][0]["true_on_grid_m3"], rel=1e-9)
    assert acc2["parts"][0]["true_on_grid_m3"] == pytest.approx(box.enclosed_volume(), rel=1e-6)
