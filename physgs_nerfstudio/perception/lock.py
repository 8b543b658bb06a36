"""One perception run per dataset at a time: a lock file in the dataset.

Two runs on one dataset would pay for every request twice and write every observation twice. A run takes
``<data>/perception/perceive.lock``, created with ``O_CREAT | O_EXCL`` (atomic, also over NFS v3+), holding
the holder's pid, host, start time and command line; it is removed when the run ends, however it ends.

A second run refuses with one line naming the holder (:class:`LockHeld`), or with ``wait=True`` polls until
the lock is free. A lock whose holder is gone does not block: on the same host, a holder pid that no longer
runs makes the lock stale; a lock file that cannot be read (a kill between creating and filling it) is stale
once it is ``GRACE_S`` seconds old. A stale lock is removed by whoever holds the short-lived takeover lock
``perceive.lock.takeover`` (also ``O_EXCL``), after reading it again under it, so two runs that find the same
stale lock cannot both take over. A lock held on another host is never presumed stale: the message says
which file to delete if that run is known to be gone.
"""

from __future__ import annotations

import json
import logging
import os
import socket
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

from ..errors import DatasetError, PhysGSError

logger = logging.getLogger(__name__)

LOCK_FILE = "perception/perceive.lock"
GRACE_S = 10.0
"""Age after which an unreadable lock file (or a left-over takeover lock) counts as stale."""


class LockHeld(PhysGSError, RuntimeError):
    """Another run holds the dataset's lock."""


@dataclass
class LockInfo:
    pid: int
    host: str
    started: str
    """ISO time (UTC) the holder took the lock."""
    command: str

    @classmethod
    def mine(cls) -> LockInfo:
        started = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        return cls(os.getpid(), socket.gethostname(), started, " ".join(sys.argv)[:300])

    def describe(self) -> str:
        return f"pid {self.pid} on {self.host}, since {self.started} ({self.command or 'no command line'})"


def _pid_alive(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    return True


def read_lock(path: Path) -> LockInfo | None:
    """The holder recorded in ``path`` (None when absent or unreadable)."""
    try:
        d = json.loads(Path(path).read_text(encoding="utf-8"))
        return LockInfo(int(d["pid"]), str(d["host"]), str(d["started"]), str(d.get("command", "")))
    except (OSError, ValueError, KeyError, TypeError):
        return None


def holder_of(path: Path) -> str:
    """Who holds the lock at ``path``, as the refusal says it: the recorded holder, or what the file holds
    instead (nothing yet, part of a record, something else)."""
    try:
        raw = Path(path).read_bytes()
    except IsADirectoryError:
        return "nobody (the lock is a folder, not a file)"
    except OSError as err:
        return f"unknown (the lock file cannot be read: {err.strerror or err})"
    info = read_lock(path)
    if info is not None:
        alive = "" if info.host != socket.gethostname() or _pid_alive(info.pid) else ", no longer running"
        return info.describe() + alive
    if not raw.strip():
        return f"a run that is starting (the lock file is still empty, {_age_s(path):.0f} s old)"
    try:
        d = json.loads(raw)
        pid = int(d["pid"]) if isinstance(d, dict) else None
    except (ValueError, KeyError, TypeError):
        pid = None
    if pid is not None:
        state = "running" if _pid_alive(pid) else "not running"
        return f"pid {pid} ({state} here), in a lock file without its host and start time"
    return (f"unknown: the lock file holds {len(raw)} bytes that are not a lock record ({_age_s(path):.0f} s old; "
            f"taken over after {GRACE_S:g} s)")  # fmt: skip


def _age_s(path: Path) -> float:
    try:
        return time.time() - path.stat().st_mtime
    except OSError:
        return 0.0


def _stale(path: Path, info: LockInfo | None) -> bool:
    if path.is_dir():  # not a lock file: never removed here (the message says to delete it)
        return False
    if info is None:
        return path.exists() and _age_s(path) > GRACE_S
    return info.host == socket.gethostname() and not _pid_alive(info.pid)


def _create(path: Path, info: LockInfo) -> bool:
    """Create ``path`` holding ``info`` if it does not exist (atomically); whether it was created."""
    try:
        fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
    except FileExistsError:
        return False
    try:
        os.write(fd, json.dumps(asdict(info)).encode("utf-8"))
        os.fsync(fd)
    finally:
        os.close(fd)
    return True


def _remove_if_stale(path: Path) -> bool:
    """Remove ``path`` if it is stale, under the takeover lock; whether it was removed."""
    takeover = path.with_name(path.name + ".takeover")
    if not _create(takeover, LockInfo.mine()):
        if _stale(takeover, read_lock(takeover)) or _age_s(takeover) > GRACE_S:
            takeover.unlink(missing_ok=True)  # its holder died inside the few lines below
        return False
    try:
        info = read_lock(path)  # read again: only the takeover holder may remove a lock
        if not _stale(path, info):
            return False
        logger.warning("taking over the stale lock %s (%s)", path, info.describe() if info else "unreadable")
        path.unlink(missing_ok=True)
        return True
    finally:
        takeover.unlink(missing_ok=True)


class DatasetLock:
    """``with DatasetLock(data, wait=...)``: hold the dataset's perception lock for the block."""

    def __init__(self, root: Path, wait: bool = False, poll_s: float = 0.5,
                 notify: Callable[[str], None] | None = None):  # fmt: skip
        self.path = Path(root) / LOCK_FILE
        self.wait = wait
        self.poll_s = poll_s
        self.notify = notify or (lambda msg: logger.warning("%s", msg))
        self.info: LockInfo | None = None

    def acquire(self) -> None:
        root = self.path.parent.parent
        if not root.is_dir():
            raise DatasetError(f"{root} is not a directory: --data must be a nerfstudio dataset directory")
        self.path.parent.mkdir(exist_ok=True)
        mine, told = LockInfo.mine(), False
        while not _create(self.path, mine):
            if _remove_if_stale(self.path):
                continue
            who = holder_of(self.path)
            if self.path.is_dir():
                raise LockHeld(f"{self.path} is a folder, not a lock file: no run holds it; delete the folder "
                               f"(rm -r {self.path}) and rerun.")  # fmt: skip
            if not self.wait:
                raise LockHeld(
                    f"{self.path.parent.parent} is being perceived by another run: {who}. Wait for it, pass "
                    f"--wait-for-lock to queue behind it, or delete {self.path} if that run is gone."
                )
            if not told:
                self.notify(f"waiting for the perception lock {self.path}, held by {who}")
                told = True
            time.sleep(self.poll_s)
        self.info = mine

    def release(self) -> None:
        if self.info is None:
            return
        if read_lock(self.path) == self.info:  # never remove a lock someone took over from us
            self.path.unlink(missing_ok=True)
        self.info = None

    def __enter__(self):
        self.acquire()
        return self

    def __exit__(self, *exc) -> None:
        self.release()
