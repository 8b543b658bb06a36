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

The file's size once its aliases are expanded is bounded too (a "billion laughs" file: a few lines of
aliases of aliases that expand to billions of nodes): at most :data:`MAX_ALIASES` alias uses and
:data:`MAX_EXPANDED_NODES` nodes with every alias expanded (a config that ns-train wrote has about 15 and 600).
A config object's ``_target`` must be its class's own target class or a subclass of it
(``DataParserConfig._target`` a DataParser, never a writer or a trainer): nerfstudio builds what ``_target``
names when it sets a config up.

:func:`load_config_tree` reads the same files without importing anything they name: every ``!!python/object``
becomes a :class:`ConfigObject` (the class's dotted name and its fields) and every ``!!python/name`` a
:class:`ClassRef`; only paths and ``frozenset`` are built. A tag is then checked by its name (a class of one of
:data:`CLASS_PACKAGES`), and :meth:`ConfigObject.build` builds a subtree for real, with the checks above, when
it is needed. ``physgs export`` reads a run this way: importing nerfstudio's trainer (its viewer, every model)
only to check the names of classes it never uses took seconds.

The ``ns-*`` commands themselves (``ns-viewer``, ``ns-eval``, ``ns-export``, ``ns-train --load-config``) read
configs with nerfstudio's unsafe loader: they do not protect you this way.
"""

from __future__ import annotations

import dataclasses
import enum
import importlib
import pathlib
import re
from pathlib import Path, PurePath
from typing import Any

import yaml

from .errors import PhysGSError

__all__ = ["ClassRef", "ConfigObject", "UnsafeConfigError", "check_node", "check_targets", "load_config_tree", "load_config_yaml",
           "yaml_bounds_problem"]

CLASS_PACKAGES = ("nerfstudio", "physgs_nerfstudio", "torch.optim", "gsplat")
"""packages whose classes a config may name (``!!python/object``, ``!!python/name``)"""
CALLABLE_BUILTINS = {"builtins.frozenset": frozenset}
"""callables other than paths and enums that ``!!python/object/apply`` may call"""
_STD = "tag:yaml.org,2002:"
_PY = _STD + "python/"
_PLAIN_TAGS = {"str", "int", "float", "bool", "null", "seq", "map", "set", "omap", "pairs", "binary",
               "timestamp", "merge", "value"}  # fmt: skip
_PY_PLAIN = {"none", "bool", "str", "unicode", "bytes", "int", "long", "float", "complex", "list", "tuple", "dict"}
MAX_ALIASES = 64
"""alias uses (``*name``) a config may hold"""
MAX_EXPANDED_NODES = 100_000
"""nodes a config may hold with every alias expanded"""
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


_PATH_CLASSES = {"PurePath", "PurePosixPath", "PureWindowsPath", "Path", "PosixPath", "WindowsPath"}


def _named_class(name: str) -> bool:
    """By its name alone (nothing imported): a class path in :data:`CLASS_PACKAGES` or a pathlib path."""
    if not _DOTTED.match(name):
        return False
    module, _, attr = name.rpartition(".")
    return _in_packages(module) or (module == "pathlib" and attr in _PATH_CLASSES)


def _why_not(tag: str, *, by_name: bool = False) -> str | None:
    """None when ``tag`` is allowed, else the reason it is refused. ``by_name``: judge class names without
    importing them (:func:`load_config_tree`, which builds none of them)."""
    if tag.startswith(_PY):
        kind, _, target = tag[len(_PY):].partition(":")
        if kind in _PY_PLAIN and not target:
            return None
        if by_name:
            allowed = _named_class(target) or (kind in ("object/apply", "object/new") and target in CALLABLE_BUILTINS)
        elif kind in ("object", "name"):
            allowed = _allowed_class(target)
        else:
            allowed = kind in ("object/apply", "object/new") and _allowed_call(target)
        if allowed and kind in ("object", "name", "object/apply", "object/new"):
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


def check_node(node: yaml.Node, path: Path | str, *, by_name: bool = False) -> None:
    """Raise :class:`UnsafeConfigError` at the first node whose tag is not allowed (module doc; ``by_name``: see
    :func:`_why_not`)."""
    seen: set[int] = set()
    stack = [node]
    while stack:
        n = stack.pop()
        if id(n) in seen:  # aliases share nodes: visit each once
            continue
        seen.add(id(n))
        why = _why_not(n.tag, by_name=by_name)
        if why is not None:
            raise _refuse(path, n.start_mark.line + 1, n.tag, why)
        if isinstance(n, yaml.SequenceNode):
            stack.extend(n.value)
        elif isinstance(n, yaml.MappingNode):
            for k, v in n.value:
                stack.extend((k, v))


def _refuse(path: Path, line: int, tag: str, why: str) -> UnsafeConfigError:
    shown = tag.replace(_STD, "!!")
    return UnsafeConfigError(
        f"{path}, line {line}: refused `{shown}` ({why}); a nerfstudio/physgs config only builds their config "
        "classes, paths and enums. Nothing in the file was run: do not pass this file to ns-* commands either, and "
        "use the config.yml that ns-train wrote."
    )


class ClassRef:
    """A ``!!python/name`` of a config read by :func:`load_config_tree`: the dotted name, not imported."""

    def __init__(self, name: str):
        self.name = name

    def __repr__(self) -> str:
        return f"ClassRef({self.name!r})"

    def build(self, memo: dict[int, Any] | None = None) -> Any:
        if not _allowed_class(self.name):
            raise UnsafeConfigError(f"refused `!!python/name:{self.name}` (not a class of {', '.join(CLASS_PACKAGES)})")
        return _resolve(self.name)


class ConfigObject:
    """A ``!!python/object`` (``call`` False) or ``!!python/object/apply`` / ``new`` (``call`` True: enums) of a
    config read by :func:`load_config_tree`: the class's dotted name and its fields (``args`` for a call), with
    attribute access to the fields. Nothing of it is imported until :meth:`build`."""

    def __init__(self, class_name: str, fields: dict[str, Any] | None = None, *, args: tuple = (),
                 call: bool = False, line: int = 0):  # fmt: skip
        object.__setattr__(self, "_meta", (class_name, call, line))
        object.__setattr__(self, "_fields", dict(fields or {}))
        object.__setattr__(self, "_args", tuple(args))

    @property
    def class_name(self) -> str:
        return self._meta[0]

    @property
    def fields(self) -> dict[str, Any]:
        return self._fields

    def __getattr__(self, name: str) -> Any:
        fields = object.__getattribute__(self, "_fields")
        if name in fields:
            return fields[name]
        raise AttributeError(f"{self._meta[0]} in the config has no field {name!r}")

    def __setattr__(self, name: str, value: Any) -> None:
        self._fields[name] = value

    def __repr__(self) -> str:
        return f"ConfigObject({self.class_name!r}, {sorted(self._fields)})"

    def build(self, memo: dict[int, Any] | None = None) -> Any:
        """The real object, as nerfstudio's loader builds it (a class's ``__new__`` and its fields set, or the
        call of an enum or path), after :func:`_why_not`'s full check of every class it names."""
        memo = {} if memo is None else memo
        if id(self) in memo:
            return memo[id(self)]
        name, call, line = self._meta
        tag = _PY + ("object/apply:" if call else "object:") + name
        why = _why_not(tag)
        if why is not None:
            raise _refuse(Path("config"), line, tag, why)
        cls = CALLABLE_BUILTINS.get(name) or _resolve(name)
        if call:
            obj = cls(*_build(self._args, memo))
            memo[id(self)] = obj
            return obj
        obj = cls.__new__(cls)
        memo[id(self)] = obj
        state = _build(self._fields, memo)
        if hasattr(obj, "__setstate__"):
            obj.__setstate__(state)
        else:
            obj.__dict__.update(state)
        why = _wrong_target(obj)
        if why is not None:
            raise _refuse(Path("config"), line, tag, why)
        return obj


