"""Each scene's state on disk: ``OUT/scenes/<scene>/state.json``, rewritten atomically after every change.

``{"scene", "data", "stages": {STAGE: {"status": "running"|"done"|"failed", "attempts", "started",
"finished", "seconds", "outputs": {...}, "metrics": {...}, "error": "one line", "error_kind"}}}``.
A stage found ``running`` when a batch starts was interrupted (the batch was killed) and is redone.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

STAGES: tuple[str, ...] = ("perceive", "train", "export")
"""Per-scene stages, in order; ``eval`` runs once over all scenes at the end (summary.py)."""
STATE_FILE = "state.json"


def scene_dir(output_dir: Path, name: str) -> Path:
    return Path(output_dir) / "scenes" / name


def state_path(output_dir: Path, name: str) -> Path:
    return scene_dir(output_dir, name) / STATE_FILE


def load_state(output_dir: Path, name: str) -> dict:
    path = state_path(output_dir, name)
    if path.is_file():
        try:
            data = json.loads(path.read_text())
            if isinstance(data, dict) and isinstance(data.get("stages"), dict):
                return data
        except ValueError:
            pass  # a torn file cannot happen with the atomic write; treat anything unreadable as new
    return {"scene": name, "stages": {}}


def save_state(output_dir: Path, name: str, state: dict) -> None:
    path = state_path(output_dir, name)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".state-", suffix=".json")
    with os.fdopen(fd, "w") as f:
        json.dump(state, f, indent=1)
    os.replace(tmp, path)


def stage_status(state: dict, stage: str) -> str | None:
    rec = state.get("stages", {}).get(stage)
    return rec.get("status") if rec else None
