"""`physgs perceive`: masks -> VLM -> validated observations -> fusion -> material maps in the dataset."""

from __future__ import annotations

from dataclasses import dataclass

from .pipeline import PerceptionConfig, PerceptionResult


def summary_table(result: PerceptionResult):
    """A rich Table summarising a run."""
    from rich.table import Table

    sim = " (SIMULATED VLM)" if result.simulated else ""
    table = Table(title=f"physgs perceive: {result.data}{sim}", show_header=False)
    table.add_column("item")
    table.add_column("value")
    rows = [
        ("frames", str(len(result.views))),
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
    for k, v in rows:
        table.add_row(k, v)
    return table


@dataclass
class PerceiveCommand(PerceptionConfig):
    """Estimate materials and physical properties of a nerfstudio dataset's frames with a VLM, fuse them
    (Dirichlet materials per pixel, NIG property posteriors per material) and write materials.json,
    per-frame material maps and their transforms.json entries."""

    def main(self) -> None:
        import logging

        from rich.console import Console

        from .pipeline import run_perception

        logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
        result = run_perception(self)
        console = Console()
        console.print(summary_table(result))
        for msg in result.failed[:5]:
            console.print(f"[yellow]failed:[/yellow] {msg}")
        if len(result.failed) > 5:
            console.print(
                f"[yellow]... and {len(result.failed) - 5} more failures; rerun to retry them[/yellow]"
            )
