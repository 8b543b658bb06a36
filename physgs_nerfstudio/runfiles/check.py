"""Check a trained run's files before nerfstudio loads it; one line naming the file and the fix otherwise.

:func:`check_run` is what ``physgs export`` (and :meth:`PropertyField.from_checkpoint`) call before loading a
run (:mod:`.loader`; ``eval_setup`` for others). In order:

1. ``config.yml`` is read through :mod:`physgs_nerfstudio.safe_yaml` (a crafted file cannot run code) as a tree
   of :class:`~physgs_nerfstudio.safe_yaml.ConfigObject` (nothing it names is imported; :meth:`RunFiles.trainer_config`
   builds nerfstudio's TrainerConfig when a caller needs it);
2. it is a nerfstudio run of a PhysGS method (a splatfacto/nerfacto run is named as such, instead of failing
   later inside nerfstudio, e.g. with "no NVIDIA driver"), and its dataparser config is one of
   :data:`DATAPARSERS` building that class's dataparser (:func:`check_dataparser`);
3. the checkpoint folder: a run folder copied or moved elsewhere keeps the stored (old) paths in its config,
   so the folder *beside the config* is used when the stored one is absent or differs (and a line says
   which one was used); the latest ``step-*.ckpt`` must exist and be a complete PyTorch zip archive (a
   truncated copy is named, not an ``IndexError`` or an unpickling traceback);
4. the dataset's ``transforms.json`` parses and holds a ``frames`` list.

:meth:`RunFiles.apply` is the ``update_config_callback`` for ``eval_setup``: it points the loaded config at
the checked run folder and checkpoint.
"""

from __future__ import annotations

import json
import os
import re
import sys
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import PhysGSError

__all__ = ["DATAPARSERS", "RunFiles", "RunFilesError", "check_dataparser", "check_run", "check_transforms"]

_STEP = re.compile(r"^step-(\d+)\.ckpt$")
_RETRAIN = "copy the run folder again from where it was trained, or retrain"


class RunFilesError(PhysGSError, ValueError):
    """A run's config, checkpoint or dataset cannot be used as it is (the message names the file)."""


@dataclass
class RunFiles:
    """The checked files of a run."""

    config_path: Path
    config: Any
    """the run's config as read by :func:`~physgs_nerfstudio.safe_yaml.load_config_tree` (a ConfigObject tree)"""
    run_dir: Path
    """the folder whose checkpoints and dataparser_transforms.json are used"""
    checkpoint: Path
    step: int
    relocated: bool
    """True when run_dir is the config's folder and differs from the path stored in the config"""

    def trainer_config(self) -> Any:
        """nerfstudio's TrainerConfig of the run, built from the checked tree and pointed at the checked files."""
        return self.apply(self.config.build())

    def apply(self, config: Any) -> Any:
        """``eval_setup(..., update_config_callback=files.apply)``: load exactly the checked checkpoint."""
        config.load_step = self.step
        if self.relocated:
            run_dir = self.run_dir
            # nerfstudio derives every run path from get_base_dir() (output_dir/experiment/method/timestamp,
            # as stored at training time): answer the folder the config was found in instead
            config.get_base_dir = lambda: run_dir  # type: ignore[method-assign]
        return config


_TRAINER_CONFIG = "nerfstudio.engine.trainer.TrainerConfig"
_METHODS_GROUP = "nerfstudio.method_configs"


def _is_physgs(config: Any) -> bool:
    model = getattr(getattr(config, "pipeline", None), "model", None)
    return getattr(model, "class_name", "").startswith("physgs_nerfstudio.")


def _registered_methods() -> set[str]:
    """Method names nerfstudio's plugin registry would find (entry points and NERFSTUDIO_METHOD_CONFIGS), read
    without loading them (nerfstudio's discover_methods imports every method, seconds)."""
    from importlib.metadata import entry_points

    names = {ep.name for ep in entry_points(group=_METHODS_GROUP)}
    for item in os.environ.get("NERFSTUDIO_METHOD_CONFIGS", "").split(","):
        if "=" in item:
            names.add(item.split("=", 1)[0].strip())
    return names


def _method_of(config_path: Path, config: Any) -> None:
    if getattr(config, "class_name", None) != _TRAINER_CONFIG:
        kind = getattr(config, "class_name", type(config).__name__).rpartition(".")[2]
        raise RunFilesError(f"{config_path}: not the config of a nerfstudio run ({kind}); pass the "
                            "config.yml that `ns-train physgs` wrote into outputs/<scene>/physgs/<time>/.")  # fmt: skip
    method = getattr(config, "method_name", None)
    if not _is_physgs(config):
        raise RunFilesError(
            f"{config_path}: a run of method {method!r}, not PhysGS: physgs export needs a run of "
            "`ns-train physgs` or `physgs-lite` (for that run's plain splat use `ns-export gaussian-splat`)."
        )
    if method not in _registered_methods():
        raise RunFilesError(f"{config_path}: method {method!r} is not registered with nerfstudio in this "
                            "environment; install physgs-nerfstudio here (pip install -e .) and retry.")  # fmt: skip


