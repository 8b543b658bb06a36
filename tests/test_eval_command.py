"""`physgs eval` end to end through tyro: tables printed, JSON + CSV written, errors exit cleanly."""

import csv
import json

import pytest
import tyro

from physgs_nerfstudio.cli import entrypoint
from physgs_nerfstudio.errors import PhysGSError
from physgs_nerfstudio.eval.command import EvalCommand, parse_prediction_spec


def _files(tmp):
    (tmp / "t.csv").write_text("item,property,value,unit\na,mass,2,kg\nb,mass,4,kg\n")
    (tmp / "p.csv").write_text("item,property,mean,low,high,level\na,mass,2.5,2,3,0.9\n")
    return tmp / "t.csv", tmp / "p.csv"


def test_cli_writes_json_and_csv(tmp_path, capsys):
    t, p = _files(tmp_path)
    out = tmp_path / "out"
    cfg = tyro.cli(EvalCommand, args=["--dataset", "table", "--ground-truth", str(t), "--predictions", f"ours={p}",
                                      "--output-dir", str(out)])
    cfg.main()
    printed = capsys.readouterr().out
    assert "ours" in printed and "ADE" in printed and "b [mass]" in printed  # missing item is shown
    data = json.loads((out / "eval.json").read_text())
    assert data["aggregates"][0]["values"]["ADE"] == pytest.approx(0.5)
    assert data["missing"] == [{"method": "ours", "item": "b", "prop": "mass", "reason": "no prediction"}]
    with (out / "summary.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert rows[0]["method"] == "ours" and rows[0]["n_missing"] == "1"
    with (out / "items.csv").open() as fh:
        items = list(csv.DictReader(fh))
    assert items[0]["item"] == "a" and float(items[0]["ADE"]) == pytest.approx(0.5)
    assert (out / "missing.csv").is_file()


def test_malformed_input_exits_with_message(tmp_path, capsys):
    t, p = _files(tmp_path)
    p.write_text("item,property,mean,low,high\na,mass,1,3,2\n")
    args = ["eval", "--dataset", "table", "--ground-truth", str(t), "--output-dir", str(tmp_path / "o"), "--predictions"]
    with pytest.raises(SystemExit) as exc:
        entrypoint([*args, str(p)])
    assert exc.value.code == 1  # errors exit 1, as every physgs command's
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("physgs eval: error: ") and "p.csv, line 2: low 3 > high 2" in err[0]
    j = tmp_path / "p.json"
    j.write_text('{"a": 1}')
    with pytest.raises(SystemExit):
        entrypoint([*args, str(j)])
    assert '{"predictions": [...]}' in capsys.readouterr().err  # markup-like text survives


def test_strict_fails_on_missing_items(tmp_path):
    t, p = _files(tmp_path)
    cfg = EvalCommand(dataset="table", ground_truth=t, predictions=(str(p),), output_dir=tmp_path / "o", strict=True)
    with pytest.raises(PhysGSError, match="--strict: 1 ground-truth entries were not scored"):
        cfg.main()


def test_prediction_spec(tmp_path):
    assert parse_prediction_spec("n2p=preds/x.json") == ("n2p", tmp_path.__class__("preds/x.json"))
    odd = tmp_path / "a=b.csv"
    odd.write_text("")
    assert parse_prediction_spec(str(odd)) == (None, odd)


def test_synth_scenes_against_export_reports(tmp_path):
    """Generated scenes' total mass vs each scene's report.json (coverage of the 90 % interval)."""
    truths = {"cup": 0.30, "box": 2.0}
    for name, kg in truths.items():
        (tmp_path / "scenes" / name).mkdir(parents=True)
        (tmp_path / "scenes" / name / "ground_truth.json").write_text(json.dumps({"object": name, "total_mass_kg": kg}))
    rep = tmp_path / "results" / "cup" / "export" / "report.json"
    rep.parent.mkdir(parents=True)
    rep.write_text(json.dumps({"mass": {"mean_kg": 0.33, "interval_kg": [0.25, 0.40], "level": 0.9, "simulated": True}}))
    from physgs_nerfstudio.eval.command import run_eval

    res = run_eval(EvalCommand(dataset="synth", ground_truth=tmp_path / "scenes", predictions=(str(tmp_path / "results"),)))
    (row,) = res.items
    assert row.item == "cup" and row.covered is True and row.ADE == pytest.approx(0.03)
    assert "simulated" in row.notes
    assert [m.item for m in res.missing] == ["box"]
    (tmp_path / "scenes" / "box" / "ground_truth.json").write_text(json.dumps({"object": "box"}))
    from physgs_nerfstudio.eval.errors import EvalInputError

    with pytest.raises(EvalInputError, match=r"box/ground_truth\.json, key 'total_mass_kg': missing"):
        run_eval(EvalCommand(dataset="synth", ground_truth=tmp_path / "scenes", predictions=(str(tmp_path / "results"),)))
