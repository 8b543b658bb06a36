"""ABO-500 as NeRF2Physics distributes it, and NeRF2Physics' own mass predictions.

Layout (``--ground-truth`` is the ``abo_500`` folder, or a folder containing ``abo_500/``)::

    abo_500/
      filtered_product_weights.json   {"<item_id>": <mass in kg>, ...}
      splits.json                     {"train": [...], "val": [...], "test": [...]}  (scene names or item ids)
      scenes/<item_id>_<suffix>/      one folder per scene (``abo_500/<scene>/`` is accepted too)

A scene's item id is its name up to the first ``_`` (``B075YQXRBS_ATVPDKIKX0DER`` -> ``B075YQXRBS``), as in
NeRF2Physics' evaluation. Evaluation units are scenes when the split or the folders name them, else item
ids; predictions keyed by a scene name or by an item id both match.

NeRF2Physics predictions (``preds/preds_mass.json``): ``{"<scene>": [low, high], ...}`` in kg; the point
estimate is the midpoint; the pair is kept as an interval of unknown nominal level (coverage is reported,
not NLL/CRPS). Point estimates are scored as predicted: NeRF2Physics' ``evaluation.py`` declares
``--clamp_min/--clamp_max`` (0.01, 100 kg) but never applies them. :func:`clamp_point_estimates` is there for
``physgs eval --clamp MIN MAX``.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

from ..errors import input_error
from ..fileio import load_json, to_float
from ..records import Measurement, Prediction

__all__ = [
    "SPLITS_FILE",
    "SPLIT_CHOICES",
    "WEIGHTS_FILE",
    "AboDataset",
    "align_to_items",
    "clamp_point_estimates",
    "find_abo_root",
    "is_interval_mapping",
    "item_id_of",
    "list_scenes",
    "load_abo500",
    "load_splits",
    "load_weights",
    "read_n2p_mass_predictions",
]

WEIGHTS_FILE = "filtered_product_weights.json"
SPLITS_FILE = "splits.json"
SPLIT_CHOICES = ("train", "val", "test", "train+val", "all")
_SCENE_RE = re.compile(r"^[^_\s]+_\S+$")


def item_id_of(name: str) -> str:
    """Item id of a scene name (text before the first underscore); an item id is its own item id."""
    return name.split("_", 1)[0]


def find_abo_root(path: Path) -> Path:
    path = Path(path)
    for cand in (path, path / "abo_500", path / "data" / "abo_500"):
        if (cand / WEIGHTS_FILE).is_file():
            return cand
    raise input_error(path, None, f"no {WEIGHTS_FILE} here nor in abo_500/ under it",
                      "Pass the unzipped ABO-500 folder (NeRF2Physics' data/abo_500) as --ground-truth")


def load_weights(root: Path) -> dict[str, float]:
    path = Path(root) / WEIGHTS_FILE
    data = load_json(path)
    if not isinstance(data, dict):
        raise input_error(path, None, f"expected a JSON object mapping item id -> kg, got {type(data).__name__}",
                          "Use NeRF2Physics' filtered_product_weights.json")
    return {str(k).strip(): to_float(v, path, f"item {k!r}", "weight (kg)", positive=True) for k, v in data.items()}


def load_splits(root: Path) -> dict[str, list[str]] | None:
    path = Path(root) / SPLITS_FILE
    if not path.is_file():
        return None
    data = load_json(path)
    if not isinstance(data, dict):
        raise input_error(path, None, "expected a JSON object {\"train\": [...], \"val\": [...], \"test\": [...]}",
                          "Use NeRF2Physics' splits.json")
    out: dict[str, list[str]] = {}
    for name, entries in data.items():
        if not isinstance(entries, list):
            raise input_error(path, f"split {name!r}", f"expected a list of scene names or item ids, got {type(entries).__name__}",
                              "Write each split as a JSON list")
        for i, e in enumerate(entries):
            if not isinstance(e, str) or not e.strip():
                raise input_error(path, f"split {name!r}[{i}]", f"expected a scene name or item id, got {e!r}",
                                  "Write entries as strings")
        out[name] = [e.strip() for e in entries]
    return out


def list_scenes(root: Path, weights: dict[str, float]) -> list[str]:
    """Scene folders under ``root/scenes`` (all of them) or ``root`` (those named ``<known item>_<suffix>``)."""
    root = Path(root)
    if (root / "scenes").is_dir():
        return sorted(p.name for p in (root / "scenes").iterdir() if p.is_dir())
    return sorted(p.name for p in root.iterdir()
                  if p.is_dir() and _SCENE_RE.match(p.name) and item_id_of(p.name) in weights)


@dataclass
class AboDataset:
    root: Path
    split: str
    measurements: list[Measurement]
    no_ground_truth: list[str] = field(default_factory=list)   # scenes/items of the split without a weight


def load_abo500(path: Path, split: str = "test") -> AboDataset:
    """Ground-truth masses of one split (``train``, ``val``, ``test``, ``train+val``, ``all``)."""
    root = find_abo_root(path)
    weights = load_weights(root)
    if split not in SPLIT_CHOICES:
        raise input_error(root, None, f"unknown split {split!r}", f"Choose one of {', '.join(SPLIT_CHOICES)}")
    if split == "all":
        names = list_scenes(root, weights) or sorted(weights)
    else:
        splits = load_splits(root)
        if splits is None:
            raise input_error(root / SPLITS_FILE, None, "file not found, but a split was asked for",
                              "Put NeRF2Physics' splits.json next to the weights, or use --split all")
        wanted = split.split("+")
        missing_splits = [s for s in wanted if s not in splits]
        if missing_splits:
            raise input_error(root / SPLITS_FILE, None, f"no split named {', '.join(missing_splits)} "
                              f"(present: {', '.join(splits)})", "Choose a split the file has")
        names = [n for s in wanted for n in splits[s]]
    seen: set[str] = set()
    measurements: list[Measurement] = []
    no_gt: list[str] = []
    source = str(root / WEIGHTS_FILE)
    for name in names:
        if name in seen:
            continue
        seen.add(name)
        item = item_id_of(name)
        if item not in weights:
            no_gt.append(name)
            continue
        measurements.append(Measurement(item=name, prop="mass", value=weights[item], unit="kg",
                                        group=split, source=f"{source}[{item!r}]"))
    return AboDataset(root=root, split=split, measurements=measurements, no_ground_truth=no_gt)


def is_interval_mapping(data: object) -> bool:
    """True for NeRF2Physics' ``{"<scene>": [low, high]}`` prediction files."""
    return (isinstance(data, dict) and bool(data)
            and all(isinstance(v, list) and len(v) == 2 for v in data.values()))


