"""`physgs perceive`: masks -> VLM -> validated observations -> fusion -> material maps in the dataset."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from ..advanced import Advanced
from .config import PerceptionConfig
from .pipeline import PerceptionResult

if TYPE_CHECKING:
    from .active import ActiveConfig


def summary_table(result: PerceptionResult):
    """A rich Table summarising a run."""
    from rich.table import Table

    sim = " (SIMULATED VLM)" if result.simulated else ""
    table = Table(title=f"physgs perceive: {result.data}{sim}", show_header=False)
    table.add_column("item")
    table.add_column("value")
    rows = [
        ("frames", str(len(result.views))),
        ("frames skipped (unreadable image)", str(len(result.skipped_frames))),
        ("masks", str(result.masks)),
        ("backend / model", f"{result.backend} / {result.model}"),
        ("VLM calls made (uncached)", str(result.calls)),
        ("cache hits", str(result.cache_hits)),
        ("masks resumed from an earlier run", str(result.resumed_masks)),
        ("skipped (budget / max calls)", str(result.skipped_budget)),
        ("failed requests", str(len(result.failed))),
        ("observations (total / new)", f"{result.observations} / {result.new_observations}"),
        ("dropped candidates / validation notes", f"{result.dropped_candidates} / {result.reasons}"),
        ("tokens (prompt / completion)", f"{result.usage.prompt_tokens} / {result.usage.completion_tokens}"),
        ("estimated cost (USD)", f"{result.cost_usd:.4f}"),
        ("simulated", str(result.simulated)),
        (
            "materials found",
            ", ".join(f"{n} ({result.material_counts.get(n, 0)})" for n in result.materials) or "-",
        ),
        ("materials.json", str(result.materials_json) if result.materials_json else "-"),
        ("time", f"{result.seconds:.1f} s"),
    ]
    if hasattr(result, "stop_reason"):  # an active run (perception.active.ActiveResult)
        rows[1:1] = [
            ("active: masks answered / candidates", f"{result.answered} / {result.candidates}"),
            ("active: queried this run", str(len(result.queried))),
            ("active: stop reason", result.stop_reason or "-"),
            ("active: final uncertainty", f"{result.final_uncertainty:.3f}"),
        ]
    for k, v in rows:
        table.add_row(k, v)
    return table


@dataclass
class PerceiveCommand(PerceptionConfig):
    """Estimate materials and physical properties of a nerfstudio dataset's frames with a VLM, fuse them
    (Dirichlet materials per pixel, NIG property posteriors per material) and write materials.json,
    per-frame material maps and their transforms.json entries.

    With --active only the masks the current beliefs say are most informative are asked, until --query-budget
    masks are answered or the best remaining score is below --stop-uncertainty; a later run without --active
    asks only the rest.

    The VLM and the segmenter are subcommands, after the other options:
    physgs perceive --data D vlm:simulated; physgs perceive --data D vlm:openai --vlm.model gpt-5
    segmenter:sam --segmenter.checkpoint sam_vit_h.pth."""

    active: bool = False
    """Ask only the most informative masks instead of every mask of every view."""
    query_budget: int | None = None
    """With --active: stop once this many masks are answered, earlier runs included (None: no limit)."""
    stop_uncertainty: float | None = None
    """With --active: stop when the best remaining score, between 0 and 2, is below this (None: never)."""
    active_batch_size: Advanced[int] = 8
    """With --active: masks chosen per step, sent together before the beliefs are updated."""

    def active_config(self) -> ActiveConfig:
        """The :class:`~physgs_nerfstudio.perception.active.ActiveConfig` of the active-mode flags."""
        from .active import ActiveConfig

        return ActiveConfig(budget=self.query_budget, stop_uncertainty=self.stop_uncertainty,
                            batch_size=self.active_batch_size)

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.active and (self.query_budget is not None or self.stop_uncertainty is not None):
            raise ValueError("--query-budget / --stop-uncertainty only apply with --active")
        if self.active:
            self.active_config()  # validate the flags before any work

    def run(self) -> PerceptionResult:
        """Run exhaustive or (``active``) active perception; returns the run's result."""
        if self.active:
            from .active import run_active_perception

            return run_active_perception(self, self.active_config())  # type: ignore[arg-type]
        from .pipeline import run_perception

        return run_perception(self)

    def main(self) -> None:
        import logging

        from rich.console import Console
        from rich.markup import escape

        logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
        result = self.run()
        console = Console()
        console.print(summary_table(result))
        for msg in result.failed[:5]:
            console.print(f"[yellow]failed:[/yellow] {msg}")
        if len(result.failed) > 5:
            console.print(
                f"[yellow]... and {len(result.failed) - 5} more failures; rerun to retry them[/yellow]"
            )
        for msg in result.skipped_frames:
            console.print(f"[yellow]skipped frame:[/yellow] {escape(msg)}", highlight=False)
        if result.skipped_frames:
            console.print(f"[yellow]{len(result.skipped_frames)} frame(s) skipped; --strict makes this fatal[/yellow]")
