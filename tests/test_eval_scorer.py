"""The scorer: point metrics, calibration from the different uncertainty forms, hardness scales, bookkeeping."""

import math
from statistics import NormalDist

import numpy as np
import pytest

from physgs_nerfstudio.eval import metrics
from physgs_nerfstudio.eval.records import Measurement, Mixture, Prediction
from physgs_nerfstudio.eval.scorer import ScoreConfig, score
from physgs_nerfstudio.materials import hardness


def _m(item, value, prop="mass", **kw):
    return Measurement(item=item, prop=prop, value=value, **kw)


def test_point_metrics_match_the_metric_module():
    rng = np.random.default_rng(0)
    truth = rng.uniform(0.1, 10, size=12)
    pred = truth * rng.uniform(0.3, 3, size=12)
    res = score([_m(f"i{k}", t) for k, t in enumerate(truth)], [Prediction(f"i{k}", "mass", p) for k, p in enumerate(pred)])
    agg = res.aggregates[0].values
    for name, fn in metrics.POINT_METRICS.items():
        assert agg[name] == pytest.approx(float(np.mean(fn(truth, pred))))


def test_calibration_forms():
    nd = NormalDist()
    truth = 1.0
    z90 = nd.inv_cdf(0.95)
    preds = [
        Prediction("std", "mass", 1.5, std=0.5),
        Prediction("interval", "mass", 1.5, low=1.5 - z90 * 0.5, high=1.5 + z90 * 0.5, level=0.9),
        Prediction("mix", "mass", 1.5, mixture=Mixture((0.5, 0.5), (1.0, 2.0), (0.5, 0.5))),
        Prediction("samples", "mass", 1.5, samples=(0.5, 1.0, 1.5, 2.0)),
        Prediction("range_only", "mass", 1.5, low=1.2, high=2.0),
    ]
    res = score([_m(p.item, truth) for p in preds], preds)
    rows = {r.item: r for r in res.items}
    # a 90 % interval is read as the Gaussian with that central interval: same as the std form
    assert rows["interval"].distribution == "normal_from_interval"
    assert rows["interval"].nll == pytest.approx(rows["std"].nll)
    assert rows["std"].nll == pytest.approx(-math.log(NormalDist(1.5, 0.5).pdf(1.0)))
    assert rows["std"].pit == pytest.approx(NormalDist(1.5, 0.5).cdf(1.0))
    assert rows["mix"].crps == pytest.approx(float(metrics.crps_mixture([1.0], [[0.5, 0.5]], [[1.0, 2.0]], [[0.5, 0.5]])[0]))
    assert rows["samples"].crps_samples is not None and rows["samples"].nll is None
    assert rows["range_only"].covered is False and rows["range_only"].nll is None
    agg = res.aggregates[0].values
    assert agg["n_calibration"] == 3 and agg["n_interval"] == 2
    pits = np.array([rows[k].pit for k in ("std", "interval", "mix")])
    assert agg["coverage@0.5"] == pytest.approx(np.mean(np.abs(pits - 0.5) <= 0.25))


def test_hardness_converted_into_the_reading_scale_with_std():
    m = [_m("a", 60.0, "shore_hardness", scale="D"), _m("b", 60.0, "shore_hardness", scale="A")]
    preds = [Prediction("a", "shore_hardness", 110.0, std=5.0, scale="A_eq"),
             Prediction("b", "shore_hardness", 60.0, std=5.0, scale="D")]
    rows = {r.item: r for r in score(m, preds).items}
    f = lambda x: float(hardness.from_canonical(x, "D"))
    assert rows["a"].pred == pytest.approx(f(110.0))
    nll_expected = -math.log(NormalDist(f(110.0), (f(115.0) - f(105.0)) / 2).pdf(60.0))
    assert rows["a"].nll == pytest.approx(nll_expected)
    assert rows["b"].pred == pytest.approx(float(hardness.convert(60.0, "D", "A")))
    assert "converted" in rows["b"].notes


def test_non_positive_values_skip_log_metrics_but_keep_ade():
    res = score([_m("a", 0.5, "offset", unit="mm")], [Prediction("a", "offset", -0.5, unit="mm")])
    (row,) = res.items
    assert row.ADE == pytest.approx(1.0) and row.ALDE is None and row.MnRE is None
    assert "undefined" in row.notes


def test_duplicates_units_and_non_finite_predictions_are_reported():
    with pytest.raises(ValueError, match="two entries for item 'a'"):
        score([_m("a", 1.0, source="f:2"), _m("a", 2.0, source="f:3")], [])
    with pytest.raises(ValueError, match="two predictions for item 'a'"):
        score([_m("a", 1.0)], [Prediction("a", "mass", 1.0), Prediction("a", "mass", 2.0)])
    with pytest.raises(ValueError, match="units differ"):
        score([_m("a", 1.0, "offset", unit="mm")], [Prediction("a", "offset", 1.0, unit="cm")])
    res = score([_m("a", 1.0), _m("b", 1.0)], [Prediction("a", "mass", None, notes=("query outside",)),
                                               Prediction("b", "mass", float("nan"))])
    assert [m.item for m in res.missing] == ["a", "b"]
    assert res.aggregates[0].n_missing == 2 and res.aggregates[0].n_scored == 0


def test_material_accuracy_uses_library_aliases():
    ms = [Measurement("a", "material", None, label="oak"), Measurement("b", "material", None, label="steel")]
    ps = [Prediction("a", "material", None, label="Oak"), Prediction("b", "material", None, label="glass")]
    agg = score(ms, ps, ScoreConfig(material_env=None)).aggregates[0]
    assert agg.values["material_accuracy"] == 0.5
