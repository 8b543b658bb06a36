"""The built-in segmenter's whole-object masks on an object standing on a support (segment_builtin's module doc, "The
whole object"): the background is what touches the image border, and the support seen through the object or in its
shadow is background too. Oracles: the label images of drawn scenes, and the label maps of generated scenes (the
project renderer; the path tracer where mitsuba is installed)."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from helpers.benchmarks import load_benchmark

from physgs_nerfstudio.perception.segment_builtin import BuiltinSegmenterConfig

OBJECT, SHADOW, HOLE = 1, 2, 3


def _standing_frame(seed: int = 0, object_rgb=(60, 90, 160), floor_rgb=(190, 170, 140)) -> tuple[np.ndarray, np.ndarray]:
    """96 px: a backdrop over a textured beige floor that runs past the left, right and bottom borders; a square frame
    (label 1) standing on it with the floor seen through its opening (label 3) and its shadow on the floor beside it
    (label 2: the floor at 55% of its light); pixel noise."""
    rng = np.random.default_rng(seed)
    h = 96
    yy, xx = np.mgrid[0:h, 0:h]
    img = np.empty((h, h, 3))
    img[:] = (150, 160, 175)
    floor = yy >= 40
    img[floor] = np.array(floor_rgb) * (1 + 0.06 * rng.standard_normal((int(floor.sum()), 1)))
    lab = np.zeros((h, h), np.int32)
    outer = (np.abs(xx - 44) <= 16) & (yy >= 26) & (yy <= 70)
    hole = (np.abs(xx - 44) <= 8) & (yy >= 40) & (yy <= 64)
    shadow = (xx > 60) & (xx <= 78) & (yy >= 56) & (yy <= 70)
    img[shadow] *= 0.55
    lab[shadow] = SHADOW
    img[outer & ~hole] = object_rgb
    lab[outer & ~hole] = OBJECT
    lab[hole] = HOLE
    img += rng.normal(0, 2.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8), lab


def _whole(masks, shape) -> np.ndarray:
    whole = [m.segmentation for m in masks if m.level == "whole"]
    return np.any(whole, 0) if whole else np.zeros(shape, bool)


@pytest.mark.parametrize("seed", [0, 1])
def test_the_whole_mask_keeps_the_object_and_leaves_its_shadow_and_opening(seed):
    img, lab = _standing_frame(seed)
    u = _whole(BuiltinSegmenterConfig().setup().segment(img), lab.shape)
    obj = lab == OBJECT
    assert (u & obj).sum() / (u | obj).sum() > 0.9
    assert (u & (lab == SHADOW)).sum() < 0.05 * (lab == SHADOW).sum()
    assert (u & (lab == HOLE)).sum() < 0.05 * (lab == HOLE).sum()
    # the support's rule is what leaves them: without it the shadow and the opening are in the whole mask
    off = _whole(BuiltinSegmenterConfig(support_chroma=None).setup().segment(img), lab.shape)
    assert (off & (lab == SHADOW)).sum() > 0.5 * (lab == SHADOW).sum()
    assert (off & (lab == HOLE)).sum() > 0.5 * (lab == HOLE).sum()


def test_a_grey_object_darker_than_a_grey_floor_is_not_taken_for_its_shadow():
    """On a neutral grey floor chromaticity cannot tell a grey object from the floor in less light: the rule compares
    only a coloured support, so the dark grey frame keeps its whole mask (its shadow, as dark as the frame here, stays
    in it: the rule's documented limit on grey supports)."""
    img, lab = _standing_frame(0, object_rgb=(95, 95, 95), floor_rgb=(170, 170, 170))
    u = _whole(BuiltinSegmenterConfig().setup().segment(img), lab.shape)
    obj = lab == OBJECT
    assert (u & obj).sum() > 0.9 * obj.sum()


def test_a_low_contrast_object_keeps_its_mask_whatever_its_stability():
    """A grey-blue object only a little darker and bluer than its backdrop and floor: the perturbed merge takes it
    into the floor (stability near 0), which must not drop the whole mask."""
    img, lab = _standing_frame(0, object_rgb=(150, 150, 175))
    u = _whole(BuiltinSegmenterConfig().setup().segment(img), lab.shape)
    obj = lab == OBJECT
    assert (u & obj).sum() / (u | obj).sum() > 0.8


def test_a_run_without_object_masks_says_so_in_one_line(tmp_path, caplog):
    """A segmenter that finds no whole object in any view: the run warns once, with the count and what to try."""
    from helpers.perception_scene import make_scene

    from physgs_nerfstudio.perception import PerceptionConfig, run_perception
    from physgs_nerfstudio.perception.segment import Mask
    from physgs_nerfstudio.perception.simulated import SimulatedConfig

    class PartsOnly:
        name = "builtin"

        def segment(self, image):
            seg = np.zeros(image.shape[:2], bool)
            seg[10:30, 10:30] = True
            return [Mask(seg, int(seg.sum()), 0.9, 0.9, "part")]

        def fingerprint(self):
            return "parts-only"

    root = make_scene(tmp_path / "scene", num_views=3)
    with caplog.at_level(logging.WARNING):
        run_perception(PerceptionConfig(data=root, vlm=SimulatedConfig(), progress=False, write_outputs=False),
                       segmenter=PartsOnly())  # fmt: skip
    lines = [r.getMessage() for r in caplog.records if "no whole-object mask" in r.getMessage()]
    assert len(lines) == 1 and "\n" not in lines[0]
    assert "in 3 of 3 views" in lines[0] and ".[sam]" in lines[0]


def _scene_scores(tmp_path, renderer: str, family: str, seed: int, **kw) -> dict:
    synth = pytest.importorskip("physgs_nerfstudio.synth")
    ms = load_benchmark("mass_suite.py", "mass_suite_masks")
    root = synth.generate_scene(synth.SynthConfig(out=tmp_path / family, object=family, seed=seed, shape="drawn",
                                                  support="floor", pose="standing", renderer=renderer, **kw))
    return ms.mask_scores(root)


@pytest.mark.parametrize("family", ["mug", "crate"])
def test_generated_objects_on_a_floor_get_whole_masks_off_the_floor(tmp_path, family):
    s = _scene_scores(tmp_path, "project", family, 7, views=6, resolution=96)
    assert s["iou"] > 0.6 and s["support_share"] < 0.15, s


def test_path_traced_object_on_a_floor_gets_whole_masks_off_the_floor(tmp_path):
    pytest.importorskip("mitsuba")
    s = _scene_scores(tmp_path, "mitsuba", "mug", 7, views=4, resolution=96, spp=16)
    assert s["iou"] > 0.5 and s["support_share"] < 0.25, s
