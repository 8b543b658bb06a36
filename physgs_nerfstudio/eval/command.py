"""`physgs eval`: score predictions against a benchmark's ground truth; print and save the tables.

Examples::

    # ABO-500 test split: our exports (results/<scene>/report.json) against NeRF2Physics' ranges
    physgs eval --dataset abo500 --ground-truth data/abo_500 \
        --predictions physgs=results/ nerf2physics=preds/preds_mass.json

    # friction / Shore hardness points, sampled from each scene's exported voxel grid
    physgs eval --dataset points --ground-truth points.json --predictions results/

    # terrain classes (Ewen et al. 2022), per-image predictions in a CSV
    physgs eval --dataset terrain --ground-truth terrain_images/ --predictions preds.csv

    # generated scenes (physgs synth --suite) against their exports: mass accuracy and interval coverage
    physgs eval --dataset synth --ground-truth scenes/ --predictions results/

    # your own measurements (see physgs_nerfstudio/eval/adapters/table.py for the columns)
    physgs eval --dataset table --ground-truth truth.csv --predictions preds.csv
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from .errors import EvalInputError, input_error
from .records import Measurement, Prediction

__all__ = ["EvalCommand", "parse_prediction_spec", "reject_nonpositive_masses", "run_eval"]


def parse_prediction_spec(spec: str) -> tuple[str | None, Path]:
    """``NAME=PATH`` -> (NAME, PATH); a bare PATH -> (None, PATH). A path that exists is never split."""
    if "=" in spec and not Path(spec).exists():
        name, _, path = spec.partition("=")
        if name.strip() and path.strip():
            return name.strip(), Path(path.strip())
    return None, Path(spec)


@dataclass
class EvalCommand:
    """Score predictions against ground truth: ADE/ALDE/APE/MnRE, material accuracy, interval coverage, NLL, CRPS."""

    ground_truth: Path
    """The ground truth: a folder or a file, laid out as --dataset says."""
    predictions: tuple[str, ...]
    """One or more [NAME=]PATH, each an export results folder, a report.json or a prediction JSON/CSV file."""
    dataset: Literal["abo500", "points", "terrain", "table", "synth"] = "table"
    """Layout of --ground-truth: abo500, points (friction/hardness points), terrain, table (your CSV/JSON) or synth."""
    split: Literal["train", "val", "test", "train+val", "all"] = "test"
    """abo500: which split of splits.json to score."""
    clamp: tuple[float, float] | None = None
    """abo500: clamp every point estimate to MIN MAX kg before scoring (None: unclamped, as NeRF2Physics scores)."""
    interpolation: Literal["trilinear", "nearest"] = "trilinear"
    """points: voxel grid sampling (bilinear / nearest for pixel maps)."""
    field: Literal["voxel", "ply"] = "voxel"
    """points: which exported field to sample when a scene has both."""
    points_frame: Literal["scene", "metres", "world"] = "scene"
    """points: frame of the annotations' xyz: the export's scene units, metres, or the dataset's world frame."""
    max_distance: float | None = None
    """points: with a PLY field, queries farther than this from every Gaussian count as missing."""
    n2p_hardness: Literal["a_d100", "a_eq", "A", "D"] = "a_d100"
    """points: encoding of hardness in NeRF2Physics prediction files (a_d100: Shore A as is, Shore D + 100)."""
    terrain_table: Path | None = None
    """terrain: CSV class,mu,sigma replacing the built-in Ewen et al. (2022) class table."""
    levels: tuple[float, ...] = (0.5, 0.9)
    """Nominal central-interval levels for the PIT coverage of predictive distributions."""
    material_env: str = "indoor"
    """Material library whose aliases are used when comparing material names."""
    output_dir: Path = Path("eval_results")
    """Where eval.json, items.csv, summary.csv (and missing.csv) are written."""
    per_group: bool = False
    """Also print per-group rows (terrain classes, objects, ...); the files always have them."""
    strict: bool = False
    """Exit with an error when any ground-truth item has no usable prediction."""

    def main(self) -> None:
        from rich.console import Console

        console = Console()
        try:
            result = run_eval(self)
        except EvalInputError:
            raise  # a PhysGSError: `physgs eval: error: ...`, exit status 1 (cli.one_line_errors)
        except ValueError as err:
            raise EvalInputError(None, None, str(err)) from None
        from .output import print_result, write_result

        print_result(result, per_group=self.per_group or self.dataset == "terrain", console=console)
        paths = write_result(result, self.output_dir)
        console.print("wrote " + ", ".join(str(p) for p in paths.values()))
        if self.strict and result.missing:
            raise EvalInputError(None, None, f"--strict: {len(result.missing)} ground-truth entries were not scored",
                                 "see missing.csv for which, and why")  # fmt: skip


