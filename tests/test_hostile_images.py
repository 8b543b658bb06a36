"""Image files whose header claims a huge size (issue 72, serious 4): one opening function with a pixel limit,
used by every reader; perception skips such a frame as it skips an unreadable one. Oracle: PNG files written
byte by byte here (a valid header of the claimed size, a few bytes of pixels)."""

from __future__ import annotations

import json
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from helpers.perception_scene import make_scene
from helpers.perception_server import FakeServer
from PIL import Image

from physgs_nerfstudio.image_files import MAX_PIXELS, BadImage, open_image, read_array
from physgs_nerfstudio.perception import PerceptionConfig, run_perception
from physgs_nerfstudio.perception.images import BadFrame, read_image
from physgs_nerfstudio.perception.vlm import OpenAIConfig


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def bomb_png(path: Path, width: int, height: int, mode: int = 2) -> Path:
    """A PNG whose header says width x height (colour type ``mode``: 2 RGB, 0 grey) with one row of pixels."""
    header = struct.pack(">IIBBBBB", width, height, 8, mode, 0, 0, 0)
    row = b"\0" + b"\0" * (width * (3 if mode == 2 else 1))
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", header) + _chunk(b"IDAT", zlib.compress(row))
                     + _chunk(b"IEND", b""))  # fmt: skip
    return path


@pytest.mark.parametrize("size", [(30000, 30000), (9000, 9000), (8193, 8192)])
def test_a_header_over_the_limit_is_refused_before_decoding(tmp_path, size):
    w, h = size
    assert w * h > MAX_PIXELS
    path = bomb_png(tmp_path / "bomb.png", w, h)
    with pytest.raises(BadImage) as ei:
        read_array(path)
    msg = str(ei.value)
    assert str(path) in msg and "\n" not in msg and "8192 x 8192" in msg, msg
    with pytest.raises(BadFrame) as ei:  # perception's reader: the frame's own error, which it skips
        read_image(path, "images/bomb.png")
    assert "images/bomb.png" in str(ei.value)


def test_an_image_at_the_limit_opens(tmp_path):
    path = tmp_path / "ok.png"
    Image.fromarray(np.full((4, 5), 7, np.uint8)).save(path)
    with open_image(path) as im:
        assert im.size == (5, 4)
    assert read_array(path).tolist() == [[7] * 5] * 4
    with pytest.raises(BadImage, match="5 x 4 pixels, over the limit of 19 pixels"), open_image(path, max_pixels=19):
        pass


def test_perceive_skips_a_bomb_frame_as_an_unreadable_one(tmp_path, monkeypatch):
    monkeypatch.setenv("PHYSGS_IMG_KEY", "sk-img")
    root = make_scene(tmp_path / "scene", num_views=3)
    bomb_png(root / "images/frame_00001.png", 30000, 30000)
    with FakeServer() as srv:
        vlm = OpenAIConfig(base_url=srv.base_url, model="m", api_key_env="PHYSGS_IMG_KEY", timeout_s=5.0,
                           backoff_base_s=0.01, backoff_max_s=0.02)  # fmt: skip
        result = run_perception(PerceptionConfig(data=root, vlm=vlm, progress=False, prompt="baseline"))
    assert result.calls == 2 and len(result.skipped_frames) == 1
    assert "frame_00001" in result.skipped_frames[0] and "pixels" in result.skipped_frames[0]
    frames = {f["file_path"]: f for f in json.loads((root / "transforms.json").read_text())["frames"]}
    assert "material_path" not in frames["images/frame_00001.png"]
    assert "material_path" in frames["images/frame_00000.png"]


def test_every_image_reader_goes_through_open_image():
    """No module of the package opens an image file with PIL itself (the limit would not hold there)."""
    package = Path(__file__).resolve().parents[1] / "physgs_nerfstudio"
    allowed = {"image_files.py"}
    skipped = {"synth"}  # generated scenes read back their own renders (synth/example.py)
    found = [f"{p.relative_to(package)}" for p in package.rglob("*.py")
             if p.name not in allowed and p.relative_to(package).parts[0] not in skipped
             and "Image.open(" in p.read_text()]  # fmt: skip
    assert found == []
