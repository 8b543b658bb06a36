"""The export's light loader against nerfstudio's own eval_setup (the oracle) on a saved run."""

from __future__ import annotations

import torch

from physgs_nerfstudio.export.command import load_run
from physgs_nerfstudio.export.field import PropertyField
from physgs_nerfstudio.runfiles.check import check_run
from physgs_nerfstudio.runfiles.loader import load_run_model

STEP = 7


def test_light_loader_matches_eval_setup(saved_run) -> None:
    from nerfstudio.utils.eval_utils import eval_setup

    _, pipeline, _, step = eval_setup(saved_run, test_mode="inference")
    files = check_run(saved_run)
    rm = load_run_model(files.config, files.checkpoint)
    assert rm.step == step == STEP
    want = pipeline.model.state_dict()
    got = rm.model.state_dict()
    assert set(got) == set(want)
    for key, value in want.items():
        assert torch.equal(got[key].cpu(), value.cpu()), key
    assert not rm.model.training
    cams, ref = rm.dataparser_outputs.cameras, pipeline.datamanager.train_dataparser_outputs.cameras
    assert torch.equal(cams.camera_to_worlds, ref.camera_to_worlds) and torch.equal(cams.fx, ref.fx)
    a = PropertyField.from_model(rm.model)
    b = PropertyField.from_model(pipeline.model)
    for name in ("means", "quats", "scales", "opacities", "alpha", "labelled"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None and y is None) or torch.equal(x.cpu(), y.cpu()), name
    assert a.material_names == b.material_names


def test_load_run_reads_masks_only_when_asked(saved_run) -> None:
    light = load_run(saved_run, capture=False)
    full = load_run(saved_run)
    assert light.views == [] and light.observations == []
    assert len(full.views) == int(light.cameras.camera_to_worlds.shape[0]) > 0
    assert torch.equal(light.field.means, full.field.means)


def test_export_field_without_the_model_matches_the_model_s_field(saved_run) -> None:
    """load_run builds the field from the checkpoint's tensors (PropertyField.from_state) without building the
    model; the oracle is PropertyField.from_model on nerfstudio's own eval_setup pipeline."""
    import sys

    from nerfstudio.utils.eval_utils import eval_setup

    field = load_run(saved_run, capture=False).field
    _, pipeline, _, _ = eval_setup(saved_run, test_mode="inference")
    want = PropertyField.from_model(pipeline.model)
    for name in ("means", "quats", "scales", "opacities", "alpha", "labelled", "evidence", "sh_dc", "sh_rest"):
        x, y = getattr(field, name), getattr(want, name)
        assert x is not None and y is not None and torch.equal(x.cpu(), y.cpu()), name
    for f in ("tau", "kappa", "a", "b"):
        assert torch.equal(getattr(field.nig, f), getattr(want.nig, f)), f
    assert (field.material_names, field.material_colors, field.thickness_m, field.material_weights) == (
        want.material_names, want.material_colors, want.thickness_m, want.material_weights)
    assert torch.equal(field.pi(), want.pi())
    assert "physgs_nerfstudio.nerfstudio.model" in sys.modules  # (eval_setup imported it; the next test: load_run alone)


def test_export_loading_imports_no_model(saved_run) -> None:
    import subprocess
    import sys

    code = ("import sys; from pathlib import Path; from physgs_nerfstudio.export.command import load_run; "
            "r = load_run(Path(sys.argv[1])); print(r.field.num_gaussians, len(r.views), sorted(m for m in "
            "('physgs_nerfstudio.nerfstudio.model', 'nerfstudio.models.splatfacto', 'nerfstudio.engine.trainer', "
            "'nerfstudio.viewer.viewer') if m in sys.modules))")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code, str(saved_run)], capture_output=True, text=True, check=True)
    n, views, imported = out.stdout.split(maxsplit=2)
    assert int(n) > 1 and int(views) > 0 and imported.strip() == "[]", out.stdout + out.stderr[-2000:]


def test_export_defaults_for_old_configs_are_the_model_config_s() -> None:
    from physgs_nerfstudio.nerfstudio.model import PhysGSModelConfig
    from physgs_nerfstudio.runfiles.loader import MODEL_DEFAULTS

    cfg = PhysGSModelConfig()
    assert MODEL_DEFAULTS == {name: getattr(cfg, name) for name in MODEL_DEFAULTS}
