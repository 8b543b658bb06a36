"""Terrain Class Friction (Ewen et al. 2022): class-mean ground truth, per-image and per-class predictions."""

import json

import pytest

from physgs_nerfstudio.eval.adapters import terrain
from physgs_nerfstudio.eval.command import EvalCommand, run_eval
from physgs_nerfstudio.eval.errors import EvalInputError


def _tree(tmp):
    root = tmp / "terrain"
    for cls, names in {"carpet": ["a.jpg", "b.jpg"], "Laminated Flooring": ["c.png"], "rocks": ["d.jpeg"]}.items():
        (root / cls).mkdir(parents=True)
        for n in names:
            (root / cls / n).write_bytes(b"")
    return root


def test_per_image_predictions_scored_against_class_means(tmp_path):
    root = _tree(tmp_path)
    truth = terrain.read_terrain_truth(root)
    mu = {m.item: m.value for m in truth}
    assert mu["carpet/a.jpg"] == terrain.EWEN2022_FRICTION["carpet"][0]
    assert {m.group for m in truth} == {"carpet", "laminated_flooring", "rocks"}
    preds = tmp_path / "preds.csv"
    preds.write_text("item,property,mean,std\n"
                     "a.jpg,friction,0.50,0.05\n"             # bare file name matches carpet/a.jpg
                     "carpet/b.jpg,kinetic_friction,0.70,0.05\n"
                     "Laminated Flooring/c.png,kinetic_friction,0.30,\n")
    result = run_eval(EvalCommand(dataset="terrain", ground_truth=root, predictions=(f"gpt5={preds}",)))
    carpet_mu = terrain.EWEN2022_FRICTION["carpet"][0]
    carpet = next(a for a in result.aggregates if a.group == "carpet")
    assert carpet.n_scored == 2
    assert carpet.values["ADE"] == pytest.approx((abs(0.5 - carpet_mu) + abs(0.7 - carpet_mu)) / 2)
    allrow = next(a for a in result.aggregates if a.group == "all")
    assert (allrow.n_expected, allrow.n_scored) == (4, 3)
    assert [m.item for m in result.missing] == ["rocks/d.jpeg"]
    assert allrow.values["n_calibration"] == 2


def test_per_class_predictions_and_custom_table(tmp_path):
    labels = tmp_path / "labels.json"
    labels.write_text(json.dumps({"img1.jpg": "ice", "img2.jpg": "asphalt"}))
    table = tmp_path / "classes.csv"
    table.write_text("class,mu,sigma\nice,0.05,0.02\nasphalt,0.7,0.1\n")
    preds = tmp_path / "p.json"
    preds.write_text(json.dumps([{"item": "Ice", "property": "friction", "mean": 0.1},
                                 {"item": "asphalt", "property": "friction", "mean": 0.6}]))
    result = run_eval(EvalCommand(dataset="terrain", ground_truth=labels, terrain_table=table,
                                  predictions=(str(preds),)))
    assert result.protocol["unit"] == "per class"
    rows = {r.item: r for r in result.items}
    assert rows["ice"].APE == pytest.approx(abs(0.05 - 0.1) / 0.05)
    assert rows["asphalt"].ADE == pytest.approx(0.1)


def test_malformed_terrain_inputs(tmp_path):
    labels = tmp_path / "labels.csv"
    labels.write_text("image,class\nx.jpg,carpet\ny.jpg,lava\n")
    with pytest.raises(EvalInputError, match=r"labels\.csv, line 3: unknown terrain class 'lava'"):
        terrain.read_terrain_truth(labels)
    table = tmp_path / "t.csv"
    table.write_text("class,mu,sigma\ncarpet,0.5,0.1\nCarpet,0.6,0.1\n")
    with pytest.raises(EvalInputError, match=r"t\.csv, line 3: class 'carpet' listed twice"):
        terrain.load_class_table(table)
    table.write_text("class,mu,sigma\ncarpet,-0.5,0.1\n")
    with pytest.raises(EvalInputError, match=r"line 2: mu must be > 0"):
        terrain.load_class_table(table)
    (tmp_path / "empty").mkdir()
    with pytest.raises(EvalInputError, match="no images in class sub-folders"):
        terrain.read_terrain_truth(tmp_path / "empty")
