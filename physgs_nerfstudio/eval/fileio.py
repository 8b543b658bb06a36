"""Reading evaluation inputs with errors that point at the file, the line or entry, and the fix."""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from .errors import input_error

__all__ = ["load_json", "opt_float", "read_csv", "to_float", "to_str"]


class _DuplicateKey(Exception):
    def __init__(self, key: str):
        self.key = key


def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in pairs:
        if k in out:
            raise _DuplicateKey(k)
        out[k] = v
    return out


def load_json(path: Path) -> Any:
    """Parse a JSON file; a syntax error names the line and column."""
    path = Path(path)
    if not path.is_file():
        raise input_error(path, None, "file not found", "Check the path (and the dataset root you passed)")
    try:
        return json.loads(path.read_text(encoding="utf-8"), object_pairs_hook=_no_duplicates)
    except _DuplicateKey as dup:
        raise input_error(path, f"key {dup.key!r}", "appears twice in one JSON object (the first would be lost)",
                          "Keep one entry per key") from None
    except json.JSONDecodeError as err:
        raise input_error(path, f"line {err.lineno}, column {err.colno}", f"invalid JSON ({err.msg})",
                          "Fix the JSON syntax at that position") from None
    except UnicodeDecodeError:
        raise input_error(path, None, "not UTF-8 text", "Save the file as UTF-8 JSON") from None
    except RecursionError:
        raise input_error(path, None, "nested too deeply to read (lists or objects inside each other thousands of "
                          "levels deep)", "Write the records as a flat list") from None


def _fields(path: Path, line_no: int, line: str) -> list[str]:
    """One CSV line's fields; a field over csv's limit (128 KiB) or a malformed line names the line."""
    try:
        return next(csv.reader([line]))
    except csv.Error as err:
        raise input_error(path, f"line {line_no}", f"not a readable CSV line ({err})",
                          "Keep each field short (a number, a name or a unit)") from None


def read_csv(path: Path, required: Iterable[str], optional: Iterable[str] = ()) -> list[tuple[int, dict[str, str]]]:
    """Rows of a CSV file with a header, as ``(line number, {column: text})``; columns lower-cased.

    Blank lines and lines starting with ``#`` are skipped. Unknown columns are an error (a typo would
    otherwise silently drop data), as are missing required columns and rows with too many fields.
    """
    path = Path(path)
    if not path.is_file():
        raise input_error(path, None, "file not found", "Check the path")
    required = [c.lower() for c in required]
    allowed = set(required) | {c.lower() for c in optional}
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise input_error(path, None, "not UTF-8 text", "Save the file as UTF-8 CSV") from None
    lines = [(i + 1, ln) for i, ln in enumerate(text.splitlines()) if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise input_error(path, None, "empty CSV file", f"Write a header line with columns {', '.join(required)}")
    header_no, header_line = lines[0]
    header = [h.strip().lower() for h in _fields(path, header_no, header_line)]
    missing = [c for c in required if c not in header]
    if missing:
        raise input_error(path, f"line {header_no} (header)", f"missing column(s) {', '.join(missing)}; "
                          f"header is {', '.join(header)}", f"The header must name {', '.join(required)}"
                          + (f" and may name {', '.join(sorted(allowed - set(required)))}" if allowed - set(required) else ""))
    unknown = [c for c in header if c not in allowed]
    if unknown:
        raise input_error(path, f"line {header_no} (header)", f"unknown column(s) {', '.join(unknown)}",
                          f"Allowed columns: {', '.join(required + sorted(allowed - set(required)))}")
    rows: list[tuple[int, dict[str, str]]] = []
    for line_no, line in lines[1:]:
        fields = _fields(path, line_no, line)
        if len(fields) > len(header):
            raise input_error(path, f"line {line_no}", f"{len(fields)} fields but the header has {len(header)}",
                              "Quote values that contain commas, or remove the extra fields")
        fields += [""] * (len(header) - len(fields))
        rows.append((line_no, {h: f.strip() for h, f in zip(header, fields)}))
    return rows


def to_float(value: Any, path: Path, where: str, name: str, *, positive: bool = False) -> float:
    """A finite number (JSON number or numeric text), else an error naming the field."""
    if isinstance(value, bool) or value is None or (isinstance(value, str) and not value.strip()):
        raise input_error(path, where, f"{name} is missing or not a number (got {value!r})", f"Give {name} as a number")
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise input_error(path, where, f"{name} is not a number (got {value!r})", f"Give {name} as a number") from None
    if not math.isfinite(x):
        raise input_error(path, where, f"{name} is not finite (got {value!r})", f"Give a finite {name} or drop the entry")
    if positive and x <= 0:
        raise input_error(path, where, f"{name} must be > 0 (got {x:g})", f"Give a positive {name} or drop the entry")
    return x


def opt_float(value: Any, path: Path, where: str, name: str, *, positive: bool = False) -> float | None:
    """Like :func:`to_float`, but None / blank text gives None."""
    if value is None or (isinstance(value, str) and not value.strip()):
        return None
    return to_float(value, path, where, name, positive=positive)


def to_str(value: Any, path: Path, where: str, name: str) -> str:
    if not isinstance(value, (str, int)) or isinstance(value, bool) or not str(value).strip():
        raise input_error(path, where, f"{name} must be a non-empty string (got {value!r})", f"Give {name} as text")
    return str(value).strip()
