"""Load a nerfstudio ``config.yml`` without letting the file run code.

nerfstudio writes a run's config with ``yaml.dump`` and reads it back with the unsafe ``yaml.Loader``
(``nerfstudio.utils.eval_utils.eval_setup``), so a crafted ``config.yml`` such as::

    x: !!python/object/apply:os.system ["touch pwned.txt"]

runs its command while being read. Every ``physgs`` command that takes ``--load-config`` reads the file here
first: the YAML is parsed into nodes (parsing builds nothing), every node's tag is checked against what a
nerfstudio or physgs config can contain, and only then is the checked node tree built. Allowed:

* plain YAML (strings, numbers, lists, maps, sets, binary, timestamps) and ``!!python/`` scalars, tuples,
  lists and dicts;
* ``!!python/object:C`` and ``!!python/name:C`` for a *class* ``C`` defined in ``nerfstudio``,
  ``physgs_nerfstudio``, ``torch.optim`` or ``gsplat`` (configs, ``_target`` classes, optimisers);
  ``!!python/object`` sets the instance's attributes, it calls nothing;
* ``!!python/object/apply:C`` and ``!!python/object/new:C`` only for ``pathlib`` paths, ``frozenset`` and
  ``Enum`` classes of those packages (calling them builds a value and runs nothing else).

Anything else (``os.system``, ``subprocess.*``, ``builtins.eval``, ``!!python/module``, a function, a class
re-exported from another package, an unknown tag) is refused with one line naming the file, the line and
the tag. Nothing of the file is built before the whole tree passed.

The ``ns-*`` commands themselves (``ns-viewer``, ``ns-eval``, ``ns-export``, ``ns-train --load-config``) read
configs with nerfstudio's unsafe loader: they do not protect you this way.
"""

from __future__ import annotations

import enum
import importlib
import re
from pathlib import Path, PurePath
from typing import Any

import yaml

from .errors import PhysGSError

__all__ = ["UnsafeConfigError", "check_node", "load_config_yaml"]

CLASS_PACKAGES = ("nerfstudio", "physgs_nerfstudio", "torch.optim", "gsplat")
"""packages whose classes a config may name (``!!python/object``, ``!!python/name``)"""
CALLABLE_BUILTINS = {"builtins.frozenset": frozenset}
"""callables other than paths and enums that ``!!python/object/apply`` may call"""
_STD = "tag:yaml.org,2002:"
_PY = _STD + "python/"
_PLAIN_TAGS = {"str", "int", "float", "bool", "null", "seq", "map", "set", "omap", "pairs", "binary",
               "timestamp", "merge", "value"}  # fmt: skip
_PY_PLAIN = {"none", "bool", "str", "unicode", "bytes", "int", "long", "float", "complex", "list", "tuple", "dict"}
_DOTTED = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)+$")


class UnsafeConfigError(PhysGSError, ValueError):
    """A config file that is not valid YAML, or that asks to build or call something a config never holds."""


def _in_packages(module: str) -> bool:
    return any(module == p or module.startswith(p + ".") for p in CLASS_PACKAGES)


def _resolve(name: str) -> Any:
    """``pkg.mod.Name`` -> the object, importing ``pkg.mod`` only when it lies in :data:`CLASS_PACKAGES`
    or is ``pathlib``; None when it cannot be resolved or is not allowed to be imported."""
    if not _DOTTED.match(name):
        return None
    module, _, attr = name.rpartition(".")
    if not (_in_packages(module) or module == "pathlib"):
        return None
    try:
        obj = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError):
        return None
    return obj


def _allowed_class(name: str) -> bool:
    """A class defined (not merely imported) in one of :data:`CLASS_PACKAGES`, or a pathlib path."""
    obj = _resolve(name)
    if not isinstance(obj, type):
        return False
    if issubclass(obj, PurePath):
        return obj.__module__ == "pathlib"
    return _in_packages(obj.__module__)


def _allowed_call(name: str) -> bool:
    """What ``!!python/object/apply`` / ``new`` may call: a pathlib path class, frozenset, an allowed Enum."""
    if name in CALLABLE_BUILTINS:
        return True
    if not _allowed_class(name):
        return False
    obj = _resolve(name)
    return issubclass(obj, (PurePath, enum.Enum))


def _why_not(tag: str) -> str | None:
    """None when ``tag`` is allowed, else the reason it is refused."""
    if tag.startswith(_PY):
        kind, _, target = tag[len(_PY):].partition(":")
        if kind in _PY_PLAIN and not target:
            return None
        if kind in ("object", "name") and _allowed_class(target):
            return None
        if kind in ("object/apply", "object/new") and _allowed_call(target):
            return None
        if kind == "module":
            return "it imports a module"
        if kind in ("object/apply", "object/new"):
            return f"it calls {target or '?'}"
        if kind in ("object", "name"):
            return f"{target or '?'} is not a class of {', '.join(CLASS_PACKAGES)}"
        return "unknown python tag"
    if tag.startswith(_STD) and tag[len(_STD):] in _PLAIN_TAGS:
        return None
    return "unknown tag"


def check_node(node: yaml.Node, path: Path | str) -> None:
    """Raise :class:`UnsafeConfigError` at the first node whose tag is not allowed (module doc)."""
    seen: set[int] = set()
    stack = [node]
    while stack:
        n = stack.pop()
        if id(n) in seen:  # aliases share nodes: visit each once
            continue
        seen.add(id(n))
        why = _why_not(n.tag)
        if why is not None:
            shown = n.tag.replace(_STD, "!!")
            raise UnsafeConfigError(
                f"{path}, line {n.start_mark.line + 1}: refused `{shown}` ({why}); a nerfstudio/physgs config "
                "only builds their config classes, paths and enums. Nothing in the file was run: do not pass "
                "this file to ns-* commands either, and use the config.yml that ns-train wrote."
            )
        if isinstance(n, yaml.SequenceNode):
            stack.extend(n.value)
        elif isinstance(n, yaml.MappingNode):
            for k, v in n.value:
                stack.extend((k, v))


def load_config_yaml(path: Path | str) -> Any:
    """Parse ``path``, check every tag (module doc), then build and return the document."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise UnsafeConfigError(f"{path}: not a text file; pass the config.yml that ns-train wrote.") from None
    loader = yaml.Loader(text)  # nerfstudio's loader; it only builds the tree check_node passed
    try:
        node = loader.get_single_node()
        if node is None:
            raise UnsafeConfigError(f"{path}: the file is empty; pass the config.yml that ns-train wrote.")
        check_node(node, path)
        return loader.construct_document(node)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f", line {mark.line + 1}" if mark is not None else ""
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise UnsafeConfigError(f"{path}{where}: not a readable YAML config ({problem}); pass the config.yml "
                                "that ns-train wrote.") from None  # fmt: skip
    finally:
        loader.dispose()
