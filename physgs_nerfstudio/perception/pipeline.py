"""Perception pipeline: frames -> masks -> prompts -> (cached) VLM -> validation -> observation store ->
fusion -> material maps in the dataset. Reusable as ``run_perception(config) -> PerceptionResult``
(``physgs perceive``, ``physgs demo`` and single-image mode call it).

Per frame, in order: segment (masks are saved under ``perception/masks/`` and reused, so mask ids stay
stable across resumed runs), build one prompt per mask not yet recorded, answer from the cache in the main
thread when possible, else submit to a thread pool of ``max_concurrency`` workers; answers are validated
and committed to the store in the main thread as they complete. A killed or failed run can simply be run
again: done masks are skipped, and answers received before the kill are in the cache.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from dataclasses import asdict, dataclass, field, is_dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from ..fusion.maps import MapFusionConfig
from ..materials import PROPERTY_KEYS, MaterialLibrary, PriorConfig, load_library
from .cache import ResponseCache
from .prompts import SCHEMA_VERSION, PromptConfig, VLMRequest, build_request
from .segment import (
    BuiltinSegmenterConfig,
    Mask,
    SamSegmenterConfig,
    Segmenter,
    load_masks,
    make_segmenter,
    save_masks,
)
from .simulated import SIMULATED_MODEL, SimulatedBackend, SimulatedConfig
from .store import MaskDone, ObservationStore
from .validate import Candidate, ValidationConfig, Validator
from .vlm import CachedBackend, OpenAIBackend, OpenAIConfig, Usage, VLMError, VLMResponse

logger = logging.getLogger(__name__)

MASK_DIR = "perception/masks"


@dataclass
class PerceptionConfig:
    """Masks -> VLM -> validated observations -> Bayesian fusion -> material maps, for a nerfstudio dataset."""

    data: Path
    """Nerfstudio dataset directory (with transforms.json)."""
    segmenter: Literal["builtin", "sam"] = "builtin"
    """builtin: weight-free SLIC superpixel masks merged by colour (weaker than SAM); sam: segment-anything (pip install -e ".[sam]")."""
    sam_checkpoint: Path | None = None
    """SAM checkpoint file (required with --segmenter sam)."""
    sam_model_type: str = "vit_h"
    """vit_h | vit_l | vit_b, matching the checkpoint."""
    vlm: Literal["openai", "replay", "simulated"] = "openai"
    """openai: any OpenAI-compatible endpoint; replay: cached answers only; simulated: generated scenes only."""
    model: str = "gpt-5"
    """Model name sent to the endpoint (and part of the cache key)."""
    base_url: str = "https://api.openai.com/v1"
    """OpenAI-compatible endpoint root, e.g. http://localhost:8000/v1 (vLLM) or http://localhost:11434/v1 (Ollama)."""
    api_key_env: str = "OPENAI_API_KEY"
    """Name of the environment variable holding the API key ('' for keyless local servers)."""
    replay_source: Literal["openai", "simulated"] = "openai"
    """With --vlm replay: which backend filled the cache."""
    env: str = "indoor"
    """Material library: indoor | outdoor | path to a library YAML."""
    library_files: tuple[Path, ...] = ()
    """Extra library YAML files merged into --env."""
    max_views: int | None = None
    """Use at most this many frames (evenly spaced); None: all."""
    max_concurrency: int = 4
    """VLM requests in flight at once."""
    budget: float | None = None
    """Stop issuing new (uncached) requests once the estimated cost reaches this many USD (needs the
    --usd-per-1k-* rates); None: no limit. Unqueried masks are done by a later run."""
    max_calls: int | None = None
    """At most this many uncached requests in this run; None: no limit."""
    prompt: Literal["triplet", "baseline"] = "triplet"
    """triplet: per-mask full | overlay | isolated prompt (PhysGS); baseline: raw image only, one per frame."""
    cache_dir: Path | None = None
    """Response cache directory; default <data>/perception/cache."""
    overwrite: bool = False
    """Start over even if observations.jsonl exists (old files kept as .bak)."""
    strict: bool = False
    """Raise at the end if any request failed (default: report failures and fuse what arrived)."""
    legend: Literal["observed", "library"] = "observed"
    """Materials in materials.json: the observed ones, or the whole library."""
    write_outputs: bool = True
    """Write materials.json, the per-frame maps and transforms.json entries."""
    progress: bool = True
    """Show progress bars."""
    timeout_s: float = 120.0
    max_retries: int = 5
    json_mode: bool = True
    """Ask for response_format json_object (switched off automatically if the server rejects it)."""
    usd_per_1k_prompt_tokens: float = 0.0
    usd_per_1k_completion_tokens: float = 0.0
    builtin: BuiltinSegmenterConfig = field(default_factory=BuiltinSegmenterConfig)
    sam: SamSegmenterConfig = field(default_factory=SamSegmenterConfig)
    prompt_options: PromptConfig = field(default_factory=PromptConfig)
    simulated: SimulatedConfig = field(default_factory=SimulatedConfig)
    validation: ValidationConfig = field(default_factory=ValidationConfig)
    fusion: MapFusionConfig = field(default_factory=MapFusionConfig)
    prior: PriorConfig = field(default_factory=PriorConfig)

    def __post_init__(self) -> None:
        if self.max_concurrency < 1:
            raise ValueError("max_concurrency must be >= 1")


