"""Plain CSV/JSON tables for users' own measurements and predictions."""

import json

import pytest

from physgs_nerfstudio.eval.adapters.table import read_prediction_table, read_truth_table
from physgs_nerfstudio.eval.command import EvalCommand, run_eval
from physgs_nerfstudio.eval.errors import EvalInputError
from physgs_nerfstudio.materials import hardness

TRUTH = """# my measurements
item,property,value,unit,scale,group
mug,mass,350,g,,kitchen
mug,shore_hardness,80,Shore D,,kitchen
mug,material,ceramic,,,kitchen
shoe,friction,0.6,,,
shoe,youngs_modulus,5,MPa,,
box,mass,1.0,kg,,
"""

PREDS = """item,property,mean,low,high,level,std,unit,scale,material
mug,mass,0.40,0.30,0.50,0.9,,kg,,
mug,shore_hardness,130,,,,4,,A_eq,
mug,material,Ceramic,,,,,,,
shoe,kinetic_friction,0.5,,,,0.1,,,
shoe,stiffness,0.004,,,,,GPa,,
ghost,mass,1,,,,,kg,,
"""


def test_units_scales_materials_missing_and_unmatched(tmp_path):
    (tmp_path / "t.csv").write_text(TRUTH)
    (tmp_path / "p.csv").write_text(PREDS)
    truth = read_truth_table(tmp_path / "t.csv")
    assert next(m for m in truth if m.prop == "mass" and m.item == "mug").value == pytest.approx(0.35)
    assert next(m for m in truth if m.prop == "shore_hardness").scale == "D"
    result = run_eval(EvalCommand(dataset="table", ground_truth=tmp_path / "t.csv", predictions=(f"mine={tmp_path / 'p.csv'}",)))
    rows = {(r.item, r.prop): r for r in result.items}
    assert rows[("mug", "mass")].ADE == pytest.approx(0.05)
    assert rows[("mug", "mass")].covered is True
    assert rows[("shoe", "youngs_modulus")].pred == pytest.approx(4e6)
    assert rows[("shoe", "youngs_modulus")].MnRE == pytest.approx(0.8)
    d = float(hardness.from_canonical(130.0, "D"))
    assert rows[("mug", "shore_hardness")].pred == pytest.approx(d)
    assert rows[("mug", "material")].correct is True
    mat = next(a for a in result.aggregates if a.prop == "material" and a.group == "all")
    assert mat.values["material_accuracy"] == 1.0
    assert [(m.item, m.prop) for m in result.missing] == [("box", "mass")]
    assert [(m.item, m.prop) for m in result.unmatched] == [("ghost", "mass")]
    mass = next(a for a in result.aggregates if a.prop == "mass" and a.group == "all")
    assert (mass.n_expected, mass.n_scored, mass.n_missing) == (2, 1, 1)
    assert mass.values["interval_level"] == 0.9


def test_json_tables(tmp_path):
    (tmp_path / "t.json").write_text(json.dumps({"measurements": [
        {"item": "a", "property": "density", "value": 1.2, "unit": "g/cm^3"}]}))
    (tmp_path / "p.json").write_text(json.dumps([{"item": "a", "property": "density", "mean": 1100, "std": 50}]))
    result = run_eval(EvalCommand(dataset="table", ground_truth=tmp_path / "t.json", predictions=(str(tmp_path / "p.json"),)))
    (row,) = result.items
    assert row.truth == pytest.approx(1200.0) and row.ADE == pytest.approx(100.0)
    assert row.method == "p" and row.distribution == "normal"


@pytest.mark.parametrize(
    "text, match",
    [
        ("item,property,value,unit,colour\nmug,mass,1,kg,red\n", r"t\.csv, line 1 \(header\): unknown column\(s\) colour"),
        ("item,property,value\nmug,mass,1\n", r"t\.csv, line 1 \(header\): missing column\(s\) unit"),
        ("item,property,value,unit\nmug,mass,1,kg\nmug,mass,heavy,kg\n", r"t\.csv, line 3: value is not a number"),
        ("item,property,value,unit\nmug,mass,1,stone\n", r"t\.csv, line 2: unit 'stone' is not a known unit of mass"),
        ("item,property,value,unit\nmug,hardness,50,\n", r"t\.csv, line 2: shore_hardness without a scale"),
        ("item,property,value,unit\nmug,mass,1,kg,extra\n", r"t\.csv, line 2: 5 fields but the header has 4"),
    ],
)
def test_malformed_truth_tables(tmp_path, text, match):
    (tmp_path / "t.csv").write_text(text)
    with pytest.raises(EvalInputError, match=match):
        read_truth_table(tmp_path / "t.csv")


def test_malformed_prediction_tables(tmp_path):
    p = tmp_path / "p.csv"
    p.write_text("item,property,mean,low\nmug,mass,1,0.5\n")
    with pytest.raises(EvalInputError, match=r"p\.csv, line 2: only one of low/high given"):
        read_prediction_table(p)
    p.write_text("item,property,mean,std\nmug,mass,1,-2\n")
    with pytest.raises(EvalInputError, match=r"line 2: std must be > 0"):
        read_prediction_table(p)
    j = tmp_path / "p.json"
    j.write_text(json.dumps([{"item": "a", "property": "mass"}]))
    with pytest.raises(EvalInputError, match=r"p\.json, entry 0: missing key\(s\) mean"):
        read_prediction_table(j)
    j.write_text('[{"item": "a", "property": "mass", "mean": 1, "mean": 2}]')
    with pytest.raises(EvalInputError, match=r"key 'mean': appears twice"):
        read_prediction_table(j)


def test_json_prediction_mixture_and_samples(tmp_path):
    from physgs_nerfstudio.eval import metrics

    (tmp_path / "t.csv").write_text("item,property,value,unit\na,mass,1500,g\n")
    (tmp_path / "p.json").write_text(json.dumps([{"item": "a", "property": "mass", "mean": 1200, "unit": "g",
                                                  "mixture": {"weights": [1, 3], "means": [1000, 1400], "stds": [100, 200]},
                                                  "samples": [1000, 1300, 1600]}]))
    (row,) = run_eval(EvalCommand(dataset="table", ground_truth=tmp_path / "t.csv",
                                  predictions=(str(tmp_path / "p.json"),))).items
    expected = metrics.crps_mixture([1.5], [[0.25, 0.75]], [[1.0, 1.4]], [[0.1, 0.2]])[0]
    assert row.distribution == "mixture" and row.crps == pytest.approx(float(expected))
    assert row.crps_samples == pytest.approx(float(metrics.crps_samples([1.5], [[1.0, 1.3, 1.6]])[0]))
    (tmp_path / "p.json").write_text(json.dumps([{"item": "a", "property": "mass", "mean": 1,
                                                  "mixture": {"weights": [1], "means": [1, 2], "stds": [1, 1]}}]))
    with pytest.raises(EvalInputError, match=r"p\.json, entry 0, mixture: weights, means and stds must be"):
        read_prediction_table(tmp_path / "p.json")
