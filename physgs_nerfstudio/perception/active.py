"""Active querying: spend a VLM query budget on the (view, mask) pairs whose answers are expected to tell the
most, instead of asking about every mask of every view.

Every candidate query (a mask not yet answered) gets an acquisition score from the current beliefs:

    score(m) = w_material * H[pi_m] / log K                       material uncertainty under the mask
             + w_property * sum_k pi_mk * mean_p r_kp              property uncertainty of its likely materials
             + exploration * [no mask of m's view answered yet]

* ``pi_m``: the predictive material distribution of the mask: the per-pixel Dirichlet of its view
  (alpha = alpha0 + lambda * evidence, evidence = sum over the view's answered masks of level weight x
  confidence, exactly as ``fusion.maps.fuse_view``), averaged over the mask's pixels, plus (``transfer`` > 0)
  evidence carried over from answered masks of OTHER views with a similar appearance (Gaussian kernel on the
  masks' mean CIE-Lab colour, bandwidth ``transfer_bandwidth``): the only cross-view link available before
  any 3D reconstruction exists. ``H[pi_m]`` is the per-pixel entropy averaged over the mask (the transferred
  evidence added to every pixel), normalised by log K. Masks over pixels that are already confidently
  labelled score low.
* ``r_kp = epi_kp / (epi_kp + tol_kp^2)`` in [0, 1): the NIG epistemic variance Var[mu] of material k and
  property p against a tolerance (``property_tolerance``: relative, i.e. that many log units for log-space
  properties and that fraction of the library's typical value otherwise): ~1 while the material's mean is
  uncertain beyond the tolerance, -> 0 once it is pinned down. For the properties in ``property_keys``
  (default density, the one that drives mass); the per-material posteriors are updated in closed form from
  merged ``Moments``. (Relative to the prior's own epistemic variance would be unbounded: a narrow library
  range with noisy answers makes the posterior Var[mu] exceed the prior's.)
* the exploration bonus favours views nobody has looked at yet.

Queries are chosen greedily in batches of ``batch_size`` (a batch is sent concurrently); within a batch,
after a mask is picked the scores of masks like it (same view: overlapping pixels; other views: similar
appearance) are damped by ``diversity`` so one batch does not ask the same question twice. After each batch
the beliefs are updated and the scores recomputed. The run stops when ``budget`` answered masks are reached
(counting those of earlier runs: the store is shared with ``run_perception`` and resumable), when no
candidate is left, or when the largest score without the exploration term falls below ``stop_uncertainty``.

``ActiveSelector`` is the policy alone (no I/O, used by the benchmark); ``ActiveScheduler`` makes it the
scheduler of a :class:`~.pipeline.PerceptionRun` (``run_active_perception``), so the backends, cache,
observation store and dataset outputs are those of the exhaustive run, openai / replay / simulated all work
and observations.jsonl has the same format.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..bayes import NIG, Moments, nig_posterior
from ..fusion.maps import MapFusionConfig
from ..fusion.properties import property_row
from ..materials import PROPERTY_KEYS, MaterialLibrary, PriorConfig, log_space_flags
from .config import PerceptionConfig
from .lock import DatasetLock
from .pipeline import Outcome, PerceptionResult, PerceptionRun, Query, load_image

logger = logging.getLogger(__name__)

ACTIVE_LOG = "perception/active.json"


@dataclass
class ActiveConfig:
    """Active query selection (module docstring)."""

    budget: int | None = None
    """Stop once this many masks are answered in total (earlier runs included); None: no query limit."""
    stop_uncertainty: float | None = None
    """Stop when the best remaining score without the exploration term is below this (scores lie in
    [0, w_material + w_property]); None: never stop early."""
    batch_size: int = 8
    """Queries chosen per round (sent concurrently, then the beliefs are updated)."""
    w_material: float = 1.0
    w_property: float = 1.0
    exploration: float = 0.25
    """Bonus for masks of views without any answered mask."""
    transfer: float = 0.5
    """Weight of evidence carried over from similar-looking answered masks of other views (0: off)."""
    transfer_bandwidth: float = 10.0
    """Appearance kernel bandwidth, CIE-Lab Delta E of the masks' mean colours."""
    diversity: float = 0.7
    """Within a batch, damp the scores of masks similar to one already picked by this factor (0..1)."""
    property_keys: tuple[str, ...] = ("density",)
    """Properties whose epistemic variance enters the score."""
    property_tolerance: float = 0.05
    """Relative precision at which a material's property mean counts as known (see r_kp above)."""
    alpha0: float | None = None
    """Dirichlet prior per material for scoring; None: 1 / K (total prior mass 1: with a unit prior per
    material of a large library, a handful of answers would barely move the entropy)."""
    score_size: int = 128
    """Masks are downsampled to this long side for scoring (does not affect the queries)."""

    def __post_init__(self) -> None:
        if self.budget is not None and self.budget < 0:
            raise ValueError("ActiveConfig.budget must be >= 0")
        if self.batch_size < 1:
            raise ValueError("ActiveConfig.batch_size must be >= 1")
        if not 0 <= self.diversity <= 1:
            raise ValueError("ActiveConfig.diversity must lie in [0, 1]")
        unknown = set(self.property_keys) - set(PROPERTY_KEYS)
        if unknown:
            raise ValueError(
                f"ActiveConfig.property_keys: unknown keys {sorted(unknown)}; known {list(PROPERTY_KEYS)}"
            )


