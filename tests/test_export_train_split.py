"""The export's reader of a run's training cameras (runfiles/train_split.py) against nerfstudio's own dataparser."""

from __future__ import annotations

import json
import logging
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from physgs_nerfstudio.export.command import load_run
from physgs_nerfstudio.runfiles import train_split
from physgs_nerfstudio.runfiles.check import check_run
from physgs_nerfstudio.runfiles.loader import _dataparser_outputs, load_run_state
from physgs_nerfstudio.runfiles.train_split import TrainSplit, Unsupported, read_train_split
from physgs_nerfstudio.safe_yaml import load_config_tree


def _tree(config_path: Path, data: Path | None = None, **dataparser):
    config = load_config_tree(config_path)
    dm = config.pipeline.datamanager
    if data is not None:
        dm.data = data
    for key, value in dataparser.items():
        dm.dataparser.fields[key] = value
    return config


def _assert_same(fast, want) -> None:
    """Every camera value (bit-equal, same dtype and shape), image, material map and the legend."""
    a, b = fast.cameras, want.cameras
    for name in ("camera_to_worlds", "fx", "fy", "cx", "cy", "width", "height", "distortion_params"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape and torch.equal(x, y), name
    assert fast.image_filenames == want.image_filenames
    for key in ("material_filenames", "material_confidence_filenames"):
        assert fast.metadata[key] == want.metadata[key], key
    la, lb = fast.metadata["material_legend"], want.metadata["material_legend"]
    assert (la.names, la.property_keys, la.log_space, la.alpha0, la.lam, la.path) == (
        lb.names, lb.property_keys, lb.log_space, lb.alpha0, lb.lam, lb.path)  # fmt: skip
    assert torch.equal(la.colors, lb.colors) and all(torch.equal(la.nig[f], lb.nig[f]) for f in la.nig)


def _oracle(config_path: Path, run_dir: Path, data: Path | None = None, **dataparser) -> None:
    """nerfstudio's training split (as eval_setup) of the config with these dataparser fields, its
    dataparser_transforms.json saved as training saves it, against the fast reader's."""
    want = _dataparser_outputs(_tree(config_path, data, **dataparser).build())
    run_dir.mkdir(parents=True, exist_ok=True)
    want.save_dataparser_transform(run_dir / "dataparser_transforms.json")
    config = _tree(config_path, data, **dataparser)
    fast = read_train_split(config.pipeline.datamanager.dataparser, config.pipeline.datamanager.data, run_dir)
    assert isinstance(fast, TrainSplit)
    _assert_same(fast, want)


def _variant(run: Path, dest: Path, names: dict[int, str] | None = None, **top) -> Path:
    """A copy of the run's dataset (images, maps, legend) whose transforms.json has its frames in another order,
    per-frame intrinsics and distortion, other image names (``names``: index -> file_path) and ``top`` keys."""
    data = Path(check_run(run).config.pipeline.datamanager.data)
    shutil.copytree(data, dest)
    meta = json.loads((dest / "transforms.json").read_text())
    frames = meta["frames"]
    for i, f in enumerate(frames):
        f.update(fl_x=meta["fl_x"] + 0.37 * i, fl_y=meta["fl_y"] - 0.11 * i, cx=meta["cx"] + 0.5 * i,
                 cy=meta["cy"] - 0.25 * i, w=meta["w"] + i, h=meta["h"] + 2 * i, k1=0.01 * i, p2=-0.002 * i)  # fmt: skip
        if names and i in names:
            f["file_path"] = names[i]
    for key in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
        del meta[key]
    meta["frames"] = frames[::-1]
    meta.update(top)
    (dest / "transforms.json").write_text(json.dumps(meta))
    return dest


@pytest.mark.parametrize("mode", [{"eval_mode": "fraction", "train_split_fraction": 0.5},
                                  {"eval_mode": "fraction"}, {"eval_mode": "interval", "eval_interval": 3},
                                  {"eval_mode": "all"}])  # fmt: skip
def test_fast_reader_equals_nerfstudio_s_dataparser(saved_run, tmp_path, mode) -> None:
    _oracle(saved_run, tmp_path / "run", **mode)
    data = _variant(saved_run, tmp_path / "data", names={0: "images/a/b.png", 1: "images/a-b.png"})
    _oracle(saved_run, tmp_path / "run2", data, **mode)


def test_fast_reader_filename_mode_and_split_lists(saved_run, tmp_path) -> None:
    names = {i: f"images/frame_{i:03d}_{'eval' if i % 3 == 1 else 'train'}.png" for i in range(6)}
    data = _variant(saved_run, tmp_path / "named", names=names)
    _oracle(saved_run, tmp_path / "run", data, eval_mode="filename")
    listed = _variant(saved_run, tmp_path / "listed", train_filenames=["images/frame_004.png", "images/frame_001.png",
                      "./images/frame_002.png"], val_filenames=["images/frame_000.png"])  # fmt: skip
    _oracle(saved_run, tmp_path / "run2", listed)
    val_only = _variant(saved_run, tmp_path / "val_only", val_filenames=["images/frame_000.png"])
    config = _tree(saved_run, val_only)
    with pytest.raises(Unsupported, match="no train_filenames"):  # nerfstudio refuses it: it says why
        read_train_split(config.pipeline.datamanager.dataparser, val_only, tmp_path / "run2")


def test_fast_reader_recovers_a_colmap_applied_transform(saved_run, tmp_path) -> None:
    data = _variant(saved_run, tmp_path / "data", applied_transform=[[0, 1, 0, 0], [1, 0, 0, 0], [0, 0, -1, 0]])
    _oracle(saved_run, tmp_path / "run", data)


def test_export_through_both_paths_is_the_same(saved_run, monkeypatch) -> None:
    fast = load_run(saved_run)

    def refuse(*args, **kwargs):
        raise Unsupported("test")

    monkeypatch.setattr(train_split, "read_train_split", refuse)
    slow = load_run(saved_run)
    assert type(slow.cameras).__name__ == "Cameras" and type(fast.cameras).__name__ == "TrainCameras"
    for name in ("means", "quats", "scales", "opacities", "alpha", "labelled", "evidence", "sh_dc", "sh_rest"):
        assert torch.equal(getattr(fast.field, name), getattr(slow.field, name)), name
    assert (fast.field.material_names, fast.field.thickness_m, fast.field.metres_per_unit) == (
        slow.field.material_names, slow.field.thickness_m, slow.field.metres_per_unit)  # fmt: skip
    assert len(fast.views) == len(slow.views) > 0
    for a, b in zip(fast.views, slow.views):
        assert (a.name, a.width, a.height, a.mask_source) == (b.name, b.width, b.height, b.mask_source)
        assert torch.equal(a.viewmat, b.viewmat) and torch.equal(a.K, b.K) and torch.equal(a.mask, b.mask)
    from physgs_nerfstudio.export.command import object_geometry
    from physgs_nerfstudio.mass import MassConfig, integrate_mass

    cfg = MassConfig(n_samples=64)
    masses = []
    for run in (fast, slow):
        try:
            report = integrate_mass(run.field, object_geometry(run, cfg.geometry), cfg)
            masses.append(json.dumps(report.to_dict(), sort_keys=True) if hasattr(report, "to_dict") else repr(report))
        except Exception as err:  # noqa: BLE001 - the random field may have no object: then the same error
            masses.append(f"{type(err).__name__}: {err}")
    assert masses[0] == masses[1]


def test_export_loading_imports_no_nerfstudio(saved_run) -> None:
    code = ("import sys; from pathlib import Path; from physgs_nerfstudio.export.command import load_run; "
            "r = load_run(Path(sys.argv[1])); print(r.field.num_gaussians, len(r.views), sorted(m for m in sys.modules "
            "if m.split('.')[0] in ('nerfstudio', 'sympy')))")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code, str(saved_run)], capture_output=True, text=True, check=True)
    n, views, imported = out.stdout.split(maxsplit=2)
    assert int(n) > 1 and int(views) > 0 and imported.strip() == "[]", out.stdout + out.stderr[-2000:]


