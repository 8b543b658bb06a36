"""Issue 17, the files side: hostile or careless files and folders give one line and lose nothing.

Each test names the issue's item. Oracles: the bytes of a previous export before and after a failed one, a
marker file a YAML payload would create, nerfstudio's own config writer and loader, Gent's relation computed
here, hand-written tables.
"""

from __future__ import annotations

import copy
import errno
import hashlib
import json
import math
import os
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from physgs_nerfstudio.errors import PhysGSError
from physgs_nerfstudio.export import command as export_command
from physgs_nerfstudio.export.command import ExportCommand, LoadedRun, load_run, run_export
from physgs_nerfstudio.export.shapes import field_from, solid_box
from physgs_nerfstudio.export.staging import MARKER, ExportDirError, ExportStage, ExportWriteError
from physgs_nerfstudio.geometry import GeometryConfig, reconstruct_object
from physgs_nerfstudio.mass import MassConfig
from physgs_nerfstudio.runfiles.check import RunFilesError, check_run
from physgs_nerfstudio.safe_yaml import ConfigObject, UnsafeConfigError, load_config_tree, load_config_yaml

REPO = Path(__file__).resolve().parents[1]


def _one_line(err: BaseException) -> str:
    text = str(err)
    assert "\n" not in text.strip(), text
    return text


def _tree(d: Path) -> dict[str, str]:
    """{relative path: sha1} of every file under d (the oracle for "the previous export is unchanged")."""
    return {p.relative_to(d).as_posix(): hashlib.sha1(p.read_bytes()).hexdigest()
            for p in sorted(d.rglob("*")) if p.is_file()}  # fmt: skip


def _leftovers(d: Path) -> list[str]:
    return sorted(p.name for p in d.parent.iterdir() if p.name.startswith(f".{d.name}.physgs-"))


# ------------------------------------------------------------------------------------------ a small run
@pytest.fixture(scope="module")
def small_run():
    """A two-material box with its carved geometry, computed once (export tests reuse it)."""
    from helpers.shapes import ring_views

    means, scales, quats = solid_box((0.6, 0.4, 0.3), 0.05)
    labels = (means[:, 0] > 0).long()
    pf = field_from(means, 0.5 * scales, quats, densities=[700.0, 2500.0], labels=labels,
                    thickness_m=[None, 0.003], names=["oak", "glass"], metres_per_unit=0.5)  # fmt: skip
    views = ring_views(pf, (0, 0, 0), 1.8, n=6, elevations=(-20.0, 40.0), size=32, mask_pf=replace(pf, scales=pf.scales * 4))
    cfg = GeometryConfig(resolution=20, backend="reference", variants=False)
    geo = reconstruct_object(pf, pf.pi(), views, (), list(pf.thickness_m), cfg, material_names=pf.material_names)
    return LoadedRun(pf, None, views, [], None), geo


MASS = MassConfig(n_samples=200)
OUTS = ("ply", "voxels", "mass")


@pytest.fixture
def export(small_run, monkeypatch):
    """run_export(out, **kw) on the small run, its geometry cached."""
    run, geo = small_run
    monkeypatch.setattr(export_command, "object_geometry", lambda *a, **k: geo)

    def go(out: Path, **kw):
        kw.setdefault("outputs", OUTS)
        return run_export(run, out, mass=MASS, quiet=True, **kw)

    return go


def _enospc(*_a, **_k):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def _partial_npz(path, **arrays):
    """np.savez_compressed that writes 3 arrays, then the disk is full (what the issue found)."""
    import zipfile

    with zipfile.ZipFile(path, "w") as z:
        for k in list(arrays)[:3]:
            with z.open(f"{k}.npy", "w") as f:
                np.lib.format.write_array(f, np.asanyarray(arrays[k]))
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))


