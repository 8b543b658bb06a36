"""Single-image mode: image(s) -> masks at three levels -> (cached) VLM per mask -> fusion over the image's
masks and levels -> dense per-pixel material / property / uncertainty maps, figures and summaries.

Perception (segmentation, prompts, VLM backends, cache, validation, the resumable observation store) is
``perception.run_perception`` run on a small workspace in the output directory (see ``inputs.py``); fusion
is ``fusion`` + ``bayes`` applied per image (see ``maps.py``). Output layout::

    <output_dir>/summary.json                run: backend, calls, cache hits, failures, one entry per image
    <output_dir>/<name>/maps.npz             H x W arrays (keys and units: maps.NPZ_KEYS, also in summary.json)
    <output_dir>/<name>/summary.json         legend, per-material posteriors, pixel statistics, files
    <output_dir>/<name>/material.png        legend colours + legend
    <output_dir>/<name>/<key>_<stat>.png    stat in mean | aleatoric | epistemic | total (std shown)
    <output_dir>/<name>/overview.png         RGB | material | friction | Young's modulus | total uncertainty
    <output_dir>/observations.jsonl, perception/   the perception workspace (cache, masks, commit log)
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import tyro

from ..fusion.writer import jsonable
from ..materials import PROPERTY_KEYS, MaterialLibrary, load_library
from ..perception.config import PerceptionConfig
from ..perception.pipeline import PerceptionResult
from ..perception.segment import Mask, Segmenter
from ..perception.simulated import SimulatedConfig
from .inputs import (
    InputError,
    StagedImage,
    find_images,
    ground_truth_material,
    ground_truth_root,
    match_ground_truth,
    stage_images,
)
from .maps import (
    HARDNESS_SCALES,
    NPZ_KEYS,
    ImageMaps,
    compute_image_maps,
    finite_summary,
    normalize_properties,
    save_npz,
)

logger = logging.getLogger(__name__)

SUMMARY_VERSION = 1
RESERVED_NAMES = {"images", "perception"}


@dataclass
class SingleImageConfig:
    """Dense 2D material, property and uncertainty maps of single images (the paper's fabric, terrain and
    outdoor results): masks at three levels, one VLM query per mask (cached, resumable), Bayesian fusion
    over the image's masks and levels."""

    path: tyro.conf.Positional[Path]
    """An image file, or a folder of images (each is processed on its own)."""
    output_dir: Path = Path("physgs_image")
    """Where the maps, figures, summaries and the perception workspace (cache, masks) go."""
    ground_truth: Path | None = None
    """A generated scene (`physgs synth`) or its ground_truth.json; needed by vlm:simulated, adds an accuracy check."""
    properties: tuple[str, ...] = PROPERTY_KEYS
    """Properties to map (keys or friction / hardness / stiffness)."""
    hardness_scale: Literal["A", "D", "00", "A_eq"] = "D"
    """Shore scale of the hardness maps (A_eq: the internal Shore A-equivalent scale)."""
    uncertainty_property: str = "kinetic_friction"
    """Property whose total uncertainty the overview panel shows."""
    overview_properties: tuple[str, ...] = ("kinetic_friction", "youngs_modulus")
    """Property means shown in the overview panel (among --properties)."""
    uncovered: Literal["library", "legend"] = "library"
    """Prior of pixels without evidence: flat Dirichlet over the library (maximal uncertainty) or the image's legend."""
    max_side: int | None = 1024
    """Downscale images whose long side exceeds this (maps are at the working size); None: keep."""
    figures: bool = True
    """Write the PNG figures (maps.npz and summary.json are always written)."""
    dpi: int = 150
    """Resolution of the PNG figures in dots per inch."""
    perception: Annotated[PerceptionConfig, tyro.conf.arg(name="")] = field(
        default_factory=lambda: PerceptionConfig(data=Path("."))
    )
    """The perception settings; --data is not used (single-image mode works in --output-dir)."""

    def __post_init__(self) -> None:
        self.properties = normalize_properties(self.properties)
        (self.uncertainty_property,) = normalize_properties([self.uncertainty_property])
        self.overview_properties = tuple(normalize_properties(self.overview_properties)) if self.overview_properties else ()
        if self.hardness_scale not in HARDNESS_SCALES:
            raise ValueError(f"hardness_scale must be one of {HARDNESS_SCALES}")
        if self.max_side is not None and self.max_side < 16:
            raise ValueError("max_side must be >= 16 (or None)")
        if isinstance(self.perception.vlm, SimulatedConfig) and self.ground_truth is None:
            raise ValueError(
                "vlm:simulated answers from a generated scene's ground truth: pass --ground-truth SCENE_DIR "
                "(a `physgs synth` output). For real photographs use vlm:openai (or vlm:replay)."
            )

    def perception_config(self) -> PerceptionConfig:
        """The perception run of single-image mode: ``perception`` on the workspace in ``output_dir``, without
        dataset outputs (fusion happens per image here) and never strict (failures are reported at the end)."""
        return replace(self.perception, data=Path(self.output_dir), strict=False, write_outputs=False)


