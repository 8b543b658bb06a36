"""The object's geometry kept beside its run, so that an export pays only for what it writes.

Carving the object (:func:`physgs_nerfstudio.geometry.reconstruct_object`) is most of a mass export's work. Its
result is a function of the checkpoint, the dataset's files (cameras, object masks, perception's answers), the
export's geometry settings and the code, so it is stored once computed, in ``RUN_DIR/physgs_cache/``, and reused
by every later export whose inputs are the same:

- ``ns-train physgs`` computes it right after its final checkpoint on a CUDA device
  (``--pipeline.precompute-geometry``, :func:`.run.precompute_geometry`), where CUDA, gsplat and SciPy are
  already loaded, so a user's first ``physgs export`` only loads the run and integrates the mass;
- ``physgs export`` reads it (``--geometry-cache``, default on), and stores what it computes on a miss, so a
  second export of the same run and settings (other outputs, another Monte Carlo) skips the carving.

**The key** (:func:`cache_key`) is a SHA-256 over: this format's version; the bytes of every ``.py`` file of the
package (any code change is a miss); torch's version and the device type (the CPU and CUDA depth rules differ);
the checkpoint's path, size and modification time; the same of ``config.yml`` and ``dataparser_transforms.json``;
the relative path, size and modification time of every file under the dataset folder (masks, material maps,
perception's records, transforms.json); the loading arguments (scale, known length, library, mask width); and the
geometry settings (every field of :class:`~physgs_nerfstudio.geometry.GeometryConfig`). Anything else that
changes makes a new key, and a stale entry is never read. What is not in the key cannot change the carving.

**The file** is ``torch.save`` of plain containers and CPU tensors, read with ``weights_only=True`` (no pickled
code runs, as with the checkpoints): the geometry's dataclasses are written as tagged dictionaries and rebuilt
from an allow-list of their classes. The per-voxel mixture, zero outside the carved union, is stored on that
union only. An unreadable, truncated or foreign file is a miss with a warning, never an error, and the export
computes the geometry as it would without the cache. At most :data:`KEEP` entries are kept per run, newest first.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import logging
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

logger = logging.getLogger(__name__)

__all__ = ["GeometryCache", "cache_for_run", "cache_key", "decode_geometry", "encode_geometry", "load_args"]

FORMAT = 1
"""version of the file's layout (a change makes every older entry a miss)"""
KEEP = 4
"""entries kept per run (the newest)"""
STALE_TMP_S = 3600
"""a temporary file this old is a killed writer's (removed when the next entry is stored)"""
CACHE_DIR = "physgs_cache"
_PACKAGE = Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------------------------------------- the file
def _classes() -> dict[str, type]:
    from ..bayes.nig import NIG
    from ..geometry.grid import VoxelGrid
    from ..geometry.reconstruct import ObjectGeometry
    from ..geometry.select import ObjectSelection
    from ..geometry.structure import PartStructure
    from ..geometry.support import SupportPlane

    return {c.__name__: c for c in (ObjectGeometry, VoxelGrid, PartStructure, NIG, ObjectSelection, SupportPlane)}


def _encode(x: Any, classes: dict[str, type]) -> Any:
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        name = type(x).__name__
        if classes.get(name) is not type(x):
            raise TypeError(f"geometry cache: {name} is not a class the cache may hold")
        return {"__dc__": name, "f": {f.name: _encode(getattr(x, f.name), classes)
                                      for f in dataclasses.fields(x) if f.init}}  # fmt: skip
    if isinstance(x, np.ndarray):
        if x.dtype == object:
            raise TypeError("geometry cache: object arrays cannot be stored")
        if x.dtype.kind in "iu" and x.size:  # stored in the smallest integer type that holds it (lossless)
            small = np.result_type(np.min_scalar_type(int(x.min())), np.min_scalar_type(int(x.max())))
            if small.itemsize < x.itemsize and small.kind == "i" or small == np.uint8:
                return {"__np__": torch.from_numpy(np.ascontiguousarray(x.astype(small))), "dtype": x.dtype.str}
        return {"__np__": torch.from_numpy(np.ascontiguousarray(x))}
    if isinstance(x, torch.Tensor):
        return {"__pt__": x.detach().cpu()}
    if isinstance(x, tuple):
        return {"__tuple__": [_encode(v, classes) for v in x]}
    if isinstance(x, list):
        return [_encode(v, classes) for v in x]
    if isinstance(x, dict):
        return {"__dict__": [[str(k), _encode(v, classes)] for k, v in x.items()]}
    if isinstance(x, np.generic):
        return x.item()
    if x is None or isinstance(x, (bool, int, float, str)):
        return x
    raise TypeError(f"geometry cache: cannot store a {type(x).__name__}")


