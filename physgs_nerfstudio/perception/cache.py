"""Disk cache of VLM responses, so a rerun makes no paid call.

Key: sha256 over (backend, model, variant, system prompt, text prompt, sha256 of each image, schema
version), see :func:`request_key`. ``variant`` distinguishes configurations of one backend that answer
differently (the simulated backend's noise model); it is empty for real endpoints.

One JSON file per key at ``<root>/<key[:2]>/<key>.json`` holding the response text, the token usage and
non-secret context (backend, model, view, mask id). API keys are never passed to this module. Writes are
atomic (temporary file + ``os.replace``), so a killed run never leaves a half-written entry.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

logger = logging.getLogger(__name__)

CACHE_FORMAT = 1


def request_key(
    backend: str,
    model: str,
    variant: str,
    system: str,
    text: str,
    image_hashes: Sequence[str],
    schema_version: str,
) -> str:
    payload = json.dumps(
        {
            "backend": backend,
            "model": model,
            "variant": variant,
            "system": system,
            "text": text,
            "images": list(image_hashes),
            "schema": schema_version,
        },
        sort_keys=True,
        separators=(",", ":"),
    )
    return hashlib.sha256(payload.encode("utf-8")).hexdigest()


@dataclass
class CacheEntry:
    key: str
    text: str
    usage: dict[str, int]
    simulated: bool
    meta: dict[str, Any]


class ResponseCache:
    """Thread-safe enough for one process: each entry is one atomically renamed file."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    def path(self, key: str) -> Path:
        if len(key) != 64 or any(c not in "0123456789abcdef" for c in key):
            raise ValueError(f"not a cache key: {key!r}")
        return self.root / key[:2] / f"{key}.json"

    def get(self, key: str) -> CacheEntry | None:
        path = self.path(key)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
            entry = CacheEntry(
                key=key,
                text=str(data["text"]),
                usage={k: int(v) for k, v in dict(data.get("usage") or {}).items()},
                simulated=bool(data.get("simulated", False)),
                meta=dict(data.get("meta") or {}),
            )
        except FileNotFoundError:
            with self._lock:
                self.misses += 1
            return None
        except (OSError, ValueError, KeyError, TypeError) as err:
            logger.warning("ignoring unreadable cache entry %s (%s)", path, err)
            with self._lock:
                self.misses += 1
            return None
        with self._lock:
            self.hits += 1
        return entry

    def __contains__(self, key: str) -> bool:
        return self.path(key).is_file()

    def put(
        self,
        key: str,
        text: str,
        usage: dict[str, int] | None,
        simulated: bool,
        meta: dict[str, Any] | None = None,
    ) -> Path:
        path = self.path(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        record = {
            "format": CACHE_FORMAT,
            "key": key,
            "text": text,
            "usage": dict(usage or {}),
            "simulated": bool(simulated),
            "meta": dict(meta or {}),
        }
        data = json.dumps(record, ensure_ascii=False, sort_keys=True).encode("utf-8")
        fd, tmp = tempfile.mkstemp(prefix=f".{key[:8]}.", suffix=".tmp", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)
        except BaseException:
            try:
                os.unlink(tmp)
            except OSError:
                pass
            raise
        return path