@dataclass
class PerceptionResult:
    data: Path
    views: list[str]
    masks: int = 0
    observations: int = 0
    new_observations: int = 0
    calls: int = 0
    """Uncached backend queries answered in this run."""
    cache_hits: int = 0
    resumed_masks: int = 0
    """Masks skipped because an earlier run recorded them."""
    failed: list[str] = field(default_factory=list)
    skipped_budget: int = 0
    dropped_candidates: int = 0
    reasons: int = 0
    usage: Usage = field(default_factory=Usage)
    cost_usd: float = 0.0
    simulated: bool = False
    backend: str = ""
    model: str = ""
    materials: list[str] = field(default_factory=list)
    material_counts: dict[str, int] = field(default_factory=dict)
    label_paths: dict[str, str] = field(default_factory=dict)
    confidence_paths: dict[str, str] = field(default_factory=dict)
    materials_json: Path | None = None
    seconds: float = 0.0


# ---------------------------------------------------------------------------------------------------------
# pieces
# ---------------------------------------------------------------------------------------------------------


def load_frames(root: Path) -> tuple[dict, list[dict]]:
    path = Path(root) / "transforms.json"
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found: --data must be a nerfstudio dataset directory")
    meta = json.loads(path.read_text(encoding="utf-8"))
    frames = [f for f in meta.get("frames", []) if isinstance(f, dict) and "file_path" in f]
    if not frames:
        raise ValueError(f"{path} lists no frames with a file_path")
    return meta, frames


def select_views(frames: Sequence[dict], max_views: int | None) -> list[dict]:
    """Evenly spaced subset (first and last included) of at most max_views frames, in dataset order."""
    if max_views is None or max_views >= len(frames):
        return list(frames)
    if max_views <= 0:
        return []
    idx = np.unique(np.round(np.linspace(0, len(frames) - 1, max_views)).astype(int))
    return [frames[i] for i in idx]


def load_image(root: Path, file_path: str) -> np.ndarray:
    from PIL import Image

    path = Path(root) / file_path
    if not path.is_file():
        raise FileNotFoundError(f"frame image {path} not found")
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"), dtype=np.uint8)


def build_backend(config: PerceptionConfig, library: MaterialLibrary, cache: ResponseCache) -> CachedBackend:
    if config.vlm == "openai":
        inner = OpenAIBackend(_openai_config(config))
        return CachedBackend(inner, cache)
    if config.vlm == "simulated":
        return CachedBackend(SimulatedBackend(config.data, library, config.simulated), cache)
    if config.vlm == "replay":
        if config.replay_source == "simulated":
            return CachedBackend(
                None,
                cache,
                name="simulated",
                model=SIMULATED_MODEL,
                variant=config.simulated.fingerprint(),
                simulated=True,
            )
        return CachedBackend(None, cache, name="openai", model=config.model, variant="", simulated=False)
    raise ValueError(f"unknown VLM backend {config.vlm!r}; choose openai, replay or simulated")