def _decode(x: Any, classes: dict[str, type], device: torch.device) -> Any:
    if isinstance(x, list):
        return [_decode(v, classes, device) for v in x]
    if not isinstance(x, dict):
        return x
    if "__np__" in x:
        if "dtype" not in x:
            return x["__np__"].numpy()
        dtype = np.dtype(x["dtype"])
        if dtype.kind not in "iu":
            raise ValueError(f"geometry cache: an integer array stored as {dtype}")
        return x["__np__"].numpy().astype(dtype)
    if "__pt__" in x:
        return x["__pt__"].to(device)
    if "__tuple__" in x:
        return tuple(_decode(v, classes, device) for v in x["__tuple__"])
    if "__dict__" in x:
        return {k: _decode(v, classes, device) for k, v in x["__dict__"]}
    if "__dc__" in x:
        cls = classes[x["__dc__"]]  # KeyError: a class outside the allow-list (a foreign file)
        return cls(**{k: _decode(v, classes, device) for k, v in x["f"].items()})
    raise ValueError("geometry cache: unknown entry")


def encode_geometry(geo: Any) -> dict[str, Any]:
    """An :class:`~physgs_nerfstudio.geometry.ObjectGeometry` as plain containers and CPU tensors (module doc);
    the per-voxel mixture on the carved union only (where it is not zero)."""
    classes = _classes()
    mixture = geo.mixture
    union = geo.parts >= 0
    sparse = mixture.ndim == 4 and union.shape == mixture.shape[:3] and not mixture[~union].any()
    if sparse:
        geo = dataclasses.replace(geo, mixture=np.zeros((0,), mixture.dtype))
    out = _encode(geo, classes)
    out["mixture_on_union"] = {"__np__": torch.from_numpy(np.ascontiguousarray(mixture[union]))} if sparse else None
    out["mixture_shape"] = list(mixture.shape)
    return out


def decode_geometry(data: dict[str, Any], device: torch.device | str = "cpu") -> Any:
    """The inverse of :func:`encode_geometry`: tensors on ``device``, arrays as NumPy (bit for bit the stored)."""
    classes = _classes()
    geo = _decode({"__dc__": data["__dc__"], "f": data["f"]}, classes, torch.device(device))
    on_union = data.get("mixture_on_union")
    if on_union is not None:
        values = on_union["__np__"].numpy()
        mixture = np.zeros(tuple(data["mixture_shape"]), values.dtype)
        mixture[geo.parts >= 0] = values
        geo = dataclasses.replace(geo, mixture=mixture)
    return geo


# ---------------------------------------------------------------------------------------------- the key
_CODE_HASH: str | None = None


def code_fingerprint() -> str:
    """SHA-256 of every ``.py`` file of the package (paths and bytes): a new version or an edit is a new key."""
    global _CODE_HASH
    if _CODE_HASH is None:
        h = hashlib.sha256()
        for path in sorted(_PACKAGE.rglob("*.py")):
            h.update(str(path.relative_to(_PACKAGE)).encode())
            h.update(path.read_bytes())
        _CODE_HASH = h.hexdigest()
    return _CODE_HASH


def _stat(path: Path | None) -> list[Any] | None:
    if path is None:
        return None
    try:
        st = Path(path).stat()
    except OSError:
        return [str(path), None]
    return [str(Path(path).resolve()), st.st_size, st.st_mtime_ns]


def _not_input(folder: Path) -> bool:
    """Folders under a dataset that no export reads: this cache's, a physgs export's (its marker file) and a
    nerfstudio run's (config.yml beside nerfstudio_models/: a run trained with its outputs inside the dataset)."""
    return (folder.name == CACHE_DIR or (folder / ".physgs-export.json").is_file()
            or ((folder / "nerfstudio_models").is_dir() and (folder / "config.yml").is_file()))  # fmt: skip


def _tree_stats(folder: Path | None) -> list[Any]:
    """(relative path, size, mtime) of every file under ``folder`` (sorted), skipping the folders that are no
    export's input (:func:`_not_input`)."""
    if folder is None or not Path(folder).is_dir():
        return []
    rows = []
    for root, dirs, files in os.walk(folder):
        dirs[:] = sorted(d for d in dirs if not _not_input(Path(root) / d))
        for name in sorted(files):
            p = Path(root) / name
            try:
                st = p.stat()
            except OSError:
                continue
            rows.append([str(p.relative_to(folder)), st.st_size, st.st_mtime_ns])
    return rows