def _fail_at(monkeypatch, where: str) -> None:
    """Make the disk fill up at one point of the export (the write layer of each writer)."""
    import plyfile

    from physgs_nerfstudio.export import staging

    if where == "ply":
        def half(self, stream):
            Path(stream).write_bytes(b"ply\nformat binary_little_endian 1.0\n")
            _enospc()
        monkeypatch.setattr(plyfile.PlyData, "write", half)
    elif where == "voxels":
        monkeypatch.setattr(np, "savez_compressed", _partial_npz)
    elif where in ("report", "marker"):
        name = "report.json" if where == "report" else MARKER
        real = Path.write_text

        def write_text(self, data, *a, **k):
            if self.name == name:
                real(self, data[: len(data) // 3], *a, **k)
                _enospc()
            return real(self, data, *a, **k)
        monkeypatch.setattr(Path, "write_text", write_text)
    elif where == "swap":
        real_rename = os.rename

        def rename(src, dst):
            if ".physgs-staging-" in str(src):
                _enospc()
            return real_rename(src, dst)
        monkeypatch.setattr(staging.os, "rename", rename)


# ------------------------------------------------------------------------------------------ 3: as a unit
@pytest.mark.parametrize("where", ["ply", "voxels", "report", "marker", "swap"])
def test_3_disk_full_anywhere_keeps_the_previous_export(export, tmp_path, monkeypatch, where):
    out = tmp_path / "export"
    first = export(out)
    assert (out / MARKER).is_file() and first.mass is not None
    before = _tree(out)
    assert {"property_field.ply", "voxels.npz", "report.json", MARKER} <= set(before)
    _fail_at(monkeypatch, where)
    with pytest.raises(ExportWriteError) as ei:
        export(out)
    msg = _one_line(ei.value)
    assert str(out) in msg and "previous export" in msg
    monkeypatch.undo()
    assert _tree(out) == before  # byte for byte
    assert _leftovers(out) == []


def test_3_a_silently_short_voxel_grid_fails_the_check(export, tmp_path, monkeypatch):
    out = tmp_path / "export"
    export(out)
    before = _tree(out)

    def short(path, **arrays):  # a writer that "succeeds" with 3 of its arrays
        np.savez(path, **{k: arrays[k] for k in list(arrays)[:3]}, meta=arrays["meta"])
    monkeypatch.setattr(np, "savez_compressed", short)
    with pytest.raises(ExportWriteError, match="voxels.npz.*missing"):
        export(out)
    assert _tree(out) == before and _leftovers(out) == []


def test_3_a_kill_between_the_two_renames_is_repaired(export, tmp_path):
    out = tmp_path / "export"
    export(out)
    before = _tree(out)
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True, check=True)
    pid = int(dead.stdout)
    os.rename(out, tmp_path / f".export.physgs-old-{pid}-abcd1234")  # the state a kill -9 leaves
    (tmp_path / f".export.physgs-staging-{pid}-efgh5678").mkdir()
    stage = ExportStage.open(out, log=lambda line: None)
    stage.abort()
    assert _tree(out) == before and _leftovers(out) == []


def _mount_tmpfs(mnt: Path, size: int) -> None:
    if os.geteuid() != 0:
        pytest.skip("a real full disk needs root to mount a tmpfs")
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mnt)],
                          capture_output=True, text=True, check=False)  # fmt: skip
    if proc.returncode != 0:
        pytest.skip(f"mount -t tmpfs failed here: {proc.stderr.strip() or proc.returncode}")


