"""Fixtures shared by more than one test module. Plain helpers (scenes, fake servers, shapes) live in
tests/helpers/ and are imported from there; no test module imports another."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(scope="module")
def saved_run(tmp_path_factory) -> Path:
    """A physgs-lite run saved as `ns-train` saves it (config.yml, dataparser_transforms.json, checkpoints),
    with every Gaussian tensor randomised so that a load that keeps the initial state cannot pass; its last
    checkpoint is step 7, with a stale one of zeros at step 3. Module-scoped: each module gets a run of its own."""
    import torch
    import yaml
    from helpers.nerfstudio_scenes import write_blob_scene

    from method_configs.physgs_config import physgs_lite_trainer_config

    root = tmp_path_factory.mktemp("run")
    write_blob_scene(root / "data", num_views=6, size=32)
    config = physgs_lite_trainer_config()
    config.pipeline.datamanager.data = root / "data"
    config.pipeline.model.sh_degree = 1
    config.output_dir = root / "outputs"
    config.timestamp = "t"
    config.set_experiment_name()
    pipeline = config.pipeline.setup(device="cpu", test_mode="val")
    g = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for p in pipeline.model.gauss_params.values():
            p.copy_(torch.rand(p.shape, generator=g))
        pipeline.model.lifted_views.fill_(3)  # as after a lifting: the labelled fraction and evidence are read
    base = config.get_base_dir()
    base.mkdir(parents=True)
    (base / "config.yml").write_text(yaml.dump(config), "utf8")
    pipeline.datamanager.train_dataparser_outputs.save_dataparser_transform(base / "dataparser_transforms.json")
    ckpt_dir = config.get_checkpoint_dir()
    ckpt_dir.mkdir(parents=True)
    stale = {k: torch.zeros_like(v) if v.is_floating_point() else v for k, v in pipeline.state_dict().items()}
    torch.save({"step": 3, "pipeline": stale, "optimizers": {}, "scalers": {}}, ckpt_dir / "step-000000003.ckpt")
    step = 7
    torch.save({"step": step, "pipeline": pipeline.state_dict(), "optimizers": {}, "scalers": {}},
               ckpt_dir / f"step-{step:09d}.ckpt")  # fmt: skip
    return base / "config.yml"


@pytest.fixture(scope="session")
def viewer_run(tmp_path_factory) -> tuple[Path, Path, dict]:
    """(config.yml, dataset folder, ground_truth.json) of a tiny trained scene for the viewer tests: `physgs
    demo`'s first three stages (generated mug, perception with the simulated VLM and the built-in segmenter,
    `ns-train physgs-lite` on the CPU) at 8 views of 48 px and 30 iterations. Trained once per session."""
    from rich.console import Console

    from physgs_nerfstudio.demo import DemoCommand

    root = tmp_path_factory.mktemp("viewer_scene")
    cmd = DemoCommand(output_dir=root, views=8, resolution=48, iterations=30)
    console = Console(quiet=True)
    gt = cmd.stage_scene(console)
    cmd.stage_perceive(console, gt.get("env"))
    config = cmd.stage_train(console)
    return config, cmd.scene_dir, gt
