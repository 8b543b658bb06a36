"""benchmarks/variant_volumes.py on hand-made suite rows with known ratios."""

from __future__ import annotations

import json

import pytest
from bench_modules import load_benchmark


@pytest.fixture(scope="module")
def vv():
    return load_benchmark("variant_volumes.py", "physgs_bench_variant_volumes")


def _row(obj: str, enclosed: list[float], variants: dict[str, float]) -> dict:
    return {"object": obj, "true_parts": [{"enclosed_volume_m3": e} for e in enclosed],
            "volume_by_variant_m3": variants}  # fmt: skip


def test_ratios_divide_by_the_parts_enclosed_sum_and_skip_other_objects(vv):
    rows = [_row("chair", [0.004, 0.006], {"nominal": 0.009, "front2x": 0.011}),
            _row("mug", [0.001], {"nominal": 0.0004}),  # an open vessel: not counted by default
            _row("table", [0.02], {})]  # no variants recorded: skipped
    r = vv.variant_ratios(rows)
    assert list(r) == ["chair"]
    assert r["chair"] == pytest.approx({"nominal": 0.9, "front2x": 1.1})
    assert "mug" in vv.variant_ratios(rows, ("mug",))


def test_summary_medians_over_objects(vv):
    ratios = {"a": {"nominal": 0.8, "k2": 0.95}, "b": {"nominal": 0.9, "k2": 1.1}, "c": {"nominal": 1.2}}
    s = vv.summary(ratios)
    assert list(s) == ["nominal", "k2"]  # the nominal first
    assert s["nominal"]["median_abs_error"] == pytest.approx(0.2)  # |errors| 0.2, 0.1, 0.2
    assert s["nominal"]["median_ratio"] == pytest.approx(0.9)
    assert s["k2"] == pytest.approx({"median_abs_error": 0.075, "median_ratio": 1.025, "objects": 2})


def test_cli_writes_its_json(vv, tmp_path, capsys):
    f = tmp_path / "suite.json"
    f.write_text(json.dumps({"rows": [_row("crate", [0.01], {"nominal": 0.0095, "front2x": 0.0101})]}))
    vv.main([str(f), "--variants", "front2x", "--json", str(tmp_path / "out.json")])
    out = json.loads((tmp_path / "out.json").read_text())[str(f)]
    assert out["ratios"]["crate"]["front2x"] == pytest.approx(1.01)
    assert "crate 1.01" in capsys.readouterr().out
