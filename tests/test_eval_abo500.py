"""ABO-500 layout (NeRF2Physics' distribution) and NeRF2Physics' [low, high] mass predictions."""

import json
import math
from pathlib import Path

import pytest

from physgs_nerfstudio.eval.adapters import abo500
from physgs_nerfstudio.eval.command import EvalCommand, run_eval
from physgs_nerfstudio.eval.errors import EvalInputError

WEIGHTS = {"A1": 2.0, "B2": 10.0, "C3": 0.5, "D4": 1.0}


def _abo(tmp: Path, scenes_sub: bool = True, split_entries=None) -> Path:
    root = tmp / "data" / "abo_500"
    base = root / "scenes" if scenes_sub else root
    for s in ("A1_x", "B2_y", "C3_z", "D4_q"):
        (base / s).mkdir(parents=True)
    (root / "filtered_product_weights.json").write_text(json.dumps(WEIGHTS))
    split_entries = split_entries or ["A1_x", "B2_y", "C3_z", "E5_w"]
    (root / "splits.json").write_text(json.dumps({"train": ["D4_q"], "val": [], "test": split_entries}))
    return root


def _report(path: Path, mean, low=None, high=None, level=None):
    """report.json as `physgs export` writes it (export/report.py: {"mass": MassReport.to_dict()})."""
    path.parent.mkdir(parents=True, exist_ok=True)
    mass = {"mean_kg": mean, "median_kg": mean, "n_samples": 64, "simulated": False, "units": {"mass": "kg"}}
    if low is not None:
        mass.update(interval_kg=[low, high], level=level)
    path.write_text(json.dumps({"mass": mass}))


def _agg(result, method, group="all"):
    return next(a for a in result.aggregates if a.method == method and a.group == group)


def test_n2p_midpoint_with_clamp_option_and_our_reports_one_scorer(tmp_path):
    _abo(tmp_path)
    n2p = tmp_path / "preds_mass.json"
    n2p.write_text(json.dumps({"A1_x": [1.0, 3.0], "B2_y": [150.0, 250.0], "C3_z": [0.001, 0.003]}))
    res = tmp_path / "results"
    _report(res / "A1_x" / "report.json", 2.5, 2.0, 3.0, 0.9)
    _report(res / "B2_y" / "export" / "report.json", 9.0)
    result = run_eval(EvalCommand(dataset="abo500", ground_truth=tmp_path, split="test", clamp=(0.01, 100.0),
                                  predictions=(f"n2p={n2p}", f"ours={res}")))
    rows = {(r.method, r.item): r for r in result.items}
    # midpoints, clamped to [0.01, 100] kg (--clamp 0.01 100; the default scores them as predicted)
    assert rows[("n2p", "A1_x")].pred == pytest.approx(2.0)
    assert rows[("n2p", "B2_y")].pred == pytest.approx(100.0)
    assert rows[("n2p", "C3_z")].pred == pytest.approx(0.01)
    assert "clamped" in rows[("n2p", "B2_y")].notes
    # [low, high] coverage of their raw ranges
    assert [rows[("n2p", s)].covered for s in ("A1_x", "B2_y", "C3_z")] == [True, False, False]
    a = _agg(result, "n2p")
    errs = [abs(2.0 - 2.0), abs(100.0 - 10.0), abs(0.01 - 0.5)]
    assert a.values["ADE"] == pytest.approx(sum(errs) / 3)
    assert a.values["ALDE"] == pytest.approx((0 + math.log(10.0) + abs(math.log(0.01 / 0.5))) / 3)
    assert a.values["MnRE"] == pytest.approx((1 + 0.1 + 0.02) / 3)
    assert a.values["interval_coverage"] == pytest.approx(1 / 3)
    assert "interval_level" not in a.values and "nll" not in a.values  # their ranges have no nominal level
    # ours: the C3 scene has no report -> missing, not dropped
    ours = _agg(result, "ours")
    assert (ours.n_expected, ours.n_scored, ours.n_missing) == (3, 2, 1)
    assert [(m.method, m.item) for m in result.missing] == [("ours", "C3_z")]
    assert ours.values["ADE"] == pytest.approx((0.5 + 1.0) / 2)
    assert rows[("ours", "A1_x")].distribution == "normal_from_interval"
    assert ours.values["n_calibration"] == 1
    # the split names a scene without a weight: reported in the protocol
    assert result.protocol["split_entries_without_ground_truth"] == ["E5_w"]


