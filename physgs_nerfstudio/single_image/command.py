"""`physgs image PATH`: dense 2D material, property and uncertainty maps of single images."""

from __future__ import annotations

from dataclasses import dataclass

from .pipeline import SingleImageConfig, SingleImageResult


def summary_table(result: SingleImageResult):
    """A rich Table of a run: one row per image."""
    from rich.table import Table

    p = result.perception
    sim = " (SIMULATED VLM)" if p.simulated else ""
    table = Table(title=f"physgs image -> {result.output_dir}{sim}")
    for col in ("image", "masks", "observations", "covered", "materials", "GT accuracy", "output"):
        table.add_column(col)
    for r in result.images:
        acc = "-" if r.ground_truth_accuracy is None else f"{100 * r.ground_truth_accuracy:.1f}%"
        table.add_row(
            r.source.name,
            str(r.masks),
            str(r.observations),
            f"{100 * r.covered_fraction:.0f}%",
            ", ".join(r.materials) or "-",
            acc,
            r.skipped or str(r.out_dir),
        )
    table.caption = (
        f"{p.backend} / {p.model}: {p.calls} VLM calls, {p.cache_hits} cache hits, {p.resumed_masks} masks resumed, "
        f"{len(p.failed)} failed, cost ${p.cost_usd:.4f}, {result.seconds:.1f} s"
    )
    return table


@dataclass
class ImageCommand(SingleImageConfig):
    """Single-image mode: segment each image at three levels, ask a VLM about every mask (cached and
    resumable), fuse the answers over the image's masks and levels (NIG property posteriors per material,
    a Dirichlet over materials per pixel) and write dense maps: material, each property's mean, aleatoric,
    epistemic and total uncertainty (maps.npz, PNG figures with colour bars, an overview panel and
    summary.json).

    The VLM and the segmenter are subcommands, after the other options: physgs image photo.jpg vlm:openai
    --vlm.model gpt-5 segmenter:sam --segmenter.checkpoint sam_vit_h.pth."""

    def main(self) -> None:
        import logging

        from rich.console import Console

        from .inputs import InputError
        from .pipeline import run_single_image

        logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
        try:
            result = run_single_image(self)
        except InputError as err:
            raise SystemExit(f"physgs image: {err}") from None
        console = Console()
        console.print(summary_table(result))
        for msg in result.perception.failed[:5]:
            console.print(f"[yellow]failed:[/yellow] {msg}")
        if len(result.perception.failed) > 5:
            console.print(f"[yellow]... and {len(result.perception.failed) - 5} more failures; rerun to retry them[/yellow]")


def entrypoint() -> None:
    """Stand-alone entry point (``python -m physgs_nerfstudio.single_image.command``)."""
    import tyro

    from ..cli import one_line_errors

    with one_line_errors("physgs image"):
        tyro.cli(ImageCommand).main()


if __name__ == "__main__":
    entrypoint()
