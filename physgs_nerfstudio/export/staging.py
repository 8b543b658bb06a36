"""Write an export as a unit: stage it beside the output folder, check it, then swap it in.

``physgs export --output-dir D`` writes into ``.D.physgs-staging-<pid>-<random>/`` next to ``D``. When every
writer has finished, :func:`verify_export` reads every file back (each ``.npz`` opens and every array in it
reads, a voxel grid has all its arrays, ``.json`` parses, a ``.ply`` header parses and the file has exactly
the bytes its header announces, ``.png`` passes PIL's checks) and fsyncs it; then a marker,
``.physgs-export.json`` (format, time, the run, every file with its size), is written and ``D`` is swapped:
``D`` -> ``.D.physgs-old-...``, staging -> ``D``, old deleted. Any failure before the swap (a full disk,
a failing writer, Ctrl-C) deletes the staging folder and leaves ``D`` exactly as it was. A kill between the
two renames leaves ``.D.physgs-old-...``: the next export puts it back first.

Which folders may be replaced (:func:`check_output_dir`): a missing or empty ``D``, or a previous export
of ours (its marker lists every entry in it; exports from before the marker: only our file names, with a
PhysGS report or PLY). Any other non-empty folder is refused unless ``overwrite=True`` (``--overwrite``),
which replaces it whole (its old content is deleted once the new export is complete); even then the
filesystem root, the home folder, the current folder and any folder holding the run or its dataset are
refused. A mount point is refused (it cannot be renamed): export into a folder inside it.
"""

from __future__ import annotations

import json
import os
import shutil
import struct
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from ..errors import PhysGSError

__all__ = ["MARKER", "ExportDirError", "ExportStage", "ExportWriteError", "check_output_dir", "verify_export"]

MARKER = ".physgs-export.json"
FORMAT = "physgs-export/1"
OUR_NAMES = frozenset({"property_field.ply", "voxels.npz", "maps", "report.json", MARKER})
"""what an export of ours contains (without the marker: exports written before it existed)"""


class ExportDirError(PhysGSError, ValueError):
    """The output folder cannot be used (foreign content, a mount point, the run's own folder, ...)."""


class ExportWriteError(PhysGSError, OSError):
    """Writing or checking the staged export failed; the previous export is unchanged."""


# ------------------------------------------------------------------------------------------ the folder
def _entries(d: Path) -> list[str]:
    return sorted(p.name for p in d.iterdir()) if d.is_dir() else []


def _legacy_ours(d: Path, names: list[str]) -> bool:
    """An export written before the marker: only our names, and a PhysGS report.json or PLY among them."""
    if not names or not set(names) <= OUR_NAMES:
        return False
    try:
        report = json.loads((d / "report.json").read_text()) if "report.json" in names else None
        if isinstance(report, dict) and isinstance(report.get("mass"), dict):
            return True
        if "property_field.ply" in names:
            with open(d / "property_field.ply", "rb") as f:
                return b"\ncomment physgs " in f.read(1 << 16)
    except (OSError, ValueError):
        return False
    return False


def is_our_export(d: Path) -> bool:
    """True when ``d`` holds an export of ours and nothing else (module doc)."""
    names = _entries(d)
    if MARKER not in names:
        return _legacy_ours(d, names)
    try:
        listed = json.loads((d / MARKER).read_text()).get("files", {})
    except (OSError, ValueError, AttributeError):
        return False
    top = {Path(rel).parts[0] for rel in listed} | {MARKER}
    return set(names) <= top


def _contains(parent: Path, child: Path) -> bool:
    return parent == child or parent in child.parents


