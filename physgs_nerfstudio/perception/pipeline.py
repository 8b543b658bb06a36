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

import errno
import json
import logging
import math
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from ..errors import DatasetError, PhysGSError
from ..fusion.transaction import WriteFailed
from ..fusion.transaction import recover as recover_dataset
from ..fusion.writer import jsonable
from ..materials import PROPERTY_KEYS, MaterialLibrary, load_library
from ..urls import redact_urls
from .cache import ResponseCache
from .config import PerceptionConfig
from .images import BadFrame, read_image
from .lock import DatasetLock
from .prompts import SCHEMA_VERSION, PromptConfig, VLMRequest, build_request
from .segment import Mask, Segmenter, load_masks, save_masks
from .store import MaskDone, ObservationStore
from .validate import Candidate, Validator
from .vlm import CachedBackend, Usage, VLMAuthError, VLMError, VLMResponse

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
    skipped_frames: list[str] = field(default_factory=list)
    """One line per frame left out because its image could not be read."""
    segmented_views: set[str] = field(default_factory=set)
    """Views the segmenter's masks were made or read for in this run."""
    views_without_object: set[str] = field(default_factory=set)
    """... of them, those without a ``whole``-level mask (no object found: :func:`no_object_message`)."""


def no_object_message(result: PerceptionResult, segmenter: str) -> str:
    """One line: in how many views the segmenter found no whole object, why that matters and what to try."""
    hint = (' (too little contrast against its support or background for the built-in segmenter: try SAM weights, '
            'pip install -e ".[sam]" and segmenter:sam --segmenter.checkpoint PATH)' if segmenter == "builtin" else "")
    return (f"the {segmenter} segmenter found no whole-object mask in {len(result.views_without_object)} of "
            f"{len(result.segmented_views)} views{hint}; the object's geometry is carved from those masks, so "
            "those views cannot place it")


class NoObservations(PhysGSError, RuntimeError):
    """The run ended without a single observation: nothing was written into the dataset."""


def usable_observations(observations: list[dict], path: Path) -> list[dict]:
    """The records fusion can use: a material name and a confidence in (0, 1]. Others (a hand-edited
    ``observations.jsonl`` with NaN confidences) are left out with one warning; when records exist and none is
    usable, :class:`NoObservations`: fusing nothing would replace a good materials.json with an empty legend."""
    import math

    def usable(o: dict) -> bool:
        try:
            p = float(o.get("confidence"))
        except (TypeError, ValueError):
            return False
        return isinstance(o.get("material"), str) and math.isfinite(p) and 0.0 < p <= 1.0

    kept = [o for o in observations if usable(o)]
    if len(kept) < len(observations):
        if not kept:
            raise NoObservations(f"{path}: none of its {len(observations)} observations is usable (each needs a "
                                 "material and a confidence in (0, 1]; NaN is not): the dataset's outputs are left "
                                 "as they were. Restore the file, or rerun with --overwrite to ask again.")  # fmt: skip
        logger.warning("%s: %d of %d observations left out (no material, or a confidence not in (0, 1])", path,
                       len(observations) - len(kept), len(observations))  # fmt: skip
    return kept


# ---------------------------------------------------------------------------------------------------------
# pieces
# ---------------------------------------------------------------------------------------------------------


def load_frames(root: Path) -> tuple[dict, list[dict]]:
    """transforms.json and its frames with a ``file_path``; :class:`DatasetError` naming the file when it
    is missing, not JSON, not an object or without frames."""
    path = Path(root) / "transforms.json"
    if not path.is_file():
        raise DatasetError(f"{path} not found: --data must be a nerfstudio dataset directory")
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as err:
        raise DatasetError(f"{path} is not UTF-8 text ({err.reason} at byte {err.start}); "
                           "write it as UTF-8 JSON") from None  # fmt: skip
    except json.JSONDecodeError as err:
        raise DatasetError(f"{path} is not valid JSON ({err.msg}, line {err.lineno} column {err.colno}); "
                           "fix the file or regenerate it (ns-process-data)") from None  # fmt: skip
    except RecursionError:
        raise DatasetError(f"{path} is nested too deeply to read (lists or objects inside each other thousands of "
                           "levels deep); fix the file or regenerate it (ns-process-data)") from None  # fmt: skip
    if not isinstance(meta, dict):
        raise DatasetError(f"{path} holds a JSON {type(meta).__name__}, not an object; nerfstudio expects "
                           '{"frames": [{"file_path": ...}, ...], ...}')  # fmt: skip
    raw = meta.get("frames")
    if not isinstance(raw, list):
        raise DatasetError(f"{path} has no 'frames' list; nerfstudio expects one entry per image")
    frames = [f for f in raw if isinstance(f, dict) and isinstance(f.get("file_path"), str) and f["file_path"]]
    if not frames:
        raise DatasetError(f"{path} lists no frames with a file_path")
    if len(frames) < len(raw):
        logger.warning("%s: %d frame entries without a file_path ignored", path, len(raw) - len(frames))
    return meta, frames