def _base_dir(config: Any) -> Path:
    """nerfstudio's ExperimentConfig.get_base_dir of the stored fields (experiment name from the data folder
    when unset, as set_experiment_name)."""
    name = getattr(config, "experiment_name", None)
    if name is None:
        data = getattr(config.pipeline.datamanager, "data", None)
        name = str((data.parent if data.is_file() else data).stem) if data is not None else "unnamed"
    return Path(f"{config.output_dir}/{name}/{config.method_name}/{config.timestamp}")


def _steps(folder: Path) -> dict[int, Path]:
    if not folder.is_dir():
        return {}
    found = {}
    for p in folder.iterdir():
        m = _STEP.match(p.name)
        if m and p.is_file():
            found[int(m.group(1))] = p
    return found


def _same(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _checkpoint_dir(config_path: Path, config: Any, log: Callable[[str], None]) -> tuple[Path, Path, bool]:
    """(run_dir, checkpoint dir, relocated): the stored folder if it is this config's, else the one beside it."""
    beside_run = config_path.parent
    beside = beside_run / Path(config.relative_model_dir)
    stored_run = _base_dir(config)
    stored = stored_run / Path(config.relative_model_dir)
    if _same(stored_run, beside_run) or _same(stored, beside):
        return stored_run, stored, False
    if _steps(beside):
        state = "absent" if not stored.exists() else "another folder"
        log(f"physgs: checkpoints from {beside} beside the config (the path stored in the config, {stored}, is "
            f"{state}: the run folder was copied or moved).")  # fmt: skip
        return beside_run, beside, True
    if _steps(stored):
        log(f"physgs: no checkpoint beside the config; using the one stored in the config: {stored}.")
        return stored_run, stored, False
    raise RunFilesError(
        f"{beside}: no checkpoint (step-*.ckpt) there nor at the config's stored path {stored}; training writes one "
        "every --steps-per-save steps and at the end: let the run finish, or " + _RETRAIN + "."
    )


def _check_checkpoint(path: Path) -> None:
    """A complete PyTorch zip archive: the central directory reads, ``data.pkl`` is there with a good CRC and
    every entry lies inside the file. (The tensors' CRCs are not computed: that read the whole checkpoint, with
    the optimizers' moments, on every export; a truncated copy loses the central directory at its end.)"""
    size = path.stat().st_size
    try:
        with zipfile.ZipFile(path) as z:
            infos = z.infolist()
            pkl = next((i for i in infos if i.filename.endswith("data.pkl")), None)
            if pkl is not None:
                z.read(pkl)  # checks its CRC
            outside = next((i.filename for i in infos if i.header_offset + i.compress_size > size), None)
    except (zipfile.BadZipFile, OSError, EOFError) as err:
        raise RunFilesError(f"{path}: the checkpoint is truncated or damaged ({size} bytes, {err}); "
                            f"{_RETRAIN}.") from None  # fmt: skip
    if pkl is None or outside is not None:
        why = f"{outside} lies beyond its end" if outside else "no data.pkl"
        raise RunFilesError(f"{path}: the checkpoint is damaged ({why}); {_RETRAIN}.")


DATAPARSERS = {"physgs_nerfstudio.nerfstudio.dataparser.PhysGSDataParserConfig":
               "physgs_nerfstudio.nerfstudio.dataparser.PhysGSDataParser"}  # fmt: skip
"""the dataparser config classes a run's config may build to read its cameras, and the class each must build"""


def check_dataparser(dp_config: Any, where: Path | str = "config") -> None:
    """Refuse a run's dataparser config (a ConfigObject of the tree, or a built one) unless it is one of
    :data:`DATAPARSERS`, its ``_target`` that class's dataparser and no other object inside it: a crafted config
    could otherwise name any class of nerfstudio there, and ``setup()`` would build it."""
    from ..safe_yaml import ClassRef, ConfigObject, UnsafeConfigError

    if not isinstance(dp_config, ConfigObject):  # built by the caller from a checked config
        name = f"{type(dp_config).__module__}.{type(dp_config).__qualname__}"
        target = getattr(dp_config, "_target", None)
        target = f"{getattr(target, '__module__', '?')}.{getattr(target, '__qualname__', '?')}"
        inner: list[str] = []
    else:
        name = dp_config.class_name
        ref = dp_config.fields.get("_target")
        target = ref.name if isinstance(ref, ClassRef) else repr(ref)
        inner = [k for k, v in dp_config.fields.items() if k != "_target" and isinstance(v, (ConfigObject, ClassRef))]
    fix = "use the config.yml that ns-train wrote"
    if name not in DATAPARSERS:
        raise UnsafeConfigError(f"{where}: refused dataparser {name} (a PhysGS run reads its cameras with "
                                f"{', '.join(DATAPARSERS)}); {fix}.")  # fmt: skip
    if target != DATAPARSERS[name]:
        raise UnsafeConfigError(f"{where}: refused the dataparser's _target {target} (it must be {DATAPARSERS[name]}); "
                                f"{fix}.")  # fmt: skip
    if inner:
        raise UnsafeConfigError(f"{where}: refused the dataparser's field {inner[0]} (an object where the dataparser "
                                f"holds plain values); {fix}.")  # fmt: skip


def _dataset_path(config: Any) -> Path | None:
    dm = config.pipeline.datamanager
    data = getattr(dm, "data", None) or getattr(getattr(dm, "dataparser", None), "data", None)
    return Path(data) if data is not None else None


def check_transforms(path: Path) -> dict:
    """Parse a dataset's ``transforms.json``; RunFilesError naming the file and the fix when it cannot be used."""
    fix = ("restore it from transforms.json.bak (physgs perceive keeps the original) or rewrite it with "
           "ns-process-data")  # fmt: skip
    try:
        meta = json.loads(Path(path).read_text(encoding="utf-8"))
    except json.JSONDecodeError as err:
        raise RunFilesError(f"{path}: not valid JSON (line {err.lineno}, column {err.colno}: {err.msg}); {fix}.") from None
    except (OSError, UnicodeDecodeError) as err:
        raise RunFilesError(f"{path}: cannot be read ({err}); {fix}.") from None
    except RecursionError:
        raise RunFilesError(f"{path}: nested too deeply to read; {fix}.") from None
    if not isinstance(meta, dict):
        raise RunFilesError(f"{path}: a JSON {type(meta).__name__}, not an object with a \"frames\" list; {fix}.")
    frames = meta.get("frames")
    if not isinstance(frames, list) or not frames:
        raise RunFilesError(f"{path}: no \"frames\" list (or an empty one); {fix}.")
    bad = next((i for i, f in enumerate(frames) if not isinstance(f, dict) or not isinstance(f.get("file_path"), str)), None)
    if bad is not None:
        raise RunFilesError(f"{path}: frame {bad} has no \"file_path\" string; {fix}.")
    return meta


def _check_dataset(config_path: Path, config: Any) -> None:
    data = _dataset_path(config)
    if data is None:
        return
    if not data.exists():
        where = f" (relative to the current folder {Path.cwd()})" if not data.is_absolute() else ""
        raise RunFilesError(f"{config_path}: its dataset {data}{where} is not found; run from the folder you trained "
                            "in, or put the dataset back there (the run reads its cameras and masks).")  # fmt: skip
    transforms = data if data.suffix == ".json" else data / "transforms.json"
    if transforms.exists():
        check_transforms(transforms)


def check_run(config_path: Path, *, log: Callable[[str], None] | None = None) -> RunFiles:
    """Run the checks of the module doc; return the files to load."""
    from ..safe_yaml import load_config_tree

    log = log or (lambda line: print(line, file=sys.stderr))
    config_path = Path(config_path)
    if config_path.is_dir() and (config_path / "config.yml").is_file():
        config_path = config_path / "config.yml"
    if not config_path.is_file():
        raise RunFilesError(f"{config_path} not found: pass the config.yml of an `ns-train physgs` run.")
    config = load_config_tree(config_path)
    _method_of(config_path, config)
    check_dataparser(config.pipeline.datamanager.dataparser, config_path)
    run_dir, ckpt_dir, relocated = _checkpoint_dir(config_path, config, log)
    steps = _steps(ckpt_dir)
    if not steps:
        raise RunFilesError(f"{ckpt_dir}: no checkpoint (step-*.ckpt); training writes one every --steps-per-save "
                            "steps and at the end: let the run finish, or " + _RETRAIN + ".")  # fmt: skip
    load_step = getattr(config, "load_step", None)
    step = load_step if load_step is not None else max(steps)
    if step not in steps:
        raise RunFilesError(f"{ckpt_dir}: no step-{step:09d}.ckpt (the config's load_step); steps there: "
                            f"{sorted(steps)}.")  # fmt: skip
    _check_checkpoint(steps[step])
    _check_dataset(config_path, config)
    return RunFiles(config_path, config, run_dir, steps[step], step, relocated)
