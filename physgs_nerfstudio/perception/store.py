"""Append-only observation store with crash-safe resume.

Two files in the dataset:

* ``observations.jsonl`` (the contract of docs/architecture.md): one JSON object per candidate material of
  a mask, appended as answers arrive;
* ``perception/progress.jsonl``: the commit log. Its first line is a header with the run's configuration
  fingerprint; every further line marks one (view, mask_id) as done, with the number of observations it
  wrote, the validation reasons, token usage and whether the answer came from the cache.

Commit protocol for one mask: all its observation lines are written with ONE ``write`` + flush + fsync,
then the progress line (one write + fsync). On open, observation lines of a mask without a progress line
(a kill between the two writes) and any torn line at the end of either file (a kill inside a write) are
removed (atomic rewrite), so every mask is either fully recorded once or not at all. A resumed run skips
the done masks; the ones it redoes are answered from the response cache, so no paid call is repeated.
"""

from __future__ import annotations

import json
import logging
import os
import threading
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import PhysGSError

logger = logging.getLogger(__name__)

STORE_VERSION = 1
OBSERVATIONS_FILE = "observations.jsonl"
PROGRESS_FILE = "perception/progress.jsonl"


class StoreMismatch(PhysGSError, RuntimeError):
    """The existing observations were made with another configuration (a user error: `physgs perceive` says it in
    one line, with the fix)."""


@dataclass
class MaskDone:
    view: str
    mask_id: int
    level: str
    num_observations: int
    reasons: list[str]
    cached: bool
    usage: dict[str, int]


def _read_jsonl(path: Path) -> tuple[list[dict], bool]:
    """Parsed lines and whether anything was dropped (torn or garbled lines)."""
    if not path.is_file():
        return [], False
    raw = path.read_bytes()
    out: list[dict] = []
    dropped = False
    lines = raw.split(b"\n")
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        if i == len(lines) - 1:  # no trailing newline: a torn final write
            logger.warning("%s: dropping an incomplete last line (interrupted write)", path)
            dropped = True
            continue
        try:
            obj = json.loads(line)
        except ValueError:
            logger.warning("%s: dropping unreadable line %d", path, i + 1)
            dropped = True
            continue
        if isinstance(obj, dict):
            out.append(obj)
        else:
            dropped = True
    return out, dropped


def _dumps(obj: Any) -> bytes:
    return (json.dumps(obj, ensure_ascii=False, allow_nan=True, separators=(", ", ": ")) + "\n").encode(
        "utf-8"
    )


