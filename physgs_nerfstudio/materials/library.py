"""Material libraries (indoor, outdoor, user files): loading, validation, alias resolution, priors.

A library file is YAML::

    version: 1                      # optional
    env: indoor                     # optional (defaults to the file name's stem)
    description: ...                # optional, free text
    materials:
      - name: oak                   # snake_case canonical name, unique in the library
        category: wood
        aliases: [oak wood, red oak]
        color: [150, 94, 38]        # legend colour, RGB 0..255 (or "#965e26")
        density: {typical: 750, low: 600, high: 900}               # kg/m^3, > 0
        kinetic_friction: {typical: 0.40, low: 0.25, high: 0.60}   # dimensionless, in [0, 2]
        shore_hardness: {scale: D, typical: 72, low: 65, high: 80} # Shore A, D or "00" (quote 00), 0..100
        youngs_modulus: {typical: 1.1e+10, low: 8.0e+9, high: 1.4e+10}  # Pa, > 0
        thickness_m: 0.018          # wall thickness for shell mass, or null (solid)
        confusable: [maple, walnut] # names in the same (merged) library
        source: "Wood Handbook (USDA FPL); Engineering ToolBox typical ranges"

Numbers may be written as YAML numbers or numeric strings ("2e11": PyYAML reads exponents without a dot
and sign as strings). Every range needs ``low <= typical <= high`` and ``low < high``. Hardness is stored
in :mod:`.hardness`'s canonical A_eq scale; ``Material.hardness_scale`` keeps the scale the source quoted.
"""

from __future__ import annotations

import functools
import logging
import math
import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from ..errors import PhysGSError
from . import hardness as _hardness
from .keys import PROPERTY_KEYS

if TYPE_CHECKING:  # pragma: no cover
    from ..bayes.nig import NIG
    from .priors import PriorConfig

__all__ = [
    "BUILTIN_ENVS",
    "PROPERTY_KEYS",
    "Material",
    "MaterialLibrary",
    "MaterialLibraryError",
    "PropertyRange",
    "load_library",
    "normalize_name",
]

logger = logging.getLogger(__name__)

BUILTIN_ENVS: tuple[str, ...] = ("indoor", "outdoor")

_ENTRY_KEYS = {"name", "category", "aliases", "color", "thickness_m", "confusable", "source", *PROPERTY_KEYS}
_REQUIRED_KEYS = {"name", "category", "color", "source", *PROPERTY_KEYS}
_FILE_KEYS = {"version", "env", "description", "materials"}
_NAME_RE = re.compile(r"^[a-z][a-z0-9]*(_[a-z0-9]+)*$")
_FRICTION_MAX = 2.0
_Loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class MaterialLibraryError(PhysGSError, ValueError):
    """A library file is malformed; the message names the file, the entry and the fix."""


@dataclass(frozen=True)
class PropertyRange:
    """Typical value and plausible range of one property (canonical units)."""

    typical: float
    low: float
    high: float

    def as_tuple(self) -> tuple[float, float, float]:
        return (self.typical, self.low, self.high)


@dataclass(frozen=True)
class Material:
    """One library entry; ``properties`` holds PROPERTY_KEYS in canonical units (hardness in A_eq)."""

    name: str
    category: str
    color: tuple[int, int, int]
    aliases: tuple[str, ...]
    properties: dict[str, PropertyRange]
    hardness_scale: str
    thickness_m: float | None
    confusable: tuple[str, ...]
    source: str

    def __hash__(self) -> int:  # properties is a dict: hash the identifying fields only
        return hash((self.name, self.category, self.color, self.source))

    def quoted_hardness(self) -> PropertyRange:
        """Hardness range back in the scale the source quoted (``hardness_scale``)."""
        r = self.properties["shore_hardness"]
        conv = lambda v: float(_hardness.from_canonical(v, self.hardness_scale))
        return PropertyRange(conv(r.typical), conv(r.low), conv(r.high))


# --------------------------------------------------------------------------------------------- names

