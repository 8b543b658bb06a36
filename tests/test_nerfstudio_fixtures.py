"""The blob scene of tests/helpers/nerfstudio_scenes.py, checked itself."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from helpers.nerfstudio_scenes import write_blob_scene


def test_blob_scene_fixture(tmp_path: Path) -> None:
    """The fixture itself: both materials visible, maps aligned with the images' size."""
    gt = write_blob_scene(tmp_path, num_views=4, size=32)
    for fp, lab in gt.items():
        assert lab.shape == (32, 32)
        assert set(np.unique(lab)) == {0, 1, 2}, fp
    meta = json.loads((tmp_path / "transforms.json").read_text())
    assert all("material_path" in f for f in meta["frames"])