def _openai_config(config: PerceptionConfig) -> OpenAIConfig:
    return OpenAIConfig(
        base_url=config.base_url,
        model=config.model,
        api_key_env=config.api_key_env,
        timeout_s=config.timeout_s,
        max_retries=config.max_retries,
        max_concurrency=config.max_concurrency,
        json_mode=config.json_mode,
        usd_per_1k_prompt_tokens=config.usd_per_1k_prompt_tokens,
        usd_per_1k_completion_tokens=config.usd_per_1k_completion_tokens,
    )


def _segmenter(config: PerceptionConfig) -> Segmenter:
    """The segmenter of ``config``'s ``segmenter``, ``builtin``, ``sam``, ``sam_checkpoint`` and
    ``sam_model_type`` (the only fields read, so ``SingleImageConfig`` works too)."""
    sam = config.sam
    if config.sam_checkpoint is not None or config.sam_model_type != sam.model_type:
        from dataclasses import replace

        sam = replace(
            sam, checkpoint=config.sam_checkpoint or sam.checkpoint, model_type=config.sam_model_type
        )
    return make_segmenter(config.segmenter, builtin=config.builtin, sam=sam)


def _jsonable(obj):
    if is_dataclass(obj):
        return {k: _jsonable(v) for k, v in asdict(obj).items()}
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    return obj


def run_fingerprint(
    config: PerceptionConfig, segmenter_fp: str, backend: CachedBackend, library: MaterialLibrary
) -> str:
    prompt = _jsonable(config.prompt_options)
    prompt["kind"] = config.prompt
    return json.dumps(
        {
            "segmenter": segmenter_fp,
            "backend": backend.name,
            "model": backend.model,
            "variant": backend.variant,
            "prompt": prompt,
            "schema": SCHEMA_VERSION,
            "env": library.env,
            "materials": library.names,
        },
        sort_keys=True,
    )


def observation_records(
    request: VLMRequest, candidates: Sequence[Candidate], backend: CachedBackend, response: VLMResponse
) -> list[dict]:
    """observations.jsonl records (docs/architecture.md) of one answered mask."""
    out = []
    for c in candidates:
        props = {
            k: (None if math.isnan(v) else float(v))
            for k, v in ((k, c.properties.get(k, math.nan)) for k in PROPERTY_KEYS)
        }
        props["thickness_m"] = c.thickness_m
        out.append(
            {
                "view": request.view,
                "mask_id": int(request.mask_id),
                "level": request.level,
                "material": c.material,
                "confidence": float(c.confidence),
                "properties": props,
                "backend": backend.name,
                "model": backend.model,
                "simulated": bool(response.simulated or backend.simulated),
                "request_key": response.key,
            }
        )
    return out


def commit_answer(
    request: VLMRequest,
    response: VLMResponse,
    *,
    result: PerceptionResult,
    validator: Validator,
    backend: CachedBackend,
    store: ObservationStore,
    cost_of: Callable[[Usage], float] | None,
) -> tuple[MaskDone, list[dict]]:
    """Account one answer in ``result`` (cache hit, or uncached call with its usage and cost), validate it
    and commit its observation records to ``store``; returns the commit and the records."""
    if response.cached:
        result.cache_hits += 1
    else:
        result.calls += 1
        result.usage = Usage(
            result.usage.prompt_tokens + response.usage.prompt_tokens,
            result.usage.completion_tokens + response.usage.completion_tokens,
            result.usage.total_tokens + response.usage.total_tokens,
        )
        if cost_of is not None:
            result.cost_usd += float(cost_of(response.usage))
    checked = validator(response.text, context=request.describe())
    result.reasons += len(checked.reasons)
    result.dropped_candidates += sum("dropped" in r for r in checked.reasons)
    records = observation_records(request, checked.candidates, backend, response)
    done = MaskDone(
        request.view,
        request.mask_id,
        request.level,
        len(records),
        checked.reasons,
        response.cached,
        response.usage.to_dict(),
    )
    store.commit(done, records)
    result.new_observations += len(records)
    return done, records


