"""The run manifest: what a run was trained with, written by training and checked before a run is used.

A checkpoint holds the Gaussians' material evidence for the legend of the dataset's ``materials.json`` *as it
was at training time* (K materials in that order). Perception rerun on the dataset afterwards rewrites that
file: another number of materials made the export fail deep inside, the same materials in another order were
used without a word (the steel's evidence read as ceramic). So training writes ``physgs_manifest.json`` into the
run folder (:func:`write_manifest`) with

* the legend: the material names in order and a digest of ``materials.json``'s contents (posteriors, priors,
  thicknesses, the evidence settings; formatting is ignored);
* the dataset files training read, each with its SHA-256: ``transforms.json`` (its parsed contents) and every
  training frame's material and confidence map (their bytes), by their path in the dataset.

:func:`check_manifest` recomputes them from the dataset as it is now and raises :class:`RunManifestError`, one
line naming what changed and what to do, on any difference. A run without a manifest (trained before runs
carried one) is used as before, with one line saying it cannot be checked.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from ..errors import PhysGSError

__all__ = ["MANIFEST", "RunManifestError", "check_manifest", "dataset_dir", "manifest_of", "write_manifest"]

MANIFEST = "physgs_manifest.json"
"""the manifest's file name in the run folder (beside config.yml)"""
VERSION = 1
_FIX = ("export the run with the dataset it was trained on (restore the materials.json and maps it had), or retrain "
        "on the dataset as it is now")  # fmt: skip


class RunManifestError(PhysGSError, ValueError):
    """The dataset (its legend, posteriors or maps) is not the one the run was trained with; or the manifest is
    unreadable. The message says what changed."""


def _canonical(value: Any) -> bytes:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=True).encode()


def _file_sha(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _json_sha(path: Path) -> tuple[str, Any]:
    """SHA-256 of a JSON file's parsed contents (keys sorted: formatting ignored) and the contents."""
    try:
        value = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as err:
        raise RunManifestError(f"{path}: cannot be read ({type(err).__name__}); {_FIX}.") from None
    return hashlib.sha256(_canonical(value)).hexdigest(), value


def _rel(path: Path, data_dir: Path) -> str:
    return Path(os.path.relpath(Path(path), Path(data_dir))).as_posix()


def _map_files(metadata: Mapping[str, Any]) -> list[Path]:
    files: Iterable[Any] = [*(metadata.get("material_filenames") or []),
                            *(metadata.get("material_confidence_filenames") or [])]  # fmt: skip
    return sorted({Path(p) for p in files if p is not None})


def manifest_of(data_dir: Path, metadata: Mapping[str, Any]) -> dict[str, Any]:
    """The manifest of a dataset's training split: ``metadata`` is the split's DataparserOutputs metadata
    (``material_legend``, ``material_filenames``, ``material_confidence_filenames``)."""
    data_dir = Path(data_dir)
    legend = metadata["material_legend"]
    materials_path = Path(getattr(legend, "path", None) or data_dir / "materials.json")
    materials_sha, _ = _json_sha(materials_path)
    transforms_sha, _ = _json_sha(data_dir / "transforms.json")
    try:
        files = {_rel(p, data_dir): _file_sha(p) for p in _map_files(metadata)}
    except OSError as err:
        raise RunManifestError(f"{getattr(err, 'filename', None) or data_dir}: cannot be read ({err.strerror or err}); "
                               f"{_FIX}.") from None  # fmt: skip
    return {"version": VERSION, "materials": list(legend.names), "materials_file": _rel(materials_path, data_dir),
            "materials_sha256": materials_sha, "transforms_sha256": transforms_sha, "files": files}  # fmt: skip


def write_manifest(run_dir: Path, data_dir: Path, metadata: Mapping[str, Any]) -> Path:
    """Write the manifest of the training split into ``run_dir`` (one rename: never half written)."""
    path = Path(run_dir) / MANIFEST
    tmp = path.with_name(f".{MANIFEST}.tmp")
    tmp.write_text(json.dumps(manifest_of(data_dir, metadata), indent=1) + "\n", encoding="utf-8")
    os.replace(tmp, path)
    return path


def _read(path: Path) -> dict[str, Any]:
    _, value = _json_sha(path)
    keys = ("materials", "materials_sha256", "transforms_sha256", "files")
    if not isinstance(value, dict) or any(k not in value for k in keys) or not isinstance(value["files"], dict):
        raise RunManifestError(f"{path}: not a run manifest (it lacks {', '.join(keys)}); remove it to use the run "
                               "unchecked, or retrain.")  # fmt: skip
    return value


def _names(names: list[str]) -> str:
    shown = ", ".join(str(n) for n in names[:8])
    return f"[{shown}{', ...' if len(names) > 8 else ''}] ({len(names)})"


def _first_difference(a: list[str], b: list[str]) -> str:
    if len(a) != len(b):
        return f"{len(a)} materials then, {len(b)} now"
    i = next(i for i, (x, y) in enumerate(zip(a, b)) if x != y)
    return f"material {i + 1} was {a[i]!r}, is {b[i]!r}"


def dataset_dir(data: Path | str | None) -> Path | None:
    """The dataset folder of a datamanager's ``data`` (a folder, or its transforms.json)."""
    if data is None:
        return None
    data = Path(data)
    return data.parent if data.suffix == ".json" else data


def check_manifest(run_dir: Path, data_dir: Path, metadata: Mapping[str, Any]) -> bool:
    """Compare the run's manifest with the dataset as it is now (module doc). False when the run has none;
    :class:`RunManifestError` on a difference."""
    path = Path(run_dir) / MANIFEST
    if not path.is_file():
        return False
    saved = _read(path)
    now = manifest_of(data_dir, metadata)
    materials = Path(data_dir) / now["materials_file"]
    if list(saved["materials"]) != now["materials"]:
        raise RunManifestError(
            f"{materials}: the run {run_dir} was trained with the materials {_names(saved['materials'])}, the dataset "
            f"now lists {_names(now['materials'])} ({_first_difference(saved['materials'], now['materials'])}): "
            f"perception was rerun after training; {_FIX}.")  # fmt: skip
    if saved["materials_sha256"] != now["materials_sha256"]:
        raise RunManifestError(f"{materials}: its posteriors changed since the run {run_dir} was trained (same "
                               f"materials, other values); {_FIX}.")  # fmt: skip
    if saved["transforms_sha256"] != now["transforms_sha256"]:
        raise RunManifestError(f"{Path(data_dir) / 'transforms.json'}: changed since the run {run_dir} was trained "
                               f"(cameras or map paths); {_FIX}.")  # fmt: skip
    for rel, sha in sorted(saved["files"].items()):
        p = Path(data_dir) / rel
        if rel not in now["files"] or now["files"][rel] != sha:
            what = "is missing" if not p.is_file() else "changed"
            raise RunManifestError(f"{p}: {what} since the run {run_dir} was trained; {_FIX}.")
    extra = sorted(set(now["files"]) - set(saved["files"]))
    if extra:
        raise RunManifestError(f"{Path(data_dir) / extra[0]}: a map the run {run_dir} was not trained with; {_FIX}.")
    return True
