"""Change a dataset as one transaction: every file or none of them.

Perception's outputs are many files (label, confidence and preview PNGs per frame, the legend,
materials.json, transforms.json and its backup) that only make sense together: new label ids beside an old
materials.json make ``ns-train`` refuse the dataset. :class:`DatasetTransaction` stages every file in a
hidden directory inside the dataset (same file system, so moving a file in is a rename), then commits:

1. stage: each file is written (and fsynced) under ``<data>/.physgs-staging-<id>/<relative path>``; any
   error (a full disk, say) removes the staging directory and leaves the dataset exactly as it was;
2. commit point: the list of staged files is written to ``<staging>/COMMIT`` (fsynced, then renamed into
   place, so it is either complete or absent);
3. apply: each staged file is renamed over its target (``transforms.json`` last), then the staging
   directory is removed.

A run killed during 3 leaves a staging directory with ``COMMIT``: :func:`recover` (called before every new
transaction and at the start of a perception run) finishes it. One without ``COMMIT`` is an aborted
transaction and is removed. Every byte goes through :func:`write_file`, the one write layer (tests replace
it to simulate a full disk).
"""

from __future__ import annotations

import errno
import json
import logging
import os
import shutil
import uuid
from collections.abc import Sequence
from pathlib import Path

from ..errors import PhysGSError

logger = logging.getLogger(__name__)

STAGING_PREFIX = ".physgs-staging-"
JOURNAL = "COMMIT"
LAST = ("materials.json", "transforms.json")
"""Applied last, in this order: the files that point at the others."""


class WriteFailed(PhysGSError, OSError):
    """Writing the dataset's outputs failed (e.g. the disk is full); nothing was changed."""


def write_file(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` and fsync it: the write layer of every dataset output."""
    try:
        with open(path, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
    except OSError as err:
        if err.filename is None:
            err.filename = str(path)
        raise


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """``path`` replaced by ``data`` in one rename; no temporary file is left behind on an error."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        write_file(tmp, data)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _ordered(files: Sequence[str]) -> list[str]:
    return sorted(files, key=lambda rel: LAST.index(rel) + 1 if rel in LAST else 0)


def _apply(root: Path, staging: Path, files: Sequence[str]) -> None:
    for rel in _ordered(files):
        src, dst = staging / rel, root / rel
        if not src.exists():  # moved already (an interrupted apply being finished)
            continue
        dst.parent.mkdir(parents=True, exist_ok=True)
        os.replace(src, dst)
    shutil.rmtree(staging, ignore_errors=True)


def recover(root: Path) -> None:
    """Finish the committed transactions left in ``root`` by a killed run; remove the uncommitted ones."""
    root = Path(root)
    for staging in sorted(root.glob(STAGING_PREFIX + "*")):
        journal = staging / JOURNAL
        try:
            files = json.loads(journal.read_text(encoding="utf-8"))["files"]
        except (OSError, ValueError, KeyError, TypeError):
            logger.warning("removing the unfinished dataset update %s (nothing of it was applied)", staging)
            shutil.rmtree(staging, ignore_errors=True)
            continue
        logger.warning("finishing the interrupted dataset update %s", staging)
        _apply(root, staging, files)


class DatasetTransaction:
    """``with DatasetTransaction(root) as txn: txn.write_bytes(rel, data); ...`` commits at the end of the
    block, or (on an exception) removes everything it staged. Paths are relative to ``root``."""

    def __init__(self, root: Path):
        self.root = Path(root)
        recover(self.root)
        self.staging = self.root / f"{STAGING_PREFIX}{uuid.uuid4().hex[:12]}"
        self.files: list[str] = []

    def _target(self, rel: str) -> Path:
        path = (self.staging / rel).resolve()
        if os.path.commonpath([path, self.staging.resolve()]) != str(self.staging.resolve()):
            raise ValueError(f"{rel!r} leaves the dataset")
        return path

    def write_bytes(self, rel: str, data: bytes) -> None:
        path = self._target(rel)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_file(path, data)
        if rel not in self.files:
            self.files.append(rel)

    def write_text(self, rel: str, text: str) -> None:
        self.write_bytes(rel, text.encode("utf-8"))

    def commit(self) -> None:
        if not self.files:
            self.abort()
            return
        journal = self.staging / JOURNAL
        atomic_write_bytes(journal, json.dumps({"files": self.files}).encode("utf-8"))
        _apply(self.root, self.staging, self.files)

    def abort(self) -> None:
        shutil.rmtree(self.staging, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self.abort()
            if isinstance(exc, OSError) and not isinstance(exc, PhysGSError):
                raise WriteFailed(_failure_message(self.root, exc)) from exc
            return
        try:
            self.commit()
        except OSError as err:
            if (self.staging / JOURNAL).exists():
                raise WriteFailed(
                    f"moving the new outputs into {self.root} was interrupted ({err}); the update is recorded "
                    f"in {self.staging} and the next run finishes it"
                ) from err
            self.abort()
            raise WriteFailed(_failure_message(self.root, err)) from err


def _failure_message(root: Path, err: OSError) -> str:
    what = "the disk is full" if err.errno in (errno.ENOSPC, errno.EDQUOT) else f"{err.strerror or err}"
    return (
        f"could not write the outputs into {root} ({what}: {getattr(err, 'filename', '') or 'a file'}); the "
        "dataset was left as it was. Free some space (or fix the permissions) and run again: answers are cached."
    )