# ------------------------------------------------------------------------------------------ loading
def _load_generic(path: Path, name: str | None) -> list[Prediction]:
    """Report folder / report.json / prediction table, for datasets keyed by item names."""
    from .adapters.report import is_mass_report, read_mass_report, read_results_dir
    from .adapters.table import read_prediction_table
    from .fileio import load_json

    if path.is_dir():
        return read_results_dir(path, method=name or "physgs")
    if path.suffix.lower() == ".json":
        data = load_json(path)
        if is_mass_report(data):
            return [read_mass_report(path, method=name or "physgs")]
    if path.suffix.lower() in (".json", ".csv"):
        return read_prediction_table(path, method=name or path.stem)
    raise input_error(path, None, "unsupported prediction file", "Pass a results folder, a report.json, or a .csv/.json table")


def _abo(cfg: EvalCommand) -> tuple[list[Measurement], list[Prediction], dict]:
    from .adapters import abo500
    from .fileio import load_json

    ds = abo500.load_abo500(cfg.ground_truth, cfg.split)
    preds: list[Prediction] = []
    for spec in cfg.predictions:
        name, path = parse_prediction_spec(spec)
        if path.suffix.lower() == ".json" and path.is_file() and abo500.is_interval_mapping(load_json(path)):
            preds += abo500.read_n2p_mass_predictions(path, method=name or "nerf2physics")
        else:
            preds += _load_generic(path, name)
    preds = abo500.align_to_items(preds, [m.item for m in ds.measurements])
    if cfg.clamp is not None:
        preds = abo500.clamp_point_estimates(preds, *cfg.clamp)
    protocol = {"dataset": "abo500", "root": str(ds.root), "split": cfg.split, "clamp_kg": cfg.clamp,
                "split_entries_without_ground_truth": ds.no_ground_truth}
    return ds.measurements, preds, protocol


def _points(cfg: EvalCommand) -> tuple[list[Measurement], list[Prediction], dict]:
    from .adapters import points
    from .adapters.table import read_prediction_table
    from .fileio import load_json

    ds = points.read_point_annotations(cfg.ground_truth)
    preds: list[Prediction] = []
    for spec in cfg.predictions:
        name, path = parse_prediction_spec(spec)
        if path.is_dir():
            preds += points.sample_export_predictions(ds, path, method=name or "physgs", prefer=cfg.field,
                                                      interpolation=cfg.interpolation, max_distance=cfg.max_distance,
                                                      frame=cfg.points_frame)
        elif path.suffix.lower() == ".json" and path.is_file() and _is_nested_mapping(load_json(path)):
            preds += points.read_n2p_point_predictions(path, ds, method=name or "nerf2physics",
                                                       hardness_encoding=cfg.n2p_hardness)
        else:
            preds += read_prediction_table(path, method=name or path.stem)
    protocol = {"dataset": "points", "annotations": str(cfg.ground_truth), "interpolation": cfg.interpolation,
                "field": cfg.field, "points_frame": cfg.points_frame, "n2p_hardness": cfg.n2p_hardness,
                "hardness": "compared in each reading's Shore scale"}
    return ds.measurements, preds, protocol


def _is_nested_mapping(data: object) -> bool:
    return isinstance(data, dict) and bool(data) and all(isinstance(v, dict) for v in data.values()) \
        and "predictions" not in data