def check_frame_paths(root: Path, frames: Sequence[dict], allow_outside: bool = False) -> None:
    """Refuse frames whose image lies outside the dataset (``../x.png``, an absolute path, a symlink out of
    it): a downloaded dataset could otherwise make a run upload any image on this disk to the VLM."""
    if allow_outside:
        return
    base = os.path.realpath(root)
    outside = []
    for f in frames:
        target = os.path.realpath(os.path.join(base, f["file_path"]))
        if os.path.commonpath([base, target]) != base:
            outside.append(f"{f['file_path']!r} -> {target}")
    if outside:
        more = f" and {len(outside) - 3} more" if len(outside) > 3 else ""
        raise DatasetError(
            f"{Path(root) / 'transforms.json'}: {len(outside)} frame(s) point outside the dataset "
            f"({'; '.join(outside[:3])}{more}); their images would be read and sent to the VLM. Move them into "
            "the dataset, or pass --allow-outside-paths if that is intended."
        )


def select_views(frames: Sequence[dict], max_views: int | None) -> list[dict]:
    """Evenly spaced subset (first and last included) of at most max_views frames, in dataset order."""
    if max_views is None or max_views >= len(frames):
        return list(frames)
    if max_views <= 0:
        return []
    idx = np.unique(np.round(np.linspace(0, len(frames) - 1, max_views)).astype(int))
    return [frames[i] for i in idx]


