"""The geometry cache (physgs_nerfstudio/export/geometry_cache.py): a stored geometry is the computed one bit for
bit, every input of the key changes it, and an unreadable entry is a miss, never an error."""

from __future__ import annotations

import dataclasses
import logging
import os
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers.shapes import box_on_floor, ring_views

from physgs_nerfstudio.export import geometry_cache as gc
from physgs_nerfstudio.geometry import GeometryConfig, reconstruct_object
from physgs_nerfstudio.mass import MassConfig, integrate_mass


@pytest.fixture(scope="module")
def floor_geometry():
    """A box on a floor (a resting plane, a selection, parts, a structure with its NIG): the field and its
    geometry."""
    pf, _, _ = box_on_floor()
    views = ring_views(pf, (0.0, 0.0, 0.15), 1.6, n=12, elevations=(20.0, 50.0))
    cfg = GeometryConfig(resolution=40, backend="reference")
    geo = reconstruct_object(pf, pf.pi(), views, (), list(pf.thickness_m), cfg, material_names=pf.material_names)
    return pf, geo


def _assert_same(a, b, path="geometry"):
    """Recursive equality: the same types, arrays of the same dtype and bits, tensors likewise."""
    assert type(a) is type(b), path
    if dataclasses.is_dataclass(a):
        for f in dataclasses.fields(a):
            _assert_same(getattr(a, f.name), getattr(b, f.name), f"{path}.{f.name}")
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b, equal_nan=True), path
    elif isinstance(a, torch.Tensor):
        assert a.dtype == b.dtype and a.shape == b.shape and torch.equal(a.cpu(), b.cpu()), path
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            _assert_same(x, y, f"{path}[{i}]")
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for k in a:
            _assert_same(a[k], b[k], f"{path}[{k!r}]")
    else:
        assert a == b, path


def test_a_stored_geometry_is_the_computed_one_bit_for_bit(floor_geometry, tmp_path):
    pf, geo = floor_geometry
    assert geo.selection.plane is not None and geo.num_parts >= 1  # the plane and the parts are stored too
    cache = gc.GeometryCache(tmp_path / "physgs_cache", "ab" * 32)
    path = cache.save(geo)
    assert path is not None and path.is_file()
    loaded = cache.load("cpu")
    _assert_same(geo, loaded)
    # the file is read without unpickling code, and the mass from it is the mass from the computed geometry
    torch.load(path, weights_only=True)
    cfg = MassConfig(n_samples=500)
    a, b = integrate_mass(pf, geo, cfg), integrate_mass(pf, loaded, cfg)
    assert (a.mean_kg, a.median_kg, tuple(a.interval_kg)) == (b.mean_kg, b.median_kg, tuple(b.interval_kg))


def test_the_mixture_is_stored_on_the_carved_union_only(floor_geometry):
    _, geo = floor_geometry
    enc = gc.encode_geometry(geo)
    assert enc["mixture_on_union"]["__np__"].shape[0] == int((geo.parts >= 0).sum()) < geo.parts.size
    # a mixture that is not zero outside the union is stored whole
    mixture = geo.mixture.copy()
    mixture[tuple(np.argwhere(geo.parts < 0)[0])] = 0.5
    whole = gc.encode_geometry(dataclasses.replace(geo, mixture=mixture))
    assert whole["mixture_on_union"] is None
    np.testing.assert_array_equal(gc.decode_geometry(whole).mixture, mixture)


def _run_files(root: Path) -> dict:
    run = root / "run"
    (run / "nerfstudio_models").mkdir(parents=True)
    ckpt = run / "nerfstudio_models" / "step-000000099.ckpt"
    ckpt.write_bytes(b"weights")
    (run / "config.yml").write_text("method_name: physgs\n")
    (run / "dataparser_transforms.json").write_text("{}")
    data = root / "data"
    (data / "masks").mkdir(parents=True)
    (data / "transforms.json").write_text("{}")
    (data / "masks" / "frame_00001.png").write_bytes(b"mask")
    return {"checkpoint": ckpt, "config_path": run / "config.yml", "run_dir": run, "data_dir": data,
            "geometry": GeometryConfig(), "device": "cuda", "load_args": gc.load_args(None, None, None, 640)}  # fmt: skip


