"""Prompts (triplet / baseline) and the SAM segmenter's wiring (with a stand-in segment_anything)."""

from __future__ import annotations

import hashlib
import sys
import types

import numpy as np
import pytest

from physgs_nerfstudio.perception.prompts import PromptConfig, build_request, isolated_panel, triplet_image
from physgs_nerfstudio.perception.segment_sam import SamSegmenter, SamSegmenterConfig


def _img():
    rng = np.random.default_rng(1)
    img = rng.integers(0, 255, (40, 60, 3), dtype=np.uint8)
    mask = np.zeros((40, 60), bool)
    mask[10:25, 20:35] = True
    return img, mask


def test_triplet_layout_and_isolated_part():
    img, mask = _img()
    cfg = PromptConfig()
    trip = triplet_image(img, mask, cfg)
    assert trip.shape == (40, 3 * 60 + 2 * cfg.gap, 3)
    assert (trip[:, :60] == img).all()
    iso = isolated_panel(img, mask, cfg)
    grey = (iso == cfg.background_grey).all(-1)
    assert grey.mean() > 0.3 and (iso[~grey] != cfg.background_grey).any()


def test_request_bytes_are_deterministic_and_text_names_library():
    img, mask = _img()
    names = ["ceramic", "steel", "oak"]
    a = build_request("v", 0, "part", img, mask, names, "indoor")
    b = build_request("v", 0, "part", img.copy(), mask.copy(), names, "indoor")
    assert a.images == b.images and a.image_hashes() == [hashlib.sha256(a.images[0]).hexdigest()]
    for word in names + [
        "caption",
        "candidates",
        "density",
        "kinetic_friction",
        "shore_scale",
        "youngs_modulus",
        "thickness_m",
    ]:
        assert word in a.text
    jpg = build_request("v", 0, "part", img, mask, names, "indoor", PromptConfig(image_format="jpeg"))
    assert (
        jpg.mime == "image/jpeg"
        and jpg.images
        == build_request("v", 0, "part", img, mask, names, "indoor", PromptConfig(image_format="jpeg")).images
    )
    base = build_request("v", 0, "whole", img, None, names, "outdoor", PromptConfig(kind="baseline"))
    assert "dominant visible region" in base.text and base.images != a.images


def test_sam_missing_package_says_what_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "segment_anything", None)
    with pytest.raises(ImportError, match=r'pip install -e "\.\[sam\]"'):
        SamSegmenter(SamSegmenterConfig(checkpoint="x.pth")).segment(np.zeros((8, 8, 3), np.uint8))


def test_sam_filtering_dedup_and_levels(monkeypatch, tmp_path):
    H = W = 32
    whole = np.zeros((H, W), bool)
    whole[4:28, 4:28] = True
    part = np.zeros((H, W), bool)
    part[4:16, 4:28] = True
    sub = np.zeros((H, W), bool)
    sub[4:10, 4:12] = True
    records = [
        {"segmentation": whole, "predicted_iou": 0.95, "stability_score": 0.97},
        {"segmentation": whole.copy(), "predicted_iou": 0.93, "stability_score": 0.96},  # duplicate
        {"segmentation": part, "predicted_iou": 0.94, "stability_score": 0.95},
        {"segmentation": sub, "predicted_iou": 0.92, "stability_score": 0.95},
        {"segmentation": part.T.copy(), "predicted_iou": 0.5, "stability_score": 0.99},  # low IoU score
    ]

    class Gen:
        def __init__(self, model, **kw):
            self.kw = kw

        def generate(self, image):
            return records

    class Model:
        def to(self, device):
            return self

    fake = types.SimpleNamespace(
        SamAutomaticMaskGenerator=Gen, sam_model_registry={"vit_b": lambda checkpoint: Model()}
    )
    monkeypatch.setitem(sys.modules, "segment_anything", fake)
    with pytest.raises(FileNotFoundError, match="--segmenter.checkpoint"):
        SamSegmenter(SamSegmenterConfig(checkpoint=tmp_path / "missing.pth", model_type="vit_b")).segment(
            np.zeros((H, W, 3), np.uint8)
        )
    ckpt = tmp_path / "sam.pth"
    ckpt.write_bytes(b"0")
    masks = SamSegmenter(
        SamSegmenterConfig(checkpoint=ckpt, model_type="vit_b", device="cpu", min_area_px=8)
    ).segment(np.zeros((H, W, 3), np.uint8))
    assert [m.level for m in masks] == ["whole", "part", "subpart"]
    assert masks[0].predicted_iou == pytest.approx(0.95)