def _singular(word: str) -> str:
    if len(word) > 4 and word.endswith("ies"):
        return word[:-3] + "y"
    if len(word) > 3 and word.endswith("es") and word[:-2].endswith(("ss", "x", "ch", "sh")):
        return word[:-2]
    if len(word) > 2 and word.endswith("s") and not word.endswith(("ss", "us", "is")):
        return word[:-1]
    return word


def normalize_name(text: str) -> str:
    """Lookup key of a material name or alias: lower case, ``_``/``-``/punctuation as spaces, single
    spaces, last word singular ("Stainless-Steel" -> "stainless steel", "Pebbles" -> "pebble")."""
    words = re.sub(r"[^0-9a-z]+", " ", text.lower().replace("'", "")).split()
    if not words:
        return ""
    words[-1] = _singular(words[-1])
    return " ".join(words)


def _candidates(text: str) -> list[str]:
    """Normalised keys to try for a free-text name: whole text, text without parentheses, their contents."""
    keys = [normalize_name(text)]
    inner = re.findall(r"\(([^()]*)\)", text)
    if inner:
        keys.append(normalize_name(re.sub(r"\([^()]*\)", " ", text)))
        keys.extend(normalize_name(part) for part in inner)
    for sep in ("/", ","):
        if sep in text:
            keys.extend(normalize_name(part) for part in text.split(sep))
    return [k for k in dict.fromkeys(keys) if k]


# ------------------------------------------------------------------------------------------- library

class MaterialLibrary:
    """An ordered set of materials with alias lookup; index order = the K axis of every [K, ...] tensor."""

    def __init__(self, env: str, materials: Sequence[Material], sources: Sequence[str] = ()):
        self.env = env
        self.materials: list[Material] = list(materials)
        self.names: list[str] = [m.name for m in self.materials]
        self.sources: tuple[str, ...] = tuple(sources)
        self._index = {n: i for i, n in enumerate(self.names)}
        self._lookup: dict[str, str] = {}
        for m in self.materials:
            for text in (m.name, *m.aliases):
                self._lookup[normalize_name(text)] = m.name

    def __len__(self) -> int:
        return len(self.materials)

    def __iter__(self) -> Iterator[Material]:
        return iter(self.materials)

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and name in self._index

    def __getitem__(self, name: str) -> Material:
        return self.materials[self.index(name)]

    def __repr__(self) -> str:
        return f"MaterialLibrary(env={self.env!r}, {len(self)} materials)"

    def index(self, name: str) -> int:
        """Position of canonical ``name``; KeyError naming close matches otherwise."""
        if name in self._index:
            return self._index[name]
        resolved = self.resolve(name) if isinstance(name, str) else None
        hint = f" Did you mean the canonical name {resolved!r}? (use library.resolve first)" if resolved else ""
        raise KeyError(
            f"material {name!r} is not in the {self.env!r} library ({len(self)} materials: "
            f"{', '.join(self.names[:8])}, ...).{hint}"
        )

    def resolve(self, name: str) -> str | None:
        """Canonical name for a free-text material name or alias (case, spaces, ``_``/``-``, plural 's',
        a parenthesised synonym as in "acrylic (PMMA)"), or None if nothing matches."""
        if not isinstance(name, str):
            return None
        for key in _candidates(name):
            if key in self._lookup:
                return self._lookup[key]
        return None

    def material(self, name: str) -> Material:
        """Material for a canonical name or alias; KeyError if nothing matches."""
        canonical = self.resolve(name)
        if canonical is None:
            raise KeyError(f"material {name!r} matches no name or alias of the {self.env!r} library.")
        return self[canonical]

    def colors(self) -> list[tuple[int, int, int]]:
        return [m.color for m in self.materials]

    def prior_params(self, names: Sequence[str] | None = None, config: PriorConfig | None = None):
        """Raw NIG prior tensors (dict tau, kappa, a, b; [K, P] float64); see :mod:`.priors`."""
        from .priors import PriorConfig, prior_params

        mats = self.materials if names is None else [self[self._canonical(n)] for n in names]
        return prior_params(mats, config if config is not None else PriorConfig())

    def nig_prior(self, names: Sequence[str] | None = None, config: PriorConfig | None = None) -> NIG:
        """NIG prior [K, P] (float64) for ``names`` (default: all, library order) in PROPERTY_KEYS order,
        in the fused space (log for log-space properties); see :class:`.priors.PriorConfig`."""
        from ..bayes.nig import NIG

        return NIG(**self.prior_params(names, config))

    def _canonical(self, name: str) -> str:
        if name in self._index:
            return name
        resolved = self.resolve(name)
        if resolved is None:
            self.index(name)  # raises the helpful KeyError
        return resolved  # type: ignore[return-value]


