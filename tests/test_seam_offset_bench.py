"""benchmarks/seam_offset.py: a seam's offset from the voxels read as the other part's material, on two stacked
blocks whose true seam and read seam are known."""

from __future__ import annotations

import numpy as np
import pytest
from bench_modules import load_benchmark


@pytest.fixture(scope="module")
def bench():
    return load_benchmark("seam_offset.py", "physgs_bench_seam_offset")


class _Block:
    """A stand-in for a layout part: an axis-aligned box in world coordinates."""

    def __init__(self, name, material, lo, hi):
        self.name, self.material, self.lo, self.hi = name, material, np.asarray(lo), np.asarray(hi)

    def to_local(self, x):
        return x

    def outer(self):
        return self

    def contains(self, x):
        return np.all((x >= self.lo) & (x < self.hi), axis=1)


def _grid(read_cut: int, footprint: float = 1.0):
    """A 10^3 grid of 0.1 voxels, all solid; the export's part 0 below voxel layer ``read_cut``, part 1 above."""
    occ = np.ones((10, 10, 10), np.uint8)
    pid = np.where(np.indices(occ.shape)[2] < read_cut, 0, 1).astype(np.int32)
    return {"occupancy": occ, "part_id": pid, "origin_scene": np.zeros(3), "voxel_size_scene": 0.1,
            "meta": {"geometry": {"pixel_footprint_voxels": footprint}}}


def test_a_seam_read_one_layer_low_is_one_voxel_off(bench):
    parts = [_Block("sole", "rubber", (0, 0, 0), (1, 1, 0.5)), _Block("upper", "leather", (0, 0, 0.5), (1, 1, 1))]
    tf = np.hstack([np.eye(3), np.zeros((3, 1))])
    (row,) = bench.seam_offsets(_grid(4), ["rubber", "leather"], tf, 1.0, parts)
    assert row["faces"] == 100 and row["a_read_as_b"] == 100 and row["b_read_as_a"] == 0
    assert row["offset_voxels"] == pytest.approx(1.0) and not row["misread"]
    (row,) = bench.seam_offsets(_grid(7, footprint=2.0), ["rubber", "leather"], tf, 1.0, parts)
    assert row["offset_voxels"] == pytest.approx(-2.0) and row["offset_units"] == pytest.approx(-1.0)
    (row,) = bench.seam_offsets(_grid(5), ["rubber", "leather"], tf, 1.0, parts)
    assert row["offset_voxels"] == 0.0
    # a whole part read as the other's material is a misread, not a seam's place
    (row,) = bench.seam_offsets(_grid(0), ["rubber", "leather"], tf, 1.0, parts)
    assert row["misread"]
    # parts of one material have no seam to measure
    same = [_Block("a", "oak", (0, 0, 0), (1, 1, 0.5)), _Block("b", "oak", (0, 0, 0.5), (1, 1, 1))]
    assert bench.seam_offsets(_grid(4), ["oak", "oak"], tf, 1.0, same) == []