def check_output_dir(output_dir: Path, *, overwrite: bool = False, protect: Iterable[Path | None] = ()) -> Path:
    """The resolved output folder if an export may be written there, else :class:`ExportDirError`."""
    final = Path(output_dir).expanduser().resolve()
    if final.exists() and not final.is_dir():
        raise ExportDirError(f"{final}: exists and is not a folder; pass a folder for --output-dir.")
    if final.is_dir() and os.path.ismount(final):
        raise ExportDirError(f"{final} is a mount point, which cannot be swapped for the new export; pass a folder "
                             f"inside it (--output-dir {final / 'export'}).")  # fmt: skip
    keep = [Path("/"), Path.home().resolve(), Path.cwd().resolve()]
    keep += [Path(p).expanduser().resolve() for p in protect if p is not None]
    hit = next((p for p in keep if _contains(final, p)), None)
    if final.exists() and hit is not None:
        raise ExportDirError(f"{final}: replacing it would delete {hit} (it is inside); pick an --output-dir of its own.")
    names = _entries(final)
    if names and not is_our_export(final) and not overwrite:
        shown = ", ".join(names[:5]) + (", ..." if len(names) > 5 else "")
        raise ExportDirError(f"{final}: not empty and not a previous physgs export (holds {shown}); choose an empty "
                             "or new --output-dir, or pass --overwrite to replace the folder and everything in it.")  # fmt: skip
    return final


# ------------------------------------------------------------------------------------------ the checks
_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
              "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}  # fmt: skip


def _check_ply(path: Path) -> None:
    with open(path, "rb") as f:
        head = f.read(1 << 20)
    end = head.find(b"end_header\n")
    if not head.startswith(b"ply\n") or end < 0:
        raise ValueError("no PLY header")
    lines = head[:end].decode("ascii", "replace").splitlines()
    fmt = next((ln.split()[1] for ln in lines if ln.startswith("format ")), "")
    rows, row_bytes, has_list = [], 0, False
    for ln in lines:
        parts = ln.split()
        if parts[:1] == ["element"]:
            if rows:
                rows[-1] = (rows[-1][0], row_bytes)
            rows.append((int(parts[2]), 0))
            row_bytes = 0
        elif parts[:1] == ["property"]:
            has_list |= parts[1] == "list"
            row_bytes += _PLY_SIZES.get(parts[1], 0)
    if rows:
        rows[-1] = (rows[-1][0], row_bytes)
    if fmt.startswith("binary") and not has_list:
        want = end + len(b"end_header\n") + sum(n * b for n, b in rows)
        have = path.stat().st_size
        if have != want:
            raise ValueError(f"{have} bytes, the header announces {want}")
        return
    from plyfile import PlyData

    PlyData.read(str(path))


def _check_npz(path: Path) -> None:
    import numpy as np

    with np.load(path, allow_pickle=False) as z:
        names = list(z.files)
        arrays = {k: z[k] for k in names}  # reads every member (zip CRC checked)
    if not names:
        raise ValueError("no arrays")
    if "meta" in arrays:
        meta = json.loads(str(arrays["meta"]))
        if str(meta.get("format", "")).startswith("physgs-voxels"):
            want = {"occupancy", "part_id", "material_index", "material_prob", "origin_m", "voxel_size_m"}
            want |= {f"{k}_{s}" for k in meta.get("property_keys", []) for s in ("mean", "total")}
            missing = sorted(want - set(names))
            if missing:
                raise ValueError(f"{len(names)} arrays, missing {', '.join(missing)}")


def _check_png(path: Path) -> None:
    from ..image_files import open_image

    with open_image(path):  # decodes it (a truncated file fails), within the pixel limit
        pass


_CHECKS: dict[str, Callable[[Path], None]] = {
    ".json": lambda p: json.loads(p.read_text(encoding="utf-8")) and None,
    ".npz": _check_npz, ".ply": _check_ply, ".png": _check_png,
}  # fmt: skip


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def verify_export(folder: Path, expected: Iterable[Path] = ()) -> dict[str, int]:
    """Check every file under ``folder`` (module doc) and that each ``expected`` one exists; fsync them.
    Returns {relative path: size}. Raises ValueError naming the file."""
    folder = Path(folder)
    for p in expected:
        if not Path(p).is_file():
            raise ValueError(f"{Path(p).name}: was not written")
    sizes: dict[str, int] = {}
    for p in sorted(folder.rglob("*")):
        if not p.is_file() or p.name == MARKER:
            continue
        rel = p.relative_to(folder).as_posix()
        size = p.stat().st_size
        if size == 0:
            raise ValueError(f"{rel}: empty file")
        try:
            _CHECKS.get(p.suffix.lower(), lambda _: None)(p)
        except (OSError, ValueError, SyntaxError, EOFError, struct.error, KeyError) as err:
            raise ValueError(f"{rel}: unreadable ({err})") from None
        _fsync(p)
        sizes[rel] = size
    return sizes