def load_image(root: Path, file_path: str) -> np.ndarray:
    """A frame's image as uint8 RGB (16-bit and float images scaled, images.py); :class:`BadFrame` when it
    cannot be read."""
    return read_image(Path(root) / file_path, file_path)


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
    request: VLMRequest, candidates: Sequence[Candidate], backend: CachedBackend, response: VLMResponse,
    object_name: str | None = None,
) -> list[dict]:
    """observations.jsonl records (docs/architecture.md) of one answered mask; ``object_name``: the whole object
    the answer says the part belongs to (the same in each of its candidates' records; None: not said)."""
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
                "object": object_name,
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
        check_frame_paths(root, self.frames, config.allow_outside_paths)
        recover_dataset(root)  # finish (or drop) a dataset update a killed run left behind
        self.views = [f["file_path"] for f in self.frames]
        self.bad_views: set[str] = set()
        self.library = library or load_library(config.env, extra_files=config.library_files)
        if backend is None:
            cache = ResponseCache(config.cache_dir or root / "perception" / "cache")
            backend = CachedBackend(config.vlm.setup(root, self.library), cache, config.validation.max_text_chars)
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
    def frame_image(self, view: str) -> np.ndarray | None:
        """The view's image; None for a frame that cannot be read, which is skipped with a warning and
        reported at the end (``config.strict``: raised)."""
        try:
            return load_image(self.root, view)
        except BadFrame as err:
            if self.config.strict:
                raise
            if view not in self.bad_views:
                self.bad_views.add(view)
                self.result.skipped_frames.append(str(err))
                logger.warning("skipping a frame: %s", err)
            return None

    def masks(self, view: str, image: np.ndarray) -> list[Mask]:
        """The view's masks: the saved ones when they match the segmenter, else segmented now and saved."""
        h, w = image.shape[:2]
        if self.segmenter is None:
            return [whole_image_mask(h, w)]
        path = mask_path(self.root, view)
        masks = load_masks(path, self.seg_fp)
        if masks is None or (masks and masks[0].segmentation.shape != (h, w)):
            masks = self.segmenter.segment(image)
            save_masks(path, masks, (h, w), self.seg_fp)
        self.result.segmented_views.add(view)
        if not any(m.level == "whole" for m in masks):
            self.result.views_without_object.add(view)
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
            except VLMAuthError as err:  # every further request would be refused too: stop the run
                raise VLMAuthError(f"{err} The dataset was not changed; answers received so far are cached.") from None
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
        records = observation_records(q.request, checked.candidates, self.backend, response, checked.object)
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
        except OSError as err:
            if err.errno not in (errno.ENOSPC, errno.EDQUOT):
                raise
            raise WriteFailed(f"the disk is full ({err.filename or self.root}); free some space and run again: "
                              "what was recorded is kept and resumed") from None  # fmt: skip
        finally:
            # let requests already sent finish (their answers land in the cache), drop the queued ones
            self.pool.shutdown(wait=True, cancel_futures=True)
        self.finish()
        scheduler.step_finish(self, state)
        if self.config.strict and self.result.failed:
            raise VLMError(f"{len(self.result.failed)} requests failed; first: {self.result.failed[0]}")
        return self.result

    def view_masks(self, view: str) -> tuple[np.ndarray, np.ndarray, list[str]] | None:
        """For fusion: the view's image, mask stack and levels (None if it was never segmented or its image
        cannot be read)."""
        if view in self.bad_views:
            return None
        masks = None
        if self.segmenter is not None:
            masks = load_masks(mask_path(self.root, view), self.seg_fp)
            if masks is None:
                return None
        image = self.frame_image(view)
        if image is None:
            return None
        if masks is None:
            masks = [whole_image_mask(*image.shape[:2])]
        stack = np.stack([m.segmentation for m in masks]) if masks else np.zeros((0,) + image.shape[:2], bool)
        return image, stack, [m.level for m in masks]

    def finish(self) -> None:
        """Count the stored observations into ``result``, fuse and write the dataset outputs
        (``config.write_outputs``), and write the run summary."""
        from ..fusion.dataset import write_dataset_outputs

        config, result = self.config, self.result
        observations = usable_observations(self.store.observations(), self.store.obs_path)
        result.observations = len(observations)
        for o in observations:
            result.material_counts[o["material"]] = result.material_counts.get(o["material"], 0) + 1
        if config.write_outputs and not observations:
            asked = (result.failed or result.calls or result.cache_hits or result.resumed_masks or result.skipped_frames
                     or not result.masks)
            if asked:  # questions were asked (or could not be) and nothing came of them: a failed run
                raise NoObservations(no_observations_message(result))
            logger.warning("no mask was asked in this run (budget or stop rule): the dataset outputs are not written")
        if config.write_outputs and observations:
            segmenter = config.segmenter.name if self.segmenter is not None else "none (baseline prompt)"
            source = {"backend": result.backend, "model": result.model, "segmenter": segmenter,
                      "prompt": config.prompt}  # fmt: skip
            out = write_dataset_outputs(
                self.root, self.views, observations, self.library, self.view_masks, legend=config.legend,
                fusion=config.fusion, prior=config.prior, source=source, simulated=result.simulated,
            )  # fmt: skip
            result.materials, result.materials_json = out.materials, out.materials_json
            result.label_paths, result.confidence_paths = out.label_paths, out.confidence_paths
        if result.views_without_object:
            logger.warning(no_object_message(result, config.segmenter.name))
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
            image = run.frame_image(view)
            if image is None:
                continue
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
    with DatasetLock(config.data, wait=config.wait_for_lock):
        run = PerceptionRun(config, backend=backend, segmenter=segmenter, library=library, on_commit=on_commit)
        return run.run(ExhaustiveScheduler())


def no_observations_message(result: PerceptionResult) -> str:
    """Why a run ended without observations, and what to do."""
    why = []
    if result.failed:
        why.append(f"{len(result.failed)} request(s) failed (first: {result.failed[0]})")
    if result.skipped_frames:
        why.append(f"{len(result.skipped_frames)} frame(s) could not be read (first: {result.skipped_frames[0]})")
    if result.skipped_budget:
        why.append(f"{result.skipped_budget} mask(s) left out by --budget / --max-calls")
    if result.reasons:
        why.append(f"validation dropped every answer ({result.reasons} notes in perception/progress.jsonl)")
    if not result.masks and not result.skipped_frames:
        why.append("no mask was found")
    return (
        f"no observations for {result.data}: {'; '.join(why) or 'no answer arrived'}. materials.json, "
        "transforms.json and the material maps were not changed; fix the cause and run again (answers already "
        "received are cached)."
    )


def _write_run_summary(root: Path, config: PerceptionConfig, result: PerceptionResult) -> None:
    from ..fusion.writer import atomic_write_text

    summary = {
        "config": jsonable(config),
        "result": {
            k: jsonable(sorted(v) if isinstance(v, set) else v)
            for k, v in asdict(result).items() if k not in ("label_paths", "confidence_paths")
        },
    }
    text = redact_urls(json.dumps(summary, indent=2, default=str))  # no user:password@ of a --vlm.base-url
    try:
        atomic_write_text(root / "perception" / "run.json", text)
    except OSError as err:  # the dataset outputs are written; the summary is only a record
        logger.warning("could not write %s: %s", root / "perception" / "run.json", err)