def _downsample(mask: np.ndarray, size: int) -> np.ndarray:
    h, w = mask.shape
    step = max(1, math.ceil(max(h, w) / size))
    if step == 1:
        return mask
    small = mask[step // 2 :: step, step // 2 :: step]
    if not small.any() and mask.any():  # tiny mask: keep one pixel
        ys, xs = np.nonzero(mask)
        small = np.zeros_like(small)
        small[min(ys[0] // step, small.shape[0] - 1), min(xs[0] // step, small.shape[1] - 1)] = True
    return small


def mask_features(image: np.ndarray, masks: Sequence[np.ndarray]) -> np.ndarray:
    """[M, 3] mean CIE-Lab colour of each mask (uint8 RGB image)."""
    from skimage.color import rgb2lab

    lab = rgb2lab(np.asarray(image, dtype=np.uint8)).reshape(-1, 3)
    out = np.zeros((len(masks), 3))
    for i, m in enumerate(masks):
        sel = np.asarray(m, bool).reshape(-1)
        if sel.any():
            out[i] = lab[sel].mean(0)
    return out


class ActiveSelector:
    """The query policy (module docstring), independent of any backend or file.

    Args:
        views: view names in dataset order.
        masks: per view, bool [M, H, W] (full resolution; downsampled internally).
        levels: per view, the level of each mask.
        features: per view, [M, F] appearance features (e.g. :func:`mask_features`).
        library: material library (its names are the K classes).
    """

    def __init__(
        self,
        views: Sequence[str],
        masks: dict[str, np.ndarray],
        levels: dict[str, Sequence[str]],
        features: dict[str, np.ndarray],
        library: MaterialLibrary,
        config: ActiveConfig | None = None,
        fusion: MapFusionConfig | None = None,
        prior: PriorConfig | None = None,
    ):
        self.cfg = cfg = config or ActiveConfig()
        self.fusion = fusion or MapFusionConfig()
        self.library = library
        self.names = list(library.names)
        self.index = {n: i for i, n in enumerate(self.names)}
        K = self.K = len(self.names)
        self.alpha0 = cfg.alpha0 if cfg.alpha0 is not None else 1.0 / K
        self.lam = self.fusion.lam
        self.views = list(views)
        # candidates
        self.cand: list[tuple[str, int]] = []
        self._view_of: list[int] = []
        feats, self._stacks, self._area, self._level_w, self._cand_index = [], {}, {}, {}, {}
        for vi, view in enumerate(self.views):
            stack = np.asarray(masks.get(view, np.zeros((0, 1, 1), bool)), bool)
            small = (
                np.stack([_downsample(m, cfg.score_size) for m in stack])
                if len(stack)
                else np.zeros((0, 1, 1), bool)
            )
            flat = torch.from_numpy(small.reshape(len(small), -1).astype(np.float32))
            self._stacks[view] = flat
            self._area[view] = flat.sum(1).clamp_min(1)
            lv = list(levels.get(view, []))
            self._level_w[view] = np.array([self.fusion.level_weights.get(x, 1.0) for x in lv], np.float64)
            f = np.asarray(features.get(view, np.zeros((len(stack), 3))), np.float64).reshape(len(stack), -1)
            for mi in range(len(stack)):
                self._cand_index[(view, mi)] = len(self.cand)
                self.cand.append((view, mi))
                self._view_of.append(vi)
                feats.append(f[mi])
        N = len(self.cand)
        self._view_of_arr = np.asarray(self._view_of, np.int64)
        self.features = np.stack(feats) if feats else np.zeros((0, 3))
        if N:
            d2 = ((self.features[:, None, :] - self.features[None, :, :]) ** 2).sum(-1)
            self._kernel = np.exp(-d2 / (2 * cfg.transfer_bandwidth**2))
        else:
            self._kernel = np.zeros((0, 0))
        self.done = np.zeros(N, bool)
        self.failed = np.zeros(N, bool)
        self.mask_evidence = np.zeros((N, K))  # level weight x sum p onehot, of answered masks
        self._view_has = np.zeros(len(self.views), bool)
        # properties
        self.prior_cfg = prior or PriorConfig()
        flags = log_space_flags(self.prior_cfg)
        self._log = flags
        self.prior: NIG = library.nig_prior(self.names, self.prior_cfg)
        self.moments = Moments.zeros((K, len(PROPERTY_KEYS)), dtype=torch.float64)
        self._pidx = [PROPERTY_KEYS.index(k) for k in cfg.property_keys]
        tol = np.empty((K, len(self._pidx)))
        for j, p in enumerate(self._pidx):
            if self._log[p]:
                tol[:, j] = cfg.property_tolerance
            else:
                typical = np.array([library[n].properties[PROPERTY_KEYS[p]].typical for n in self.names])
                tol[:, j] = cfg.property_tolerance * np.maximum(np.abs(typical), 1e-12)
        self._tol2 = tol**2
        self._ratio = self._property_ratio(self.prior)
        self.history: list[dict] = []

    # -- updates -------------------------------------------------------------------------------------
    def observe(self, view: str, mask_id: int, records: Sequence[dict]) -> None:
        """Record the answer (observation records, possibly none) of one (view, mask)."""
        i = self._cand_index.get((view, int(mask_id)))
        if i is None:
            logger.debug("active: ignoring an answer for unknown mask %s/%s", view, mask_id)
            return
        self.done[i] = True
        self._view_has[self._view_of[i]] = True
        lw = self._level_w[view][int(mask_id)]
        cls, conf, vals = [], [], []
        for r in records:
            k = self.index.get(r.get("material"))
            try:
                p = float(r.get("confidence"))
            except (TypeError, ValueError):
                continue
            if k is None or not (0 < p <= 1) or not math.isfinite(p):
                continue
            self.mask_evidence[i, k] += lw * p
            cls.append(k)
            conf.append(p)
            vals.append(property_row(r.get("properties") or {}, self._log))
        if cls:
            m = Moments.from_observations(
                torch.as_tensor(cls),
                torch.as_tensor(conf, dtype=torch.float64),
                torch.as_tensor(vals, dtype=torch.float64),
                self.K,
            )
            self.moments = self.moments.merge(m)
            self._ratio = self._property_ratio(nig_posterior(self.prior, self.moments))

    def _property_ratio(self, nig: NIG) -> np.ndarray:
        epi = nig.epistemic()[:, self._pidx].numpy()
        return (epi / (epi + self._tol2)).mean(1)

    def mark_failed(self, view: str, mask_id: int) -> None:
        """Exclude a candidate whose query failed (not retried in this run)."""
        i = self._cand_index.get((view, int(mask_id)))
        if i is not None:
            self.failed[i] = True

    # -- scoring ---------------------------------------------------------------------------------------
    def _predictive(self) -> tuple[np.ndarray, np.ndarray]:
        """[N, K] mean pixel predictive and [N] mean pixel entropy (normalised) of every candidate."""
        N, K = len(self.cand), self.K
        pi = np.zeros((N, K))
        H = np.zeros(N)
        # carried-over evidence from answered masks of other views
        trans = np.zeros((N, K))
        if self.cfg.transfer > 0 and self.done.any():
            kd = self._kernel[:, self.done].copy()
            same = self._view_of_arr[:, None] == self._view_of_arr[None, self.done]
            kd[same] = 0.0
            trans = self.cfg.transfer * (kd @ self.mask_evidence[self.done])
        logK = math.log(K) if K > 1 else 1.0
        for view in self.views:
            flat = self._stacks[view]
            if flat.shape[0] == 0:
                continue
            idx = np.asarray([self._cand_index[(view, mi)] for mi in range(flat.shape[0])])
            # per-pixel evidence of the view, + the mask's transferred evidence on each of its pixels
            ev_view = torch.from_numpy(self.mask_evidence[idx].astype(np.float32))
            px = (flat.T @ ev_view).numpy().astype(np.float64)  # [HW, K]
            for j, i in enumerate(idx):
                sel = flat[j].numpy() > 0
                e = px[sel] + trans[i][None, :]
                alpha = self.alpha0 + self.lam * e
                p = alpha / alpha.sum(1, keepdims=True)
                pi[i] = p.mean(0)
                H[i] = float((-(p * np.log(p)).sum(1)).mean()) / logK
        return pi, H

    def scores(self, with_exploration: bool = True) -> np.ndarray:
        """[N] acquisition score of every candidate (-inf for answered or failed ones)."""
        pi, H = self._predictive()
        cfg = self.cfg
        s = cfg.w_material * H + cfg.w_property * (pi @ self._ratio)
        if with_exploration:
            s = s + cfg.exploration * (~self._view_has[self._view_of_arr])
        s = np.where(self.done | self.failed, -np.inf, s)
        return s

    def uncertainty(self) -> float:
        """The largest remaining score without the exploration term (0 when nothing is left)."""
        s = self.scores(with_exploration=False)
        s = s[np.isfinite(s)]
        return float(s.max()) if s.size else 0.0

    def remaining(self) -> int:
        return int((~(self.done | self.failed)).sum())

    def select(self, n: int) -> list[tuple[str, int]]:
        """Greedy batch of up to ``n`` candidates (see the module docstring)."""
        s = self.scores()
        picked: list[int] = []
        damp = np.ones_like(s)
        for _ in range(min(n, self.remaining())):
            eff = np.where(np.isfinite(s), s * damp, -np.inf)
            eff[picked] = -np.inf
            i = int(np.argmax(eff))
            if not np.isfinite(eff[i]):
                break
            picked.append(i)
            sim = self._kernel[i].copy()
            same = self._view_of_arr == self._view_of_arr[i]
            view, mi = self.cand[i]
            flat = self._stacks[view]
            inter = (flat @ flat[mi]).numpy() / self._area[view].numpy()  # pixel overlap within the view
            sim[same] = np.maximum(sim[same], inter)
            damp *= 1.0 - self.cfg.diversity * np.clip(sim, 0, 1)
        self.history.append(
            {"selected": [list(self.cand[i]) for i in picked], "scores": [float(s[i]) for i in picked]}
        )
        return [self.cand[i] for i in picked]


# ---------------------------------------------------------------------------------------------------------
# the scheduler of an active PerceptionRun (same backends, cache, store and outputs as run_perception)
# ---------------------------------------------------------------------------------------------------------


@dataclass
class ActiveResult(PerceptionResult):
    queried: list[tuple[str, int]] = field(default_factory=list)
    """(view, mask_id) answered in this run, in query order."""
    candidates: int = 0
    """Masks over all views (the exhaustive number of queries)."""
    answered: int = 0
    """Masks answered in total (earlier runs included)."""
    stop_reason: str = ""
    final_uncertainty: float = float("nan")


class ActiveScheduler:
    """Batches chosen by :class:`ActiveSelector` (module docstring) for a :class:`~.pipeline.PerceptionRun`.

    State: ``selector`` (the beliefs), ``masks`` (per view, its masks), ``stop`` (why the run ended).
    """

    def __init__(self, config: ActiveConfig | None = None):
        self.config = config or ActiveConfig()

    def initialize_state(self, run: PerceptionRun) -> dict[str, Any]:
        """Segment every view, build the selector and feed it the answers of earlier runs."""
        masks, stacks, levels, feats = {}, {}, {}, {}
        for view in run.views:
            image = run.frame_image(view)
            if image is None:  # unreadable: skipped (reported at the end)
                continue
            ms = masks[view] = run.masks(view, image)
            stacks[view] = np.stack([m.segmentation for m in ms]) if ms else np.zeros((0,) + image.shape[:2], bool)
            levels[view] = [m.level for m in ms]
            feats[view] = mask_features(image, [m.segmentation for m in ms])
            run.result.masks += len(ms)
        run.result.candidates = run.result.masks
        cfg = run.config
        views = [v for v in run.views if v in masks]
        selector = ActiveSelector(views, stacks, levels, feats, run.library, self.config, cfg.fusion, cfg.prior)
        by_mask: dict[tuple[str, int], list[dict]] = {}
        for o in run.store.observations():
            by_mask.setdefault((str(o["view"]), int(o["mask_id"])), []).append(o)
        for view, mid in run.store.done():
            if view in masks:
                selector.observe(view, mid, by_mask.get((view, mid), []))
                run.result.resumed_masks += 1
        return {"selector": selector, "masks": masks, "stop": ""}

    def _stop_reason(self, run: PerceptionRun, selector: ActiveSelector) -> str:
        budget, floor = self.config.budget, self.config.stop_uncertainty
        if selector.remaining() == 0:
            return "every mask answered"
        if budget is not None and int(selector.done.sum()) >= budget:
            return f"query budget of {budget} reached"
        if floor is not None and selector.uncertainty() < floor:
            return f"uncertainty below {floor}"
        if not run.budget_left():
            return "call/cost budget reached"
        return ""

    def step_batch(self, run: PerceptionRun, state: dict[str, Any]) -> list[Query]:
        selector: ActiveSelector = state["selector"]
        state["stop"] = self._stop_reason(run, selector)
        if state["stop"]:
            return []
        n = self.config.batch_size
        if self.config.budget is not None:
            n = min(n, self.config.budget - int(selector.done.sum()))
        picked = selector.select(n)
        if not picked:
            state["stop"] = "no candidate left"
        run.add_to_progress(len(picked))
        images = {view: load_image(run.root, view) for view in {v for v, _ in picked}}
        return [run.query(view, mid, state["masks"][view][mid], images[view]) for view, mid in picked]

    def step_answer(self, run: PerceptionRun, state: dict[str, Any], outcome: Outcome) -> None:
        query, records = outcome
        if records is None:  # failed, replay miss or over budget: not asked again in this run
            state["selector"].mark_failed(query.view, query.mask_id)
            return
        state["selector"].observe(query.view, query.mask_id, records)
        run.result.queried.append((query.view, query.mask_id))

    def step_finish(self, run: PerceptionRun, state: dict[str, Any]) -> None:
        selector: ActiveSelector = state["selector"]
        result = run.result
        result.stop_reason = state["stop"]
        result.answered = int(selector.done.sum())
        result.final_uncertainty = selector.uncertainty()
        _write_active_log(run.root, self.config, result, selector)


def run_active_perception(
    config: PerceptionConfig,
    active: ActiveConfig | None = None,
    *,
    backend=None,
    segmenter=None,
    library: MaterialLibrary | None = None,
    on_commit: Callable | None = None,
) -> ActiveResult:
    """Active-mode perception: segment every view, then ask the masks chosen by :class:`ActiveSelector`
    until the budget is spent or the uncertainty is low, committing answers to the same resumable
    observation store as :func:`.pipeline.run_perception`; then fuse and write the dataset outputs like it.

    ``config.max_calls`` / ``config.budget`` (USD) still cap uncached calls; ``active.budget`` caps the number
    of answered masks (cache hits and earlier runs included).
    """
    if config.prompt != "triplet":
        raise ValueError("active querying chooses masks, so it needs --prompt triplet")
    with DatasetLock(config.data, wait=config.wait_for_lock):
        run = PerceptionRun(config, backend=backend, segmenter=segmenter, library=library, on_commit=on_commit,
                            result_type=ActiveResult)  # fmt: skip
        return run.run(ActiveScheduler(active))
def _write_active_log(
    root: Path, active: ActiveConfig, result: ActiveResult, selector: ActiveSelector
) -> None:
    from ..fusion.writer import atomic_write_text

    doc = {
        "config": asdict(active),
        "candidates": result.candidates,
        "answered": result.answered,
        "queried_this_run": [list(q) for q in result.queried],
        "stop_reason": result.stop_reason,
        "final_uncertainty": result.final_uncertainty,
        "rounds": selector.history,
    }
    atomic_write_text(Path(root) / ACTIVE_LOG, json.dumps(doc, indent=1))
