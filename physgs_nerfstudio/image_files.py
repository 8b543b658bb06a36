"""The one function that opens an image file: a pixel limit checked from the header, before anything is decoded.

A PNG's header can claim any size: a 2 KB file that says 30000 x 30000 makes a decoder allocate 2.7 GB, and
Pillow's own guard raises ``DecompressionBombError``, an exception no reader expected (a traceback after paid VLM
requests, at the same frame on every rerun). :func:`open_image` reads the header only, refuses an image of more
than :data:`MAX_PIXELS` pixels (8192 x 8192) and turns every way an image file can fail (missing, not an image,
truncated, a bomb) into one :class:`BadImage` line naming the file. Readers catch it where an unreadable file is
expected: perception skips such a frame as it skips an unreadable one, a label map is treated as absent where the
reader allows it, and the rest end with the line. Every image reader of the package goes through here.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from .errors import DatasetError

__all__ = ["MAX_PIXELS", "BadImage", "open_image", "read_array"]

MAX_PIXELS = 8192 * 8192
"""the most pixels (width x height) an image file may have; larger ones are refused before they are decoded"""


class BadImage(DatasetError):
    """An image file that cannot be used: missing, not an image, truncated, or over :data:`MAX_PIXELS`."""


@contextmanager
def open_image(path: Path | str, *, what: str | None = None, max_pixels: int = MAX_PIXELS) -> Iterator[Any]:
    """``with open_image(path) as im``: the PIL image, its pixels loaded, after the size check (module doc).
    ``what``: how the message names the file (default: its path)."""
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    what = what or f"image {path}"
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            im = Image.open(path)
    except (Image.DecompressionBombError, Image.DecompressionBombWarning):
        raise BadImage(f"{what}: its header claims more than {max_pixels} pixels (the limit is "
                       f"{_shown(max_pixels)}); replace it with a smaller image or remove it") from None  # fmt: skip
    except FileNotFoundError:
        raise BadImage(f"{what} not found") from None
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as err:
        raise BadImage(f"{what} cannot be read as an image ({_reason(err)}); replace it or remove it") from None
    with im:
        w, h = im.size
        if w * h > max_pixels:
            raise BadImage(f"{what} is {w} x {h} pixels, over the limit of {_shown(max_pixels)}; downscale it or "
                           "remove it")  # fmt: skip
        try:
            im.load()
        except (OSError, ValueError, SyntaxError, MemoryError) as err:
            raise BadImage(f"{what} cannot be read as an image ({_reason(err)}); replace it or remove it") from None
        yield im


def read_array(path: Path | str, *, what: str | None = None) -> np.ndarray:
    """The pixels of an image file as a numpy array (as ``np.asarray(Image.open(path))``), through
    :func:`open_image`."""
    with open_image(path, what=what) as im:
        return np.asarray(im)


def _reason(err: BaseException) -> str:
    text = "".join(c if c.isprintable() else " " for c in str(err))
    return " ".join(text.split())[:160] or type(err).__name__


def _shown(pixels: int) -> str:
    side = int(pixels**0.5)
    return f"{side} x {side}" if side * side == pixels else f"{pixels} pixels"
