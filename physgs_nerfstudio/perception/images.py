"""Frame images as 8-bit RGB, whatever their storage, and a clear line for those that cannot be read.

``PIL.Image.convert("RGB")`` clips 16-bit and float images to 255: a 16-bit PNG (mode ``I;16``) becomes
white. :func:`to_rgb8` scales instead: integer images by their bit depth (16-bit: / 65535; 32-bit ``I``
images by 65535 when their values fit 16 bits, else by their true range), float images (``F``) by 1 when
their values lie in [0, 1], else by their true range; non-finite values become 0. Every other mode goes
through Pillow's own conversion (palette, grey, RGBA, CMYK, ...). 16-bit RGB PNGs are read by Pillow as
8-bit RGB already (the high byte, i.e. scaled by the bit depth).
"""

from __future__ import annotations

import errno
import logging
from pathlib import Path

import numpy as np
from jaxtyping import UInt8

from ..errors import DatasetError

logger = logging.getLogger(__name__)


class BadFrame(DatasetError):
    """A frame image that cannot be used (missing, unreadable, a symlink loop)."""


def _scale(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    if hi <= lo:
        return np.zeros(values.shape, np.uint8)
    return np.clip(np.round((values - lo) / (hi - lo) * 255.0), 0, 255).astype(np.uint8)


def to_rgb8(im) -> UInt8[np.ndarray, "H W 3"]:
    """A PIL image as uint8 RGB [H, W, 3] (module docstring for the scaling)."""
    mode = im.mode
    if mode.startswith("I;16") or mode == "I":
        a = np.asarray(im).astype(np.float64)
        hi = 65535.0 if (mode != "I" or (a.size and a.min() >= 0 and a.max() <= 65535)) else float(a.max())
        lo = 0.0 if hi == 65535.0 else float(a.min())
        grey = _scale(a, lo, hi)
    elif mode == "F":
        a = np.asarray(im).astype(np.float64)
        finite = np.isfinite(a)
        a = np.where(finite, a, 0.0)
        vals = a[finite]
        lo, hi = (
            (0.0, 1.0)
            if vals.size == 0 or (vals.min() >= 0 and vals.max() <= 1)
            else (vals.min(), vals.max())
        )
        grey = _scale(a, float(lo), float(hi))
    else:
        return np.asarray(im.convert("RGB"), dtype=np.uint8)
    return np.repeat(grey[..., None], 3, axis=-1)


def read_image(path: Path, name: str | None = None) -> UInt8[np.ndarray, "H W 3"]:
    """The image at ``path`` as uint8 RGB; :class:`BadFrame` naming it (``name``: how the dataset calls it)
    when it is missing, empty, not an image, truncated, a symlink loop or over the pixel limit
    (:data:`physgs_nerfstudio.image_files.MAX_PIXELS`)."""
    from ..image_files import BadImage, open_image

    path = Path(path)
    what = f"frame image {name!r} ({path})" if name and name != str(path) else f"frame image {path}"
    try:
        size = path.stat().st_size
    except OSError as err:
        if err.errno == errno.ELOOP:
            raise BadFrame(
                f"{what} is a symlink loop; point the link at a real file or remove the frame"
            ) from None
        raise BadFrame(
            f"{what} not found; fix its file_path in transforms.json or remove the frame"
        ) from None
    if not path.is_file():
        raise BadFrame(f"{what} is not a file; fix its file_path in transforms.json") from None
    if size == 0:
        raise BadFrame(f"{what} is empty (0 bytes); replace it or remove the frame from transforms.json")
    try:
        with open_image(path, what=what) as im:  # the pixel limit (image_files.MAX_PIXELS) before decoding
            return np.ascontiguousarray(to_rgb8(im))
    except BadImage as err:
        raise BadFrame(f"{err} (the frame is skipped)") from None