# -------------------------------------------------------------------------------------------- loading

def _fail(where: str, msg: str) -> MaterialLibraryError:
    return MaterialLibraryError(f"{where}: {msg}")


def _number(value: Any, where: str, field: str) -> float:
    if isinstance(value, bool) or value is None:
        raise _fail(where, f"{field} must be a number, got {value!r}.")
    if isinstance(value, str):
        try:
            value = float(value.strip())
        except ValueError:
            raise _fail(where, f"{field} must be a number, got the text {value!r}.") from None
    if not isinstance(value, (int, float)):
        raise _fail(where, f"{field} must be a number, got {value!r} ({type(value).__name__}).")
    value = float(value)
    if not math.isfinite(value):
        raise _fail(where, f"{field} must be finite, got {value!r}.")
    return value


def _string_list(value: Any, where: str, field: str) -> tuple[str, ...]:
    if value is None:
        return ()
    if isinstance(value, str) or not isinstance(value, (list, tuple)):
        raise _fail(where, f"{field} must be a list of strings, e.g. [a, b]; got {value!r}.")
    out = []
    for v in value:
        if not isinstance(v, str) or not v.strip():
            raise _fail(where, f"{field} entries must be non-empty strings; got {v!r}.")
        out.append(v.strip())
    return tuple(out)


def _color(value: Any, where: str) -> tuple[int, int, int]:
    if isinstance(value, str):
        m = re.fullmatch(r"#([0-9a-fA-F]{6})", value.strip())
        if not m:
            raise _fail(where, f"color {value!r} must be [r, g, b] with integers 0..255 or '#rrggbb'.")
        h = m.group(1)
        return (int(h[0:2], 16), int(h[2:4], 16), int(h[4:6], 16))
    if (
        not isinstance(value, (list, tuple))
        or len(value) != 3
        or not all(isinstance(c, int) and not isinstance(c, bool) and 0 <= c <= 255 for c in value)
    ):
        raise _fail(where, f"color {value!r} must be [r, g, b] with integers 0..255 or '#rrggbb'.")
    return (int(value[0]), int(value[1]), int(value[2]))


def _range(value: Any, where: str, key: str, extra: Sequence[str] = ()) -> tuple[float, float, float]:
    allowed = {"typical", "low", "high", *extra}
    if not isinstance(value, Mapping):
        raise _fail(where, f"{key} must be a mapping {{typical: .., low: .., high: ..}}; got {value!r}.")
    unknown = sorted(set(value) - allowed)
    if unknown:
        raise _fail(where, f"{key} has unknown keys {unknown}; allowed: {sorted(allowed)}.")
    missing = sorted(k for k in ("typical", "low", "high", *extra) if k not in value)
    if missing:
        raise _fail(where, f"{key} is missing {missing}.")
    t, lo, hi = (_number(value[k], where, f"{key}.{k}") for k in ("typical", "low", "high"))
    if not (lo <= t <= hi):
        raise _fail(where, f"{key} needs low <= typical <= high; got low={lo:g}, typical={t:g}, high={hi:g}.")
    if not lo < hi:
        raise _fail(where, f"{key} needs low < high (a zero-width range gives a degenerate prior); got {lo:g}.")
    return t, lo, hi