def _own_target(cls: type) -> Any:
    """The ``_target`` a config dataclass sets by default (its field's default or default factory), else None."""
    f = getattr(cls, "__dataclass_fields__", {}).get("_target")
    if f is None:
        return None
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return None if f.default is dataclasses.MISSING else f.default


def _wrong_target(obj: Any) -> str | None:
    """None when ``obj`` has no ``_target`` or it is its class's own target class (or a subclass of it), else why
    not (module doc)."""
    target = getattr(obj, "__dict__", {}).get("_target")
    if target is None:
        return None
    own = _own_target(type(obj))
    own = getattr(own, "__origin__", own)  # a generic alias (``DataManager[T]``): its class
    if not isinstance(own, type):
        return f"its _target {_name(target)} is not declared by {type(obj).__name__}"
    if isinstance(target, type) and issubclass(target, own):
        return None
    return f"its _target {_name(target)} is not a {own.__name__}, the class {type(obj).__name__} builds"


def _name(obj: Any) -> str:
    return f"{getattr(obj, '__module__', '?')}.{getattr(obj, '__qualname__', type(obj).__name__)}"


def check_targets(document: Any, path: Path | str) -> None:
    """Raise :class:`UnsafeConfigError` at the first built config object whose ``_target`` is not its class's own
    (:func:`_wrong_target`), walking dataclass fields, lists, tuples and dicts."""
    seen: set[int] = set()
    stack = [document]
    while stack:
        obj = stack.pop()
        if id(obj) in seen or isinstance(obj, (str, bytes, int, float, type, PurePath)) or obj is None:
            continue
        seen.add(id(obj))
        if isinstance(obj, dict):
            stack.extend(obj.values())
        elif isinstance(obj, (list, tuple, set, frozenset)):
            stack.extend(obj)
        elif dataclasses.is_dataclass(obj):
            why = _wrong_target(obj)
            if why is not None:
                shown = f"!!python/object:{type(obj).__module__}.{type(obj).__qualname__}"
                raise UnsafeConfigError(f"{path}: refused `{shown}` ({why}); nothing in the file was built beyond "
                                        "its config classes: use the config.yml that ns-train wrote.")  # fmt: skip
            stack.extend(getattr(obj, "__dict__", {}).values())


