"""The training downscale never makes every Gaussian "large on screen" (issue 14's out-of-memory batch run)."""

from __future__ import annotations

import pytest

from physgs_nerfstudio.nerfstudio.model import MIN_SPLIT_RADIUS_PX, training_downscale


@pytest.mark.parametrize("long_side", [64, 96, 128, 200, 384, 512, 800, 1600])
@pytest.mark.parametrize("scheduled", [1, 2, 4, 8])
def test_screen_split_threshold_stays_above_the_minimum_radius(long_side, scheduled):
    d = training_downscale(scheduled, long_side, 0.05, True)
    assert 1 <= d <= scheduled and d & (d - 1) == 0  # a power of two, never coarser than the schedule
    if d > 1:  # coarser than full resolution only where the split threshold stays meaningful
        assert long_side / d * 0.05 >= MIN_SPLIT_RADIUS_PX
    if d < scheduled:  # and reduced only where the schedule's own factor was not
        assert long_side / (2 * d) * 0.05 < MIN_SPLIT_RADIUS_PX


def test_the_schedule_is_kept_where_it_is_safe_or_the_split_is_off():
    assert training_downscale(4, 512, 0.05, True) == 4  # the 512 px chair trains as splatfacto-big does
    assert training_downscale(4, 128, 0.05, True) == 1  # 32 px exploded; 128 px keeps radii below the threshold
    assert training_downscale(4, 384, 0.05, True) == 2
    assert training_downscale(4, 128, 0.05, False) == 4  # screen-size split off: the schedule is harmless
