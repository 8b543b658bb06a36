"""Start what an export will need while it loads the run: the GPU's context and the geometry's libraries.

An export of the mass first reads the run (its YAML, checkpoint and every view's mask file), then carves. On an
H100's host the carving's first calls paid for things that have nothing to do with the run: SciPy's ndimage and
spatial modules (about 0.3-0.5 s to import, most of it parsing docstrings), OpenCV, scikit-image's marching
cubes, the CUDA context that the first tensor on the GPU creates (about 0.25 s) and gsplat's compiled library
(:func:`..render.gsplat_build.prepare_gsplat`, which loads it once whichever thread asks first). :func:`start_warmup` makes them on a
background thread at once, so they overlap the loading: most of the loading and the first GPU work run in C
with Python's lock released (zlib for the masks, torch's operators), and an import blocks only a thread that
needs the same module, until it is done. Nothing here changes a result: an import or an initialisation that
fails on the thread is left for the export to meet, and report, where it needs it.
"""

from __future__ import annotations

import importlib
import threading

__all__ = ["GEOMETRY_MODULES", "start_warmup"]

GEOMETRY_MODULES = ("scipy.ndimage", "scipy.spatial", "cv2", "skimage.measure")
"""imported by the geometry at its first use, in that order (lazily: a PLY-only export needs none of them)"""


def _warm(cuda: bool, modules: tuple[str, ...]) -> None:
    if cuda:
        try:
            import torch

            torch.cuda.init()
            if modules:  # the geometry renders the views' depth with gsplat: its library loaded (or found missing)
                from ..render.gsplat_build import prepare_gsplat

                prepare_gsplat()
        except Exception:  # noqa: BLE001 - the export meets the same error where it needs the device
            pass
    for name in modules:
        try:
            importlib.import_module(name)
        except Exception:  # noqa: BLE001 - likewise: the geometry's own import reports a missing package
            pass


def start_warmup(*, cuda: bool, geometry: bool) -> threading.Thread | None:
    """Start the warm-up thread (module doc) and return it; None when there is nothing to warm. ``cuda``: create
    the CUDA context; ``geometry``: import :data:`GEOMETRY_MODULES`. The thread is a daemon: an export that fails
    early does not wait for it."""
    modules = GEOMETRY_MODULES if geometry else ()
    if not cuda and not modules:
        return None
    t = threading.Thread(target=_warm, args=(cuda, modules), name="physgs-export-warmup", daemon=True)
    t.start()
    return t