def cache_key(*, checkpoint: Path, config_path: Path, run_dir: Path, data_dir: Path | None, geometry: Any,
              device: str, load_args: dict[str, Any]) -> str:  # fmt: skip
    """The SHA-256 key of one geometry (module doc)."""
    from ..fusion.writer import jsonable

    record = {
        "format": FORMAT,
        "code": code_fingerprint(),
        "torch": torch.__version__,
        "device": torch.device(device).type,
        "checkpoint": _stat(checkpoint),
        "config": _stat(config_path),
        "transforms": _stat(Path(run_dir) / "dataparser_transforms.json"),
        "data_dir": str(Path(data_dir).resolve()) if data_dir is not None else None,
        "data": _tree_stats(data_dir),
        "load": jsonable(load_args),
        "geometry": jsonable(geometry),
    }
    return hashlib.sha256(json.dumps(record, sort_keys=True).encode()).hexdigest()


# ---------------------------------------------------------------------------------------------- the cache
@dataclass
class GeometryCache:
    """One run's geometry cache entry for one key (module doc)."""

    folder: Path
    key: str

    @property
    def path(self) -> Path:
        return self.folder / f"geometry-{self.key[:24]}.pt"

    def load(self, device: torch.device | str = "cpu") -> Any | None:
        """The stored geometry on ``device``, or None (no entry, or one that cannot be read: a warning)."""
        path = self.path
        if not path.is_file():
            return None
        try:
            data = torch.load(path, map_location="cpu", weights_only=True)
            if not isinstance(data, dict) or data.get("key") != self.key or data.get("format") != FORMAT:
                raise ValueError("its key does not match its name")
            geo = decode_geometry(data["geometry"], device)
        except Exception as err:  # noqa: BLE001 - any unreadable entry is a miss; the export computes the geometry
            logger.warning("geometry cache %s could not be read (%s); computing the geometry instead", path,
                           " ".join(str(err).split())[:200])  # fmt: skip
            return None
        try:
            os.utime(path)  # the newest entry is kept longest
        except OSError:
            pass
        return geo

    def save(self, geo: Any) -> Path | None:
        """Store ``geo`` in one rename (:func:`physgs_nerfstudio.fusion.transaction.atomic_write_bytes`, the
        project's write layer: a full disk or a kill leaves the old entry or none, never half of one); None when
        the folder is not writable (a read-only run: the export works as without the cache)."""
        from ..fusion.transaction import atomic_write_bytes

        path = self.path
        try:
            buffer = io.BytesIO()
            torch.save({"format": FORMAT, "key": self.key, "geometry": encode_geometry(geo)}, buffer)
            atomic_write_bytes(path, buffer.getvalue())
        except (OSError, RuntimeError) as err:
            logger.info("geometry cache not written to %s (%s)", path, err)
            return None
        self._prune()
        return path

    def _prune(self) -> None:
        def mtime(p: Path) -> int:
            try:
                return p.stat().st_mtime_ns
            except OSError:  # pruned by another export meanwhile
                return -1

        for old in sorted(self.folder.glob("geometry-*.pt"), key=mtime, reverse=True)[KEEP:]:
            old.unlink(missing_ok=True)
        stale = time.time_ns() - STALE_TMP_S * 10**9  # a writer killed mid-write left its temporary file
        for tmp in self.folder.glob(".geometry-*.tmp"):
            if 0 <= mtime(tmp) < stale:
                tmp.unlink(missing_ok=True)


def cache_for_run(run: Any, geometry: Any, device: str, load_args: dict[str, Any]) -> GeometryCache | None:
    """The cache entry of a loaded run (:class:`.run.LoadedRun` with its ``source``) for these settings;
    None when the run has no source files (an in-memory run)."""
    src = getattr(run, "source", None)
    if src is None:
        return None
    key = cache_key(checkpoint=src.checkpoint, config_path=src.config_path, run_dir=src.run_dir,
                    data_dir=run.data_dir, geometry=geometry, device=device, load_args=load_args)  # fmt: skip
    return GeometryCache(Path(src.run_dir) / CACHE_DIR, key)


def load_args(scale: float | None, known_length: Sequence[float] | None, env: str | None,
              max_view_width: int | None) -> dict[str, Any]:  # fmt: skip
    """The loading arguments that enter the key (module doc)."""
    return {"scale": scale, "known_length": None if known_length is None else list(known_length), "env": env,
            "max_view_width": max_view_width}

