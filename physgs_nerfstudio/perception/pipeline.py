"""Perception pipeline: frames -> masks -> prompts -> (cached) VLM -> validation -> observation store ->
fusion -> material maps in the dataset. Reusable as ``run_perception(config) -> PerceptionResult``
(``physgs perceive``, ``physgs demo`` and single-image mode call it).

One :class:`PerceptionRun` is built per run (dataset, library, cached backend, segmenter, store, validator)
and answers batches of queries through its single dispatcher :meth:`PerceptionRun.ask` (cache lookup,
budget, submit to a pool of ``max_concurrency`` workers, failure); answers are validated and committed to
the store in the main thread as they complete. Which queries are asked, in which order, is the job of a
scheduler with a small explicit state (``initialize_state``, ``step_batch``, ``step_answer``,
``step_finish``): :class:`ExhaustiveScheduler` asks every mask of every frame in dataset order;
``active.ActiveScheduler`` the most informative ones. Masks are saved under ``perception/masks/`` and
reused, so mask ids stay stable across resumed runs. A killed or failed run can simply be run again: done
masks are skipped, and answers received before the kill are in the cache.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from ..fusion.writer import jsonable
from ..materials import PROPERTY_KEYS, MaterialLibrary, load_library
from .cache import ResponseCache
from .config import PerceptionConfig
from .prompts import SCHEMA_VERSION, PromptConfig, VLMRequest, build_request
from .segment import Mask, Segmenter, load_masks, save_masks
from .store import MaskDone, ObservationStore
from .validate import Candidate, Validator
from .vlm import CachedBackend, Usage, VLMError, VLMResponse

logger = logging.getLogger(__name__)

MASK_DIR = "perception/masks"

__all__ = ["PerceptionConfig", "PerceptionResult", "PerceptionRun", "ExhaustiveScheduler", "run_perception"]


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


def run_fingerprint(
    config: PerceptionConfig, segmenter_fp: str, backend: CachedBackend, library: MaterialLibrary
) -> str:
    prompt = jsonable(config.prompt_options)
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

    def advance(self, task, n: int = 1) -> None:
        if self._p is not None and task is not None and n:
            self._p.advance(task, n)

    def grow(self, task, n: int) -> None:
        """``n`` more steps in the task's total."""
        if self._p is not None and task is not None:
            total = next(t.total for t in self._p.tasks if t.id == task) or 0
            self._p.update(task, total=total + n)


# ---------------------------------------------------------------------------------------------------------
# the run
# ---------------------------------------------------------------------------------------------------------


def _short_hash(text: str) -> str:
    import hashlib

    return hashlib.sha256(text.encode()).hexdigest()[:8]


def mask_path(root: Path, view: str) -> Path:
    from ..fusion.writer import frame_names

    return Path(root) / MASK_DIR / f"{frame_names([view])[view]}__{_short_hash(view)}.npz"


def whole_image_mask(h: int, w: int) -> Mask:
    """The one mask of the baseline prompt."""
    return Mask(np.ones((h, w), bool), h * w, 1.0, 1.0, "whole")


@dataclass
class Query:
    """One question: the (view, mask) it is about and its prompt."""

    view: str
    mask_id: int
    request: VLMRequest


Outcome = tuple[Query, "list[dict] | None"]
"""A query and its committed observation records (possibly none), or None when it got no answer (the
request failed, replay had no cached answer, or the budget was spent)."""


class Scheduler(Protocol):
    """Which queries a :class:`PerceptionRun` asks, in which order (cf. gsplat's strategies)."""

    def initialize_state(self, run: PerceptionRun) -> dict[str, Any]: ...

    def step_batch(self, run: PerceptionRun, state: dict[str, Any]) -> list[Query]:
        """The next batch; an empty one ends the run."""
        ...

    def step_answer(self, run: PerceptionRun, state: dict[str, Any], outcome: Outcome) -> None: ...

    def step_finish(self, run: PerceptionRun, state: dict[str, Any]) -> None: ...