def _build(value: Any, memo: dict[int, Any]) -> Any:
    if isinstance(value, (ConfigObject, ClassRef)):
        return value.build(memo)
    if isinstance(value, dict):
        return {_build(k, memo): _build(v, memo) for k, v in value.items()}
    if isinstance(value, (list, tuple, set, frozenset)):
        return type(value)(_build(v, memo) for v in value)
    return value


class _AliasBudget:
    """Counts alias uses while composing (at most :data:`MAX_ALIASES`); mixed into a PyYAML loader."""

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            self._aliases = getattr(self, "_aliases", 0) + 1
            if self._aliases > MAX_ALIASES:
                line = self.peek_event().start_mark.line + 1
                raise _TooBig(line, f"more than {MAX_ALIASES} aliases")
        return super().compose_node(parent, index)  # type: ignore[misc]


class _BoundedLoader(_AliasBudget, yaml.Loader):
    """nerfstudio's loader, with the alias budget."""


class _TooBig(Exception):
    def __init__(self, line: int, what: str):
        super().__init__(what)
        self.line, self.what = line, what


def _check_size(node: yaml.Node) -> None:
    """Refuse a tree of more than :data:`MAX_EXPANDED_NODES` nodes with its aliases expanded (module doc); the
    shared nodes are counted once per use, without expanding anything."""
    size: dict[int, int] = {}
    stack: list[tuple[yaml.Node, bool]] = [(node, False)]
    while stack:
        n, done = stack.pop()
        if id(n) in size:
            continue
        kids = [c for kv in n.value for c in kv] if isinstance(n, yaml.MappingNode) else (
            list(n.value) if isinstance(n, yaml.SequenceNode) else [])  # fmt: skip
        if not done:
            stack.append((n, True))
            stack.extend((c, False) for c in kids if id(c) not in size)
            continue
        size[id(n)] = 1 + sum(size.get(id(c), 0) for c in kids)
        if size[id(n)] > MAX_EXPANDED_NODES:
            raise _TooBig(n.start_mark.line + 1, f"more than {MAX_EXPANDED_NODES} nodes with its aliases expanded")


class _TreeLoader(_BoundedLoader):
    """nerfstudio's loader with the python object tags building :class:`ConfigObject` / :class:`ClassRef`."""


def _tree_object(loader: yaml.Loader, suffix: str, node: yaml.Node):
    obj = ConfigObject(suffix, line=node.start_mark.line + 1)
    yield obj
    if isinstance(node, yaml.MappingNode):
        obj.fields.update(loader.construct_mapping(node, deep=True))


