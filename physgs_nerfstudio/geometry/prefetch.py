"""The geometry's compiled dependencies (SciPy's ndimage and spatial, scikit-image's marching cubes, OpenCV) imported
on a background thread while the run loads.

Their first import costs a fixed 0.5-0.8 s per process (an H100 machine's profile of `physgs export --outputs mass`:
SciPy's ndimage alone 0.75 s), paid in the middle of the object's selection. Started when an export needs the
geometry, the imports overlap the checkpoint's loading, the mask files' reading and the GPU's lifting, which
release the GIL for much of their time. A module that fails to import is left alone: the geometry imports it
again where it needs it, and that import reports the error.
"""

from __future__ import annotations

import importlib
import threading

__all__ = ["prefetch_imports"]

MODULES = ("scipy.ndimage", "scipy.spatial", "skimage.measure", "cv2")


def prefetch_imports(modules: tuple[str, ...] = MODULES) -> threading.Thread:
    """Start importing ``modules`` on a daemon thread; returns the thread (joining it is optional)."""

    def run() -> None:
        for name in modules:
            try:
                importlib.import_module(name)
            except Exception:  # noqa: BLE001, S112 - reported where the geometry imports it itself
                continue

    thread = threading.Thread(target=run, name="physgs-geometry-imports", daemon=True)
    thread.start()
    return thread
