"""Loading a run that is not what it should be (issue 72): the run manifest (training records the legend,
posteriors and maps it trained with; export and the viewer refuse, in one line, a dataset that changed since),
and checkpoints and poses that cannot be used. Oracles: the dataset's and the checkpoint's contents edited by
hand here (materials reordered, one added, a posterior and a map changed, NaN tensors, a missing key, a pickle
payload that would create a file, a zero pose) and the same run loaded unedited."""

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
    from helpers.nerfstudio_scenes import write_synth_scene
    from nerfstudio.configs.method_configs import all_methods
    from nerfstudio.engine.callbacks import TrainingCallbackAttributes

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


# ------------------------------------------------------------------------------------------ checkpoints
def _ckpt(cfg: Path) -> Path:
    return cfg.parent / "nerfstudio_models" / "step-000000007.ckpt"


class _Payload:
    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


@pytest.mark.parametrize("damage,expect", [
    ("nan", "holds 3 NaN or infinite values"),
    ("no_evidence", "not a PhysGS checkpoint (no gauss_params.dirichlet_evidence"),
    ("pickle", "not a checkpoint of tensors"),
    ("no_pipeline", 'no "pipeline" state'),
])  # fmt: skip
def test_a_bad_checkpoint_is_one_line(copy_of, tmp_path, damage, expect):
    from physgs_nerfstudio.runfiles.check import RunFilesError

    cfg, _ = copy_of
    ckpt = _ckpt(cfg)
    loaded = torch.load(ckpt, map_location="cpu", weights_only=True)
    marker = tmp_path / "pwned.txt"
    if damage == "nan":
        loaded["pipeline"]["_model.gauss_params.means"][0] = float("nan")
    elif damage == "no_evidence":
        del loaded["pipeline"]["_model.gauss_params.dirichlet_evidence"]
    elif damage == "pickle":
        loaded["payload"] = _Payload(marker)
    else:
        loaded = {"step": 7}
    torch.save(loaded, ckpt)
    with pytest.raises(RunFilesError) as ei:
        load_run(cfg, capture=False)
    msg = str(ei.value)
    assert "\n" not in msg and str(ckpt) in msg and expect in msg, msg
    assert not marker.exists()


def test_a_checkpoint_of_another_legend_size_without_a_manifest_is_one_line(copy_of):
    from physgs_nerfstudio.runfiles.check import RunFilesError

    cfg, data = copy_of
    (cfg.parent / MANIFEST).unlink()
    doc = _materials(data)
    doc["materials"].append(dict(doc["materials"][0], name="extra"))
    _write_materials(data, doc)
    with pytest.raises(RunFilesError, match="trained with 2 materials, the dataset.s materials.json lists 3"):
        load_run(cfg, capture=False)