def failure_message(request: VLMRequest, err: Exception) -> str:
    """What ``result.failed`` records for a query that raised: a VLMError's own message (it names the
    request), anything else (a backend bug) prefixed with the request."""
    return str(err) if isinstance(err, VLMError) else f"{request.describe()}: {type(err).__name__}: {err}"


def budget_left(config: PerceptionConfig, paid: int, cost_usd: float) -> bool:
    """Whether another uncached request may be sent after ``paid`` of them costing ``cost_usd`` so far
    (``config.max_calls``, ``config.budget``)."""
    if config.max_calls is not None and paid >= config.max_calls:
        return False
    return not (config.budget is not None and cost_usd >= config.budget)


class _Progress:
    """rich progress bars (or nothing)."""

    def __init__(self, enabled: bool):
        self.enabled = enabled
        self._p = None

    def __enter__(self):
        if self.enabled:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

            self._p = Progress(
                TextColumn("{task.description}"),
                BarColumn(),
                MofNCompleteColumn(),
                TimeElapsedColumn(),
                transient=False,
            )
            self._p.__enter__()
        return self

    def __exit__(self, *exc):
        if self._p is not None:
            self._p.__exit__(*exc)

    def add(self, description: str, total: int | None) -> int | None:
        return self._p.add_task(description, total=total) if self._p is not None else None

    def advance(self, task, n: int = 1, total: int | None = None) -> None:
        if self._p is not None and task is not None:
            if total is not None:
                self._p.update(task, total=total)
            self._p.advance(task, n)

    def set_total(self, task, total: int) -> None:
        if self._p is not None and task is not None:
            self._p.update(task, total=total)


# ---------------------------------------------------------------------------------------------------------
# main loop
# ---------------------------------------------------------------------------------------------------------