# ------------------------------------------------------------------------------------------ the stage
def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _recover(final: Path, log: Callable[[str], None]) -> None:
    """Leftovers of killed exports beside ``final``: staging folders are deleted, a previous export that a
    kill left moved aside is put back when ``final`` is missing (module doc)."""
    for kind in ("staging", "old"):
        prefix = f".{final.name}.physgs-{kind}-"
        for p in sorted(q for q in final.parent.iterdir() if q.name.startswith(prefix)):
            try:
                pid = int(p.name.rsplit("-", 2)[-2])
            except ValueError:
                continue
            if pid == os.getpid() or _pid_alive(pid):
                continue
            if kind == "old" and not final.exists():
                os.rename(p, final)
                log(f"physgs: restored the previous export {final} (an earlier export was killed while swapping).")
            else:
                shutil.rmtree(p, ignore_errors=True)


def _fsync_dir(d: Path) -> None:
    try:
        _fsync(d)
    except OSError:  # not every filesystem fsyncs folders
        pass


@dataclass
class ExportStage:
    """A staging folder beside ``final``: write into ``path``, then :meth:`commit` or :meth:`abort`."""

    final: Path
    path: Path

    @classmethod
    def open(cls, output_dir: Path, *, overwrite: bool = False, protect: Sequence[Path | None] = (),
             log: Callable[[str], None] | None = None) -> ExportStage:  # fmt: skip
        log = log or (lambda line: print(line, file=sys.stderr))
        final = Path(output_dir).expanduser().resolve()
        final.parent.mkdir(parents=True, exist_ok=True)
        _recover(final, log)
        final = check_output_dir(final, overwrite=overwrite, protect=protect)
        try:
            path = Path(tempfile.mkdtemp(prefix=f".{final.name}.physgs-staging-{os.getpid()}-", dir=final.parent))
        except OSError as err:
            raise ExportDirError(f"{final.parent}: cannot create the staging folder for the export there ({err}); "
                                 "the export is written beside --output-dir and then renamed into place.") from None  # fmt: skip
        return cls(final, path)

    def final_path(self, staged: Path) -> Path:
        """Where a file written under :attr:`path` will be after :meth:`commit`."""
        return self.final / Path(staged).relative_to(self.path)

    def abort(self) -> None:
        shutil.rmtree(self.path, ignore_errors=True)

    def commit(self, files: Mapping[str, Sequence[Path]], info: Mapping[str, object] | None = None) -> dict[str, list[Path]]:
        """Check the staged files, write the marker, swap the folder in; ``files`` mapped to their final paths."""
        try:
            sizes = verify_export(self.path, [p for ps in files.values() for p in ps])
        except ValueError as err:
            raise ExportWriteError(f"{self.final}: the new export failed its check ({err}); the previous export "
                                   "there is unchanged.") from None  # fmt: skip
        marker = {"format": FORMAT, "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"), **(info or {}), "files": sizes}
        (self.path / MARKER).write_text(json.dumps(marker, indent=2, default=str))
        _fsync(self.path / MARKER)
        self._swap()
        return {k: [self.final_path(p) for p in ps] for k, ps in files.items()}

    def _swap(self) -> None:
        final = self.final
        if final.is_dir() and not any(final.iterdir()):
            final.rmdir()
        if not final.exists():
            os.rename(self.path, final)
            _fsync_dir(final.parent)
            return
        old = Path(tempfile.mkdtemp(prefix=f".{final.name}.physgs-old-{os.getpid()}-", dir=final.parent))
        old.rmdir()
        os.rename(final, old)
        try:
            os.rename(self.path, final)
        except BaseException:
            os.rename(old, final)
            raise
        _fsync_dir(final.parent)
        shutil.rmtree(old, ignore_errors=True)