@pytest.mark.parametrize("pose", ["nan", "zero"])
def test_a_bad_pose_is_one_line_naming_the_frame(copy_of, pose):
    from physgs_nerfstudio.runfiles.check import RunFilesError

    cfg, data = copy_of
    (cfg.parent / MANIFEST).unlink()  # the manifest would refuse the edited transforms.json first
    meta = json.loads((data / "transforms.json").read_text())
    value = float("nan") if pose == "nan" else 0.0
    meta["frames"][1]["transform_matrix"] = [[value] * 4 for _ in range(3)] + [[0, 0, 0, 1]]
    (data / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(RunFilesError) as ei:
        load_run(cfg, capture=False)
    msg = str(ei.value)
    assert "the pose of frame" in msg and Path(meta["frames"][1]["file_path"]).name in msg and "\n" not in msg


# ------------------------------------------------------------------------------------------ an empty object
def test_an_object_too_small_for_a_surface_is_one_line():
    import numpy as np

    from physgs_nerfstudio.geometry import GeometryError
    from physgs_nerfstudio.geometry.grid import VoxelGrid
    from physgs_nerfstudio.geometry.walls import part_areas

    grid = VoxelGrid((0.0, 0.0, 0.0), 0.1, (9, 9, 9))
    solid = np.zeros(grid.shape, bool)
    solid[4, 4, 4] = True  # one voxel: smoothed, it stays below the surface level (marching cubes refused it)
    with pytest.raises(GeometryError, match="the object came out empty: carving left 1 solid voxel"):
        part_areas(grid, solid, np.zeros(grid.shape, np.int64), 1)
    solid[3:6, 3:6, 3:6] = True  # a small cube still has its surface
    assert part_areas(grid, solid, np.zeros(grid.shape, np.int64), 1).area[0] > 0


def test_no_selected_gaussian_says_what_was_seen():
    from physgs_nerfstudio.geometry.select import SelectConfig, _nothing_selected

    views = [SimpleNamespace(mask=torch.zeros(4, 4, dtype=torch.bool)) for _ in range(3)]
    prob, opaque = torch.tensor([0.1, 0.2]), torch.tensor([True, True])
    assert "none of the 3 views has an object mask" in _nothing_selected(prob, opaque, views, SelectConfig())
    views[0].mask[0, 0] = True
    msg = _nothing_selected(prob, opaque, views, SelectConfig())
    assert "1 of 3 views have object masks" in msg and "best foreground probability of an opaque Gaussian is 0.20" in msg


# ------------------------------------------------------------------------------------------ LPIPS
def test_lpips_is_skipped_without_downloading_when_its_weights_are_absent(tmp_path, monkeypatch, capsys):
    from torchmetrics.image import lpip

    from physgs_nerfstudio.nerfstudio.model import ALEXNET_WEIGHTS, _LazyLPIPS

    built = []

    class Fake:
        def __init__(self, **kw):
            built.append(kw)

        def to(self, device):
            return self

        def __call__(self, a, b):
            return torch.tensor(0.25)

    monkeypatch.setattr(lpip, "LearnedPerceptualImagePatchSimilarity", Fake)
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))  # torch.hub.get_dir(): no weights there
    a = torch.zeros(1, 3, 8, 8)
    metric = _LazyLPIPS(True)
    assert torch.isnan(metric(a, a)) and torch.isnan(metric(a, a)) and built == []  # never built: no download
    out = capsys.readouterr().out
    assert out.count("LPIPS skipped") == 1 and "nothing is downloaded" in out
    (tmp_path / "torch" / "hub" / "checkpoints").mkdir(parents=True)
    (tmp_path / "torch" / "hub" / "checkpoints" / ALEXNET_WEIGHTS).write_bytes(b"weights")
    assert float(_LazyLPIPS(True)(a, a)) == 0.25 and len(built) == 1


# ------------------------------------------------------------------------------------------ the viewer
def test_the_viewer_panel_refuses_a_swapped_legend(copy_of):
    from physgs_nerfstudio.viewer.panel import PhysicalPropertiesPanel

    cfg, data = copy_of
    doc = _materials(data)
    doc["materials"].reverse()
    _write_materials(data, doc)
    meta = _metadata_of(cfg, data)
    meta["material_legend"] = SimpleNamespace(names=[m["name"] for m in doc["materials"]], path=data / "materials.json")
    dm = SimpleNamespace(train_dataparser_outputs=SimpleNamespace(metadata=meta), config=SimpleNamespace(data=data))
    viewer = SimpleNamespace(pipeline=SimpleNamespace(datamanager=dm), log_filename=cfg.parent / "viewer_log.txt")
    panel = SimpleNamespace(control=SimpleNamespace(viewer=viewer), a_legend=SimpleNamespace(content=""))
    panel._run_dir = lambda: cfg.parent
    why = PhysicalPropertiesPanel.run_mismatch(panel)
    assert why is not None and "was trained with the materials" in why
    assert "does not match its dataset" in panel.a_legend.content
    doc["materials"].reverse()
    _write_materials(data, doc)
    meta["material_legend"].names.reverse()
    panel = SimpleNamespace(control=SimpleNamespace(viewer=viewer), a_legend=SimpleNamespace(content="legend"))
    panel._run_dir = lambda: cfg.parent
    assert PhysicalPropertiesPanel.run_mismatch(panel) is None and panel.a_legend.content == "legend"


def test_the_demo_retrains_after_perception_is_redone():
    from physgs_nerfstudio.demo import DemoCommand

    cmd = DemoCommand(force=("perceive",))
    assert cmd._forced("perceive") and cmd._forced("train") and cmd._forced("export") and not cmd._forced("scene")
    assert not DemoCommand()._forced("export") and DemoCommand(force=("export",))._forced("export")
