"""Settings from a YAML file: ``physgs COMMAND --settings FILE.yaml``.

The file is a mapping of the command's settings, nested as its configs nest and named as their fields (the flag's
name with ``_`` for ``-``)::

    mass:
      density_draw: predictive      # --mass.density-draw predictive
      geometry: {resolution: 128}   # --mass.geometry.resolution 128

A choice made by a subcommand on the command line (``vlm:openai``, ``segmenter:sam``) is one key, the choice's
name, holding that choice's settings: ``vlm: {openai: {timeout_s: 300}}``; it also becomes the default choice.
Every setting can be given, the advanced ones that ``--help`` hides too (``--help-all`` lists them all). The
file's values become the defaults of the command line, so a flag given there still overrides the file.

The file is read as plain YAML within the alias and size budgets of ``safe_yaml`` (no tags that build
objects, no alias bombs). An unknown setting, a value of the wrong type or a file that is not such a mapping
is refused, before the command does anything, with one line naming the file and the setting.
"""

from __future__ import annotations

import dataclasses
import enum
import types
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path, PurePath
from typing import Annotated, Any, Literal

from .errors import PhysGSError

FLAG = "--settings"
MAX_BYTES = 1 << 20
"""the largest settings file read (1 MiB; a file of every setting of `physgs export` is a few KiB)"""


class SettingsFileError(PhysGSError, ValueError):
    """A settings file that cannot be used: unreadable, not a YAML mapping, or naming an unknown setting or a
    value of the wrong type. The message names the file and the setting."""


def split_flag(args: Sequence[str]) -> tuple[Path | None, list[str]]:
    """``(FILE, the other arguments)`` of a command line holding ``--settings FILE`` (or ``--settings=FILE``) at
    most once; ``(None, args)`` without it."""
    found: list[str] = []
    rest: list[str] = []
    it = iter(args)
    for arg in it:
        if arg == FLAG:
            value = next(it, None)
            if value is None or value.startswith("-"):
                raise SettingsFileError(f"{FLAG} needs a file: {FLAG} FILE.yaml")
            found.append(value)
        elif arg.startswith(FLAG + "="):
            found.append(arg[len(FLAG) + 1:])
        else:
            rest.append(arg)
    if len(found) > 1:
        raise SettingsFileError(f"{FLAG} was given {len(found)} times; give one settings file")
    return (Path(found[0]) if found else None), rest


def read_settings(path: Path) -> dict[str, Any]:
    """The settings mapping of the YAML file ``path`` (an empty file: no settings)."""
    import yaml

    from .safe_yaml import yaml_bounds_problem

    try:
        if path.stat().st_size > MAX_BYTES:
            raise SettingsFileError(f"{path}: a settings file of over {MAX_BYTES >> 20} MiB; give only the "
                                    "settings that differ from the defaults")
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise SettingsFileError(f"{path}: no such settings file; give the path of a YAML file") from None
    except UnicodeDecodeError:
        raise SettingsFileError(f"{path}: not UTF-8 text; save the settings as a UTF-8 YAML file") from None
    except OSError as err:
        raise SettingsFileError(f"{path}: cannot read the settings file: {err.strerror or err}") from None
    problem = yaml_bounds_problem(text)
    if problem is not None:
        raise SettingsFileError(f"{path}: refused ({problem}); write the settings as plain YAML")
    try:
        data = yaml.load(text, Loader=yaml.SafeLoader)
    except yaml.constructor.ConstructorError as err:  # a tag that builds an object (!!python/...)
        raise SettingsFileError(f"{path}: refused (a tag plain YAML does not have: {_yaml_error(err)}); "
                                "write the settings as plain YAML") from None
    except yaml.YAMLError as err:
        raise SettingsFileError(f"{path}: not valid YAML: {_yaml_error(err)}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise SettingsFileError(f"{path}: expected a mapping of settings at the top level, such as "
                                "'mass: {geometry: {resolution: 128}}'")
    return data


def command_defaults(cls: type, settings: Mapping[str, Any], path: Path, prog: str) -> Any:
    """The defaults of the command ``cls`` with ``settings`` (read from ``path``) applied, for ``tyro.cli(cls,
    default=...)``: a ``cls`` whose fields are set without running its checks (tyro builds the command from the
    parsed values, and checks it then); a required field the file does not give stays required."""
    return _Reader(path, prog).instance(cls, settings, None, "")


class Mismatch(Exception):
    """A value that is not of a setting's type."""


_SIMPLE = {bool: "true or false", int: "an integer", float: "a number", str: "text", type(None): "null"}


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _known(name: str, names: list[str], prefix: str) -> str:
    """What a person who wrote the unknown setting ``name`` may have meant."""
    import difflib

    close = difflib.get_close_matches(name, names, n=1, cutoff=0.7)
    if close:
        return f"did you mean '{prefix}{close[0]}'?"
    if len(names) <= 12:
        return "the settings here: " + (", ".join(names) or "none")
    return f"there are {len(names)} settings here"


def _yaml_error(err: Exception) -> str:
    return " ".join(str(err).replace('in "<unicode string>", ', "").split())


def _strip(tp: Any) -> Any:
    while typing.get_origin(tp) is Annotated:
        tp = typing.get_args(tp)[0]
    return tp


def _is_dataclass(tp: Any) -> bool:
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


def _is_union(tp: Any) -> bool:
    return typing.get_origin(tp) in (typing.Union, types.UnionType)