@dataclass
class ImageResult:
    name: str
    source: Path
    out_dir: Path
    size: tuple[int, int]
    masks: int = 0
    observations: int = 0
    covered_fraction: float = 0.0
    materials: list[str] = field(default_factory=list)
    files: dict[str, str] = field(default_factory=dict)
    ground_truth_accuracy: float | None = None
    """Foreground pixels whose material matches the ground truth (only with --ground-truth)."""
    skipped: str = ""
    """Why no maps were written (e.g. the run stopped before segmenting this image)."""


@dataclass
class SingleImageResult:
    output_dir: Path
    images: list[ImageResult]
    perception: PerceptionResult
    seconds: float = 0.0


class ViewAliasBackend:
    """Thin adapter: forwards requests to ``inner`` with the workspace view renamed to the ground-truth
    frame it is a copy of (the simulated VLM looks its truth up by view). The view is not part of the cache
    key, so cached answers are the same as for the scene itself."""

    def __init__(self, inner: Any, aliases: dict[str, str]):
        self.inner = inner
        self.aliases = dict(aliases)
        self.name = inner.name
        self.model = inner.model
        self.variant = inner.variant
        self.simulated = bool(inner.simulated)

    @property
    def calls(self) -> int:
        return int(getattr(self.inner, "calls", 0))

    def cost_usd(self, usage) -> float:
        return float(self.inner.cost_usd(usage))

    def query(self, request):
        return self.inner.query(replace(request, view=self.aliases.get(request.view, request.view)))


def simulated_backend(config: SingleImageConfig, staged: Sequence[StagedImage], library: MaterialLibrary) -> ViewAliasBackend:
    """The simulated VLM of --ground-truth, answering for the staged copies of its frames (uncached)."""
    if config.ground_truth is None or not isinstance(config.perception.vlm, SimulatedConfig):
        raise InputError("the simulated VLM needs vlm:simulated and --ground-truth")
    root = ground_truth_root(config.ground_truth)
    return ViewAliasBackend(config.perception.vlm.setup(root, library), match_ground_truth(staged, root))


def _image_masks(workspace: Path, s: StagedImage, seg_fp: str | None, prompt: str) -> list[Mask] | None:
    if prompt == "baseline":
        h, w = s.image.shape[:2]
        return [Mask(np.ones((h, w), bool), h * w, 1.0, 1.0, "whole")]
    from ..perception.pipeline import mask_path
    from ..perception.segment import load_masks

    return load_masks(mask_path(workspace, s.view), seg_fp)


def _segmenter_name(config: SingleImageConfig) -> str:
    if config.perception.prompt != "triplet":
        return "none (baseline prompt)"
    return config.perception.segmenter.name


def accuracy_against_truth(maps: ImageMaps, truth: np.ndarray, truth_names: Sequence[str]) -> dict[str, float | int]:
    """Fraction of ground-truth foreground pixels whose fused material is the true one (all of them, and the
    covered ones)."""
    lut = np.array([-1] + [maps.names.index(n) + 1 if n in maps.names else -1 for n in truth_names], dtype=np.int64)
    fg = truth > 0
    hit = (maps.material.astype(np.int64) == lut[truth]) & fg
    cov = fg & maps.covered
    return {
        "foreground_pixels": int(fg.sum()),
        "foreground_accuracy": float(hit.sum() / max(int(fg.sum()), 1)),
        "covered_foreground_fraction": float(cov.sum() / max(int(fg.sum()), 1)),
        "covered_foreground_accuracy": float((hit & cov).sum() / max(int(cov.sum()), 1)),
    }


def _progress(enabled: bool):
    from ..perception.pipeline import _Progress

    return _Progress(enabled)


