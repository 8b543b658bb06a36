"""Progress of a batch, read from the scenes' state files (so both backends show the same thing): one
overall bar of finished scene stages with counts by stage, and one line per running stage (a worker's
current job: scene, stage, seconds so far)."""

from __future__ import annotations

import time
from pathlib import Path

from .state import load_state


class BatchProgress:
    def __init__(self, output_dir: Path, names: list[str], stages: list[str], console=None, enabled: bool = True):
        self.output_dir, self.names, self.stages = Path(output_dir), names, stages
        self.enabled = enabled and bool(stages) and bool(names)
        self._progress = None
        self._workers: dict[str, int] = {}
        if self.enabled:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

            self._progress = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                                      TimeElapsedColumn(), console=console, transient=False)  # fmt: skip
            self._overall = self._progress.add_task("scenes", total=len(names) * len(stages))

    def __enter__(self):
        if self._progress is not None:
            self._progress.start()
        return self

    def __exit__(self, *exc) -> None:
        if self._progress is not None:
            self.refresh()
            self._progress.stop()

    def refresh(self) -> None:
        if self._progress is None:
            return
        counts = {s: 0 for s in self.stages}
        failed = 0
        running: dict[str, str] = {}
        now = time.time()
        for name in self.names:
            stages = load_state(self.output_dir, name).get("stages", {})
            for s in self.stages:
                status = (stages.get(s) or {}).get("status")
                if status in ("done", "failed"):
                    counts[s] += 1
                    failed += status == "failed"
                elif status == "running":
                    running[f"{name}:{s}"] = f"  [cyan]{name}[/] {s} ({now - stages[s].get('started', now):.0f} s)"
        desc = "scenes by stage: " + " | ".join(f"{s} {counts[s]}/{len(self.names)}" for s in self.stages)
        if failed:
            desc += f" | [red]{failed} failed[/]"
        self._progress.update(self._overall, description=desc, completed=sum(counts.values()))
        for key in list(self._workers):
            if key not in running:
                self._progress.remove_task(self._workers.pop(key))
        for key, text in running.items():
            if key in self._workers:
                self._progress.update(self._workers[key], description=text)
            else:
                self._workers[key] = self._progress.add_task(text, total=None)
