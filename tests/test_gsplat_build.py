"""The gsplat build stamp: an earlier build of the same sources is reused whatever the files' times, anything
else is left to gsplat's JIT (no GPU needed: CUDA queries are stubbed)."""

from __future__ import annotations

import json
import os

import pytest
import torch

from physgs_nerfstudio.render import gsplat_build as gb


@pytest.fixture
def fake_gpu(monkeypatch, tmp_path):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "get_device_capability", lambda *a: (9, 0))
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    monkeypatch.setattr(gb, "_build_dir", lambda: tmp_path)
    monkeypatch.delenv("TORCH_CUDA_ARCH_LIST", raising=False)
    gb._state.clear()
    yield tmp_path
    gb._state.clear()


def _stamp(build, **change) -> None:
    (build / "gsplat_cuda.so").write_bytes(b"not a library")
    (build / gb.STAMP).write_text(json.dumps({**gb._fingerprint(), "archs": gb._arch_list(), **change}))


def test_no_gpu_means_unavailable(monkeypatch) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert gb.build_status()[0] == "unavailable"


def test_matching_stamp_is_reused_whatever_the_file_times(fake_gpu) -> None:
    assert gb.build_status()[0] == "jit"  # nothing built yet
    _stamp(fake_gpu)
    os.utime(fake_gpu / "gsplat_cuda.so", (978307200, 978307200))  # 2001: every source is newer (a reinstall)
    src = next((gb._gsplat_dir() / "cuda" / "csrc").glob("*.cu"))
    assert src.stat().st_mtime > 978307200
    status, reason = gb.build_status()
    assert status == "prebuilt", reason


@pytest.mark.parametrize("change", [{"sources_sha256": "0" * 64}, {"torch": "0.0"}, {"gsplat": "0.0"},
                                    {"archs": ["8.6"]}, {"no_fast_math": True}])  # fmt: skip
def test_anything_else_is_left_to_the_jit(fake_gpu, change) -> None:
    _stamp(fake_gpu, **change)
    status, reason = gb.build_status()
    assert status == "jit" and "rebuilt" in reason


def test_missing_stamp_and_unloadable_library_fall_back(fake_gpu) -> None:
    (fake_gpu / "gsplat_cuda.so").write_bytes(b"x")
    assert gb.build_status()[0] == "jit"
    _stamp(fake_gpu)
    assert gb.prepare_gsplat() == "jit"  # the stamped file is no library: gsplat's own JIT decides
    assert "gsplat.csrc" not in __import__("sys").modules


def test_arch_coverage(monkeypatch) -> None:
    monkeypatch.setattr(torch.cuda, "get_device_capability", lambda *a: (9, 0))
    assert gb._covers(["9.0"]) and gb._covers(["8.0+PTX"]) and gb._covers(["7.5", "9.0+PTX"])
    assert not gb._covers(["8.6"]) and not gb._covers(["10.0+PTX"]) and not gb._covers(["Hopper"])
    monkeypatch.setenv("TORCH_CUDA_ARCH_LIST", "8.0;9.0+PTX")
    assert gb._arch_list() == ["8.0", "9.0+PTX"]


def test_a_jit_load_is_stamped_once(fake_gpu, monkeypatch) -> None:
    import types

    (fake_gpu / "gsplat_cuda.so").write_bytes(b"x")
    assert gb.prepare_gsplat() == "jit"
    monkeypatch.setitem(__import__("sys").modules, "gsplat.cuda._backend", types.SimpleNamespace(_C=object()))
    gb.record_gsplat_build()
    saved = json.loads((fake_gpu / gb.STAMP).read_text())
    assert saved["archs"] == ["9.0"] and saved["sources_sha256"] == gb._fingerprint()["sources_sha256"]
    gb._state.pop("status")
    assert gb.build_status()[0] == "prebuilt"