def run_single_image(
    config: SingleImageConfig,
    *,
    backend: Any | None = None,
    segmenter: Segmenter | None = None,
    library: MaterialLibrary | None = None,
    on_commit: Callable[[Any], None] | None = None,
) -> SingleImageResult:
    """Run single-image mode (module docstring). ``backend`` (a ``perception.vlm.CachedBackend``),
    ``segmenter`` and ``library`` override what the config would build (tests, demos)."""
    from ..perception.cache import ResponseCache
    from ..perception.pipeline import run_perception
    from ..perception.store import read_observations
    from ..perception.vlm import CachedBackend, VLMError

    t0 = time.time()
    pc = config.perception
    files = find_images(config.path)
    ws = Path(config.output_dir)
    ws.mkdir(parents=True, exist_ok=True)
    staged = stage_images(files, ws, config.max_side, pc.overwrite)
    library = library or load_library(pc.env, extra_files=pc.library_files)
    pconfig = config.perception_config()
    if backend is None and isinstance(pc.vlm, SimulatedConfig):  # answers for the staged copies of its frames
        backend = CachedBackend(simulated_backend(config, staged, library), ResponseCache(pc.cache_dir or ws / "perception" / "cache"))
    seg_fp: str | None = None
    if pc.prompt == "triplet":
        segmenter = segmenter or pc.segmenter.setup()
        seg_fp = segmenter.fingerprint()
    presult = run_perception(pconfig, backend=backend, segmenter=segmenter, library=library, on_commit=on_commit)
    observations = read_observations(ws)
    by_view: dict[str, list[dict]] = {}
    for o in observations:
        by_view.setdefault(str(o.get("view")), []).append(o)

    gt_root = gt_alias = None
    if config.ground_truth is not None:
        gt_root = ground_truth_root(config.ground_truth)
        try:
            gt_alias = match_ground_truth(staged, gt_root)
        except InputError as err:
            logger.warning("ground-truth check skipped: %s", err)

    simulated = bool(presult.simulated or any(o.get("simulated") for o in observations))
    results: list[ImageResult] = []
    bar = _progress(config.perception.progress)
    with bar:
        task = bar.add("maps + figures", len(staged))
        for s in staged:
            name = f"{s.name}_maps" if s.name in RESERVED_NAMES else s.name
            res = ImageResult(s.name, s.source, ws / name, s.image.shape[:2])
            results.append(res)
            masks = _image_masks(ws, s, seg_fp, config.perception.prompt)
            if masks is None:
                res.skipped = "not segmented (the run stopped before this image); run again to resume"
                logger.warning("%s: %s", s.source, res.skipped)
                bar.advance(task)
                continue
            records = by_view.get(s.view, [])
            h, w = s.image.shape[:2]
            stack = np.stack([m.segmentation for m in masks]) if masks else np.zeros((0, h, w), bool)
            maps = compute_image_maps(
                stack,
                [m.level for m in masks],
                records,
                library,
                properties=config.properties,
                hardness_scale=config.hardness_scale,
                map_config=config.perception.fusion,
                prior_config=config.perception.prior,
                legend=config.perception.legend,
                uncovered=config.uncovered,
            )
            gt_check = None
            if gt_root is not None and gt_alias is not None and s.view in gt_alias:
                truth, truth_names = ground_truth_material(gt_root, gt_alias[s.view], (h, w))
                gt_check = {"ground_truth": str(gt_root), "frame": gt_alias[s.view], **accuracy_against_truth(maps, truth, truth_names)}
                res.ground_truth_accuracy = float(gt_check["foreground_accuracy"])
            meta = {
                "view": s.view,
                "source": str(s.source),
                "hardness_scale": config.hardness_scale,
                "log_space": maps.log_space,
                "alpha0": config.perception.fusion.alpha0,
                "lambda": config.perception.fusion.lam,
                "level_weights": dict(config.perception.fusion.level_weights),
                "uncovered_prior": maps.uncovered_prior,
                "simulated": simulated,
            }
            res.out_dir.mkdir(parents=True, exist_ok=True)
            save_npz(res.out_dir / "maps.npz", maps, s.image, meta)
            res.files = {"maps_npz": "maps.npz"}
            if config.figures:
                from .figures import save_all

                label = f"{s.source.name}{' (SIMULATED VLM)' if simulated else ''}"
                res.files.update(
                    save_all(
                        maps, s.image, res.out_dir, overview_properties=config.overview_properties,
                        uncertainty_property=config.uncertainty_property, title=label, dpi=config.dpi,
                    )
                )
            res.masks = len(masks)
            res.observations = len(records)
            res.covered_fraction = float(maps.covered.mean())
            res.materials = list(maps.names)
            summary = image_summary(config, s, res, maps, masks, records, presult, simulated, gt_check)
            _write_json(res.out_dir / "summary.json", summary)
            bar.advance(task)

    result = SingleImageResult(ws, results, presult, time.time() - t0)
    _write_json(ws / "summary.json", run_summary(config, result, simulated))
    if config.perception.strict and presult.failed:
        raise VLMError(f"{len(presult.failed)} VLM requests failed; first: {presult.failed[0]}")
    return result