class PerceptionRun:
    """Everything one perception run needs, built once from its config (module docstring).

    ``backend`` (a cache-wrapped backend, e.g. :class:`~.vlm.CachedBackend`), ``segmenter`` and ``library``
    override what the config would build (tests, demos); ``on_commit`` is called after each mask is recorded
    (progress hooks; an exception stops the run, which a later run resumes).
    """

    def __init__(
        self,
        config: PerceptionConfig,
        *,
        backend: CachedBackend | None = None,
        segmenter: Segmenter | None = None,
        library: MaterialLibrary | None = None,
        on_commit: Callable[[MaskDone], None] | None = None,
        result_type: type[PerceptionResult] | None = None,
    ):
        self.t0 = time.time()
        self.config = config
        self.root = root = Path(config.data)
        self.frames = select_views(load_frames(root)[1], config.max_views)
        self.views = [f["file_path"] for f in self.frames]
        self.library = library or load_library(config.env, extra_files=config.library_files)
        if backend is None:
            cache = ResponseCache(config.cache_dir or root / "perception" / "cache")
            backend = CachedBackend(config.vlm.setup(root, self.library), cache)
        self.backend = backend
        self.segmenter = None
        self.seg_fp = "baseline:full-image"
        if config.prompt != "baseline":
            self.segmenter = segmenter or config.segmenter.setup()
            self.seg_fp = self.segmenter.fingerprint()
        fingerprint = run_fingerprint(config, self.seg_fp, backend, self.library)
        self.store = ObservationStore(root, fingerprint, overwrite=config.overwrite)
        self.validator = Validator(self.library, config.validation)
        self.prompt_cfg = PromptConfig(**{**asdict(config.prompt_options), "kind": config.prompt})
        self.result = (result_type or PerceptionResult)(
            root, list(self.views), simulated=backend.simulated, backend=backend.name, model=backend.model
        )
        self.on_commit = on_commit
        self.paid = 0
        """Uncached requests sent in this run."""
        self.pool: ThreadPoolExecutor | None = None
        self.bar = _Progress(config.progress)
        self._task = None

    # -- pieces -----------------------------------------------------------------------------------------
    def masks(self, view: str, image: np.ndarray) -> list[Mask]:
        """The view's masks: the saved ones when they match the segmenter, else segmented now and saved."""
        h, w = image.shape[:2]
        if self.segmenter is None:
            return [whole_image_mask(h, w)]
        path = mask_path(self.root, view)
        masks = load_masks(path, self.seg_fp)
        if masks is not None and (not masks or masks[0].segmentation.shape == (h, w)):
            return masks
        masks = self.segmenter.segment(image)
        save_masks(path, masks, (h, w), self.seg_fp)
        return masks

    def query(self, view: str, mask_id: int, mask: Mask, image: np.ndarray) -> Query:
        request = build_request(
            view, mask_id, mask.level, image, mask.segmentation, list(self.library.names), self.library.env,
            self.prompt_cfg,
        )  # fmt: skip
        return Query(view, mask_id, request)

    def add_to_progress(self, queries: int, resumed: int = 0) -> None:
        """Tell the progress bar about ``queries`` more masks, ``resumed`` of them already done."""
        self.bar.grow(self._task, queries)
        self.bar.advance(self._task, resumed)

    def budget_left(self) -> bool:
        return budget_left(self.config, self.paid, self.result.cost_usd)

    # -- the dispatcher ---------------------------------------------------------------------------------
    def ask(self, batch: Sequence[Query]) -> list[Outcome]:
        """Answer a batch: from the cache where possible, else (budget allowing) by the backend, concurrently;
        every answer is validated and committed in this thread. A query the backend fails on (a replay miss
        included) is recorded in ``result.failed``; one over the budget in ``result.skipped_budget``."""
        assert self.pool is not None, "PerceptionRun.ask runs inside PerceptionRun.run"
        outcomes: list[Outcome] = []
        in_flight: dict[Future, Query] = {}
        for q in batch:
            hit = self.backend.lookup(q.request)
            if hit is not None:
                outcomes.append((q, self._commit(q, hit)))
            elif not self.budget_left():
                self.result.skipped_budget += 1
                outcomes.append((q, None))
            else:
                self.paid += 1
                in_flight[self.pool.submit(self.backend.query, q.request)] = q
        for fut in as_completed(in_flight):
            q = in_flight[fut]
            try:
                response = fut.result()
            except Exception as err:  # noqa: BLE001  (a failed query must not lose the other answers)
                msg = failure_message(q.request, err)
                self.result.failed.append(msg)
                logger.warning("%s", msg)
                outcomes.append((q, None))
                continue
            outcomes.append((q, self._commit(q, response)))
        self.bar.advance(self._task, len(batch))
        return outcomes

    def _commit(self, q: Query, response: VLMResponse) -> list[dict]:
        """Account one answer in ``result``, validate it and commit its records to the store."""
        result = self.result
        if response.cached:
            result.cache_hits += 1
        else:
            result.calls += 1
            u, r = result.usage, response.usage
            result.usage = Usage(u.prompt_tokens + r.prompt_tokens, u.completion_tokens + r.completion_tokens,
                                 u.total_tokens + r.total_tokens)  # fmt: skip
            result.cost_usd += float(self.backend.cost_usd(r))
        checked = self.validator(response.text, context=q.request.describe())
        result.reasons += len(checked.reasons)
        result.dropped_candidates += sum("dropped" in r for r in checked.reasons)
        records = observation_records(q.request, checked.candidates, self.backend, response)
        done = MaskDone(q.view, q.mask_id, q.request.level, len(records), checked.reasons, response.cached,
                        response.usage.to_dict())  # fmt: skip
        self.store.commit(done, records)
        result.new_observations += len(records)
        if self.on_commit is not None:
            self.on_commit(done)
        return records

    # -- the loop ---------------------------------------------------------------------------------------
    def run(self, scheduler: Scheduler) -> PerceptionResult:
        """Ask the scheduler's batches until it gives none, then fuse and write the outputs."""
        self.pool = ThreadPoolExecutor(max_workers=self.config.max_concurrency, thread_name_prefix="physgs-vlm")
        try:
            with self.bar:
                self._task = self.bar.add("VLM answers", 0)
                state = scheduler.initialize_state(self)
                while batch := scheduler.step_batch(self, state):
                    for outcome in self.ask(batch):
                        scheduler.step_answer(self, state, outcome)
        finally:
            # let requests already sent finish (their answers land in the cache), drop the queued ones
            self.pool.shutdown(wait=True, cancel_futures=True)
        self.finish()
        scheduler.step_finish(self, state)
        if self.config.strict and self.result.failed:
            raise VLMError(f"{len(self.result.failed)} requests failed; first: {self.result.failed[0]}")
        return self.result

    def view_masks(self, view: str) -> tuple[np.ndarray, np.ndarray, list[str]] | None:
        """For fusion: the view's image, mask stack and levels (None if it was never segmented)."""
        if self.segmenter is None:
            image = load_image(self.root, view)
            masks = [whole_image_mask(*image.shape[:2])]
        else:
            masks = load_masks(mask_path(self.root, view), self.seg_fp)
            if masks is None:
                return None
            image = load_image(self.root, view)
        stack = np.stack([m.segmentation for m in masks]) if masks else np.zeros((0,) + image.shape[:2], bool)
        return image, stack, [m.level for m in masks]

    def finish(self) -> None:
        """Count the stored observations into ``result``, fuse and write the dataset outputs
        (``config.write_outputs``), and write the run summary."""
        from ..fusion.dataset import write_dataset_outputs

        config, result = self.config, self.result
        observations = self.store.observations()
        result.observations = len(observations)
        for o in observations:
            result.material_counts[o["material"]] = result.material_counts.get(o["material"], 0) + 1
        if config.write_outputs:
            segmenter = config.segmenter.name if self.segmenter is not None else "none (baseline prompt)"
            source = {"backend": result.backend, "model": result.model, "segmenter": segmenter,
                      "prompt": config.prompt}  # fmt: skip
            out = write_dataset_outputs(
                self.root, self.views, observations, self.library, self.view_masks, legend=config.legend,
                fusion=config.fusion, prior=config.prior, source=source, simulated=result.simulated,
            )  # fmt: skip
            result.materials, result.materials_json = out.materials, out.materials_json
            result.label_paths, result.confidence_paths = out.label_paths, out.confidence_paths
        result.seconds = time.time() - self.t0
        _write_run_summary(self.root, config, result)