def _tree_call(loader: yaml.Loader, suffix: str, node: yaml.Node) -> Any:
    if isinstance(node, yaml.SequenceNode):
        args: tuple = tuple(loader.construct_sequence(node, deep=True))
        state: dict = {}
    elif isinstance(node, yaml.MappingNode):
        value = loader.construct_mapping(node, deep=True)
        args, state = tuple(value.get("args", ())), dict(value.get("state", {}) or {})
    else:
        args, state = (), {}
    module, _, attr = suffix.rpartition(".")
    if module == "pathlib" and attr in _PATH_CLASSES:  # a path: built (pathlib runs nothing else)
        return getattr(pathlib, attr)(*args)
    if suffix in CALLABLE_BUILTINS:
        return CALLABLE_BUILTINS[suffix](*args)
    return ConfigObject(suffix, state, args=args, call=True, line=node.start_mark.line + 1)


_TreeLoader.add_multi_constructor(_PY + "object:", _tree_object)
_TreeLoader.add_multi_constructor(_PY + "object/apply:", _tree_call)
_TreeLoader.add_multi_constructor(_PY + "object/new:", _tree_call)
_TreeLoader.add_multi_constructor(_PY + "name:", lambda loader, suffix, node: ClassRef(suffix))


def _read(path: Path, loader_cls: type, by_name: bool) -> Any:
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise UnsafeConfigError(f"{path}: not a text file; pass the config.yml that ns-train wrote.") from None
    try:
        loader = loader_cls(text)  # it only builds the tree check_node passed
    except yaml.YAMLError as err:  # a control character the YAML reader refuses
        problem = " ".join("".join(c if c.isprintable() else " " for c in str(err)).split())[:160]
        raise UnsafeConfigError(f"{path}: not a readable YAML config ({problem}); pass the config.yml that ns-train "
                                "wrote.") from None  # fmt: skip
    try:
        node = loader.get_single_node()
        if node is None:
            raise UnsafeConfigError(f"{path}: the file is empty; pass the config.yml that ns-train wrote.")
        check_node(node, path, by_name=by_name)
        _check_size(node)
        return loader.construct_document(node)
    except RecursionError:
        raise UnsafeConfigError(f"{path}: nested too deeply to read (lists or maps inside each other thousands of "
                                "levels deep); pass the config.yml that ns-train wrote.") from None  # fmt: skip
    except _TooBig as err:
        raise UnsafeConfigError(f"{path}, line {err.line}: refused: {err.what} (an alias bomb); a config that "
                                "ns-train wrote has a few; use that config.yml.") from None  # fmt: skip
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f", line {mark.line + 1}" if mark is not None else ""
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise UnsafeConfigError(f"{path}{where}: not a readable YAML config ({problem}); pass the config.yml "
                                "that ns-train wrote.") from None  # fmt: skip
    finally:
        loader.dispose()


class _BoundedSafeLoader(_AliasBudget, yaml.SafeLoader):
    """PyYAML's safe loader, with the alias budget."""


def yaml_bounds_problem(text: str) -> str | None:
    """None when a plain YAML text (a material library, any file read with ``yaml.safe_load``) is within the
    alias and size budgets of the module doc and nests less deeply than Python's recursion limit, else what is
    wrong (with its line). The text is composed with the pure-Python reader: libyaml's C reader overflows its stack
    on a file nested a hundred thousand levels deep, which ends the process without a word."""
    try:
        loader = _BoundedSafeLoader(text)
    except yaml.YAMLError as err:
        return " ".join("".join(c if c.isprintable() else " " for c in str(err)).split())[:160]
    try:
        node = loader.get_single_node()
        if node is not None:
            _check_size(node)
    except _TooBig as err:
        return f"line {err.line}: {err.what} (an alias bomb)"
    except RecursionError:
        return "nested too deeply (lists or maps inside each other thousands of levels deep)"
    except yaml.YAMLError:
        return None  # the caller's own reader names the syntax error
    finally:
        loader.dispose()
    return None


def load_config_yaml(path: Path | str) -> Any:
    """Parse ``path``, check every tag (module doc), then build and return the document (every config object's
    ``_target`` checked: :func:`check_targets`)."""
    document = _read(Path(path), _BoundedLoader, by_name=False)  # nerfstudio's loader, bounded
    check_targets(document, path)
    return document


def load_config_tree(path: Path | str) -> Any:
    """Parse ``path`` and check every tag by name; python objects come back as :class:`ConfigObject` /
    :class:`ClassRef`, nothing they name is imported (module doc). ``.build()`` a part to get the real object."""
    return _read(Path(path), _TreeLoader, by_name=True)
