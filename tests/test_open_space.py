"""`geometry.carve.open_space` (CarveConfig.open_fraction): the rays of hidden voxels against a brute-force march,
and the space under a table's top against a closed box's inside."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from physgs_nerfstudio.geometry.carve import DIRECTIONS, open_space, ray_hits


def _march(skin: np.ndarray, x: tuple[int, int, int], d: tuple[int, int, int]) -> bool:
    p = np.array(x) + d
    while all(0 <= p[i] < skin.shape[i] for i in range(3)):
        if skin[tuple(p)]:
            return True
        p = p + d
    return False


@settings(max_examples=25, deadline=None)
@given(st.integers(1, 9), st.integers(1, 9), st.integers(1, 9), st.floats(0.0, 0.4), st.integers(0, 2**31 - 1),
       st.sampled_from(DIRECTIONS))  # fmt: skip
def test_ray_hits_is_a_march_along_the_direction(nx, ny, nz, density, seed, d):
    skin = np.random.default_rng(seed).random((nx, ny, nz)) < density
    got = ray_hits(torch.from_numpy(skin), d).numpy()
    want = np.array([[[_march(skin, (i, j, k), d) for k in range(nz)] for j in range(ny)] for i in range(nx)])
    np.testing.assert_array_equal(got, want)


def _table(n=24):
    """A table seen from above (z up): its top's upper face and rim and its legs' outsides are the seen skin; the
    kept voxels are the top, the legs and all the space under the top (hidden behind the top in every view)."""
    kept = np.zeros((n, n, n), bool)
    skin = np.zeros_like(kept)
    kept[2:22, 2:22, 0:20] = True  # everything from the floor up to the top's underside is hidden
    kept[2:22, 2:22, 17:20] = True  # the top, 3 voxels thick
    skin[2:22, 2:22, 19] = True  # its upper face
    for a in (2, 21):  # its rim
        skin[a, 2:22, 17:20] = True
        skin[2:22, a, 17:20] = True
    for x in (2, 3, 20, 21):  # the legs' outer faces, 2 voxels square at the corners
        for y in (2, 3, 20, 21):
            skin[x, y, 0:17] = (x in (2, 21)) or (y in (2, 21))
    return kept, skin


def _closed_box(n=24):
    """A solid box seen from above and the sides: every face is seen skin but its bottom."""
    kept = np.zeros((n, n, n), bool)
    kept[4:20, 4:20, 0:16] = True
    skin = kept.copy()
    skin[5:19, 5:19, 0:15] = False  # the inside, and the bottom face that no camera sees
    return kept, skin


def test_the_space_under_a_table_is_open_and_a_closed_box_is_not():
    kept, skin = _table()
    got = open_space(torch.from_numpy(kept), torch.from_numpy(skin), 0.5).numpy()
    under = np.zeros_like(kept)
    under[6:18, 6:18, 2:15] = True  # well inside the legs and below the top
    # all of it but the voxels whose diagonal rays all run into the legs (the centre's column: 15 of 26 hit)
    assert got[under].mean() > 0.95
    assert not got[skin].any()
    assert not got[2:22, 2:22, 18].any()  # the top's inside, below its upper face: 9 of 26 rays see out
    kept, skin = _closed_box()
    assert not open_space(torch.from_numpy(kept), torch.from_numpy(skin), 0.5).numpy().any()


@pytest.mark.parametrize("fraction", [0.25, 0.5, 0.75])
def test_open_space_counts_escaping_rays(fraction):
    """Against the brute-force march: a hidden kept voxel is open iff at least ceil(fraction x 26) rays escape."""
    rng = np.random.default_rng(1)
    kept = rng.random((7, 8, 6)) < 0.8
    skin = kept & (rng.random(kept.shape) < 0.3)
    got = open_space(torch.from_numpy(kept), torch.from_numpy(skin), fraction).numpy()
    lo = np.argwhere(kept).min(0)
    hi = np.argwhere(kept).max(0) + 1
    box_skin = skin[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]]
    need = int(np.ceil(fraction * 26 - 1e-9))
    for x in np.argwhere(kept & ~skin):
        b = tuple(x - lo)
        esc = sum(not _march(box_skin, b, d) for d in DIRECTIONS)
        assert got[tuple(x)] == (esc >= need), (x, esc)
    assert not got[~kept].any() and not got[skin].any()