def _terrain(cfg: EvalCommand) -> tuple[list[Measurement], list[Prediction], dict]:
    from .adapters import terrain

    table = terrain.load_class_table(cfg.terrain_table)
    truth = terrain.read_terrain_truth(cfg.ground_truth, table)
    preds: list[Prediction] = []
    for spec in cfg.predictions:
        name, path = parse_prediction_spec(spec)
        preds += _load_generic(path, name)
    images = {m.item for m in truth}
    classes = set(table)
    per_class = bool(preds) and all(p.item not in images and terrain.normalize_class(p.item) in classes for p in preds)
    if per_class:
        from dataclasses import replace

        truth = terrain.class_truth(table)
        preds = [replace(p, item=terrain.normalize_class(p.item)) for p in preds]
    else:
        preds = terrain.align_terrain_predictions(preds, [m.item for m in truth])
    protocol = {"dataset": "terrain", "labels": str(cfg.ground_truth), "unit": "per class" if per_class else "per image",
                "class_table": {c: {"mu": mu, "sigma": sd} for c, (mu, sd) in table.items()},
                "class_table_source": str(cfg.terrain_table) if cfg.terrain_table else "Ewen et al. 2022 (PhysGS supp. B.2)"}
    return truth, preds, protocol


def _table(cfg: EvalCommand) -> tuple[list[Measurement], list[Prediction], dict]:
    from .adapters.table import read_truth_table

    truth = read_truth_table(cfg.ground_truth)
    preds: list[Prediction] = []
    for spec in cfg.predictions:
        name, path = parse_prediction_spec(spec)
        preds += _load_generic(path, name)
    return truth, preds, {"dataset": "table", "ground_truth": str(cfg.ground_truth)}


def _synth(cfg: EvalCommand) -> tuple[list[Measurement], list[Prediction], dict]:
    from .adapters.synth import read_synth_truth

    truth = read_synth_truth(cfg.ground_truth)
    preds: list[Prediction] = []
    for spec in cfg.predictions:
        name, path = parse_prediction_spec(spec)
        preds += _load_generic(path, name)
    return truth, preds, {"dataset": "synth", "ground_truth": str(cfg.ground_truth)}


_LOADERS = {"abo500": _abo, "points": _points, "terrain": _terrain, "table": _table, "synth": _synth}


def reject_nonpositive_masses(truth: Sequence[Measurement], preds: Sequence[Prediction]) -> None:
    """A mass of zero or less (ground truth or point estimate) cannot be scored (ALDE, APE, MnRE divide by it or
    take its log): :class:`EvalInputError` naming the entry."""
    for rec, value, what in [(m, m.value, "ground-truth") for m in truth] + [(p, p.mean, "predicted") for p in preds]:
        if rec.prop == "mass" and value is not None and not value > 0:
            raise input_error(rec.source or None, None if rec.source else f"item {rec.item!r}",
                              f"{what} mass of item {rec.item!r} is {value:g} kg; a mass must be > 0",
                              "Fix or remove that entry (a failed prediction is left out, not written as 0)")


def run_eval(cfg: EvalCommand):
    """Load, score and return the :class:`~.scorer.EvalResult` (no printing, no files)."""
    from .scorer import ScoreConfig, score

    if not cfg.predictions:
        raise ValueError("no --predictions given; pass at least one [NAME=]PATH.")
    truth, preds, protocol = _LOADERS[cfg.dataset](cfg)
    reject_nonpositive_masses(truth, preds)
    protocol["predictions"] = list(cfg.predictions)
    return score(truth, preds, ScoreConfig(levels=tuple(cfg.levels), material_env=cfg.material_env), protocol)


def eval_main(argv: Sequence[str] | None = None) -> None:  # pragma: no cover - convenience for `python -m`
    import tyro

    from ..cli import one_line_errors

    with one_line_errors("physgs eval"):
        tyro.cli(EvalCommand, args=argv).main()


if __name__ == "__main__":  # pragma: no cover
    eval_main()