def test_3_real_full_tmpfs_keeps_the_previous_export(export, tmp_path):
    probe = tmp_path / "probe"
    export(probe)
    pages = sum(-(-p.stat().st_size // 4096) * 4096 for p in probe.rglob("*") if p.is_file())
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    _mount_tmpfs(mnt, pages * 3 // 2 // 4096 * 4096 + 8192)  # room for one export, not for two at once
    try:
        out = mnt / "export"
        export(out)
        before = _tree(out)
        with pytest.raises(ExportWriteError) as ei:
            export(out)  # the staged copy cannot fit beside the previous one
        assert "No space left" in _one_line(ei.value) or "ENOSPC" in str(ei.value)
        assert _tree(out) == before and _leftovers(out) == []
        shutil.rmtree(out)
        export(out)  # with room again it succeeds
        assert (out / MARKER).is_file()
    finally:
        subprocess.run(["umount", str(mnt)], check=False)


# ------------------------------------------------------------------------------------------ 6: overwrite
def test_6_a_foreign_folder_is_refused_before_loading_anything(tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    for name, text in (("report.json", "{}"), ("property_field.ply", "x"), ("notes.txt", "keep me")):
        (out / name).write_text(text)
    before = _tree(out)
    cmd = ExportCommand(load_config=tmp_path / "no_such_run" / "config.yml", output_dir=out)
    with pytest.raises(ExportDirError) as ei:  # the folder is checked first: no minutes of loading wasted
        cmd.main()
    assert "--overwrite" in _one_line(ei.value) and "notes.txt" in str(ei.value)
    assert _tree(out) == before


def test_6_overwrite_replaces_the_whole_folder_and_never_mixes(export, tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("old")
    (out / "report.json").write_text("{}")
    with pytest.raises(ExportDirError):
        export(out)
    export(out, overwrite=True)
    assert sorted(_tree(out)) == sorted(["property_field.ply", "voxels.npz", "report.json", MARKER])
    report = json.loads((out / "report.json").read_text())
    assert report["files"]["ply"] == [str(out.resolve() / "property_field.ply")]  # final paths, not staging


def test_6_a_previous_export_is_replaced_whole(export, tmp_path, small_run):
    out = tmp_path / "export"
    export(out, outputs=("ply", "voxels", "mass"))
    export(out, outputs=("ply",))  # ours: replaced without --overwrite; the old voxels/report do not linger
    assert set(_tree(out)) == {"property_field.ply", MARKER}
    listed = json.loads((out / MARKER).read_text())["files"]
    assert set(listed) == {"property_field.ply"}
    (out / "notes.txt").write_text("added by hand")  # no longer only an export: refused
    with pytest.raises(ExportDirError, match="notes.txt"):
        export(out)


def test_6_an_export_from_before_the_marker_counts_as_ours(export, tmp_path):
    out = tmp_path / "export"
    export(out)
    (out / MARKER).unlink()
    export(out)
    assert (out / MARKER).is_file()


def test_6_overwrite_never_deletes_the_run_or_the_dataset(export, tmp_path, small_run):
    run_dir = tmp_path / "outputs" / "scene" / "physgs" / "t"
    run_dir.mkdir(parents=True)
    (run_dir / "config.yml").write_text("x: 1\n")
    for target in (run_dir, tmp_path / "outputs"):
        with pytest.raises(ExportDirError, match="would delete"):
            export(target, overwrite=True, source=run_dir / "config.yml")
    assert (run_dir / "config.yml").read_text() == "x: 1\n"


# ------------------------------------------------------------------------------------------ 5: YAML
PAYLOADS = {
    "apply_os_system": 'x: !!python/object/apply:os.system ["touch {m}"]\n',
    "apply_mapping_form": 'x: !!python/object/apply:os.system {{args: ["touch {m}"]}}\n',
    "new_os_system": 'x: !!python/object/new:os.system ["touch {m}"]\n',
    "subprocess": 'x: !!python/object/apply:subprocess.check_call [["touch", "{m}"]]\n',
    "popen": 'x: !!python/object/new:subprocess.Popen [["touch", "{m}"]]\n',
    "subprocess_run": 'x: !!python/object/apply:subprocess.run [["touch", "{m}"]]\n',
    "builtins_eval": "x: !!python/object/apply:builtins.eval [\"__import__('os').system('touch {m}')\"]\n",
    "builtins_exec": "x: !!python/object/apply:builtins.exec [\"open('{m}', 'w')\"]\n",
    "module_tag": "x: !!python/module:os\n",
    "name_of_function": "x: !!python/name:os.system\n",
    "attribute_chain": 'x: !!python/object/apply:pathlib.Path.touch ["{m}"]\n',
    "in_a_key": '? !!python/object/apply:os.system ["touch {m}"]\n: 1\n',
    "behind_an_alias": 'a: &p [1]\nb: *p\nc: !!python/object/apply:os.system ["touch {m}"]\n',
    "inside_a_real_config": ("!!python/object:nerfstudio.engine.trainer.TrainerConfig\n"
                             'method_name: !!python/object/apply:os.system ["touch {m}"]\n'),
    "nerfstudio_class_called": "x: !!python/object/apply:nerfstudio.engine.trainer.TrainerConfig []\n",
    "reexported_os": "x: !!python/name:nerfstudio.utils.eval_utils.os\n",
    "state_setter": ('x: !!python/object/new:pathlib.PosixPath\n  state: !!python/object/apply:os.system '
                     '["touch {m}"]\n'),
    "custom_tag": "x: !evil 1\n",
    "function_of_an_allowed_package": 'x: !!python/object/apply:nerfstudio.utils.io.write_to_json ["{m}", {{}}]\n',
}


@pytest.mark.parametrize("name", sorted(PAYLOADS))
def test_5_malicious_configs_never_run(tmp_path, name):
    marker = tmp_path / "pwned.txt"
    evil = tmp_path / "config.yml"
    evil.write_text(PAYLOADS[name].format(m=marker))
    with pytest.raises(UnsafeConfigError) as ei:
        load_config_yaml(evil)
    msg = _one_line(ei.value)
    assert str(evil) in msg and "line " in msg
    assert not marker.exists()
    with pytest.raises(PhysGSError):  # the same through the export's loader
        load_run(evil)
    assert not marker.exists()


@pytest.mark.parametrize("name", sorted(PAYLOADS))
def test_5_the_name_tree_imports_and_runs_nothing_and_its_build_refuses(tmp_path, name):
    """load_config_tree judges tags by name only; whatever it lets through as a name, build() refuses, and
    nothing runs either way."""
    marker = tmp_path / "pwned.txt"
    evil = tmp_path / "config.yml"
    evil.write_text(PAYLOADS[name].format(m=marker))
    try:
        tree = load_config_tree(evil)
    except UnsafeConfigError:
        tree = None
    if tree is not None:
        values = list(tree.fields.values()) if isinstance(tree, ConfigObject) else [*tree.keys(), *tree.values()]
        built = [v for v in values if hasattr(v, "build")]
        assert built, f"{name}: the tree holds no python object to refuse: {tree!r}"
        for value in built:
            with pytest.raises(UnsafeConfigError):
                value.build()
    assert not marker.exists()


def _nerfstudio_config(tmp_path: Path, method: str, data: Path) -> Path:
    """A config.yml written by nerfstudio itself (ExperimentConfig.save_config, as ns-train does)."""
    from nerfstudio.configs.method_configs import all_methods

    cfg = copy.deepcopy(all_methods[method])
    cfg.pipeline.datamanager.data = data
    cfg.output_dir, cfg.experiment_name, cfg.timestamp = tmp_path / "outputs", "scene", "t"
    cfg.machine.device_type = "cpu"
    cfg.save_config()
    return cfg.get_base_dir() / "config.yml"


@pytest.mark.parametrize("method", ["physgs", "physgs-lite", "splatfacto"])
def test_5_real_nerfstudio_configs_load_as_nerfstudio_loads_them(tmp_path, method):
    import yaml

    path = _nerfstudio_config(tmp_path, method, tmp_path / "scene")
    ours = load_config_yaml(path)
    theirs = yaml.load(path.read_text(), Loader=yaml.Loader)  # nerfstudio's eval_setup (trusted file here)
    assert type(ours) is type(theirs) and repr(ours) == repr(theirs)
    assert ours.method_name == method and ours.pipeline.datamanager.data == tmp_path / "scene"
    tree = load_config_tree(path)  # the export's reading: names only, then the real object when built
    assert tree.class_name == "nerfstudio.engine.trainer.TrainerConfig" and tree.method_name == method
    built = tree.build()
    assert type(built) is type(theirs) and repr(built) == repr(theirs)


def test_5_the_name_tree_imports_no_class(tmp_path):
    path = _nerfstudio_config(tmp_path, "physgs", tmp_path / "scene")
    code = ("import sys; from physgs_nerfstudio.safe_yaml import load_config_tree; t = load_config_tree(sys.argv[1]); "
            "print(t.pipeline.model.class_name, sorted(m for m in sys.modules if m.split('.')[0] in "
            "('nerfstudio', 'torch', 'gsplat') or m.startswith('physgs_nerfstudio.nerfstudio')))")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["physgs_nerfstudio.nerfstudio.model.PhysGSModelConfig", "[]"]


def _physgs(argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(REPO), PYTHONWARNINGS="ignore")
    return subprocess.run([sys.executable, "-m", "physgs_nerfstudio.cli", *argv], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300, check=False)  # fmt: skip


def test_5_6_the_cli_says_one_line_and_runs_nothing(tmp_path):
    (tmp_path / "evil.yml").write_text('x: !!python/object/apply:os.system ["touch pwned.txt"]\n')
    proc = _physgs(["export", "--load-config", "evil.yml", "--output-dir", "out"], tmp_path)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode != 0 and "Traceback" not in proc.stderr, proc.stderr
    assert lines[-1].startswith("physgs export: ") and "evil.yml, line 1: refused" in lines[-1], proc.stderr
    assert not (tmp_path / "pwned.txt").exists() and not (tmp_path / "out").exists()
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    proc = _physgs(["export", "--load-config", "evil.yml", "--output-dir", "foreign"], tmp_path)
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    assert "not empty and not a previous physgs export" in proc.stderr.strip().splitlines()[-1]
    assert (foreign / "notes.txt").read_text() == "mine"


# ------------------------------------------------------------------------------------------ 10b, 13: run files
@pytest.fixture(scope="module")
def trained_run(tmp_path_factory):
    """A physgs-lite run folder as ns-train leaves it (config.yml written by nerfstudio,
    dataparser_transforms.json, nerfstudio_models/step-*.ckpt of the pipeline's state), without training."""
    from helpers.nerfstudio_scenes import write_synth_scene

    root = tmp_path_factory.mktemp("run")
    data = root / "scene"
    write_synth_scene(data, resolution=32, views=6)
    config_path = _nerfstudio_config(root, "physgs-lite", data)
    config = load_config_yaml(config_path)
    pipeline = config.pipeline.setup(device="cpu", test_mode="inference")
    base = config_path.parent
    pipeline.datamanager.train_dataparser_outputs.save_dataparser_transform(base / "dataparser_transforms.json")
    (base / "nerfstudio_models").mkdir()
    torch.save({"step": 7, "pipeline": pipeline.state_dict()}, base / "nerfstudio_models" / "step-000000007.ckpt")
    return config_path


def test_the_cli_export_ends_at_once_with_its_files_complete(trained_run, tmp_path):
    """`physgs export` ends its process without the interpreter's teardown (cli.main): the exit status, the printed
    output and the written files are those of the normal exit (PHYSGS_NO_FAST_EXIT=1)."""
    args = ["export", "--load-config", str(trained_run), "--outputs", "ply", "--device", "cpu"]
    fast = _physgs([*args, "--output-dir", "fast"], tmp_path)
    env = dict(os.environ, PYTHONPATH=str(REPO), PYTHONWARNINGS="ignore", PHYSGS_NO_FAST_EXIT="1")
    slow = subprocess.run([sys.executable, "-m", "physgs_nerfstudio.cli", *args, "--output-dir", "slow"], cwd=tmp_path,
                          env=env, capture_output=True, text=True, timeout=300, check=False)  # fmt: skip
    assert fast.returncode == 0 and slow.returncode == 0, fast.stderr[-2000:] + slow.stderr[-2000:]
    assert fast.stdout.strip() and fast.stdout.splitlines()[-1] == slow.stdout.splitlines()[-1]
    assert _tree(tmp_path / "fast").keys() == _tree(tmp_path / "slow").keys()
    ply = [k for k in _tree(tmp_path / "fast") if k.endswith(".ply")]
    assert ply and all((tmp_path / "fast" / k).read_bytes() == (tmp_path / "slow" / k).read_bytes() for k in ply)


def _copy_run(config_path: Path, dest: Path) -> Path:
    shutil.copytree(config_path.parent, dest)
    return dest / "config.yml"


def test_10b_a_moved_run_loads_the_checkpoint_beside_its_config(trained_run, tmp_path, capsys):
    moved = _copy_run(trained_run, tmp_path / "elsewhere" / "my_run")
    original = trained_run.parent
    aside = original.with_name("t_aside")
    original.rename(aside)  # the stored path is gone
    try:
        run = load_run(moved)
    finally:
        aside.rename(original)
    err = capsys.readouterr().err
    assert f"checkpoints from {moved.parent / 'nerfstudio_models'}" in err and "absent" in err
    assert run.field.num_gaussians > 0 and run.views


def test_10b_a_copy_beside_an_existing_original_uses_its_own_checkpoint(trained_run, tmp_path):
    copy_cfg = _copy_run(trained_run, tmp_path / "copy")
    ckpts = copy_cfg.parent / "nerfstudio_models"
    (ckpts / "step-000000007.ckpt").rename(ckpts / "step-000000009.ckpt")
    lines: list[str] = []
    files = check_run(copy_cfg, log=lines.append)
    assert files.relocated and files.checkpoint == ckpts / "step-000000009.ckpt" and files.step == 9
    assert len(lines) == 1 and "another folder" in lines[0]
    cfg = files.trainer_config()
    assert Path(cfg.get_checkpoint_dir()) == ckpts and cfg.load_step == 9
    assert files.config.load_step is None  # the checked tree itself is left as read
    same = check_run(trained_run, log=lines.append)  # the original: its own stored folder, nothing printed
    assert not same.relocated and len(lines) == 1


def test_13_missing_checkpoint_is_one_line(trained_run, tmp_path):
    cfg = _copy_run(trained_run, tmp_path / "run")
    shutil.rmtree(cfg.parent / "nerfstudio_models")
    (cfg.parent / "nerfstudio_models").mkdir()  # empty: nerfstudio raised IndexError
    original = trained_run.parent / "nerfstudio_models"
    original.rename(original.with_name("hidden"))
    try:
        with pytest.raises(RunFilesError) as ei:
            load_run(cfg)
    finally:
        original.with_name("hidden").rename(original)
    assert "no checkpoint" in _one_line(ei.value) and str(cfg.parent / "nerfstudio_models") in str(ei.value)


@pytest.mark.parametrize("keep", [0, 100, 0.5])
def test_13_truncated_checkpoint_is_one_line(trained_run, tmp_path, keep):
    cfg = _copy_run(trained_run, tmp_path / "run")
    ckpt = cfg.parent / "nerfstudio_models" / "step-000000007.ckpt"
    data = ckpt.read_bytes()
    ckpt.write_bytes(data[: int(len(data) * keep) if isinstance(keep, float) else keep])
    with pytest.raises(RunFilesError) as ei:
        load_run(cfg)
    assert "truncated or damaged" in _one_line(ei.value) and str(ckpt) in str(ei.value)


def test_13_a_config_of_another_method_is_named(tmp_path):
    path = _nerfstudio_config(tmp_path, "splatfacto", tmp_path / "scene")
    (path.parent / "nerfstudio_models").mkdir()
    with pytest.raises(RunFilesError) as ei:
        load_run(path)
    assert "'splatfacto', not PhysGS" in _one_line(ei.value) and str(path) in str(ei.value)


@pytest.mark.parametrize("content,expect", [
    ('{"frames": [', "not valid JSON (line 1"),
    ("[1, 2]", "a JSON list, not an object"),
    ('{"camera_model": "OPENCV"}', 'no "frames" list'),
    ('{"frames": [{"transform_matrix": []}]}', 'frame 0 has no "file_path"'),
])  # fmt: skip
def test_13_a_broken_transforms_json_names_the_file(trained_run, tmp_path, content, expect):
    import yaml

    data = tmp_path / "scene"
    shutil.copytree(trained_run.parents[4] / "scene", data)
    (data / "transforms.json").write_text(content)
    cfg = _copy_run(trained_run, tmp_path / "run")
    config = load_config_yaml(cfg)
    config.pipeline.datamanager.data = data
    cfg.write_text(yaml.dump(config))  # as nerfstudio writes it
    with pytest.raises(RunFilesError) as ei:
        load_run(cfg)
    msg = _one_line(ei.value)
    assert msg.startswith(str(data / "transforms.json")) and expect in msg and "transforms.json.bak" in msg


# ------------------------------------------------------------------------------------------ 10d, 11: eval
def _table(tmp_path: Path, truth_kg: str, pred_kg: str):
    from physgs_nerfstudio.eval.command import EvalCommand

    (tmp_path / "t.csv").write_text(f"item,property,value,unit\na,mass,1.0,kg\nb,mass,{truth_kg},kg\n")
    (tmp_path / "p.csv").write_text(f"item,property,mean,unit\na,mass,1.2,kg\nb,mass,{pred_kg},kg\n")
    return EvalCommand(dataset="table", ground_truth=tmp_path / "t.csv", predictions=(str(tmp_path / "p.csv"),),
                       output_dir=tmp_path / "eval")  # fmt: skip


@pytest.mark.parametrize("truth,pred,where", [("0", "1", "t.csv"), ("2", "0", "p.csv"), ("2", "-0.5", "p.csv"),
                                              ("-1", "2", "t.csv")])  # fmt: skip
def test_10d_eval_rejects_zero_or_negative_masses(tmp_path, capsys, truth, pred, where):
    from physgs_nerfstudio.eval.command import run_eval
    from physgs_nerfstudio.eval.errors import EvalInputError

    cmd = _table(tmp_path, truth, pred)
    with pytest.raises(EvalInputError) as ei:
        run_eval(cmd)
    msg = _one_line(ei.value)
    assert where in msg and "item 'b'" in msg and "must be > 0" in msg
    with pytest.raises(PhysGSError):
        cmd.main()
    assert not (tmp_path / "eval").exists()


def test_11_eval_scores_unclamped_by_default_and_clamps_on_request(tmp_path):
    import tyro

    from physgs_nerfstudio.eval.command import EvalCommand, run_eval

    root = tmp_path / "abo_500"
    root.mkdir()
    (root / "filtered_product_weights.json").write_text(json.dumps({"A1": 2.0, "B2": 120.0, "C3": 0.5}))
    (root / "splits.json").write_text(json.dumps({"test": ["A1_x", "B2_y", "C3_z"]}))
    preds = tmp_path / "preds_mass.json"
    preds.write_text(json.dumps({"A1_x": [1.0, 3.0], "B2_y": [150.0, 250.0], "C3_z": [0.001, 0.003]}))
    cmd = tyro.cli(EvalCommand, args=["--dataset", "abo500", "--ground-truth", str(root), "--predictions", str(preds)])
    assert cmd.clamp is None
    rows = {r.item: r for r in run_eval(cmd).items}
    assert [rows[i].pred for i in ("A1_x", "B2_y", "C3_z")] == pytest.approx([2.0, 200.0, 0.002])
    assert rows["C3_z"].ALDE == pytest.approx(abs(math.log(0.002 / 0.5)))
    clamped = tyro.cli(EvalCommand, args=["--dataset", "abo500", "--ground-truth", str(root), "--predictions",
                                          str(preds), "--clamp", "0.01", "100"])  # fmt: skip
    assert clamped.clamp == (0.01, 100.0)
    rows = {r.item: r for r in run_eval(clamped).items}
    assert [rows[i].pred for i in ("A1_x", "B2_y", "C3_z")] == pytest.approx([2.0, 100.0, 0.01])


# ------------------------------------------------------------------------------------------ 10e: silicone
def _gent_mpa(shore_a: float) -> float:
    """Gent (1958): Young's modulus (MPa) of a rubber from its Shore A hardness."""
    return 0.0981 * (56 + 7.62336 * shore_a) / (0.137505 * (254 - 2.54 * shore_a))


def test_10e_solid_elastomers_agree_with_gents_relation():
    from physgs_nerfstudio.materials import load_library

    assert _gent_mpa(50) == pytest.approx(2.456, abs=0.002)  # the relation itself, by hand: 42.886 / 17.463
    lib = load_library("indoor")
    for name in ("silicone", "rubber", "natural_rubber", "neoprene"):
        m = lib[lib.resolve(name)]
        assert m.hardness_scale == "A"
        shore = float(m.properties["shore_hardness"].typical)  # canonical A_eq = Shore A on 0-100
        e = m.properties["youngs_modulus"]
        ratio = e.typical / (_gent_mpa(shore) * 1e6)
        assert 1 / 1.5 < ratio < 1.5, (name, e.typical, ratio)
        assert e.low <= _gent_mpa(shore) * 1e6 <= e.high
    silicone = lib[lib.resolve("silicone")].properties["youngs_modulus"]
    assert silicone.low <= _gent_mpa(20) * 1e6 * 1.01 and silicone.high >= _gent_mpa(80) * 1e6


# ------------------------------------------------------------------------ a failed geometry loses nothing else
def _no_object(*_a, **_k):
    from physgs_nerfstudio.geometry import GeometryError

    raise GeometryError("carving left no solid voxel: the object masks and the views disagree")


def test_a_failed_geometry_still_writes_the_ply_and_says_why(small_run, tmp_path, monkeypatch):
    run, _ = small_run
    monkeypatch.setattr(export_command, "object_geometry", _no_object)
    out = tmp_path / "export"
    result = run_export(run, out, mass=MASS, outputs=OUTS, quiet=True)
    assert result.mass is None and "no solid voxel" in result.error
    assert sorted(_tree(out)) == sorted(["property_field.ply", "report.json", MARKER])  # no voxels.npz
    report = json.loads((out / "report.json").read_text())
    assert report["mass"] is None and "no solid voxel" in report["mass_error"]
    assert report["files"]["ply"] == [str(out.resolve() / "property_field.ply")]


def test_the_export_command_exits_with_one_line_after_writing_the_rest(trained_run, tmp_path, monkeypatch):
    monkeypatch.setattr(export_command, "object_geometry", _no_object)
    out = tmp_path / "export"
    with pytest.raises(PhysGSError) as ei:
        ExportCommand(load_config=trained_run, output_dir=out, outputs=("ply", "mass")).main()
    msg = _one_line(ei.value)
    assert "mass and voxels not written" in msg and "written: ply, report" in msg and str(out) in msg
    assert (out / "property_field.ply").is_file() and json.loads((out / "report.json").read_text())["mass"] is None
