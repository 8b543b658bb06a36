"""The built-in segmenter keeps thin parts apart (``oversegment="slic+graph"``, segment_builtin's module doc).

A wooden top on two metal legs 6-8 px wide in a 512 px image: thinner than SLIC's superpixels (about 21 px), which
straddle each leg and its background, so the merging cannot find the legs; split along the graph segmentation's
regions, the superpixels follow the legs' edges. The oracle is the ground-truth label image: the share of each
part's pixels that a mask whose majority is that part covers (what a VLM naming the mask's majority material gets
right).
"""

from __future__ import annotations

import numpy as np
import pytest

from physgs_nerfstudio.perception.segment_builtin import BuiltinSegmenter, BuiltinSegmenterConfig


def _scene(width: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A shaded wall over a floor, a striped wooden top (label 1), two metal legs ``width`` px wide with a highlight
    along them (label 2), and pixel noise."""
    rng = np.random.default_rng(seed)
    h = 512
    yy, xx = np.mgrid[0:h, 0:h].astype(np.float64)
    img = np.empty((h, h, 3))
    lab = np.zeros((h, h), np.int32)
    img[:] = np.array([205, 195, 175]) - 0.05 * yy[..., None]
    img[yy > 330] = np.array([115, 100, 90])
    top = (np.abs(xx - 256) < 120) & (yy > 120) & (yy < 170)
    img[top] = np.array([150, 110, 60]) + 15 * np.sin(xx[top] / 6.0)[:, None]
    lab[top] = 1
    for x0 in (160, 350):
        leg = (xx >= x0) & (xx < x0 + width) & (yy >= 170) & (yy < 450)
        img[leg] = np.array([110, 115, 125]) + 30 * (1 - np.abs(xx[leg] - x0 - width / 2) / (width / 2))[:, None]
        lab[leg] = 2
    img += rng.normal(0, 2.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8), lab


def _majority_coverage(masks, lab: np.ndarray, k: int) -> float:
    covered = np.zeros(lab.shape, bool)
    for m in masks:
        vals, counts = np.unique(lab[m.segmentation], return_counts=True)
        if vals[np.argmax(counts)] == k:
            covered |= m.segmentation & (lab == k)
    return float(covered.sum() / (lab == k).sum())


@pytest.mark.parametrize("width", [6, 8])
def test_thin_legs_get_their_own_masks(width):
    img, lab = _scene(width)
    graph = BuiltinSegmenterConfig().setup().segment(img)  # the default: slic+graph
    slic = BuiltinSegmenterConfig(oversegment="slic").setup().segment(img)
    assert _majority_coverage(graph, lab, 1) > 0.9 and _majority_coverage(slic, lab, 1) > 0.9
    assert _majority_coverage(graph, lab, 2) > 0.9
    assert _majority_coverage(slic, lab, 2) < 0.5  # the case this option is for: SLIC alone loses the legs


def test_oversegment_is_checked_and_in_the_fingerprint():
    with pytest.raises(ValueError, match="oversegment"):
        BuiltinSegmenter(BuiltinSegmenterConfig(oversegment="watershed"))  # type: ignore[arg-type]
    a = BuiltinSegmenterConfig().setup().fingerprint()
    b = BuiltinSegmenterConfig(oversegment="slic").setup().fingerprint()
    assert a != b  # cached masks of the other superpixels are not reused