def _parse_entry(raw: Any, where: str) -> Material:
    if not isinstance(raw, Mapping):
        raise _fail(where, f"each material must be a mapping of fields; got {raw!r}.")
    unknown = sorted(set(raw) - _ENTRY_KEYS)
    if unknown:
        raise _fail(where, f"unknown keys {unknown}; allowed keys: {sorted(_ENTRY_KEYS)}.")
    missing = sorted(_REQUIRED_KEYS - set(raw))
    if missing:
        raise _fail(where, f"missing required fields {missing}.")
    name = raw["name"]
    if not isinstance(name, str) or not _NAME_RE.match(name):
        raise _fail(where, f"name {name!r} must be snake_case (lower-case letters, digits, underscores).")
    category = raw["category"]
    if not isinstance(category, str) or not category.strip():
        raise _fail(where, "category must be a non-empty string.")
    source = raw["source"]
    if not isinstance(source, str) or not source.strip():
        raise _fail(where, "source must be a non-empty string naming where the values come from.")

    props: dict[str, PropertyRange] = {}
    t, lo, hi = _range(raw["density"], where, "density")
    if lo <= 0:
        raise _fail(where, f"density must be > 0 kg/m^3; got low={lo:g}.")
    props["density"] = PropertyRange(t, lo, hi)
    t, lo, hi = _range(raw["kinetic_friction"], where, "kinetic_friction")
    if lo < 0 or hi > _FRICTION_MAX:
        raise _fail(where, f"kinetic_friction must lie in [0, {_FRICTION_MAX:g}]; got low={lo:g}, high={hi:g}.")
    props["kinetic_friction"] = PropertyRange(t, lo, hi)
    hraw = raw["shore_hardness"]
    t, lo, hi = _range(hraw, where, "shore_hardness", extra=("scale",))
    try:
        scale = _hardness.normalize_scale(hraw["scale"])
    except (TypeError, ValueError) as err:
        raise _fail(where, f"shore_hardness.scale: {err}") from None
    if lo < 0 or hi > 100:
        raise _fail(where, f"shore_hardness readings must lie in [0, 100] on Shore {scale}; got {lo:g}..{hi:g}.")
    props["shore_hardness"] = PropertyRange(
        *(float(_hardness.to_canonical(v, scale)) for v in (t, lo, hi))
    )
    t, lo, hi = _range(raw["youngs_modulus"], where, "youngs_modulus")
    if lo <= 0:
        raise _fail(where, f"youngs_modulus must be > 0 Pa; got low={lo:g}.")
    props["youngs_modulus"] = PropertyRange(t, lo, hi)

    thickness = raw.get("thickness_m")
    if thickness is not None:
        thickness = _number(thickness, where, "thickness_m")
        if not 0 < thickness < 1:
            raise _fail(where, f"thickness_m must be in metres, 0 < t < 1, or null; got {thickness:g}.")

    return Material(
        name=name,
        category=category.strip(),
        color=_color(raw["color"], where),
        aliases=_string_list(raw.get("aliases"), where, "aliases"),
        properties=props,
        hardness_scale=scale,
        thickness_m=thickness,
        confusable=_string_list(raw.get("confusable"), where, "confusable"),
        source=source.strip(),
    )


def _read_file(path: Path | str, label: str, text: str | None = None) -> tuple[str | None, list[Material]]:
    from ..safe_yaml import yaml_bounds_problem

    try:
        if text is None:  # a user's file (a built-in library's text is the package's own)
            text = Path(path).read_text(encoding="utf-8")
            problem = yaml_bounds_problem(text)
            if problem is not None:
                raise MaterialLibraryError(f"{label}: refused ({problem}); write the library as plain YAML entries.")
        data = yaml.load(text, Loader=_Loader)
    except yaml.YAMLError as err:
        raise MaterialLibraryError(f"{label}: not valid YAML: {err}") from None
    except UnicodeDecodeError:
        raise MaterialLibraryError(f"{label}: not UTF-8 text; save the library as a UTF-8 YAML file.") from None
    except OSError as err:
        raise MaterialLibraryError(f"{label}: cannot read the file: {err}") from None
    if not isinstance(data, Mapping) or "materials" not in data:
        raise MaterialLibraryError(f"{label}: expected a mapping with a 'materials:' list at the top level.")
    unknown = sorted(set(data) - _FILE_KEYS)
    if unknown:
        raise MaterialLibraryError(f"{label}: unknown top-level keys {unknown}; allowed: {sorted(_FILE_KEYS)}.")
    entries = data["materials"]
    if not isinstance(entries, list) or not entries:
        raise MaterialLibraryError(f"{label}: 'materials' must be a non-empty list of entries.")
    materials: list[Material] = []
    seen: dict[str, int] = {}
    for i, raw in enumerate(entries):
        name = raw.get("name") if isinstance(raw, Mapping) else None
        where = f"{label}, entry {i} ({name!r})" if name else f"{label}, entry {i}"
        mat = _parse_entry(raw, where)
        if mat.name in seen:
            raise _fail(where, f"duplicate name {mat.name!r} (also entry {seen[mat.name]}); names must be unique.")
        seen[mat.name] = i
        materials.append(mat)
    env = data.get("env")
    return (str(env) if env is not None else None), materials


