"""gsplat's CUDA library without a rebuild in every new process after a reinstall.

gsplat 1.4.0 from PyPI ships its CUDA sources and compiles them on first use (``torch.utils.cpp_extension.load``,
about 3.5 minutes on an H100) into ``$TORCH_EXTENSIONS_DIR/<py_cu>/gsplat_cuda``. Every later process calls
``load`` again, which runs ninja, and ninja rebuilds every object whose source is newer than the object. pip
unpacks a wheel's files with the time of the install, so after any reinstall of gsplat (a new environment, a
``pip install --force-reinstall``, the GPU benchmark's fresh install of carried wheels) every source is newer
than a build that is still exactly right, and the next process (an export, say) pays the whole compilation.

Fix: after a process has loaded gsplat's JIT library (so ninja found it up to date or rebuilt it), a stamp
next to it records what it was built from: the SHA-256 of gsplat's CUDA/C++ sources, gsplat's, torch's,
CUDA's and Python's versions and the GPU architectures it was compiled for. A later process whose stamp
matches imports the built library directly as ``gsplat.csrc``, the precompiled module gsplat tries before
its JIT, so neither ninja nor the compiler runs, whatever the files' times. Anything that does not match
(other sources, another torch, a GPU the library was not compiled for, no stamp yet) leaves gsplat's own JIT
in charge, which rebuilds when it must. A gsplat wheel with precompiled CUDA code (``gsplat.csrc`` present)
needs none of this. ``physgs info --build-gsplat`` compiles once, right after an install, so that no
training or export run pays for it.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import logging
import os
import sys
from pathlib import Path
from typing import Literal

logger = logging.getLogger(__name__)

__all__ = ["build_status", "prepare_gsplat", "record_gsplat_build"]

STAMP = "physgs_build_stamp.json"
Status = Literal["precompiled", "prebuilt", "jit", "unavailable"]
_state: dict[str, str] = {}


def _gsplat_dir() -> Path | None:
    spec = importlib.util.find_spec("gsplat")
    return Path(spec.origin).parent if spec is not None and spec.origin else None


def _build_dir() -> Path:
    from torch.utils.cpp_extension import _get_build_directory

    return Path(_get_build_directory("gsplat_cuda", verbose=False))


def _arch_list() -> list[str]:
    """GPU architectures a JIT build in this environment compiles for (as torch chooses them)."""
    import torch

    env = os.environ.get("TORCH_CUDA_ARCH_LIST")
    if env:
        return sorted({a.strip() for a in env.replace(";", " ").split() if a.strip()})
    caps = {torch.cuda.get_device_capability(i) for i in range(torch.cuda.device_count())}
    return sorted(f"{a}.{b}" for a, b in caps)


def _fingerprint() -> dict[str, object]:
    """What a build depends on: gsplat's sources (content, not times), versions, architectures."""
    import torch

    root = _gsplat_dir()
    h = hashlib.sha256()
    if root is not None:
        csrc = root / "cuda" / "csrc"
        for path in sorted(p for p in csrc.iterdir() if p.suffix in (".cu", ".cpp", ".h", ".cuh")):
            h.update(path.name.encode() + b"\0" + path.read_bytes())
    return {"sources_sha256": h.hexdigest(), "gsplat": _version("gsplat"), "torch": torch.__version__,
            "cuda": torch.version.cuda, "python": f"{sys.version_info[0]}.{sys.version_info[1]}",
            "no_fast_math": os.getenv("NO_FAST_MATH", "0") == "1"}  # fmt: skip


def _version(dist: str) -> str:
    import importlib.metadata as md

    try:
        return md.version(dist)
    except md.PackageNotFoundError:
        return "?"


def _covers(archs: list[str]) -> bool:
    """Whether a library compiled for ``archs`` runs on the current GPU (same major.minor, or PTX at or
    below it)."""
    import torch

    major, minor = torch.cuda.get_device_capability()
    for a in archs:
        ptx = a.endswith("+PTX")
        try:
            ma, mi = (int(x) for x in a.removesuffix("+PTX").split("."))
        except ValueError:
            continue
        if (ma, mi) == (major, minor) or (ptx and (ma, mi) <= (major, minor)):
            return True
    return False


def build_status() -> tuple[Status, str]:
    """What :func:`prepare_gsplat` will do, with the reason (for ``physgs info``); loads nothing."""
    import torch

    if importlib.util.find_spec("gsplat") is None or not torch.cuda.is_available():
        return "unavailable", "gsplat or CUDA is missing"
    if importlib.util.find_spec("gsplat.csrc") is not None:
        return "precompiled", "gsplat ships its compiled CUDA library"
    build = _build_dir()
    lib = build / "gsplat_cuda.so"
    stamp = build / STAMP
    if not lib.is_file():
        return "jit", f"no build in {build}: the first gsplat call compiles (minutes)"
    if not stamp.is_file():
        return "jit", f"{lib} has no stamp: ninja decides (a reinstall of gsplat makes it rebuild)"
    try:
        saved = json.loads(stamp.read_text())
    except (OSError, ValueError):
        return "jit", f"{stamp} is unreadable"
    fp = _fingerprint()
    changed = [k for k, v in fp.items() if saved.get(k) != v]
    if changed:
        return "jit", f"{lib} was built from other inputs ({', '.join(changed)}): it is rebuilt"
    if not _covers(list(saved.get("archs", []))):
        return "jit", f"{lib} was compiled for {saved.get('archs')}, not this GPU: it is rebuilt"
    return "prebuilt", f"{lib} matches gsplat's sources, torch and this GPU: loaded without ninja"


def prepare_gsplat() -> Status:
    """Once per process, before gsplat's first CUDA call: load a matching earlier build as ``gsplat.csrc``
    (module doc). Returns what gsplat will use."""
    if "status" in _state:
        return _state["status"]  # type: ignore[return-value]
    status, reason = build_status()
    if status == "prebuilt":
        lib = _build_dir() / "gsplat_cuda.so"
        try:
            spec = importlib.util.spec_from_file_location("gsplat_cuda", lib)
            module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
            spec.loader.exec_module(module)  # type: ignore[union-attr]
            import gsplat

            sys.modules["gsplat.csrc"] = module
            gsplat.csrc = module  # type: ignore[attr-defined]
        except (ImportError, OSError) as err:
            status, reason = "jit", f"{lib} did not load ({err}): gsplat's JIT decides"
    logger.info("gsplat CUDA library: %s (%s)", status, reason)
    _state["status"] = status
    return status


def record_gsplat_build() -> None:
    """After gsplat's first successful CUDA call in a process that used its JIT library: stamp the build
    (module doc). No-op in every other case, and on any file-system error (the stamp is an optimisation)."""
    if _state.get("status") != "jit" or _state.get("stamped"):
        return
    _state["stamped"] = "yes"
    backend = sys.modules.get("gsplat.cuda._backend")
    if backend is None or getattr(backend, "_C", None) is None:
        return
    build = _build_dir()
    if not (build / "gsplat_cuda.so").is_file():
        return
    try:
        (build / STAMP).write_text(json.dumps({**_fingerprint(), "archs": _arch_list()}, indent=1))
    except OSError as err:
        logger.info("could not stamp the gsplat build in %s (%s)", build, err)
