"""Advanced settings: fields that ``--help`` leaves out and that are set like any other.

A config field annotated ``Advanced[T]`` is parsed from the command line, read from Python and stored exactly
as a plain ``T`` field; only the help of a ``physgs`` command hides it (and, on a nested config, every field
inside it). ``--help-all`` shows every setting; ``--settings FILE.yaml`` sets any of them from a file
(``settings_file``). tyro's own ``tyro.conf.Suppress`` would also remove the flag
from the parser, so a hidden setting could no longer be given at all.
"""

from __future__ import annotations

import dataclasses
import inspect
import types
import typing
from collections.abc import Sequence
from typing import Annotated, Any, TypeVar

T = TypeVar("T")

HELP_ALL = "--help-all"
HIDDEN_NOTE = f"Advanced settings are hidden here; {HELP_ALL} lists every setting."
SETTINGS_NOTE = ("--settings FILE.yaml sets any setting, advanced ones too, from a YAML mapping nested as the flags "
                 "are (--a.b-c 1 is a: {b_c: 1}); flags given here override the file.")


class _AdvancedMarker:
    def __repr__(self) -> str:
        return "Advanced"


ADVANCED = _AdvancedMarker()
Advanced = Annotated[T, ADVANCED]
"""``Advanced[T]``: a ``T`` setting that ``--help`` does not show."""


def is_advanced(tp: Any) -> bool:
    """Whether the annotation ``tp`` is marked ``Advanced``."""
    return typing.get_origin(tp) is Annotated and any(m is ADVANCED for m in tp.__metadata__)


def has_advanced(tp: Any, _seen: set | None = None) -> bool:
    """Whether the config type ``tp`` (a dataclass, a union of them, or an ``Annotated`` one) holds any
    ``Advanced`` field, at any depth."""
    seen = set() if _seen is None else _seen
    if is_advanced(tp):
        return True
    if typing.get_origin(tp) is Annotated:
        return has_advanced(typing.get_args(tp)[0], seen)
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        return any(has_advanced(a, seen) for a in typing.get_args(tp))
    if not (isinstance(tp, type) and dataclasses.is_dataclass(tp)) or tp in seen:
        return False
    seen.add(tp)
    try:
        hints = typing.get_type_hints(tp, include_extras=True)
    except (NameError, TypeError):  # an annotation only a type checker resolves: tyro reports it when parsing
        return False
    return any(has_advanced(hints[f.name], seen) for f in dataclasses.fields(tp) if f.name in hints)


def _hiding_registry():
    """A tyro constructor registry that turns every ``Advanced`` field into a ``tyro.conf.Suppress`` one."""
    import tyro
    from tyro.constructors import ConstructorRegistry, StructConstructorSpec

    registry = ConstructorRegistry()
    busy: list[Any] = []

    @registry.struct_rule
    def hide(info):  # the default rule's spec, with the advanced fields suppressed
        if busy and busy[-1] is info:
            return None
        busy.append(info)
        try:
            spec = ConstructorRegistry.get_struct_spec(info)
        finally:
            busy.pop()
        if not isinstance(spec, StructConstructorSpec):
            return spec
        fields = tuple(dataclasses.replace(f, type=Annotated[f.type, tyro.conf.Suppress]) if is_advanced(f.type)
                       else f for f in spec.fields)  # fmt: skip
        return dataclasses.replace(spec, fields=fields)

    return registry


def cli(cls: type, *, prog: str, args: Sequence[str]) -> Any:
    """``tyro.cli(cls)`` on ``args``, with a help that hides the advanced settings (``--help-all``: all of them).
    ``--settings FILE.yaml`` among ``args`` sets the defaults from that file (``settings_file``); the other
    flags override them."""
    import tyro

    from .settings_file import command_defaults, read_settings, split_flag

    path, args = split_flag(args)
    kw: dict[str, Any] = {"prog": prog}
    if path is not None:
        kw["default"] = command_defaults(cls, read_settings(path), path, prog)
    if HELP_ALL in args:
        return tyro.cli(cls, args=["--help" if a == HELP_ALL else a for a in args], description=_help(cls, False), **kw)
    if not {"-h", "--help"} & set(args):
        return tyro.cli(cls, args=args, **kw)
    if not has_advanced(cls):
        return tyro.cli(cls, args=args, description=_help(cls, False), **kw)
    return tyro.cli(cls, args=args, description=_help(cls, True), registry=_hiding_registry(), **kw)


def _help(cls: type, hidden: bool) -> str:
    """The command's description in its help: its doc, what --help leaves out, and the settings file."""
    return "\n\n".join([inspect.cleandoc(cls.__doc__ or ""), *([HIDDEN_NOTE] if hidden else []), SETTINGS_NOTE])