def run_perception(
    config: PerceptionConfig,
    *,
    backend: CachedBackend | None = None,
    segmenter: Segmenter | None = None,
    library: MaterialLibrary | None = None,
    on_commit: Callable[[MaskDone], None] | None = None,
) -> PerceptionResult:
    """Run perception on ``config.data`` and (unless ``write_outputs=False``) fuse and write the outputs.

    ``backend``/``segmenter``/``library`` override what the config would build (tests, demos);
    ``on_commit`` is called after each mask is recorded (progress hooks; an exception stops the run, which a
    later call resumes).
    """
    t0 = time.time()
    root = Path(config.data)
    _, all_frames = load_frames(root)
    frames = select_views(all_frames, config.max_views)
    library = library or load_library(config.env, extra_files=config.library_files)
    cache = ResponseCache(config.cache_dir or root / "perception" / "cache")
    backend = backend or build_backend(config, library, cache)
    if config.prompt == "baseline":
        seg_fp = "baseline:full-image"
    else:
        segmenter = segmenter or _segmenter(config)
        seg_fp = segmenter.fingerprint()
    store = ObservationStore(
        root, run_fingerprint(config, seg_fp, backend, library), overwrite=config.overwrite
    )
    validator = Validator(library, config.validation)
    prompt_cfg = PromptConfig(**{**asdict(config.prompt_options), "kind": config.prompt})
    result = PerceptionResult(
        root,
        [f["file_path"] for f in frames],
        simulated=backend.simulated,
        backend=backend.name,
        model=backend.model,
    )
    result.resumed_masks = 0
    inner = backend.inner
    cost_of = getattr(inner, "cost_usd", None)
    paid_submitted = 0

    def handle(request: VLMRequest, response: VLMResponse) -> None:
        done, _ = commit_answer(
            request,
            response,
            result=result,
            validator=validator,
            backend=backend,
            store=store,
            cost_of=cost_of,
        )
        if on_commit is not None:
            on_commit(done)

    pool = ThreadPoolExecutor(max_workers=config.max_concurrency, thread_name_prefix="physgs-vlm")
    in_flight: dict[Future, VLMRequest] = {}

    def drain(limit: int) -> None:
        while len(in_flight) > limit:
            finished, _ = wait(list(in_flight), return_when=FIRST_COMPLETED)
            for fut in finished:
                request = in_flight.pop(fut)
                try:
                    response = fut.result()
                except Exception as err:  # noqa: BLE001  (a backend bug must not lose the other answers)
                    msg = failure_message(request, err)
                    result.failed.append(msg)
                    logger.warning("%s", msg)
                    bar.advance(task_q)
                    continue
                handle(request, response)
                bar.advance(task_q)

    names_for_prompt = list(library.names)
    total_masks = 0
    bar = _Progress(config.progress)
    try:
        with bar:
            task_v = bar.add("frames (segment + prompt)", len(frames))
            task_q = bar.add("VLM answers", 0)
            for frame in frames:
                view = frame["file_path"]
                image = load_image(root, view)
                masks = _masks_for(root, view, image, segmenter, seg_fp, config.prompt)
                result.masks += len(masks)
                total_masks += len(masks)
                bar.set_total(task_q, total_masks)
                for mask_id, mask in enumerate(masks):
                    if store.is_done(view, mask_id):
                        result.resumed_masks += 1
                        bar.advance(task_q)
                        continue
                    request = build_request(
                        view,
                        mask_id,
                        mask.level,
                        image,
                        mask.segmentation,
                        names_for_prompt,
                        library.env,
                        prompt_cfg,
                    )
                    hit = backend.lookup(request)
                    if hit is not None:
                        handle(request, hit)
                        bar.advance(task_q)
                        continue
                    if backend.replay:
                        try:
                            backend.query(request)  # raises ReplayMiss naming the request
                        except VLMError as err:
                            result.failed.append(str(err))
                            logger.warning("%s", err)
                        bar.advance(task_q)
                        continue
                    if not budget_left(config, paid_submitted, result.cost_usd):
                        result.skipped_budget += 1
                        bar.advance(task_q)
                        continue
                    paid_submitted += 1
                    in_flight[pool.submit(backend.query, request)] = request
                    drain(2 * config.max_concurrency)
                bar.advance(task_v)
            drain(0)
    finally:
        # let requests already sent finish (their answers land in the cache), drop the queued ones
        pool.shutdown(wait=True, cancel_futures=True)

    finish_run(root, frames, store, library, config, result, seg_fp, t0)
    if config.strict and result.failed:
        raise VLMError(f"{len(result.failed)} requests failed; first: {result.failed[0]}")
    return result


def _masks_for(
    root: Path, view: str, image: np.ndarray, segmenter: Segmenter | None, seg_fp: str, prompt: str
) -> list[Mask]:
    h, w = image.shape[:2]
    if prompt == "baseline":
        full = np.ones((h, w), bool)
        return [Mask(full, h * w, 1.0, 1.0, "whole")]
    from ..fusion.writer import frame_names

    path = root / MASK_DIR / f"{frame_names([view])[view]}__{_short_hash(view)}.npz"
    masks = load_masks(path, seg_fp)
    if masks is not None and (not masks or masks[0].segmentation.shape == (h, w)):
        return masks
    assert segmenter is not None
    masks = segmenter.segment(image)
    save_masks(path, masks, (h, w), seg_fp)
    return masks


def _short_hash(text: str) -> str:
    import hashlib

    return hashlib.sha256(text.encode()).hexdigest()[:8]


def mask_path(root: Path, view: str) -> Path:
    from ..fusion.writer import frame_names

    return Path(root) / MASK_DIR / f"{frame_names([view])[view]}__{_short_hash(view)}.npz"


