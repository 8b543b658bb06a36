"""Which scenes a batch runs: each is a nerfstudio dataset folder (``transforms.json``) with a unique name.

``--scenes`` may be

* one dataset folder, or a folder of them (``physgs synth --suite`` writes one per object; their
  ``ground_truth.json`` makes them scorable with ``--dataset synth``);
* the ABO-500 layout (NeRF2Physics' ``abo_500/`` with ``filtered_product_weights.json``, ``splits.json``
  and ``scenes/<id>/``): the scenes of ``--split``;
* a text file of dataset paths, one per line (``#`` comments; relative paths are relative to the file).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from ..errors import PhysGSError

TRANSFORMS = "transforms.json"
SYNTH_TRUTH = "ground_truth.json"


class SceneListError(PhysGSError, ValueError):
    """--scenes names no usable scenes; the message says where and what to do."""


@dataclass(frozen=True)
class Scene:
    name: str
    """Unique in the batch: the folder name (the key of its state, outputs and eval rows)."""
    data: Path
    truth: Literal["synth", "abo500", "none"] = "none"


@dataclass(frozen=True)
class SceneSet:
    scenes: tuple[Scene, ...]
    source: Path
    kind: Literal["folder", "abo500", "list"]
    abo_root: Path | None = None
    split: str | None = None


def _truth_of(data: Path) -> Literal["synth", "none"]:
    return "synth" if (data / SYNTH_TRUTH).is_file() else "none"


def _unique(scenes: list[Scene], source: Path) -> tuple[Scene, ...]:
    seen: dict[str, Path] = {}
    for s in scenes:
        if s.name in seen:
            raise SceneListError(f"{source}: two scenes are named {s.name!r} ({seen[s.name]} and {s.data}); "
                                 "scene names (folder names) must be unique in a batch: rename one folder")
        seen[s.name] = s.data
    return tuple(scenes)


def _from_abo(root: Path, split: str) -> SceneSet:
    from ..eval.adapters import abo500

    weights = abo500.load_weights(root)
    base = root / "scenes" if (root / "scenes").is_dir() else root
    present = abo500.list_scenes(root, weights)
    if split == "all":
        names = present
    else:
        splits = abo500.load_splits(root)
        if splits is None:
            raise SceneListError(f"{root / abo500.SPLITS_FILE}: not found; put NeRF2Physics' splits.json there "
                                 "or pass --split all")
        wanted = split.split("+")
        unknown = [s for s in wanted if s not in splits]
        if unknown:
            raise SceneListError(f"{root / abo500.SPLITS_FILE}: no split {', '.join(unknown)} (present: "
                                 f"{', '.join(splits)}); choose one with --split")
        by_item = {abo500.item_id_of(n): n for n in present}
        names = []
        for entry in (e for s in wanted for e in splits[s]):
            name = entry if entry in present else by_item.get(entry)
            if name is not None and name not in names:
                names.append(name)
    scenes = [Scene(n, base / n, "abo500") for n in names]
    return SceneSet(_unique(scenes, root), root, "abo500", abo_root=root, split=split)


def discover(source: Path, split: str = "test") -> SceneSet:
    """The scenes named by ``source`` (see the module docstring); raises :class:`SceneListError`."""
    from ..eval.adapters.abo500 import WEIGHTS_FILE

    source = Path(source).absolute()
    if not source.exists():
        raise SceneListError(f"--scenes {source}: no such file or folder; pass a dataset folder, a folder of "
                             "datasets, an ABO-500 folder or a text file of paths")
    if source.is_file():
        scenes = []
        try:
            text = source.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as err:
            raise SceneListError(f"--scenes {source}: not a readable text file of dataset paths ({type(err).__name__}); "
                                 "pass a dataset folder, a folder of datasets or a text file with one path per line") from None
        for i, line in enumerate(text.splitlines(), 1):
            line = line.split("#", 1)[0].strip()
            if not line:
                continue
            path = Path(line).expanduser()
            path = path if path.is_absolute() else source.parent / path
            try:
                listed = (path / TRANSFORMS).is_file()
            except OSError:  # a name too long for the file system, a NUL byte
                listed = False
            if not listed:
                shown = str(path) if len(str(path)) <= 200 else str(path)[:200] + "..."
                raise SceneListError(f"{source}:{i}: {shown} has no {TRANSFORMS}; list nerfstudio dataset folders")
            scenes.append(Scene(path.name, path, _truth_of(path)))
        if not scenes:
            raise SceneListError(f"{source}: no dataset paths in the file; write one folder per line")
        return SceneSet(_unique(scenes, source), source, "list")
    for root in (source, source / "abo_500"):
        if (root / WEIGHTS_FILE).is_file():
            return _from_abo(root, split)
    if (source / TRANSFORMS).is_file():
        return SceneSet((Scene(source.name, source, _truth_of(source)),), source, "folder")
    scenes = [Scene(p.name, p, _truth_of(p)) for p in sorted(source.iterdir())
              if p.is_dir() and (p / TRANSFORMS).is_file()]  # fmt: skip
    if not scenes:
        raise SceneListError(f"--scenes {source}: no {TRANSFORMS} in the folder nor in its sub-folders; pass "
                             "nerfstudio datasets (physgs synth --suite writes some)")
    return SceneSet(_unique(scenes, source), source, "folder")