def _bump(path: Path) -> None:
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))


def test_every_input_of_the_key_changes_it(tmp_path):
    files = _run_files(tmp_path)
    key = gc.cache_key(**files)
    assert gc.cache_key(**files) == key  # nothing changed
    (files["run_dir"] / gc.CACHE_DIR).mkdir()
    (files["run_dir"] / gc.CACHE_DIR / "geometry-x.pt").write_bytes(b"x")  # the cache's own files are not inputs
    assert gc.cache_key(**files) == key
    # nor are a run trained with its outputs inside the dataset, an export written there, or a cache there
    run_inside = files["data_dir"] / "outputs" / "scene" / "physgs" / "t0"
    (run_inside / "nerfstudio_models").mkdir(parents=True)
    (run_inside / "config.yml").write_text("x")
    (run_inside / "events.out.tfevents.1").write_bytes(b"grows while training")
    export_inside = files["data_dir"] / "export"
    export_inside.mkdir()
    (export_inside / ".physgs-export.json").write_text("{}")
    (export_inside / "report.json").write_text("{}")
    (files["data_dir"] / gc.CACHE_DIR).mkdir()
    (files["data_dir"] / gc.CACHE_DIR / "geometry-y.pt").write_bytes(b"y")
    assert gc.cache_key(**files) == key
    (run_inside / "events.out.tfevents.1").write_bytes(b"grew")
    assert gc.cache_key(**files) == key
    changed = {
        "geometry setting": {"geometry": GeometryConfig(resolution=96)},
        "nested geometry setting": {"geometry": dataclasses.replace(
            GeometryConfig(), carve=dataclasses.replace(GeometryConfig().carve, depth_margin_voxels=0.5))},
        "device": {"device": "cpu"},
        "scale": {"load_args": gc.load_args(0.5, None, None, 640)},
        "mask width": {"load_args": gc.load_args(None, None, None, 320)},
    }
    for what, kw in changed.items():
        assert gc.cache_key(**{**files, **kw}) != key, what
    for touch in (files["checkpoint"], files["config_path"], files["run_dir"] / "dataparser_transforms.json",
                  files["data_dir"] / "masks" / "frame_00001.png"):  # fmt: skip
        _bump(touch)
        new = gc.cache_key(**files)
        assert new != key, touch
        key = new
    (files["data_dir"] / "masks" / "frame_00002.png").write_bytes(b"mask")  # a new file in the dataset
    assert gc.cache_key(**files) != key
    key = gc.cache_key(**files)
    files["checkpoint"].write_bytes(b"other weights")  # another size
    assert gc.cache_key(**files) != key


def test_the_code_is_in_the_key(tmp_path, monkeypatch):
    files = _run_files(tmp_path)
    key = gc.cache_key(**files)
    monkeypatch.setattr(gc, "_CODE_HASH", "another version of the code")
    assert gc.cache_key(**files) != key


@pytest.mark.parametrize("content", ["garbage", "foreign_class", "other_key", "truncated"])
def test_an_unreadable_entry_is_a_miss_with_a_warning(floor_geometry, tmp_path, caplog, content):
    _, geo = floor_geometry
    cache = gc.GeometryCache(tmp_path, "cd" * 32)
    cache.save(geo)
    if content == "garbage":
        cache.path.write_bytes(b"not a torch file")
    elif content == "truncated":
        cache.path.write_bytes(cache.path.read_bytes()[:1000])
    else:
        data = torch.load(cache.path, weights_only=True)
        if content == "foreign_class":
            data["geometry"]["__dc__"] = "Popen"
        else:
            data["key"] = "ef" * 32
        torch.save(data, cache.path)
    with caplog.at_level(logging.WARNING):
        assert cache.load("cpu") is None
    assert "could not be read" in caplog.text and "computing the geometry instead" in caplog.text


def test_a_read_only_folder_is_no_error(floor_geometry, tmp_path, monkeypatch):
    _, geo = floor_geometry
    cache = gc.GeometryCache(tmp_path / "physgs_cache", "01" * 32)

    def refuse(*args, **kwargs):
        raise PermissionError("read-only file system")

    monkeypatch.setattr(gc.torch, "save", refuse)
    assert cache.save(geo) is None
    assert not list((tmp_path / "physgs_cache").glob("*"))  # no temporary file left


