"""One progress display per export stage: the stage's name, its count and its elapsed time (rich, as
nerfstudio's own displays).

A stage opens one display and advances it; nothing inside a stage starts a bar of its own. On a console that
is not a terminal (a log file, CI, a pipe) the display is silent and the stage prints one line when it ends
(name, count, seconds), so a non-interactive log gets one line per stage instead of redrawn bars.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

__all__ = ["StageProgress", "stage"]


@dataclass
class StageProgress:
    """Handle of a running stage: ``advance(n, what)`` counts ``n`` more items and may rename the current step."""

    name: str
    total: int | None
    count: int = 0
    step: str = ""
    result: str = ""
    """what the stage produced, appended to its closing line"""
    _progress: Any = None
    _task: Any = None

    def advance(self, n: int = 1, what: str | None = None) -> None:
        self.count += n
        if what is not None:
            self.step = what
        if self._progress is not None:
            desc = f"{self.name}: {self.step}" if self.step else self.name
            self._progress.update(self._task, advance=n, description=desc)

    def describe(self, what: str) -> None:
        """Name the current step without counting an item."""
        self.advance(0, what)


@contextmanager
def stage(console: Any, name: str, total: int | None = None, *, unit: str = "") -> Iterator[StageProgress]:
    """A stage's progress display on ``console`` (a rich Console); silent when it is not a terminal or is quiet.
    When the stage ends without an error, one line is logged: name, count (of total), elapsed seconds and the
    handle's ``result`` text."""
    handle = StageProgress(name, total)
    t0 = time.perf_counter()
    live = bool(getattr(console, "is_terminal", False)) and not bool(getattr(console, "quiet", False))
    progress = None
    if live:
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            SpinnerColumn,
            TextColumn,
            TimeElapsedColumn,
        )

        progress = Progress(SpinnerColumn(), TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                            TimeElapsedColumn(), console=console, transient=True)  # fmt: skip
        handle._progress, handle._task = progress, progress.add_task(name, total=total)
        progress.start()
    try:
        yield handle
    finally:
        if progress is not None:
            progress.stop()
    count = f"{handle.count}" + (f"/{total}" if total is not None else "") + (f" {unit}" if unit else "")
    tail = f": {handle.result}" if handle.result else ""
    console.log(f"{name}: {count} in {time.perf_counter() - t0:.1f} s{tail}")