def read_n2p_mass_predictions(path: Path, method: str = "nerf2physics") -> list[Prediction]:
    """NeRF2Physics' ``{"<scene or item>": [low, high]}`` mass predictions (kg), midpoint = point estimate."""
    path = Path(path)
    data = load_json(path)
    if not isinstance(data, dict) or not data:
        raise input_error(path, None, "expected a non-empty JSON object {\"<scene>\": [low, high], ...}",
                          "Pass NeRF2Physics' preds_mass.json")
    preds = []
    for key, pair in data.items():
        where = f"entry {key!r}"
        if not isinstance(pair, (list, tuple)) or len(pair) != 2:
            raise input_error(path, where, f"expected [low, high] in kg, got {pair!r}",
                              "Write each prediction as a two-number list")
        low = to_float(pair[0], path, f"{where}[0]", "low")
        high = to_float(pair[1], path, f"{where}[1]", "high")
        if low > high:
            raise input_error(path, where, f"low {low:g} > high {high:g}", "Swap or fix the bounds")
        preds.append(Prediction(item=str(key).strip(), prop="mass", mean=0.5 * (low + high), method=method,
                                low=low, high=high, level=None, unit="kg", source=f"{path}[{key!r}]"))
    return preds


def clamp_point_estimates(preds: Sequence[Prediction], lo: float = 0.01, hi: float = 100.0) -> list[Prediction]:
    """Clamp every point estimate to ``[lo, hi]`` (``--clamp``; off by default); intervals are left as predicted."""
    if not 0 < lo < hi:
        raise ValueError(f"clamp bounds must satisfy 0 < lo < hi, got ({lo}, {hi}).")
    out = []
    for p in preds:
        if p.mean is None or lo <= p.mean <= hi:
            out.append(p)
            continue
        clamped = min(max(p.mean, lo), hi)
        out.append(replace(p, mean=clamped, notes=p.notes + (f"point estimate {p.mean:g} clamped to {clamped:g}",)))
    return out


def align_to_items(preds: Sequence[Prediction], items: Sequence[str]) -> list[Prediction]:
    """Rename predictions keyed by scene name <-> item id so they meet the ground truth's keys.

    Exact key first; else the prediction's item id equals an item key; else a ground-truth scene whose item
    id is the prediction's key (only when exactly one scene has it). A prediction for another scene of the
    same item is not matched. Anything else is left as it is (the
    scorer reports it as a prediction without ground truth).
    """
    keys = set(items)
    by_item: dict[str, list[str]] = {}
    for k in items:
        by_item.setdefault(item_id_of(k), []).append(k)
    out = []
    for p in preds:
        if p.item in keys:
            out.append(p)
        elif item_id_of(p.item) in keys:
            out.append(replace(p, item=item_id_of(p.item)))
        elif len(by_item.get(p.item, [])) == 1:
            out.append(replace(p, item=by_item[p.item][0]))
        else:
            out.append(p)
    return out