def test_fallback_to_nerfstudio_without_dataparser_transforms(saved_run, tmp_path, caplog) -> None:
    files = check_run(saved_run)
    with caplog.at_level(logging.DEBUG, logger="physgs_nerfstudio.runfiles.loader"):
        rs = load_run_state(files.config, files.checkpoint, tmp_path)  # no dataparser_transforms.json there
    assert "dataparser_transforms.json not found" in caplog.text
    assert type(rs.dataparser_outputs).__name__ == "DataparserOutputs"
    fast = load_run_state(check_run(saved_run).config, files.checkpoint, files.run_dir).dataparser_outputs
    _assert_same(fast, rs.dataparser_outputs)


@pytest.mark.parametrize("change", [{"camera_model": "OPENCV_FISHEYE"}, {"applied_scale": 2.0},
                                    {"orientation_override": "none"},
                                    {"applied_transform": [[0.6, 0.8, 0, 0], [-0.8, 0.6, 0, 0], [0, 0, 1, 0]]}])  # fmt: skip
def test_fast_reader_refuses_what_it_does_not_reproduce(saved_run, tmp_path, change) -> None:
    data = _variant(saved_run, tmp_path / "data", **change)
    config = _tree(saved_run, data)
    with pytest.raises(Unsupported):
        read_train_split(config.pipeline.datamanager.dataparser, data, check_run(saved_run).run_dir)
    config = _tree(saved_run, data, orientation_method="pca")
    with pytest.raises(Unsupported, match="pca"):
        read_train_split(config.pipeline.datamanager.dataparser, data, check_run(saved_run).run_dir)
