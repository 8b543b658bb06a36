"""benchmarks/common.py: the trained scene's points back in the generator's coordinates, and the printed table."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from helpers.benchmarks import load_benchmark


@pytest.fixture(scope="module")
def common():
    return load_benchmark("common.py", "physgs_bench_common")


def test_to_world_inverts_the_dataparser_transform(common, tmp_path) -> None:
    a = math.radians(30)
    R = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1.0]])
    T = np.hstack([R, np.array([[0.1], [-0.2], [0.3]])])
    (tmp_path / "dataparser_transforms.json").write_text(json.dumps({"transform": T.tolist(), "scale": 0.5}))
    T_read, s = common.scene_transform(tmp_path)
    p_data = np.random.default_rng(0).normal(size=(5, 3))
    p_scene = s * (p_data @ R.T + T[:, 3])  # nerfstudio: p_s = s (R p_d + t)
    np.testing.assert_allclose(common.to_world(p_scene, T_read, s), p_data, atol=1e-12)


def test_table_has_a_header_a_rule_and_one_line_per_row(common) -> None:
    text = common.format_table(("a", "b"), [(1, 0.123456), ("x", None)])
    assert text.splitlines() == ["| a | b |", "|---|---|", "| 1 | 0.1235 |", "| x | - |"]