def write_dataset_outputs(
    root: Path,
    frames: Sequence[dict],
    observations: Sequence[dict],
    library: MaterialLibrary,
    config: PerceptionConfig,
    result: PerceptionResult,
    seg_fp: str,
) -> None:
    """Fuse observations into materials.json and per-frame maps; update transforms.json."""
    from ..fusion.maps import fuse_view
    from ..fusion.properties import fuse_properties, legend_names
    from ..fusion.writer import (
        frame_names,
        legend_colors,
        materials_document,
        update_transforms,
        write_legend,
        write_materials_json,
        write_view_maps,
    )

    names = legend_names(observations, library, config.legend)
    post = fuse_properties(observations, library, names, config.prior)
    result.materials = names
    colors = [library[n].color for n in names]
    palette = legend_colors(colors)
    index = {n: i for i, n in enumerate(names)}
    by_view: dict[str, list[dict]] = {}
    for o in observations:
        by_view.setdefault(o["view"], []).append(o)
    out_names = frame_names([f["file_path"] for f in frames])
    paths: dict[str, tuple[str, str]] = {}
    for frame in frames:
        view = frame["file_path"]
        if config.prompt == "baseline":
            image = load_image(root, view)
            masks = _masks_for(root, view, image, None, seg_fp, "baseline")
        else:
            masks = load_masks(mask_path(root, view), seg_fp)
            if masks is None:
                continue  # never segmented (e.g. the run stopped before this frame)
            image = load_image(root, view)
        recs = [
            r for r in by_view.get(view, []) if r["material"] in index and 0 < float(r["confidence"]) <= 1
        ]
        stack = np.stack([m.segmentation for m in masks]) if masks else np.zeros((0,) + image.shape[:2], bool)
        maps = fuse_view(
            stack,
            [m.level for m in masks],
            [int(r["mask_id"]) for r in recs],
            [index[r["material"]] for r in recs],
            [float(r["confidence"]) for r in recs],
            len(names),
            config.fusion,
        )
        paths[view] = write_view_maps(root, out_names[view], maps, palette, image)
    source = {
        "backend": result.backend,
        "model": result.model,
        "segmenter": config.segmenter if config.prompt == "triplet" else "none (baseline prompt)",
        "prompt": config.prompt,
        "observations": len(observations),
    }
    doc = materials_document(
        post,
        library,
        result.simulated or any(o.get("simulated") for o in observations),
        config.fusion,
        source,
    )
    result.materials_json = write_materials_json(root, doc)
    write_legend(root, names, colors)
    if paths:
        update_transforms(root, paths)
    result.label_paths = {v: p[0] for v, p in paths.items()}
    result.confidence_paths = {v: p[1] for v, p in paths.items()}


def finish_run(
    root: Path,
    frames: Sequence[dict],
    store: ObservationStore,
    library: MaterialLibrary,
    config: PerceptionConfig,
    result: PerceptionResult,
    seg_fp: str,
    t0: float,
) -> None:
    """After the queries: count the stored observations into ``result``, fuse and write the dataset outputs
    (``config.write_outputs``), and write the run summary."""
    observations = store.observations()
    result.observations = len(observations)
    for o in observations:
        result.material_counts[o["material"]] = result.material_counts.get(o["material"], 0) + 1
    if config.write_outputs:
        write_dataset_outputs(root, frames, observations, library, config, result, seg_fp)
    result.seconds = time.time() - t0
    _write_run_summary(root, config, result)


def _write_run_summary(root: Path, config: PerceptionConfig, result: PerceptionResult) -> None:
    from ..fusion.writer import atomic_write_text

    summary = {
        "config": _jsonable(config),
        "result": {
            k: _jsonable(v) for k, v in asdict(result).items() if k not in ("label_paths", "confidence_paths")
        },
    }
    atomic_write_text(root / "perception" / "run.json", json.dumps(summary, indent=2, default=str))
