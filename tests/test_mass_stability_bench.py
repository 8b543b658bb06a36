"""benchmarks/mass_stability.py's sweep on stand-in exports with known masses: each setting relative to the default,
the largest change and the setting that made it, a failed export named and left out of the change."""

from __future__ import annotations

from pathlib import Path

import pytest
from helpers.benchmarks import load_benchmark


@pytest.fixture(scope="module")
def bench():
    return load_benchmark("mass_stability.py", "physgs_bench_mass_stability")


def test_sweep_reports_each_setting_against_the_default(bench, monkeypatch) -> None:
    masses = {"default": 10.0, "a": 9.0, "b": 11.5, "c": None}

    def fake_export(run: Path, name: str, flags: list[str]) -> dict:
        if masses[name] is None:
            return {"setting": name, "error": "carving left no solid voxel", "rc": 1}
        return {"setting": name, "mean_kg": masses[name], "flags": flags}

    monkeypatch.setattr(bench, "export", fake_export)
    chosen = {"default": [], "a": ["--x", "1"], "b": ["--y"], "c": ["--z"]}
    r = bench.sweep(Path("/nowhere"), chosen, jobs=2)
    assert r["default_kg"] == 10.0
    assert [row["setting"] for row in r["rows"]] == ["default", "a", "b", "c"]  # in the order asked
    assert [row.get("relative_to_default") for row in r["rows"]] == [1.0, 0.9, 1.15, None]
    assert r["largest_change"] == pytest.approx(0.15) and r["largest_change_setting"] == "b"
    assert r["failed"] == ["c"]
    assert r["rows"][1]["flags"] == ["--x", "1"]


def test_every_setting_but_the_default_sets_a_flag(bench) -> None:
    assert bench.SETTINGS["default"] == []
    assert all(flags and flags[0].startswith("--mass.") for name, flags in bench.SETTINGS.items() if name != "default")