def _atomic_write_lines(path: Path, objs: Iterable[dict]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as fh:
        fh.writelines(_dumps(obj) for obj in objs)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def _append(path: Path, data: bytes) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        view = memoryview(data)
        while view:
            n = os.write(fd, view)
            view = view[n:]
        os.fsync(fd)
    finally:
        os.close(fd)


class ObservationStore:
    """See the module docstring. Not for concurrent writers; the pipeline commits from one thread."""

    def __init__(self, root: Path, fingerprint: str, overwrite: bool = False):
        self.root = Path(root)
        self.obs_path = self.root / OBSERVATIONS_FILE
        self.progress_path = self.root / PROGRESS_FILE
        self.fingerprint = fingerprint
        self._lock = threading.Lock()
        self._done: dict[tuple[str, int], MaskDone] = {}
        self._observations: list[dict] = []
        self.resumed_masks = 0
        self._open(overwrite)

    # -- opening / recovery ------------------------------------------------------------------------
    def _open(self, overwrite: bool) -> None:
        self.progress_path.parent.mkdir(parents=True, exist_ok=True)
        if overwrite:
            for p in (self.obs_path, self.progress_path):
                if p.exists():
                    os.replace(p, p.with_name(p.name + ".bak"))
                    logger.info("moved the previous %s to %s.bak", p.name, p.name)
        progress, torn_p = _read_jsonl(self.progress_path)
        obs, torn_o = _read_jsonl(self.obs_path)
        header = progress[0] if progress and progress[0].get("type") == "header" else None
        if header is not None and len(progress) == 1 and not obs:  # nothing recorded: nothing to mix
            header = None
            progress = []
        if header is None:
            if progress or obs:
                raise StoreMismatch(
                    f"{self.obs_path} exists without a readable perception/progress.jsonl header, so it cannot be "
                    "resumed safely; pass --overwrite to start over (the old files are kept as .bak)."
                )
            _atomic_write_lines(
                self.progress_path,
                [{"type": "header", "version": STORE_VERSION, "fingerprint": self.fingerprint}],
            )
            return
        if header.get("fingerprint") != self.fingerprint:
            raise StoreMismatch(
                f"{self.obs_path} was produced by another configuration ({_fingerprint_diff(header.get('fingerprint'), self.fingerprint)}), "
                "so resuming would mix incompatible observations. Pass --overwrite to start over (the old files "
                "are kept as .bak), or rerun with the original settings."
            )
        for rec in progress[1:]:
            if rec.get("type") != "done":
                continue
            try:
                d = MaskDone(
                    str(rec["view"]),
                    int(rec["mask_id"]),
                    str(rec.get("level", "")),
                    int(rec.get("num_observations", 0)),
                    list(rec.get("reasons", [])),
                    bool(rec.get("cached", False)),
                    dict(rec.get("usage") or {}),
                )
            except (KeyError, TypeError, ValueError):
                torn_p = True
                continue
            self._done[(d.view, d.mask_id)] = d
        kept = [o for o in obs if (str(o.get("view")), _int(o.get("mask_id"))) in self._done]
        # the commit log is authoritative: a done mask must have exactly its recorded observations
        counts: dict[tuple[str, int], int] = {}
        for o in kept:
            k = (str(o["view"]), int(o["mask_id"]))
            counts[k] = counts.get(k, 0) + 1
        inconsistent = {k for k, d in self._done.items() if counts.get(k, 0) != d.num_observations}
        if inconsistent:
            logger.warning(
                "%d masks have observation counts that disagree with the commit log; they will be redone",
                len(inconsistent),
            )
            for k in inconsistent:
                del self._done[k]
            kept = [o for o in kept if (str(o["view"]), int(o["mask_id"])) not in inconsistent]
        uncommitted = len(obs) - len(kept)
        if uncommitted or torn_o:
            logger.warning(
                "removing %d uncommitted observation lines from %s (interrupted run)",
                uncommitted,
                self.obs_path,
            )
            _atomic_write_lines(self.obs_path, kept)
        if torn_p or inconsistent:
            _atomic_write_lines(
                self.progress_path, [header] + [self._done_record(d) for d in self._done.values()]
            )
        self._observations = kept
        self.resumed_masks = len(self._done)

    @staticmethod
    def _done_record(d: MaskDone) -> dict:
        return {
            "type": "done",
            "view": d.view,
            "mask_id": d.mask_id,
            "level": d.level,
            "num_observations": d.num_observations,
            "reasons": d.reasons,
            "cached": d.cached,
            "usage": d.usage,
        }

    # -- queries -------------------------------------------------------------------------------------
    def is_done(self, view: str, mask_id: int) -> bool:
        return (view, int(mask_id)) in self._done

    def done(self) -> dict[tuple[str, int], MaskDone]:
        return dict(self._done)

    def observations(self) -> list[dict]:
        with self._lock:
            return list(self._observations)

    # -- writing -------------------------------------------------------------------------------------
    def commit(self, done: MaskDone, records: list[dict]) -> None:
        """Append one mask's observations (one write) and then its done marker (one write)."""
        key = (done.view, int(done.mask_id))
        with self._lock:
            if key in self._done:
                raise ValueError(f"mask {done.mask_id} of view {done.view!r} is already recorded")
            for r in records:
                if r.get("view") != done.view or _int(r.get("mask_id")) != done.mask_id:
                    raise ValueError("observation records must belong to the committed mask")
            done.num_observations = len(records)
            if records:
                _append(self.obs_path, b"".join(_dumps(r) for r in records))
            _append(self.progress_path, _dumps(self._done_record(done)))
            self._done[key] = done
            self._observations.extend(records)


def _fingerprint_diff(old: Any, new: str) -> str:
    """Names of the differing top-level fields of two JSON fingerprints (or a short generic note)."""
    try:
        a, b = json.loads(old), json.loads(new)
        keys = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
        return "differs in: " + ", ".join(keys) if keys else "differs"
    except (TypeError, ValueError, AttributeError):
        return "segmenter, VLM backend/model, prompt or library differ"


def _int(v: Any) -> int:
    try:
        return int(v)
    except (TypeError, ValueError):
        return -1


def read_observations(root: Path) -> list[dict]:
    """The committed observations of a dataset (same filtering as a resumed store, read-only)."""
    obs, _ = _read_jsonl(Path(root) / OBSERVATIONS_FILE)
    progress, _ = _read_jsonl(Path(root) / PROGRESS_FILE)
    if not progress:
        return obs
    done = {(str(r.get("view")), _int(r.get("mask_id"))) for r in progress[1:] if r.get("type") == "done"}
    return [o for o in obs if (str(o.get("view")), _int(o.get("mask_id"))) in done]
