"""A tiny trained scene for the viewer tests: `physgs demo`'s first three stages (generated mug, perception with
the simulated VLM and the built-in segmenter, `ns-train physgs-lite` on the CPU) at test_demo.py's tiny setting.
Trained once per pytest session, shared by test_viewer.py and test_viewer_browser.py."""

from __future__ import annotations

from pathlib import Path

from rich.console import Console

from physgs_nerfstudio.demo import DemoCommand

_CACHE: dict[str, tuple[Path, Path, dict]] = {}


def trained_scene(tmp_path_factory) -> tuple[Path, Path, dict]:
    """(config.yml, dataset folder, ground_truth.json) of the tiny run."""
    key = str(tmp_path_factory.getbasetemp())
    if key not in _CACHE:
        root = tmp_path_factory.mktemp("viewer_scene")
        cmd = DemoCommand(output_dir=root, views=8, resolution=48, iterations=30)
        console = Console(quiet=True)
        gt = cmd.stage_scene(console)
        cmd.stage_perceive(console, gt.get("env"))
        config = cmd.stage_train(console)
        _CACHE[key] = (config, cmd.scene_dir, gt)
    return _CACHE[key]
