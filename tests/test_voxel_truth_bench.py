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