def test_only_the_newest_entries_are_kept(floor_geometry, tmp_path):
    _, geo = floor_geometry
    paths = []
    for i in range(gc.KEEP + 2):
        path = gc.GeometryCache(tmp_path, f"{i:02d}" * 32).save(geo)
        os.utime(path, ns=(i * 10**9, i * 10**9))
        paths.append(path)
    gc.GeometryCache(tmp_path, "ff" * 32).save(geo)
    kept = sorted(p.name for p in tmp_path.glob("geometry-*.pt"))
    assert len(kept) == gc.KEEP and ("geometry-" + "ff" * 12 + ".pt") in kept
    assert not paths[0].exists() and not paths[1].exists()


def test_a_full_disk_leaves_the_stored_entries_whole(floor_geometry, tmp_path, monkeypatch):
    """The cache writes through the project's write layer (fusion.transaction.write_file, which a full disk makes
    fail): a failed store leaves no partial file, and the entries stored before still load, bit for bit."""
    import errno

    from physgs_nerfstudio.fusion import transaction

    _, geo = floor_geometry
    kept = gc.GeometryCache(tmp_path, "aa" * 32)
    kept.save(geo)
    before = kept.path.read_bytes()

    def full(path, data):
        Path(path).write_bytes(data[: len(data) // 2])  # half written, then the disk is full
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(transaction, "write_file", full)
    assert gc.GeometryCache(tmp_path, "bb" * 32).save(geo) is None
    assert sorted(p.name for p in tmp_path.iterdir()) == [kept.path.name]
    assert kept.path.read_bytes() == before
    _assert_same(geo, kept.load("cpu"))


def test_a_killed_writer_s_temporary_file_is_removed_once_stale(floor_geometry, tmp_path):
    _, geo = floor_geometry
    old = tmp_path / ".geometry-dead.1234abcd.tmp"
    fresh = tmp_path / ".geometry-busy.5678abcd.tmp"  # another export writing right now
    for f in (old, fresh):
        f.write_bytes(b"partial")
    hours_ago = (os.stat(old).st_mtime_ns - 2 * gc.STALE_TMP_S * 10**9)
    os.utime(old, ns=(hours_ago, hours_ago))
    gc.GeometryCache(tmp_path, "cc" * 32).save(geo)
    assert not old.exists() and fresh.exists()


def test_a_failed_precompute_never_fails_the_training(tmp_path, monkeypatch, capsys):
    """ns-train's AFTER_TRAIN hook: an error of the geometry (no masks, say) is one line in the log, not an
    exception out of the trainer; "off" and "auto" on a CPU do not compute at all."""
    from types import SimpleNamespace

    from method_configs import physgs_config
    from physgs_nerfstudio.export import run as export_run
    from physgs_nerfstudio.geometry import GeometryError
    from physgs_nerfstudio.nerfstudio import pipeline as pipeline_module
    from physgs_nerfstudio.nerfstudio.pipeline import PhysGSPipeline

    calls = []

    def fail(config_path, device):
        calls.append(device)
        raise GeometryError("no training view has an object mask")

    # the plugin's method configs hand the exporter's step in (the pipeline does not import the exporter)
    assert pipeline_module._GEOMETRY_STEP is physgs_config._precompute_geometry
    monkeypatch.setattr(export_run, "precompute_geometry", fail)
    config = tmp_path / "config.yml"
    config.write_text("x")
    for mode, device in (("off", "cuda"), ("auto", "cpu")):
        fake = SimpleNamespace(config=SimpleNamespace(precompute_geometry=mode),
                               model=SimpleNamespace(device=torch.device(device)))  # fmt: skip
        PhysGSPipeline._precompute_geometry(fake, config, 99)
    assert calls == []
    fake = SimpleNamespace(config=SimpleNamespace(precompute_geometry="on"),
                           model=SimpleNamespace(device=torch.device("cpu")))  # fmt: skip
    PhysGSPipeline._precompute_geometry(fake, config, 99)
    assert calls == ["cpu"]
    out = " ".join(capsys.readouterr().out.split())
    assert "not precomputed (no training view has an object mask)" in out
