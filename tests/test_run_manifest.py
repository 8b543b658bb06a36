"""The run manifest (issue 72, serious 3): training records the legend, posteriors and maps it trained with;
export and the viewer refuse, in one line, a dataset that changed since. Oracles: the dataset's files edited by
hand here (materials reordered, one added, a posterior and a map changed) and the same run exported unedited."""

from __future__ import annotations

import copy
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

from physgs_nerfstudio.export.run import load_run
from physgs_nerfstudio.runfiles.manifest import MANIFEST, RunManifestError, check_manifest, manifest_of

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """A physgs-lite run folder as ns-train leaves it, its manifest written by the pipeline's training set-up
    (get_training_callbacks with a trainer, as nerfstudio's Trainer.setup calls it), without training."""
    from nerfstudio.configs.method_configs import all_methods
    from nerfstudio.engine.callbacks import TrainingCallbackAttributes
    from test_nerfstudio_fixtures import write_synth_scene

    root = tmp_path_factory.mktemp("run")
    data = root / "scene"
    write_synth_scene(data, resolution=32, views=6)
    cfg = copy.deepcopy(all_methods["physgs-lite"])
    cfg.pipeline.datamanager.data = data
    cfg.output_dir, cfg.experiment_name, cfg.timestamp = root / "outputs", "scene", "t"
    cfg.machine.device_type = "cpu"
    cfg.save_config()
    base = cfg.get_base_dir()
    pipeline = cfg.pipeline.setup(device="cpu", test_mode="inference")
    trainer = SimpleNamespace(config=cfg)
    pipeline.get_training_callbacks(TrainingCallbackAttributes(None, None, pipeline, trainer))  # type: ignore[arg-type]
    assert (base / MANIFEST).is_file()
    pipeline.datamanager.train_dataparser_outputs.save_dataparser_transform(base / "dataparser_transforms.json")
    (base / "nerfstudio_models").mkdir()
    torch.save({"step": 7, "pipeline": pipeline.state_dict()}, base / "nerfstudio_models" / "step-000000007.ckpt")
    return base / "config.yml"


@pytest.fixture
def copy_of(run, tmp_path):
    """The run and its dataset copied (the config pointed at the copy's dataset, as nerfstudio writes it)."""
    import yaml

    from physgs_nerfstudio.safe_yaml import load_config_yaml

    data = tmp_path / "scene"
    shutil.copytree(run.parents[4] / "scene", data)
    shutil.copytree(run.parent, tmp_path / "run")
    cfg = tmp_path / "run" / "config.yml"
    config = load_config_yaml(cfg)
    config.pipeline.datamanager.data = data
    cfg.write_text(yaml.dump(config))
    return cfg, data


def _materials(data: Path) -> dict:
    return json.loads((data / "materials.json").read_text())


def _write_materials(data: Path, doc: dict) -> None:
    for i, m in enumerate(doc["materials"]):
        m["id"] = i + 1
    (data / "materials.json").write_text(json.dumps(doc, indent=2))


def test_the_manifest_records_the_legend_and_every_map(run):
    saved = json.loads((run.parent / MANIFEST).read_text())
    data = run.parents[4] / "scene"
    assert saved["materials"] == [m["name"] for m in _materials(data)["materials"]]
    frames = json.loads((data / "transforms.json").read_text())["frames"]
    listed = {f["material_path"] for f in frames} | {f["material_confidence_path"] for f in frames}
    assert set(saved["files"]) <= listed and len(saved["files"]) >= 2  # the training split's maps
    assert load_run(run, capture=False).field.num_gaussians > 0  # unchanged: accepted


def test_a_reformatted_materials_json_is_the_same_legend(copy_of):
    cfg, data = copy_of
    (data / "materials.json").write_text(json.dumps(_materials(data)))  # one line instead of indented
    assert load_run(cfg, capture=False).field.num_gaussians > 0


@pytest.mark.parametrize("edit,expect", [
    ("swap", "material 1 was"),  # same number of materials, another order: was exported silently
    ("add", "materials then"),  # another number: was a traceback inside PropertyField
    ("posterior", "its posteriors changed"),
    ("map", "changed since the run"),
    ("remove_map", "is missing since the run"),
])  # fmt: skip
def test_a_dataset_changed_after_training_is_refused_in_one_line(copy_of, edit, expect):
    cfg, data = copy_of
    doc = _materials(data)
    saved = json.loads((cfg.parent / MANIFEST).read_text())
    a_map = data / min(saved["files"])
    if edit == "swap":
        doc["materials"][0], doc["materials"][1] = doc["materials"][1], doc["materials"][0]
    elif edit == "add":
        doc["materials"].append(dict(doc["materials"][0], name="extra"))
    elif edit == "posterior":
        doc["materials"][0]["posterior"]["density"]["tau"] += 0.5
    elif edit == "map":
        a_map.write_bytes(a_map.read_bytes() + b"\0")
    else:
        a_map.unlink()
    _write_materials(data, doc)
    if edit != "remove_map":  # a missing map is the dataparser's own one-line error before the manifest
        with pytest.raises(RunManifestError) as ei:
            load_run(cfg, capture=False)
        msg = str(ei.value)
        assert "\n" not in msg and expect in msg and "retrain" in msg, msg
    else:
        with pytest.raises(RunManifestError) as ei:
            check_manifest(cfg.parent, data, {**_metadata_of(cfg, data)})
        assert expect in str(ei.value)


def _metadata_of(cfg: Path, data: Path) -> dict:
    saved = json.loads((cfg.parent / MANIFEST).read_text())
    legend = SimpleNamespace(names=saved["materials"], path=data / "materials.json")
    maps = [data / rel for rel in saved["files"] if (data / rel).exists()]
    return {"material_legend": legend, "material_filenames": maps, "material_confidence_filenames": []}


def test_the_cli_export_refuses_a_swapped_legend_with_one_line(copy_of, tmp_path):
    cfg, data = copy_of
    doc = _materials(data)
    doc["materials"].reverse()
    _write_materials(data, doc)
    env = dict(os.environ, PYTHONPATH=str(REPO), PYTHONWARNINGS="ignore")
    proc = subprocess.run([sys.executable, "-m", "physgs_nerfstudio.cli", "export", "--load-config", str(cfg),
                           "--output-dir", str(tmp_path / "out"), "--outputs", "ply", "--device", "cpu"],
                          capture_output=True, text=True, timeout=300, check=False, env=env)  # fmt: skip
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("physgs export: error: ") and "was trained with the materials" in last
    assert not (tmp_path / "out").exists()


def test_a_run_without_a_manifest_is_used_with_one_line(copy_of, capsys):
    cfg, _ = copy_of
    (cfg.parent / MANIFEST).unlink()
    assert load_run(cfg, capture=False).field.num_gaussians > 0
    err = [ln for ln in capsys.readouterr().err.splitlines() if MANIFEST in ln]
    assert len(err) == 1 and "not checked" in err[0]


def test_manifest_of_is_the_same_for_the_same_files(run):
    data = run.parents[4] / "scene"
    meta = _metadata_of(run, data)
    assert manifest_of(data, meta) == manifest_of(data, meta)