def describe(tp: Any) -> str:
    """A type as a person reads it: ``int | None`` is 'an integer or null'."""
    tp = _strip(tp)
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if tp in _SIMPLE:
        return _SIMPLE[tp]
    if _is_union(tp):
        return " or ".join(describe(a) for a in args)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in args)
    if isinstance(tp, type) and issubclass(tp, PurePath):
        return "a path"
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return "one of " + ", ".join(repr(m.name) for m in tp)
    if origin is tuple and len(args) == 2 and args[1] is Ellipsis:
        return f"a list of {describe(args[0])}"
    if origin is tuple:
        return f"a list of {len(args)}: " + ", ".join(describe(a) for a in args)
    if origin is list:
        return f"a list of {describe(args[0]) if args else 'values'}"
    if origin is dict:
        return f"a mapping of {describe(args[1]) if args else 'values'}"
    return str(tp).replace("typing.", "")


def coerce(tp: Any, value: Any) -> Any:
    """``value`` (as YAML read it) as a ``tp`` setting; raises :class:`Mismatch` when it is not one."""
    tp = _strip(tp)
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if tp is Any:
        return value
    if _is_union(tp):
        for arg in args:
            try:
                return coerce(arg, value)
            except Mismatch:
                pass
        raise Mismatch
    if origin is Literal:
        for arg in args:
            if type(arg) is type(value) and arg == value:
                return arg
        raise Mismatch
    if tp is float and type(value) in (int, float):
        return float(value)
    if tp in _SIMPLE:
        if type(value) is not tp and not (tp is type(None) and value is None):
            raise Mismatch
        return value
    if isinstance(tp, type) and issubclass(tp, PurePath) and isinstance(value, str) and value:
        return tp(value)
    if isinstance(tp, type) and issubclass(tp, enum.Enum) and isinstance(value, str) and value in tp.__members__:
        return tp[value]
    if origin in (tuple, list) and isinstance(value, list):
        if origin is list or (len(args) == 2 and args[1] is Ellipsis):
            items = [coerce(args[0] if args else Any, v) for v in value]
        elif len(args) == len(value):
            items = [coerce(a, v) for a, v in zip(args, value)]
        else:
            raise Mismatch
        return tuple(items) if origin is tuple else items
    if origin is dict and isinstance(value, dict):
        key_tp, value_tp = args or (Any, Any)
        return {coerce(key_tp, k): coerce(value_tp, v) for k, v in value.items()}
    raise Mismatch


def subcommand_choices(tp: Any) -> dict[str, type] | None:
    """name -> config class of a union of subcommand configs (``vlm:openai | vlm:replay | ...``), else None."""
    tp = _strip(tp)
    if not _is_union(tp):
        return None
    out: dict[str, type] = {}
    for arg in typing.get_args(tp):
        cls = _strip(arg)
        if not _is_dataclass(cls):
            return None
        names = [m.name for m in getattr(arg, "__metadata__", ()) if type(m).__name__ == "_SubcommandConfig"]
        out[names[0] if names and names[0] else cls.__name__] = cls
    return out


@dataclasses.dataclass
class _Reader:
    path: Path
    prog: str

    def fail(self, what: str) -> SettingsFileError:
        return SettingsFileError(f"{self.path}: {what}; fix the file ('{self.prog} --help-all' lists every setting)")

    def instance(self, cls: type, settings: Any, base: Any, prefix: str) -> Any:
        """A ``cls`` with the fields of ``base`` (else the field defaults) and ``settings`` applied."""
        import tyro

        if not isinstance(settings, dict):
            raise self.fail(f"'{prefix.rstrip('.')}' holds settings: give a mapping of them, not {_show(settings)}")
        fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
        for name in settings:
            if name not in fields:
                raise self.fail(f"unknown setting '{prefix}{name}' ({_known(str(name), list(fields), prefix)})")
        try:
            hints = typing.get_type_hints(cls, include_extras=True)
        except (NameError, TypeError) as err:  # an annotation only a type checker resolves
            raise self.fail(f"the settings of '{prefix.rstrip('.') or cls.__name__}' cannot be read from a file "
                            f"({err}); give them as flags") from None
        obj = object.__new__(cls)
        for name, f in fields.items():
            if isinstance(base, cls):
                value = getattr(base, name)
            elif f.default is not dataclasses.MISSING:
                value = f.default
            elif f.default_factory is not dataclasses.MISSING:
                value = f.default_factory()
            else:
                value = tyro.MISSING
            if name in settings:
                value = self.value(hints[name], settings[name], value, prefix + name)
            object.__setattr__(obj, name, value)
        return obj

    def value(self, tp: Any, raw: Any, current: Any, key: str) -> Any:
        """The setting ``key`` of type ``tp`` from the file's ``raw`` value (``current``: its default)."""
        cls = _strip(tp)
        if _is_dataclass(cls):
            return self.instance(cls, raw, current, key + ".")
        choices = subcommand_choices(tp)
        if choices is not None:
            if not (isinstance(raw, dict) and len(raw) == 1 and next(iter(raw)) in choices):
                raise self.fail(f"'{key}' is a choice: give one of {', '.join(choices)} with its settings, "
                                f"such as '{key.rsplit('.', 1)[-1]}: {{{next(iter(choices))}: {{}}}}'")
            (name, sub), = raw.items()
            return self.instance(choices[name], {} if sub is None else sub, current, f"{key}.{name}.")
        try:
            return coerce(tp, raw)
        except Mismatch:
            raise self.fail(f"setting '{key}' must be {describe(tp)}, not {_show(raw)}") from None