def test_scene_folders_at_top_level_and_item_id_splits(tmp_path):
    root = _abo(tmp_path, scenes_sub=False, split_entries=["A1", "B2"])
    ds = abo500.load_abo500(root, "test")
    assert [m.item for m in ds.measurements] == ["A1", "B2"]
    assert abo500.list_scenes(root, WEIGHTS) == ["A1_x", "B2_y", "C3_z", "D4_q"]
    everything = abo500.load_abo500(root, "all")
    assert [m.item for m in everything.measurements] == ["A1_x", "B2_y", "C3_z", "D4_q"]
    # predictions keyed by scene name meet ground truth keyed by item id, and the other way round
    n2p = tmp_path / "p.json"
    n2p.write_text(json.dumps({"A1_x": [1.0, 2.0], "B2": [9.0, 11.0]}))
    preds = abo500.align_to_items(abo500.read_n2p_mass_predictions(n2p), ["A1", "B2_y"])
    assert sorted(p.item for p in preds) == ["A1", "B2_y"]


def test_train_plus_val_and_unknown_split(tmp_path):
    root = _abo(tmp_path)
    assert [m.item for m in abo500.load_abo500(root, "train+val").measurements] == ["D4_q"]
    with pytest.raises(EvalInputError, match="unknown split"):
        abo500.load_abo500(root, "dev")


@pytest.mark.parametrize(
    "target, content, match",
    [
        ("filtered_product_weights.json", '{"A1": "heavy"}', r"filtered_product_weights\.json, item 'A1': weight \(kg\) is not a number"),
        ("filtered_product_weights.json", '{"A1": -2}', r"item 'A1': weight \(kg\) must be > 0"),
        ("splits.json", '{"test": ["A1_x",\n 3]}', r"splits\.json, split 'test'\[1\]"),
        ("splits.json", '{"test": [\n"A1_x" "B2"]}', r"splits\.json, line 2, column \d+: invalid JSON"),
    ],
)
def test_malformed_abo_files(tmp_path, target, content, match):
    root = _abo(tmp_path)
    (root / target).write_text(content)
    with pytest.raises(EvalInputError, match=match):
        abo500.load_abo500(root, "test")


def test_malformed_n2p_predictions_and_reports(tmp_path):
    bad = tmp_path / "preds.json"
    bad.write_text(json.dumps({"A1_x": [1.0, 3.0], "B2_y": [5.0]}))
    with pytest.raises(EvalInputError, match=r"preds\.json, entry 'B2_y': expected \[low, high\]"):
        abo500.read_n2p_mass_predictions(bad)
    bad.write_text(json.dumps({"A1_x": [3.0, 1.0]}))
    with pytest.raises(EvalInputError, match="low 3 > high 1"):
        abo500.read_n2p_mass_predictions(bad)
    _abo(tmp_path)
    rep = tmp_path / "res" / "A1_x" / "report.json"
    _report(rep, 2.0, 3.0, 1.0, 0.9)
    with pytest.raises(EvalInputError, match=r"report\.json, entry 'mass': interval low 3 > high 1"):
        run_eval(EvalCommand(dataset="abo500", ground_truth=tmp_path, predictions=(str(tmp_path / "res"),)))


def test_missing_weights_file_names_the_fix(tmp_path):
    with pytest.raises(EvalInputError, match="filtered_product_weights.json"):
        abo500.load_abo500(tmp_path, "test")