def image_summary(
    config: SingleImageConfig,
    s: StagedImage,
    res: ImageResult,
    maps: ImageMaps,
    masks: Sequence[Mask],
    records: Sequence[dict],
    presult: PerceptionResult,
    simulated: bool,
    gt_check: dict | None,
) -> dict:
    levels = [m.level for m in masks]
    answered = {int(r["mask_id"]) for r in records if r.get("material") in maps.names}
    stats = {}
    for key in maps.properties:
        stats[key] = {
            st: {"covered": finite_summary(arr, maps.covered), "all": finite_summary(arr)} for st, arr in maps.fields[key].items()
        }
    return jsonable(
        {
            "version": SUMMARY_VERSION,
            "tool": "physgs image",
            "simulated": simulated,
            "source": str(s.source),
            "view": s.view,
            "size_hw": list(s.image.shape[:2]),
            "original_size_hw": list(s.original_size),
            "backend": presult.backend,
            "model": presult.model,
            "segmenter": _segmenter_name(config),
            "prompt": config.perception.prompt,
            "env": config.perception.env,
            "masks": {"total": len(masks), **{lv: levels.count(lv) for lv in ("whole", "part", "subpart")}},
            "masks_with_evidence": len(answered),
            "observations": len(records),
            "covered_fraction": res.covered_fraction,
            "hardness_scale": config.hardness_scale,
            "properties": list(maps.properties),
            "units": maps.units,
            "variance_units": {k: ("1" if u == "1" else f"({u})^2") for k, u in maps.units.items()},
            "log_space": maps.log_space,
            "fusion": {
                "alpha0": config.perception.fusion.alpha0,
                "lambda": config.perception.fusion.lam,
                "level_weights": dict(config.perception.fusion.level_weights),
                "legend": config.perception.legend,
                "uncovered_prior": maps.uncovered_prior,
                "prior": {"kappa0": config.perception.prior.kappa0, "a0": config.perception.prior.a0, "spread_divisor": config.perception.prior.spread_divisor},
            },
            "materials": maps.per_material,
            "unknown_pixel": maps.unknown,
            "pixel_statistics": stats,
            "files": res.files,
            "npz_keys": NPZ_KEYS,
            "ground_truth_check": gt_check,
        }
    )


def run_summary(config: SingleImageConfig, result: SingleImageResult, simulated: bool) -> dict:
    p = result.perception
    return jsonable(
        {
            "version": SUMMARY_VERSION,
            "tool": "physgs image",
            "simulated": simulated,
            "input": str(config.path),
            "backend": p.backend,
            "model": p.model,
            "segmenter": _segmenter_name(config),
            "prompt": config.perception.prompt,
            "env": config.perception.env,
            "vlm": {
                "masks": p.masks,
                "calls": p.calls,
                "cache_hits": p.cache_hits,
                "resumed_masks": p.resumed_masks,
                "failed": len(p.failed),
                "failures": p.failed[:20],
                "skipped_budget": p.skipped_budget,
                "observations": p.observations,
                "new_observations": p.new_observations,
                "dropped_candidates": p.dropped_candidates,
                "usage": asdict(p.usage),
                "cost_usd": p.cost_usd,
            },
            "images": [
                {
                    "name": r.name,
                    "source": str(r.source),
                    "dir": r.out_dir.name,
                    "size_hw": list(r.size),
                    "masks": r.masks,
                    "observations": r.observations,
                    "covered_fraction": r.covered_fraction,
                    "materials": r.materials,
                    "ground_truth_accuracy": r.ground_truth_accuracy,
                    "skipped": r.skipped or None,
                }
                for r in result.images
            ],
            "seconds": result.seconds,
        }
    )


def _write_json(path: Path, obj: dict) -> None:
    from ..fusion.writer import atomic_write_text

    atomic_write_text(path, json.dumps(obj, indent=2, allow_nan=False))
