"""Mass / property accuracy on generated scenes with exact truth: the paper's ablation (w/o BI vs with BI).

For every object of the generated suite (``physgs_nerfstudio.synth.SUITE``) this script

1. renders the scene (cached under ``--work-dir``), property values drawn per material around the library
   typical value (``--jitter``; the truth then differs from the NIG prior mean, so the prior is no oracle);
2. runs perception over all views with the SIMULATED VLM (its noise/confusion model and parameters are
   printed), through ``run_perception`` (cache + observations.jsonl, so reruns are free);
3. estimates the object's mass with three estimators, all using the ground-truth part volumes
   (``volume_m3`` of ground_truth.json: the material volume, shell walls at their true thickness), so
   the comparison isolates property inference from geometry:

   (a) single view, no Bayesian inference: per part, the first view (from a start view, cyclically) in
       which a mask covers the part; the mask best matching the part (IoU with the part's visible pixels);
       its top candidate's material and reported density. Repeated for every start view; metrics are
       averaged over the start views (and their spread reported);
   (b) plain multi-view averaging, no NIG / Dirichlet: per part the majority top-candidate material of the
       masks dominated by the part (ties: summed confidence); per material the confidence-weighted plain
       mean of all reported values in the scene (paper A.3, linear units);
   (c) full PhysGS: per part a Dirichlet over materials from every mask overlapping it (evidence weight =
       level weight x overlap fraction |mask & part| / |mask| x confidence; alpha0, lambda and level
       weights of ``MapFusionConfig``); per material NIG posteriors from the library priors (density in
       log space; ``fuse_properties``); part density = mixture mean (``property_fields``, default material
       weights: the posterior probability that the material is the part's DOMINANT label,
       ``bayes.dominance_probability``); mass = sum.
       90% interval by Monte Carlo: per sample one material per part (from the same weights) and one
       density per material, shared by all parts of that material. Default density draw: the posterior
       of the material's MEAN density (NIG marginal of mu: Student-t, 2a dof, loc tau, scale^2 =
       b / (a kappa), in log space): the object's density is a fixed unknown, while the NIG's aleatoric
       spread describes the scatter of the VLM's reported values around it. The full predictive (a new
       reported value: scale^2 = b (kappa + 1) / (a kappa)) is reported as a second coverage column.
   (c-pred) the same with the paper's mixture weights taken literally: the Dirichlet posterior predictive
       alpha / sum(alpha). It converges to the average confidence split of the answers, not to the part's
       material, so confusable materials' densities stay blended in however much evidence arrives.
   (c') variant: the argmax material per part only (no mixture).

Masks: ``--segmenter oracle`` (default) cuts masks from the ground-truth part maps (whole = object
silhouette, spanning several materials; part = each visible part; subpart = halves of larger parts) so the
benchmark measures fusion, not segmentation; ``--segmenter builtin`` uses the weight-free segmenter.

``--active`` adds a second section, active querying vs asking every mask of every view, on the same scenes and
exhaustive perception (the ``active_querying`` key of accuracy.json and a second part of the printed table). The
simulated VLM answers a (view, mask) request deterministically (seeded by the request), so a query order can be
replayed from the exhaustive observations: every policy sees exactly the answers a live run would get (checked
once per run against a live ``run_active_perception`` on a copy of the first object, from the response cache).
Policies (one query = one mask of one view):

* ``active``: ``physgs_nerfstudio.perception.active.ActiveSelector`` (default ``ActiveConfig``);
* ``active (no transfer)``: the same without the cross-view appearance transfer (within-view Dirichlet
  entropy, NIG epistemic and exploration only);
* ``dataset order``: every mask of view 0, then view 1, ... (what a capped exhaustive run does);
* ``random``: uniformly random order (mean over ``--random-repeats`` seeds).

After every ``--step`` queries the object's mass is estimated with (c) (and (c')) from the answers so far
(``--active-samples`` draws, only the mean is used). Reported per object and in aggregate: the queries needed
until the mass APE is within 5% of the exhaustive estimator's APE (absolute: APE <= APE_all + 0.05; relative:
APE <= 1.05 APE_all), and the APE at 25% of the queries.

Run:  OMP_NUM_THREADS=1 python benchmarks/accuracy.py [--quick] [--active] [--work-dir DIR] [--results-dir DIR]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import shutil
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from physgs_nerfstudio.bayes import (
    dirichlet_posterior,
    evidence_from_observations,
    material_mixture_weights,
    property_fields,
)
from physgs_nerfstudio.eval.metrics import crps_samples, interval_coverage, point_metrics
from physgs_nerfstudio.fusion.maps import MapFusionConfig
from physgs_nerfstudio.fusion.properties import fuse_properties, legend_names
from physgs_nerfstudio.materials import PROPERTY_KEYS, MaterialLibrary, PriorConfig, load_library

DENSITY = PROPERTY_KEYS.index("density")
EXTRA_PROPS = ("kinetic_friction", "shore_hardness")


# =========================================================================================================
# data model shared by the estimators (hand-made in the unit test, read from a scene in the benchmark)
# =========================================================================================================


@dataclass
class PartTruth:
    id: int
    name: str
    material: str
    volume_m3: float
    mass_kg: float
    properties: dict[str, float]


@dataclass
class MaskInfo:
    view: str
    mask_id: int
    level: str
    area: int
    overlap: dict[int, int]
    """part id -> pixels of the mask on that (object) part."""


@dataclass
class SceneData:
    name: str
    parts: list[PartTruth]
    views: list[str]
    """Views in dataset order."""
    masks: dict[tuple[str, int], MaskInfo]
    observations: list[dict]
    """observations.jsonl records."""
    visible: dict[tuple[str, int], int] = field(default_factory=dict)
    """(view, part id) -> visible pixels of the part in that view (for the single-view mask choice)."""

    @property
    def mass_kg(self) -> float:
        return float(sum(p.mass_kg for p in self.parts))

    def by_mask(self) -> dict[tuple[str, int], list[dict]]:
        out: dict[tuple[str, int], list[dict]] = {}
        for o in self.observations:
            out.setdefault((str(o["view"]), int(o["mask_id"])), []).append(o)
        return out


@dataclass
class Estimate:
    """Per part material / property estimates and the object mass."""

    mass_kg: float
    part_material: list[str | None]
    part_props: dict[str, list[float]]
    """property key -> per part value (linear units; NaN when unknown)."""
    interval: tuple[float, float] | None = None
    samples: np.ndarray | None = None
    fallbacks: int = 0
    """Parts without any usable observation (library-wide typical values used)."""


def _prop(o: dict, key: str) -> float:
    v = (o.get("properties") or {}).get(key)
    try:
        v = float(v)
    except (TypeError, ValueError):
        return math.nan
    return v if math.isfinite(v) else math.nan


def _library_fallback(library: MaterialLibrary) -> dict[str, float]:
    """Library-wide median typical value per property (used only for parts never observed)."""
    return {k: float(np.median([m.properties[k].typical for m in library.materials])) for k in PROPERTY_KEYS}


def _top(records: Sequence[dict]) -> dict | None:
    good = [r for r in records if _finite_pos(r.get("confidence"))]
    return max(good, key=lambda r: float(r["confidence"])) if good else None


def _finite_pos(v) -> bool:
    try:
        return math.isfinite(float(v)) and float(v) > 0
    except (TypeError, ValueError):
        return False


# =========================================================================================================
# (a) single view
# =========================================================================================================


def estimate_single_view(scene: SceneData, library: MaterialLibrary, start: int = 0) -> Estimate:
    """Per part: the first view at or after ``start`` (cyclically) with an answered mask on the part; the mask
    with the best IoU with the part's visible pixels; its top candidate's material and reported values."""
    by_mask = scene.by_mask()
    fb = _library_fallback(library)
    V = len(scene.views)
    mats: list[str | None] = []
    props: dict[str, list[float]] = {k: [] for k in PROPERTY_KEYS}
    fallbacks = 0
    for part in scene.parts:
        chosen = None
        for j in range(V):
            view = scene.views[(start + j) % V]
            best, best_iou = None, 0.0
            for (v, mid), info in scene.masks.items():
                if v != view:
                    continue
                inter = info.overlap.get(part.id, 0)
                if inter <= 0 or _top(by_mask.get((v, mid), [])) is None:
                    continue
                vis = scene.visible.get((view, part.id), inter)
                iou = inter / max(1, info.area + vis - inter)
                if iou > best_iou:
                    best, best_iou = (v, mid), iou
            if best is not None:
                chosen = _top(by_mask[best])
                break
        if chosen is None:
            fallbacks += 1
            mats.append(None)
            for k in PROPERTY_KEYS:
                props[k].append(fb[k])
            continue
        mats.append(chosen["material"])
        typical = library[chosen["material"]].properties
        for k in PROPERTY_KEYS:
            v = _prop(chosen, k)
            props[k].append(v if math.isfinite(v) else typical[k].typical)
    mass = float(sum(p.volume_m3 * d for p, d in zip(scene.parts, props["density"])))
    return Estimate(mass, mats, props, fallbacks=fallbacks)


# =========================================================================================================
# (b) plain multi-view averaging (no NIG, no Dirichlet)
# =========================================================================================================


def estimate_average(scene: SceneData, library: MaterialLibrary) -> Estimate:
    """Majority top-candidate material per part over the masks dominated by the part; per material the
    confidence-weighted plain mean of every reported value in the scene (paper A.3, linear units)."""
    by_mask = scene.by_mask()
    fb = _library_fallback(library)
    votes: dict[int, dict[str, list[float]]] = {p.id: {} for p in scene.parts}
    for key, info in scene.masks.items():
        if not info.overlap:
            continue
        dom = max(info.overlap, key=lambda pid: info.overlap[pid])
        if dom not in votes:
            continue
        top = _top(by_mask.get(key, []))
        if top is None:
            continue
        v = votes[dom].setdefault(top["material"], [0.0, 0.0])
        v[0] += 1
        v[1] += float(top["confidence"])
    # plain weighted means per material
    sums: dict[str, dict[str, list[float]]] = {}
    for o in scene.observations:
        if not _finite_pos(o.get("confidence")):
            continue
        acc = sums.setdefault(o["material"], {k: [0.0, 0.0] for k in PROPERTY_KEYS})
        p = min(1.0, float(o["confidence"]))
        for k in PROPERTY_KEYS:
            x = _prop(o, k)
            if math.isfinite(x):
                acc[k][0] += p
                acc[k][1] += p * x
    mats: list[str | None] = []
    props: dict[str, list[float]] = {k: [] for k in PROPERTY_KEYS}
    fallbacks = 0
    for part in scene.parts:
        v = votes[part.id]
        if not v:
            fallbacks += 1
            mats.append(None)
            for k in PROPERTY_KEYS:
                props[k].append(fb[k])
            continue
        mat = max(sorted(v), key=lambda n: (v[n][0], v[n][1]))
        mats.append(mat)
        for k in PROPERTY_KEYS:
            w, s = sums.get(mat, {}).get(k, (0.0, 0.0))
            props[k].append(s / w if w > 0 else library[mat].properties[k].typical)
    mass = float(sum(p.volume_m3 * d for p, d in zip(scene.parts, props["density"])))
    return Estimate(mass, mats, props, fallbacks=fallbacks)


# =========================================================================================================
# (c) full PhysGS
# =========================================================================================================


@dataclass
class PhysGSConfig:
    fusion: MapFusionConfig = field(default_factory=MapFusionConfig)
    prior: PriorConfig = field(default_factory=PriorConfig)
    n_samples: int = 4000
    level: float = 0.9
    map_material: bool = False
    """Variant (not the paper's estimator): collapse each part's mixture to its most probable material
    (Dirichlet MAP) and use that material's NIG posterior; isolates the cost of the soft mixture."""
    density_draw: str = "posterior"
    """posterior (default): the posterior of the material's MEAN density (NIG marginal of mu, epistemic only;
    the object's density is one fixed unknown); predictive: the NIG Student-t predictive of a new reported
    value (aleatoric + epistemic)."""
    seed: int = 0
    material_weights: str = "dominant"
    """Per part material weights of the mixture: dominant (P(material is the part's dominant label), the
    product default) or predictive (alpha / sum(alpha), the paper's eq. mixture literally)."""


def part_evidence(scene: SceneData, names: Sequence[str], fusion: MapFusionConfig) -> np.ndarray:
    """[P, K] evidence sum_m w_pm p_m onehot(c_m), w_pm = level weight x |mask & part| / |mask|."""
    index = {n: i for i, n in enumerate(names)}
    pid = {p.id: j for j, p in enumerate(scene.parts)}
    cls, conf, cols = [], [], []
    for o in scene.observations:
        k = index.get(o.get("material"))
        info = scene.masks.get((str(o["view"]), int(o["mask_id"])))
        if k is None or info is None or not _finite_pos(o.get("confidence")):
            continue
        cls.append(k)
        conf.append(min(1.0, float(o["confidence"])))
        col = np.zeros(len(scene.parts))
        lw = fusion.level_weights.get(info.level, 1.0)
        for part_id, px in info.overlap.items():
            if part_id in pid:
                col[pid[part_id]] = lw * px / max(1, info.area)
        cols.append(col)
    if not cls:
        return np.zeros((len(scene.parts), len(names)))
    weights = torch.as_tensor(np.stack(cols, axis=1), dtype=torch.float64)  # [P, M]
    ev = evidence_from_observations(
        torch.as_tensor(cls), torch.as_tensor(conf, dtype=torch.float64), len(names), weights
    )
    return ev.numpy()


def _density_draws(post, k_idx: np.ndarray, n: int, mode: str, rng: np.random.Generator, log_space: bool) -> np.ndarray:
    """[n, K] one density draw per material per sample (shared by all parts of the material)."""
    nig = post.posterior.to(torch.float64)
    df, loc, scale = (t[:, DENSITY].numpy() for t in nig.student_t())
    if mode == "posterior":
        scale = np.sqrt(nig.b[:, DENSITY].numpy() / (nig.a[:, DENSITY].numpy() * nig.kappa[:, DENSITY].numpy()))
    elif mode != "predictive":
        raise ValueError(f"density_draw must be predictive|posterior, got {mode!r}")
    x = loc[None, :] + scale[None, :] * rng.standard_t(df[None, :], size=(n, len(df)))
    return np.exp(np.clip(x, -700, 700)) if log_space else np.clip(x, 0, None)


def estimate_physgs(scene: SceneData, library: MaterialLibrary, cfg: PhysGSConfig | None = None) -> Estimate:
    cfg = cfg or PhysGSConfig()
    names = legend_names(scene.observations, library)
    fb = _library_fallback(library)
    P = len(scene.parts)
    if not names:
        props = {k: [fb[k]] * P for k in PROPERTY_KEYS}
        mass = float(sum(p.volume_m3 * fb["density"] for p in scene.parts))
        return Estimate(mass, [None] * P, props, (mass, mass), fallbacks=P)
    post = fuse_properties(scene.observations, library, names, cfg.prior)
    ev = part_evidence(scene, names, cfg.fusion)
    observed = ev.sum(1) > 0
    alpha = dirichlet_posterior(torch.as_tensor(ev), cfg.fusion.alpha0, cfg.fusion.lam)
    if cfg.map_material:  # one-hot on the argmax material (a point mass, up to a negligible floor); use with
        # material_weights="predictive" (the weights are then exactly the one-hot)
        alpha = torch.where(alpha == alpha.amax(-1, keepdim=True), torch.ones_like(alpha), torch.full_like(alpha, 1e-12))
    fields = property_fields(alpha, post.posterior.to(torch.float64), post.log_space,
                             material_weights=cfg.material_weights)
    mean = fields["mean"].numpy()
    pi = material_mixture_weights(alpha, cfg.material_weights).numpy()
    props: dict[str, list[float]] = {}
    for p_i, k in enumerate(PROPERTY_KEYS):
        props[k] = [float(mean[j, p_i]) if observed[j] else fb[k] for j in range(P)]
    mats = [names[int(np.argmax(pi[j]))] if observed[j] else None for j in range(P)]
    vol = np.array([p.volume_m3 for p in scene.parts])
    mass = float((vol * np.array(props["density"])).sum())
    # Monte Carlo interval
    rng = np.random.default_rng(cfg.seed)
    S = cfg.n_samples
    rho = _density_draws(post, np.arange(len(names)), S, cfg.density_draw, rng, post.log_space[DENSITY])  # [S, K]
    samples = np.zeros(S)
    for j in range(P):
        if not observed[j]:
            samples += vol[j] * fb["density"]
            continue
        c = rng.choice(len(names), size=S, p=pi[j] / pi[j].sum())
        samples += vol[j] * rho[np.arange(S), c]
    lo, hi = np.quantile(samples, [(1 - cfg.level) / 2, (1 + cfg.level) / 2])
    return Estimate(mass, mats, props, (float(lo), float(hi)), samples, fallbacks=int((~observed).sum()))


# =========================================================================================================
# metrics
# =========================================================================================================


def mass_metrics(truth: Sequence[float], pred: Sequence[float]) -> dict[str, float]:
    return {k: float(np.mean(v)) for k, v in point_metrics(np.asarray(truth), np.asarray(pred)).items()}


def part_prop_ape(scenes: Sequence[SceneData], estimates: Sequence[Estimate], key: str) -> float:
    errs = []
    for s, e in zip(scenes, estimates):
        for j, part in enumerate(s.parts):
            t = part.properties.get(key)
            if t is None or not t > 0:
                continue
            errs.append(abs(e.part_props[key][j] - t) / t)
    return float(np.mean(errs)) if errs else math.nan


def part_material_accuracy(scenes: Sequence[SceneData], estimates: Sequence[Estimate]) -> float:
    hits = [e.part_material[j] == p.material for s, e in zip(scenes, estimates) for j, p in enumerate(s.parts)]
    return float(np.mean(hits)) if hits else math.nan


def summarize_method(scenes: Sequence[SceneData], estimates: Sequence[Estimate]) -> dict[str, float]:
    out = mass_metrics([s.mass_kg for s in scenes], [e.mass_kg for e in estimates])
    for k in EXTRA_PROPS:
        out[f"{k}_APE"] = part_prop_ape(scenes, estimates, k)
    out["density_APE"] = part_prop_ape(scenes, estimates, "density")
    out["material_acc"] = part_material_accuracy(scenes, estimates)
    out["fallback_parts"] = float(sum(e.fallbacks for e in estimates))
    if all(e.interval is not None for e in estimates):
        t = np.array([s.mass_kg for s in scenes])
        lo = np.array([e.interval[0] for e in estimates])
        hi = np.array([e.interval[1] for e in estimates])
        out["coverage90"] = float(np.mean(interval_coverage(t, lo, hi)))
        out["rel_width90"] = float(np.mean((hi - lo) / t))
        if all(e.samples is not None for e in estimates):
            out["CRPS_kg"] = float(np.mean([crps_samples(np.array([s.mass_kg]), e.samples[None, :])[0]
                                            for s, e in zip(scenes, estimates)]))
    return out


# =========================================================================================================
# scenes: generation, oracle masks, perception, loading
# =========================================================================================================


class OracleSegmenter:
    """Masks cut from the ground-truth part maps (generated scenes only): whole = the object silhouette (all
    object parts, several materials), part = each visible part, subpart = the two halves of a part's visible
    region along its principal axis (parts of at least ``4 * min_area`` pixels). Views are recognised by the
    hash of their image pixels."""

    def __init__(self, root: Path, min_area: int = 12):
        from PIL import Image

        self.min_area = int(min_area)
        gt = json.loads((Path(root) / "ground_truth.json").read_text())
        self.object_ids = {int(p["id"]) for p in gt["parts"] if p.get("role", "object") == "object"}
        self._parts: dict[str, np.ndarray] = {}
        for fr in gt["frames"]:
            img = np.asarray(Image.open(Path(root) / fr["file_path"]).convert("RGB"), dtype=np.uint8)
            self._parts[_image_hash(img)] = np.asarray(Image.open(Path(root) / fr["part_path"]))

    def fingerprint(self) -> str:
        return f"oracle-gt-parts:v1:min_area={self.min_area}"

    def segment(self, image: np.ndarray):
        from physgs_nerfstudio.perception.segment import Mask

        part = self._parts.get(_image_hash(np.asarray(image, dtype=np.uint8)))
        if part is None:
            raise KeyError("OracleSegmenter: image is not a frame of this generated scene")
        masks = []
        obj = np.isin(part, list(self.object_ids))
        if obj.sum() >= self.min_area:
            masks.append(Mask(obj, int(obj.sum()), 1.0, 1.0, "whole"))
        for pid in sorted(self.object_ids):
            m = part == pid
            area = int(m.sum())
            if area < self.min_area:
                continue
            masks.append(Mask(m, area, 1.0, 1.0, "part"))
            if area >= 4 * self.min_area:
                ys, xs = np.nonzero(m)
                pts = np.stack([xs, ys], 1).astype(float)
                pts -= pts.mean(0)
                axis = np.linalg.svd(pts, full_matrices=False)[2][0]
                proj = pts @ axis
                cut = np.median(proj)
                for half in (proj <= cut, proj > cut):
                    sub = np.zeros_like(m)
                    sub[ys[half], xs[half]] = True
                    if sub.sum() >= self.min_area:
                        masks.append(Mask(sub, int(sub.sum()), 1.0, 1.0, "subpart"))
        return masks


def _image_hash(img: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(img).tobytes()).hexdigest()


@dataclass
class BenchConfig:
    objects: tuple[str, ...]
    views: int = 16
    resolution: int = 96
    jitter: float = 0.2
    seed: int = 0
    segmenter: str = "oracle"
    work_dir: Path = Path("/tmp/physgs_bench")


def scene_dir(cfg: BenchConfig, obj: str) -> Path:
    return Path(cfg.work_dir) / f"{obj}_v{cfg.views}_r{cfg.resolution}_j{cfg.jitter:g}_s{cfg.seed}"


def prepare_scene(cfg: BenchConfig, obj: str) -> Path:
    from physgs_nerfstudio.synth import SynthConfig, generate_scene

    out = scene_dir(cfg, obj)
    if (out / "ground_truth.json").is_file() and (out / "transforms.json").is_file():
        return out
    generate_scene(SynthConfig(out=out, object=obj, views=cfg.views, resolution=cfg.resolution, seed=cfg.seed,
                               property_jitter=cfg.jitter, num_points=2000, background_points=0, overwrite=True))
    return out


def perception_config(root: Path, cfg: BenchConfig, sim=None):
    from physgs_nerfstudio.perception import PerceptionConfig
    from physgs_nerfstudio.perception.segment_builtin import BuiltinSegmenterConfig
    from physgs_nerfstudio.perception.simulated import SimulatedConfig

    return PerceptionConfig(
        data=root, vlm=sim or SimulatedConfig(seed=cfg.seed), segmenter=BuiltinSegmenterConfig(), progress=False,
        write_outputs=False, max_concurrency=1,
    )


def run_scene_perception(root: Path, cfg: BenchConfig, sim=None) -> None:
    from physgs_nerfstudio.perception import run_perception

    pc = perception_config(root, cfg, sim)
    seg = OracleSegmenter(root) if cfg.segmenter == "oracle" else None
    run_perception(pc, segmenter=seg)


def load_scene(root: Path, name: str | None = None) -> SceneData:
    """Ground truth, saved masks (with their part overlaps) and observations of a perceived scene."""
    from PIL import Image

    from physgs_nerfstudio.perception.pipeline import mask_path
    from physgs_nerfstudio.perception.segment import load_masks
    from physgs_nerfstudio.perception.store import read_observations

    root = Path(root)
    gt = json.loads((root / "ground_truth.json").read_text())
    parts = [
        PartTruth(int(p["id"]), p["name"], p["material"], float(p["volume_m3"]), float(p["mass_kg"]),
                  {k: float(v) for k, v in p["properties"].items()})
        for p in gt["parts"] if p.get("role", "object") == "object"
    ]
    ids = np.array([p.id for p in parts])
    masks: dict[tuple[str, int], MaskInfo] = {}
    visible: dict[tuple[str, int], int] = {}
    views = []
    for fr in gt["frames"]:
        view = fr["file_path"]
        views.append(view)
        part_map = np.asarray(Image.open(root / fr["part_path"])).astype(np.int64)
        counts = np.bincount(part_map.reshape(-1), minlength=int(ids.max()) + 1)
        for pid in ids:
            visible[(view, int(pid))] = int(counts[pid])
        ms = load_masks(mask_path(root, view))
        for i, m in enumerate(ms or []):
            seg = m.segmentation
            if seg.shape != part_map.shape:
                import cv2

                seg = cv2.resize(seg.astype(np.uint8), part_map.shape[::-1], interpolation=cv2.INTER_NEAREST).astype(bool)
            c = np.bincount(part_map[seg], minlength=int(ids.max()) + 1)
            masks[(view, i)] = MaskInfo(view, i, m.level, int(seg.sum()), {int(p): int(c[p]) for p in ids if c[p] > 0})
    return SceneData(name or gt.get("object", root.name), parts, views, masks, read_observations(root), visible)


# =========================================================================================================
# the benchmark
# =========================================================================================================


METHODS = ("(a) single view, no BI", "(b) multi-view average, no BI", "(c) PhysGS (Dirichlet + NIG)")
VARIANTS = {
    "physgs": ("(c) PhysGS (Dirichlet + NIG), dominant-material weights (default)", "dominant", False),
    "physgs_predictive_weights": ("(c-pred) PhysGS with predictive weights alpha/sum (the paper's eq. literally)",
                                  "predictive", False),
    "physgs_map_variant": ("(c') variant: PhysGS with the argmax material per part (no mixture)", "predictive", True),
}
"""result key -> (table label, material_weights, map_material)."""


def evaluate_scenes(scenes: Sequence[SceneData], library: MaterialLibrary, pcfg: PhysGSConfig,
                    draws: Sequence[str] = ("posterior", "predictive")) -> dict:
    """Metrics of every estimator; PhysGS variants (``VARIANTS``) once per density draw mode in ``draws``
    (``res[key][draw]``; the first draw is the one of the main table columns)."""
    # (a) over every start view
    V = min(len(s.views) for s in scenes)
    per_start = []
    for start in range(V):
        ests = [estimate_single_view(s, library, start) for s in scenes]
        per_start.append(summarize_method(scenes, ests))
    single = {k: float(np.nanmean([r[k] for r in per_start])) for k in per_start[0]}
    single_spread = {k: [float(np.nanmin([r[k] for r in per_start])), float(np.nanmax([r[k] for r in per_start]))]
                     for k in ("ADE", "ALDE", "APE", "MnRE")}
    avg_est = [estimate_average(s, library) for s in scenes]
    average = summarize_method(scenes, avg_est)
    res: dict = {"single_view": single, "single_view_range_over_start_views": single_spread, "average": average,
                 "start_views": V, "draws": list(draws)}
    per_object = []
    for key, (_, weights, use_map) in VARIANTS.items():
        res[key] = {}
        for draw in draws:
            cfg = replace(pcfg, map_material=use_map, density_draw=draw, material_weights=weights)
            ests = [estimate_physgs(s, library, cfg) for s in scenes]
            res[key][draw] = summarize_method(scenes, ests)
            if key != "physgs":
                if draw == draws[0]:
                    for row, e in zip(per_object, ests):
                        row[f"{key}_kg"] = e.mass_kg
                continue
            if draw == draws[0]:
                for s, e, ea in zip(scenes, ests, avg_est):
                    e_single = [estimate_single_view(s, library, st).mass_kg for st in range(V)]
                    per_object.append({
                        "object": s.name, "truth_kg": s.mass_kg, "single_view_kg_mean": float(np.mean(e_single)),
                        "single_view_APE_mean": float(np.mean([abs(x - s.mass_kg) / s.mass_kg for x in e_single])),
                        "average_kg": ea.mass_kg, "physgs_kg": e.mass_kg,
                        "physgs_interval_kg": list(e.interval or ()),
                        "covered": bool(e.interval[0] <= s.mass_kg <= e.interval[1]),
                        "parts": len(s.parts), "masks": len(s.masks), "observations": len(s.observations),
                    })
            for row, e in zip(per_object, ests):
                row[f"physgs_interval_kg_{draw}"] = list(e.interval or ())
                row[f"covered_{draw}"] = bool(e.interval[0] <= row["truth_kg"] <= e.interval[1])
    res["per_object"] = per_object
    return res


def markdown_table(res: dict, draws: Sequence[str]) -> str:
    d0 = draws[0]
    rows = [
        (METHODS[0] + f" (mean of {res['start_views']} start views)", res["single_view"], None),
        (METHODS[1], res["average"], None),
    ] + [(label, res[key][d0], res[key]) for key, (label, _, _) in VARIANTS.items()]
    cov_heads = " | ".join(f"90% cov. ({'mean-density' if d == 'posterior' else 'full-predictive'} draws)"
                           for d in draws)
    head = (f"| method | ADE (kg) | ALDE | APE | MnRE | {cov_heads} | friction APE | hardness APE | density APE | "
            "material acc. |")
    lines = [head, "|" + "---|" * (9 + len(draws))]
    for name, r, by_draw in rows:
        covs = " | ".join(f"{by_draw[d]['coverage90']:.1%}" if by_draw else "-" for d in draws)
        lines.append(
            f"| {name} | {r['ADE']:.4f} | {r['ALDE']:.3f} | {r['APE']:.3f} | {r['MnRE']:.3f} | {covs} | "
            f"{r['kinetic_friction_APE']:.3f} | {r['shore_hardness_APE']:.3f} | {r['density_APE']:.3f} | "
            f"{r['material_acc']:.3f} |"
        )
    extra = []
    for key, (label, _, _) in VARIANTS.items():
        for d in draws:
            r = res[key][d]
            extra.append(f"- {label.split(' ')[0]} 90% interval, density draws `{d}`: coverage {r['coverage90']:.1%}, "
                         f"mean relative width {r['rel_width90']:.3f}, CRPS {r['CRPS_kg']:.4f} kg")
    sp = res["single_view_range_over_start_views"]
    extra.append("- single view, range over start views: " + ", ".join(f"{k} [{a:.3f}, {b:.3f}]" for k, (a, b) in sp.items()))
    return "\n".join(lines) + "\n\n" + "\n".join(extra) + "\n"


def describe_noise(sim) -> str:
    return (
        "SIMULATED VLM (physgs_nerfstudio.perception.simulated): per (view, mask) the truth is the majority "
        f"ground-truth material under the mask; top candidate = truth with p_correct={sim.p_correct}, else a "
        f"confusable neighbour (or with p_random={sim.p_random} a random library material); 1..{sim.max_candidates} "
        f"candidates, confidences ~ sorted Dirichlet({sim.concentration}); values = true value (truth candidate) or "
        f"library typical (others) x exp(sigma N(0,1)), sigma={dict(sim.sigma)}; answers independent across masks "
        f"(seed {sim.seed})."
    )


# =========================================================================================================
# --active: active querying vs asking every mask (replayed from the exhaustive observations)
# =========================================================================================================

ACTIVE_ESTIMATORS = {"c": False, "c_map": True}
"""estimator key -> map_material: (c) PhysGS mixture mean, (c') its MAP-material variant"""
POLICIES = ("active", "active (no transfer)", "dataset order", "random")


@dataclass
class ActiveBench:
    """The settings of the --active section."""

    step: int = 4
    """evaluate the mass after every ``step`` queries"""
    random_repeats: int = 5
    """random orders per object (their mean is reported)"""
    samples: int = 64
    """Monte Carlo draws per estimate (only the mean is used)"""
    live_check: bool = True
    """replay check against a live ``run_active_perception`` on the first object"""


def selector_inputs(root: Path, scene: SceneData):
    """Per view of ``scene``: its mask stack, mask levels and mask features, as ``ActiveSelector`` takes them."""
    from PIL import Image

    from physgs_nerfstudio.perception.active import mask_features
    from physgs_nerfstudio.perception.pipeline import mask_path
    from physgs_nerfstudio.perception.segment import load_masks

    stacks, levels, feats = {}, {}, {}
    for view in scene.views:
        ms = load_masks(mask_path(root, view)) or []
        img = np.asarray(Image.open(root / view).convert("RGB"), dtype=np.uint8)
        stacks[view] = np.stack([m.segmentation for m in ms]) if ms else np.zeros((0,) + img.shape[:2], bool)
        levels[view] = [m.level for m in ms]
        feats[view] = mask_features(img, [m.segmentation for m in ms])
    return stacks, levels, feats


def active_order(root: Path, scene: SceneData, library, cfg) -> list[tuple[str, int]]:
    """The (view, mask) order in which ``ActiveSelector`` with ``cfg`` asks, fed the replayed answers."""
    from physgs_nerfstudio.perception.active import ActiveSelector

    stacks, levels, feats = selector_inputs(root, scene)
    sel = ActiveSelector(scene.views, stacks, levels, feats, library, cfg)
    by_mask = scene.by_mask()
    order = []
    while sel.remaining():
        batch = sel.select(cfg.batch_size)
        if not batch:
            break
        for view, mid in batch:
            sel.observe(view, mid, by_mask.get((view, mid), []))
            order.append((view, mid))
    return order


def dataset_order(scene: SceneData) -> list[tuple[str, int]]:
    rank = {v: i for i, v in enumerate(scene.views)}
    return sorted(scene.masks, key=lambda k: (rank[k[0]], k[1]))


def curve(scene: SceneData, library, order: Sequence[tuple[str, int]], ks: Sequence[int], map_material: bool,
          samples: int) -> np.ndarray:
    """Mass APE after the first k queries of ``order`` for each k."""
    by_mask = scene.by_mask()
    cfg = PhysGSConfig(n_samples=samples, map_material=map_material)
    out = []
    for k in ks:
        obs = [o for key in order[:k] for o in by_mask.get(key, [])]
        sub = replace(scene, observations=obs)
        est = estimate_physgs(sub, library, cfg)
        out.append(abs(est.mass_kg - scene.mass_kg) / scene.mass_kg)
    return np.asarray(out)


def first_within(ks: Sequence[int], apes: np.ndarray, target: float) -> int | None:
    for k, a in zip(ks, apes):
        if a <= target + 1e-12:
            return int(k)
    return None


def live_check(root: Path, scene: SceneData, library, cfg, budget: int, bench: BenchConfig) -> dict:
    """Run run_active_perception for real on a copy of ``root`` (answers come from the response cache) and
    compare its query order with the replayed one."""
    from physgs_nerfstudio.perception.active import run_active_perception

    dst = bench.work_dir / f"live_{root.name}"
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(root, dst, ignore=shutil.ignore_patterns("observations.jsonl*", "progress.jsonl*", "run.json", "active.json"))
    seg = OracleSegmenter(dst) if bench.segmenter == "oracle" else None
    res = run_active_perception(perception_config(dst, bench), replace(cfg, budget=budget), segmenter=seg)
    replayed = active_order(root, scene, library, cfg)[:budget]
    same = [tuple(q) for q in res.queried] == [tuple(q) for q in replayed]
    return {"object": scene.name, "budget": budget, "answered": res.answered, "uncached_calls": res.calls,
            "cache_hits": res.cache_hits, "stop_reason": res.stop_reason, "same_order_as_replay": same}


def policy_orders(root: Path, scene: SceneData, library, acfg, repeats: int, seed: int) -> dict[str, list]:
    """Policy -> its query orders (one, or ``repeats`` for random)."""
    keys = dataset_order(scene)
    rng = np.random.default_rng(seed)
    return {
        "active": [active_order(root, scene, library, acfg)],
        "active (no transfer)": [active_order(root, scene, library, replace(acfg, transfer=0.0))],
        "dataset order": [keys],
        "random": [[keys[i] for i in rng.permutation(len(keys))] for _ in range(repeats)],
    }


def active_rows(root: Path, scene: SceneData, library, acfg, ab: ActiveBench, seed: int) -> list[dict]:
    """One row per (estimator, policy) of one object: its APE curve and the queries it needed."""
    N = len(scene.masks)
    k25 = math.ceil(0.25 * N)
    ks = sorted(set(list(range(ab.step, N, ab.step)) + [N, k25]))
    orders = policy_orders(root, scene, library, acfg, ab.random_repeats, seed)
    rows = []
    for est, use_map in ACTIVE_ESTIMATORS.items():
        full = curve(scene, library, dataset_order(scene), [N], use_map, ab.samples)[0]
        for pol, ords in orders.items():
            cs = np.stack([curve(scene, library, o, ks, use_map, ab.samples) for o in ords])
            at25 = cs[:, ks.index(k25)]
            need_abs = [first_within(ks, c, full + 0.05) for c in cs]
            need_rel = [first_within(ks, c, 1.05 * full) for c in cs]
            rows.append({
                "object": scene.name, "estimator": est, "policy": pol, "queries_all": N, "ape_all": float(full),
                "ape_at_25pct": float(at25.mean()),
                "queries_to_abs5": float(np.mean([n if n is not None else N for n in need_abs])),
                "queries_to_rel5": float(np.mean([n if n is not None else N for n in need_rel])),
                "within_abs5_at_25pct": float(np.mean(at25 <= full + 0.05 + 1e-12)),
                "within_rel5_at_25pct": float(np.mean(at25 <= 1.05 * full + 1e-12)),
                "curve_k": ks, "curve_ape": cs.mean(0).tolist(),
            })
    return rows


def active_table(rows: Sequence[dict]) -> str:
    """The --active section's table: per estimator and policy, means over the objects."""
    lines = [("| estimator | policy | mean APE, all queries | mean APE at 25% | objects within 5 pts at 25% "
              "| within 5% rel. at 25% | mean fraction of queries to within 5 pts | ... to within 5% rel. |"),
             "|---|---|---|---|---|---|---|---|"]
    for est in ACTIVE_ESTIMATORS:
        label = "(c) mixture mean" if est == "c" else "(c') MAP material"
        for pol in POLICIES:
            rs = [r for r in rows if r["estimator"] == est and r["policy"] == pol]
            if not rs:
                continue

            def mean(key: str, rs=rs) -> float:
                return float(np.mean([r[key] for r in rs]))

            frac_abs = np.mean([r["queries_to_abs5"] / r["queries_all"] for r in rs])
            frac_rel = np.mean([r["queries_to_rel5"] / r["queries_all"] for r in rs])
            lines.append(f"| {label} | {pol} | {mean('ape_all'):.4f} | {mean('ape_at_25pct'):.4f} | "
                         f"{mean('within_abs5_at_25pct'):.0%} | {mean('within_rel5_at_25pct'):.0%} | "
                         f"{frac_abs:.2f} | {frac_rel:.2f} |")
    return "\n".join(lines)


def active_section(roots: Sequence[Path], scenes: Sequence[SceneData], library, bench: BenchConfig,
                   ab: ActiveBench) -> dict:
    """The --active section of accuracy.json: the replay check, one row per object, estimator and policy."""
    from physgs_nerfstudio.perception.active import ActiveConfig

    acfg = ActiveConfig()
    print(f"active querying: ActiveConfig {asdict(acfg)}")
    t0 = time.time()
    rows, live = [], None
    for oi, (root, scene) in enumerate(zip(roots, scenes)):
        if oi == 0 and ab.live_check:
            live = live_check(root, scene, library, acfg, math.ceil(0.25 * len(scene.masks)), bench)
            print(f"  live check ({scene.name}): {live}")
        rows += active_rows(root, scene, library, acfg, ab, bench.seed)
        print(f"  {scene.name:10s} {len(scene.masks)} masks ({time.time() - t0:.0f}s)", flush=True)
    return {"benchmark": "active querying vs exhaustive (SIMULATED VLM)", "active_config": asdict(acfg),
            "settings": asdict(ab), "live_check": live, "rows": rows, "seconds": time.time() - t0}


def parse_args(argv: Sequence[str] | None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--objects", nargs="*", default=None, help="objects (default: the whole synth SUITE)")
    ap.add_argument("--views", type=int, default=16)
    ap.add_argument("--resolution", type=int, default=96)
    ap.add_argument("--jitter", type=float, default=0.2, help="synth property_jitter: truth = typical x exp(j N(0,1)), clipped to the library range")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--segmenter", choices=("oracle", "builtin"), default="oracle")
    ap.add_argument("--samples", type=int, default=4000, help="Monte Carlo draws for the mass interval")
    ap.add_argument("--work-dir", type=Path, default=Path("/tmp/physgs_bench/accuracy"))
    ap.add_argument("--results-dir", type=Path, default=None, help="default: <work-dir>/results")
    ap.add_argument("--quick", action="store_true", help="smoke run: 3 objects, 8 views, 64 px, 1000 draws")
    act = ap.add_argument_group("active querying (--active)")
    act.add_argument("--active", action="store_true", help="add the active-querying section (about 4x the time of the rest)")
    act.add_argument("--step", type=int, default=4, help="evaluate the mass after every STEP queries")
    act.add_argument("--random-repeats", type=int, default=5)
    act.add_argument("--active-samples", type=int, default=64, help="Monte Carlo draws per estimate (only the mean is used)")
    act.add_argument("--no-live-check", action="store_true", help="skip the replay check against a live active run")
    args = ap.parse_args(argv)
    if args.quick:
        args.objects = args.objects or ["mug", "hammer", "bottle"]
        args.views, args.resolution, args.samples = min(args.views, 8), min(args.resolution, 64), min(args.samples, 1000)
        args.random_repeats = min(args.random_repeats, 2)
    return args


def main(argv: Sequence[str] | None = None) -> dict:
    from physgs_nerfstudio.perception.simulated import SimulatedConfig
    from physgs_nerfstudio.synth import SUITE

    args = parse_args(argv)
    objects = tuple(args.objects or SUITE)
    cfg = BenchConfig(objects, args.views, args.resolution, args.jitter, args.seed, args.segmenter, args.work_dir)
    sim = SimulatedConfig(seed=args.seed)
    library = load_library("indoor")
    print(describe_noise(sim))
    print(f"masks: {args.segmenter} segmenter; scenes: {len(objects)} objects x {cfg.views} views at "
          f"{cfg.resolution}px, property jitter {cfg.jitter}; work dir {cfg.work_dir}")
    print("Mass uses the GROUND-TRUTH part volumes (material volume, shells at their true wall thickness) for every "
          "estimator, so the comparison isolates property inference from geometry.")
    t0 = time.time()
    roots, scenes = [], []
    for obj in objects:
        t = time.time()
        roots.append(prepare_scene(cfg, obj))
        run_scene_perception(roots[-1], cfg, sim)
        scenes.append(load_scene(roots[-1], obj))
        print(f"  {obj:10s} {len(scenes[-1].parts)} parts, {len(scenes[-1].masks)} masks, "
              f"{len(scenes[-1].observations)} observations ({time.time() - t:.1f}s)", flush=True)
    pcfg = PhysGSConfig(n_samples=args.samples, seed=args.seed)
    draws = ("posterior", "predictive")
    res = evaluate_scenes(scenes, library, pcfg, draws)
    table = markdown_table(res, draws)
    if args.active:
        ab = ActiveBench(args.step, args.random_repeats, args.active_samples, not args.no_live_check)
        res["active_querying"] = active_section(roots, scenes, library, cfg, ab)
        table += ("\nActive querying: mass APE from the answers so far, (c) and (c'); 5 pts / 5% rel.: within that of "
                  "the APE with every query.\n\n" + active_table(res["active_querying"]["rows"]) + "\n")
    print()
    print(table)
    out_dir = args.results_dir or (cfg.work_dir / "results")
    out_dir.mkdir(parents=True, exist_ok=True)
    doc = {
        "benchmark": "accuracy (paper ablation w/o BI vs with BI) on generated scenes",
        "simulated_vlm": {"description": describe_noise(sim), "config": asdict(sim)},
        "config": {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(cfg).items()},
        "samples": args.samples, "seconds": time.time() - t0, **res,
    }
    (out_dir / "accuracy.json").write_text(json.dumps(doc, indent=2))
    print(f"\nwrote {out_dir / 'accuracy.json'} ({time.time() - t0:.1f}s; per object: its per_object)")
    return doc


if __name__ == "__main__":
    main(sys.argv[1:])
