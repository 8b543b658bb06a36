"""One scorer for every dataset and method: match predictions to ground truth, score, aggregate.

Per (method, item, property) row: the paper's point metrics (ADE, ALDE, APE, MnRE -- ALDE/MnRE/APE only
where the quantities are positive), material correctness, and calibration when the prediction carries
uncertainty:

* an explicit interval ``[low, high]`` -> ``covered`` (does it contain the truth), with its nominal level
  when known (NeRF2Physics' ranges have none);
* a Gaussian mixture, a Gaussian ``std``, or a mean with an interval of known level (read as the Gaussian
  with that central interval: ``std = (high - low) / (2 z)``, marked ``normal_from_interval``) -> NLL, CRPS
  and the PIT, from which the aggregate gives coverage at each nominal level;
* Monte Carlo samples -> sample CRPS.

Shore hardness is compared in each measurement's own scale: predictions are converted from their scale
(``A_eq`` for our exports) with :mod:`physgs_nerfstudio.materials.hardness`; stds through the conversion's
mean slope over ``mean +- std`` (the conversion is piecewise linear).

Ground truth without a prediction is *missing* (listed with the reason, counted in ``n_missing``);
predictions without ground truth are listed as *unmatched*. Nothing is dropped silently.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field, replace
from statistics import NormalDist
from typing import Any

import numpy as np

from . import metrics as M
from .records import Measurement, Mixture, Prediction

__all__ = ["Aggregate", "EvalResult", "ItemScore", "Missing", "ScoreConfig", "label_normalizer", "score"]

A_EQ = "A_eq"


@dataclass(frozen=True)
class ScoreConfig:
    """Scoring options.

    levels: nominal central-interval levels at which the aggregate reports PIT coverage.
    material_env: material library used to resolve material aliases (None = compare normalised names).
    """

    levels: tuple[float, ...] = (0.5, 0.9)
    material_env: str | None = "indoor"


@dataclass
class ItemScore:
    method: str
    item: str
    prop: str
    group: str | None
    truth: float | None
    pred: float | None
    unit: str = ""
    scale: str | None = None
    ADE: float | None = None
    ALDE: float | None = None
    APE: float | None = None
    MnRE: float | None = None
    low: float | None = None
    high: float | None = None
    level: float | None = None
    covered: bool | None = None
    distribution: str | None = None   # "mixture" | "normal" | "normal_from_interval" | None
    pit: float | None = None
    nll: float | None = None
    crps: float | None = None
    crps_samples: float | None = None
    truth_label: str | None = None
    pred_label: str | None = None
    correct: bool | None = None
    notes: str = ""


@dataclass
class Missing:
    method: str
    item: str
    prop: str
    reason: str


@dataclass
class Aggregate:
    method: str
    prop: str
    group: str                          # "all" or a group name
    n_expected: int
    n_scored: int
    n_missing: int
    values: dict[str, float] = field(default_factory=dict)


@dataclass
class EvalResult:
    items: list[ItemScore]
    aggregates: list[Aggregate]
    missing: list[Missing]
    unmatched: list[Missing]            # predictions without ground truth
    protocol: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "protocol": self.protocol,
            "aggregates": [asdict(a) for a in self.aggregates],
            "items": [asdict(i) for i in self.items],
            "missing": [asdict(m) for m in self.missing],
            "unmatched_predictions": [asdict(m) for m in self.unmatched],
        }


def label_normalizer(env: str | None) -> Callable[[str], str]:
    """Material-name comparison: library aliases when the library loads, else case/space-insensitive."""

    def plain(name: str) -> str:
        return "_".join(name.strip().lower().replace("-", " ").split())

    if env is None:
        return plain
    try:
        from ..materials import load_library

        lib = load_library(env)
    except Exception:  # noqa: BLE001 - the library is optional here; fall back to plain names
        return plain

    def resolve(name: str) -> str:
        found = lib.resolve(name)
        return found if found is not None else plain(name)

    return resolve


# --------------------------------------------------------------------------------------------- hardness
def _hardness_fn(from_scale: str | None, to_scale: str | None) -> Callable[[float], float] | None:
    if from_scale is None or to_scale is None or from_scale == to_scale:
        return None
    from ..materials import hardness as H

    def f(x: float) -> float:
        canon = x if from_scale == A_EQ else H.to_canonical(float(x), from_scale)
        return float(canon if to_scale == A_EQ else H.from_canonical(canon, to_scale))

    return f


def _convert_prediction(p: Prediction, to_scale: str | None) -> tuple[Prediction, str]:
    """``p`` expressed in Shore scale ``to_scale`` (and a note), unchanged when no conversion is needed."""
    f = _hardness_fn(p.scale, to_scale)
    if f is None:
        return p, ""

    def conv_std(m: float, s: float) -> float:
        return max(abs(f(m + s) - f(m - s)) / 2.0, 1e-12)

    mixture = None
    if p.mixture is not None:
        mixture = Mixture(p.mixture.weights, tuple(f(m) for m in p.mixture.means),
                          tuple(conv_std(m, s) for m, s in zip(p.mixture.means, p.mixture.stds)))
    q = replace(
        p, mean=None if p.mean is None else f(p.mean), low=None if p.low is None else f(p.low),
        high=None if p.high is None else f(p.high),
        std=None if (p.std is None or p.mean is None) else conv_std(p.mean, p.std), mixture=mixture,
        samples=None if p.samples is None else tuple(f(s) for s in p.samples), scale=to_scale,
    )
    return q, f"hardness converted {p.scale} -> Shore {to_scale}"


# --------------------------------------------------------------------------------------------- one row
def _one(fn, t: float, p: float) -> float:
    return float(np.asarray(fn(np.array([t]), np.array([p])))[0])


def _distribution(p: Prediction) -> tuple[str | None, Mixture | None]:
    if p.mixture is not None:
        return "mixture", p.mixture
    if p.std is not None and p.mean is not None and p.std > 0:
        return "normal", Mixture((1.0,), (p.mean,), (p.std,))
    if p.has_interval and p.level is not None and p.mean is not None and p.high > p.low:  # type: ignore[operator]
        z = NormalDist().inv_cdf(0.5 + p.level / 2)
        return "normal_from_interval", Mixture((1.0,), (p.mean,), ((p.high - p.low) / (2 * z),))  # type: ignore[operator]
    return None, None


def _score_row(m: Measurement, p: Prediction, norm: Callable[[str], str]) -> ItemScore:
    notes = list(p.notes)
    if m.prop == "shore_hardness":
        if p.scale is None:
            notes.append(f"prediction without a hardness scale: taken as Shore {m.scale}")
            p_conv = p
        else:
            p_conv, note = _convert_prediction(p, m.scale)
            if note:
                notes.append(note)
    else:
        p_conv = p
    row = ItemScore(method=p.method, item=m.item, prop=m.prop, group=m.group, truth=m.value, pred=p_conv.mean,
                    unit=m.unit, scale=m.scale, low=p_conv.low, high=p_conv.high, level=p_conv.level)
    if m.prop == "material" or m.label is not None:
        row.truth_label, row.pred_label = m.label, p.label
        if m.label is not None and p.label is not None:
            row.correct = norm(m.label) == norm(p.label)
    if m.value is not None and p_conv.mean is not None:
        t, q = float(m.value), float(p_conv.mean)
        row.ADE = _one(M.ade, t, q)
        if t > 0:
            row.APE = _one(M.ape, t, q)
        if t > 0 and q > 0:
            row.ALDE = _one(M.alde, t, q)
            row.MnRE = _one(M.mnre, t, q)
        else:
            notes.append("ALDE/MnRE undefined for non-positive values")
        if p_conv.has_interval:
            row.covered = bool(M.interval_coverage(np.array([t]), np.array([p_conv.low]), np.array([p_conv.high]))[0])
        kind, mix = _distribution(p_conv)
        if mix is not None:
            w, mu, sd = (np.array([mix.weights]), np.array([mix.means]), np.array([mix.stds]))
            row.distribution = kind
            row.pit = float(M.mixture_cdf(np.array([t]), w, mu, sd)[0])
            row.nll = float(M.gaussian_mixture_nll(np.array([t]), w, mu, sd)[0])
            row.crps = float(M.crps_mixture(np.array([t]), w, mu, sd)[0])
        if p_conv.samples:
            row.crps_samples = float(M.crps_samples(np.array([t]), np.array([p_conv.samples]))[0])
    row.notes = "; ".join(notes)
    return row


# --------------------------------------------------------------------------------------------- aggregate
def _mean(vals: Iterable[float | None]) -> tuple[float | None, int]:
    xs = [v for v in vals if v is not None and math.isfinite(v)]
    return (float(np.mean(xs)) if xs else None), len(xs)


def _aggregate(rows: Sequence[ItemScore], levels: Sequence[float]) -> dict[str, float]:
    out: dict[str, float] = {}
    for name in ("ADE", "ALDE", "APE", "MnRE"):
        mean, n = _mean(getattr(r, name) for r in rows)
        if mean is not None:
            out[name] = mean
            if n != len(rows):
                out[f"n_{name}"] = n
    covered = [r.covered for r in rows if r.covered is not None]
    if covered:
        out["interval_coverage"] = float(np.mean(covered))
        out["n_interval"] = len(covered)
        lv = {r.level for r in rows if r.covered is not None}
        if len(lv) == 1 and None not in lv:
            out["interval_level"] = float(lv.pop())  # type: ignore[arg-type]
    pits = [r.pit for r in rows if r.pit is not None]
    if pits:
        u = np.array(pits)
        for lv in levels:
            out[f"coverage@{lv:g}"] = float(np.mean(np.abs(u - 0.5) <= lv / 2))
        out["nll"] = _mean(r.nll for r in rows)[0]  # type: ignore[assignment]
        out["crps"] = _mean(r.crps for r in rows)[0]  # type: ignore[assignment]
        out["n_calibration"] = len(pits)
    cs, _ = _mean(r.crps_samples for r in rows)
    if cs is not None:
        out["crps_samples"] = cs
    correct = [r.correct for r in rows if r.correct is not None]
    if correct:
        out["material_accuracy"] = float(np.mean(correct))
        out["n_material"] = len(correct)
    return out


def score(measurements: Sequence[Measurement], predictions: Sequence[Prediction],
          config: ScoreConfig = ScoreConfig(), protocol: dict[str, Any] | None = None) -> EvalResult:
    """Score every method found in ``predictions`` against ``measurements``."""
    gt: dict[tuple[str, str], Measurement] = {}
    for m in measurements:
        key = (m.item, m.prop)
        if key in gt:
            raise ValueError(f"ground truth has two entries for item {m.item!r}, property {m.prop!r}: "
                             f"{gt[key].source or '?'} and {m.source or '?'}. Keep one measurement per item and property.")
        gt[key] = m
    by_method: dict[str, dict[tuple[str, str], Prediction]] = {}
    for p in predictions:
        table = by_method.setdefault(p.method, {})
        key = (p.item, p.prop)
        if key in table:
            raise ValueError(f"method {p.method!r} has two predictions for item {p.item!r}, property {p.prop!r}: "
                             f"{table[key].source or '?'} and {p.source or '?'}. Keep one prediction per item and property.")
        table[key] = p
    norm = label_normalizer(config.material_env) if any(m.label for m in measurements) else (lambda s: s)
    items: list[ItemScore] = []
    missing: list[Missing] = []
    unmatched: list[Missing] = []
    for method, table in by_method.items():
        for key, m in gt.items():
            p = table.get(key)
            if p is None:
                missing.append(Missing(method, m.item, m.prop, "no prediction"))
            elif m.value is not None and (p.mean is None or not p.is_finite()):
                missing.append(Missing(method, m.item, m.prop, f"prediction is not a finite number ({p.notes and p.notes[-1] or p.source})"))
            else:
                if m.unit and p.unit and m.unit != p.unit:
                    raise ValueError(f"units differ for item {m.item!r}, property {m.prop!r}: ground truth "
                                     f"{m.unit!r} ({m.source or '?'}) vs prediction {p.unit!r} ({p.source or '?'}). "
                                     "Write both in the same unit (known properties are converted automatically).")
                items.append(_score_row(m, p, norm))
        for key, p in table.items():
            if key not in gt:
                unmatched.append(Missing(method, p.item, p.prop, "no ground truth for this item/property"))
    aggregates: list[Aggregate] = []
    expected: dict[tuple[str, str], int] = defaultdict(int)
    for m in gt.values():
        expected[(m.prop, "all")] += 1
        if m.group is not None and m.group != "all":
            expected[(m.prop, m.group)] += 1
    for method in by_method:
        rows_of: dict[tuple[str, str], list[ItemScore]] = defaultdict(list)
        for r in items:
            if r.method == method:
                rows_of[(r.prop, "all")].append(r)
                if r.group is not None and r.group != "all":
                    rows_of[(r.prop, r.group)].append(r)
        for (prop, group), n_exp in expected.items():
            rows = rows_of.get((prop, group), [])
            aggregates.append(Aggregate(method, prop, group, n_exp, len(rows), n_exp - len(rows),
                                        _aggregate(rows, config.levels)))
    return EvalResult(items, aggregates, missing, unmatched, dict(protocol or {}))