class ExhaustiveScheduler:
    """Every mask of every frame, frame by frame in dataset order (one batch per frame)."""

    def initialize_state(self, run: PerceptionRun) -> dict[str, Any]:
        return {"next_view": 0}

    def step_batch(self, run: PerceptionRun, state: dict[str, Any]) -> list[Query]:
        while state["next_view"] < len(run.views):
            view = run.views[state["next_view"]]
            state["next_view"] += 1
            image = load_image(run.root, view)
            masks = run.masks(view, image)
            run.result.masks += len(masks)
            batch = [run.query(view, i, m, image) for i, m in enumerate(masks) if not run.store.is_done(view, i)]
            run.result.resumed_masks += len(masks) - len(batch)
            run.add_to_progress(len(masks), resumed=len(masks) - len(batch))
            if batch:
                return batch
        return []

    def step_answer(self, run: PerceptionRun, state: dict[str, Any], outcome: Outcome) -> None:
        pass

    def step_finish(self, run: PerceptionRun, state: dict[str, Any]) -> None:
        pass


def run_perception(
    config: PerceptionConfig,
    *,
    backend: CachedBackend | None = None,
    segmenter: Segmenter | None = None,
    library: MaterialLibrary | None = None,
    on_commit: Callable[[MaskDone], None] | None = None,
) -> PerceptionResult:
    """Run perception on every mask of ``config.data`` and (unless ``write_outputs=False``) fuse and write
    the outputs (:class:`PerceptionRun` documents the overrides)."""
    run = PerceptionRun(config, backend=backend, segmenter=segmenter, library=library, on_commit=on_commit)
    return run.run(ExhaustiveScheduler())


def _write_run_summary(root: Path, config: PerceptionConfig, result: PerceptionResult) -> None:
    from ..fusion.writer import atomic_write_text

    summary = {
        "config": jsonable(config),
        "result": {
            k: jsonable(v) for k, v in asdict(result).items() if k not in ("label_paths", "confidence_paths")
        },
    }
    atomic_write_text(root / "perception" / "run.json", json.dumps(summary, indent=2, default=str))
