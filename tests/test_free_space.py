"""The views' free space (geometry/free_space.py): the whole splat's depth carves, the masks only select."""

from __future__ import annotations

import numpy as np
import torch
from helpers.shapes import box_on_floor, geometry_of, ring_views, whole_voxel_volume

from physgs_nerfstudio.geometry.free_space import SEES_THROUGH, free_space_depths, seeded_components
from physgs_nerfstudio.geometry.gaussians import render_depth
from physgs_nerfstudio.geometry.grid import VoxelGrid


def test_seeded_components_keep_the_components_that_hold_the_seeds() -> None:
    """Three blobs; the seeds lie in two of them (one holding 2% of them, above the 1% share) and one stray seed in the
    third (0.5%, below it): the third goes, the other two stay whole (brute force over the grid)."""
    grid = VoxelGrid((0.0, 0.0, 0.0), 0.1, (30, 10, 10))
    solid = np.zeros(grid.shape, bool)
    solid[1:8, 2:8, 2:8] = solid[11:18, 2:8, 2:8] = solid[21:28, 2:8, 2:8] = True

    def at(i: float, n: int) -> torch.Tensor:
        return torch.full((n, 3), 0.45).index_put_((torch.arange(n), torch.zeros(n, dtype=torch.long)),
                                                  torch.full((n,), i * 0.1 + 0.05))  # fmt: skip

    seeds = torch.cat([at(4, 195), at(14, 4), at(24, 1)])  # 97.5%, 2%, 0.5%
    got = seeded_components(grid, solid, seeds)
    want = solid.copy()
    want[21:28] = False
    assert (got == want).all()
    outside = torch.full((5, 3), -1.0)  # no seed in a solid voxel: the solid as it is
    assert (seeded_components(grid, solid, outside) == solid).all()


def test_a_view_with_no_surface_sees_through() -> None:
    """The free-space depth is the whole splat's surface depth where a ray has one, and SEES_THROUGH where it has
    none (the rays over the floor's edge), where no object mask holds a pixel."""
    pf, _only_obj, _ = box_on_floor()
    views = ring_views(pf, (0, 0, 0.15), 1.6, n=4, elevations=(30.0,))
    depths = free_space_depths(pf, views, backend="reference")
    sky = [d == SEES_THROUGH for d in depths]
    assert any(bool(s.any()) for s in sky) and not all(bool(s.all()) for s in sky)
    for v, d, s, r in zip(views, depths, sky, render_depth(pf, views, backend="reference")):
        assert torch.equal(s, ~torch.isfinite(r.depth)) and torch.equal(d[~s], r.depth[~s])
        assert not bool(v.mask[s].any())  # no object where a ray sees through


def test_a_part_that_half_the_views_masks_miss_is_not_carved() -> None:
    """The box on its floor, its masks blanked in every other view (a segmenter that lost the object there): the
    whole splat's free space still ends at the box, which keeps its volume; the masks' visual hull alone would carve
    it to nothing in those views' directions."""
    pf, only_obj, _ = box_on_floor()
    views = ring_views(pf, (0, 0, 0.15), 1.6, elevations=(15.0, 40.0, 70.0), mask_pf=only_obj)
    full = geometry_of(pf, views)
    for v in views[::2]:
        v.mask = torch.zeros_like(v.mask)
    half = geometry_of(pf, views)
    true = 0.3**3
    assert 0.9 * true <= whole_voxel_volume(full) <= 1.2 * true
    assert abs(whole_voxel_volume(half) / whole_voxel_volume(full) - 1) < 0.1