def _check_library(materials: Sequence[Material], where_of: Mapping[str, str]) -> None:
    """Cross-entry checks on a merged library: aliases unique, colours unique, confusables exist."""
    owner: dict[str, str] = {}
    for m in materials:
        for text in (m.name, *m.aliases):
            key = normalize_name(text)
            if not key:
                raise _fail(where_of[m.name], f"alias {text!r} has no letters or digits.")
            other = owner.get(key)
            if other is not None and other != m.name:
                raise _fail(
                    where_of[m.name],
                    f"alias {text!r} (lookup key {key!r}) collides with material {other!r} "
                    f"({where_of[other]}); remove it from one of them, or override {other!r} by name.",
                )
            owner[key] = m.name
    colors: dict[tuple[int, int, int], str] = {}
    for m in materials:
        if m.color in colors:
            raise _fail(
                where_of[m.name],
                f"color {list(m.color)} is already used by {colors[m.color]!r}; legend colours must be unique.",
            )
        colors[m.color] = m.name
    names = {m.name for m in materials}
    for m in materials:
        for c in m.confusable:
            if c not in names:
                raise _fail(where_of[m.name], f"confusable {c!r} is not a material name of this library.")
            if c == m.name:
                raise _fail(where_of[m.name], "a material cannot list itself as confusable.")


@functools.cache
def _builtin(env: str) -> tuple[Material, ...]:
    ref = resources.files("physgs_nerfstudio.materials").joinpath("data", f"{env}.yaml")
    _, materials = _read_file(str(ref), f"built-in library {env}.yaml", text=ref.read_text(encoding="utf-8"))
    return tuple(materials)


def load_library(env: str | Path = "indoor", extra_files: Sequence[Path | str] = ()) -> MaterialLibrary:
    """Load a built-in library (``"indoor"``, ``"outdoor"``) or a YAML file path, then merge user files.

    Entries of ``extra_files`` with the name of an existing material replace it (logged warning); new names
    are appended. The merged library is re-validated: an alias colliding with another material's name or
    alias, a reused colour, or a confusable that names no material raises MaterialLibraryError naming the
    file and the entry.
    """
    if isinstance(env, str) and env in BUILTIN_ENVS:
        label = f"built-in library {env}.yaml"
        materials = [replace(m, properties=dict(m.properties)) for m in _builtin(env)]  # fresh dicts
        env_name = env
    else:
        path = Path(env)
        if not path.is_file():
            raise MaterialLibraryError(
                f"material library {str(env)!r} is neither a built-in environment {list(BUILTIN_ENVS)} "
                "nor an existing YAML file."
            )
        label = str(path)
        file_env, materials = _read_file(path, label)
        env_name = file_env or path.stem
    where_of = {m.name: f"{label}, entry {i} ({m.name!r})" for i, m in enumerate(materials)}
    sources = [label]

    for extra in extra_files:
        extra_label = str(extra)
        _, new = _read_file(Path(extra), extra_label)
        sources.append(extra_label)
        index = {m.name: i for i, m in enumerate(materials)}
        for j, m in enumerate(new):
            where = f"{extra_label}, entry {j} ({m.name!r})"
            if m.name in index:
                logger.warning(
                    "material %r from %s overrides the definition in %s.", m.name, extra_label, where_of[m.name]
                )
                materials[index[m.name]] = m
            else:
                index[m.name] = len(materials)
                materials.append(m)
            where_of[m.name] = where

    _check_library(materials, where_of)
    return MaterialLibrary(env_name, materials, sources=sources)
