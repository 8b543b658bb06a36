"""Strict validation of VLM answers into canonical-unit candidates (never raises on bad input).

``validate_response(text, library) -> ValidatedResponse`` (unpacks as ``candidates, reasons``). Every
problem found is a reason string (also logged at INFO on this module's logger); one bad answer, or one bad
field, never aborts a run. The rules, in order:

1. **JSON**: ```` ```json ```` fences and text around the object are tolerated (the first JSON object that
   parses is used); a top-level list is read as the candidate list and a top-level object with a
   ``material`` key as a single candidate. Answers longer than ``max_text_chars`` are rejected.
2. **Envelope / candidates** are parsed with pydantic; a candidate without a string ``material`` is dropped.
3. **Materials** are mapped to canonical names through the library's aliases (``MaterialLibrary.resolve``);
   unknown names are dropped with a reason. Candidates naming the same material are merged (confidences
   added; the most confident candidate's values kept, its missing values filled from the others).
4. **Confidence**: numbers or percentages ("80%"); clipped to [0, 1] (reason logged); a missing or
   non-numeric confidence gets an equal share ``1 / n`` (reason logged); candidates at 0 are dropped; the
   kept ones are renormalised to sum to 1 (``renormalise="always"``, the default) or only when their sum
   exceeds 1 (``"above_one"``, keeps a lone candidate's 0.6 as 0.6).
5. **Units** (values are numbers, numeric strings, or strings with a unit such as "2.7 g/cm^3", "70 GPa",
   "3 mm"; explicit units are converted):
   - density, bare number < 30: ambiguous between kg/m^3 and g/cm^3 - the reading closer (in log) to the
     candidate material's library typical density is taken (steel "7.8" -> 7800 kg/m^3; a foam's "25" stays);
   - Young's modulus, bare number < 1e4: read as Pa, MPa or GPa, whichever is closest (in log) to the
     material's typical modulus (GPa for "200" steel, MPa for "5" rubber);
   - Shore hardness: reading must lie in [0, 100] on its scale; ``shore_scale`` A | D | 00 (also "70A",
     "Shore D 60"); a missing scale means the material's library scale (reason logged); converted to the
     canonical A-equivalent scale with :func:`physgs_nerfstudio.materials.to_canonical`;
   - thickness_m, bare number >= 0.2: read as millimetres (a 20 cm wall is no shell); 0 / null = solid.
6. **Range**: non-finite values, non-positive values, and values outside [library min / 10, library max * 10]
   (over all materials, per property; ``absurd_factor``) are set to NaN (= missing) with a reason.
"""

from __future__ import annotations

import json
import logging
import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, Literal

from pydantic import AliasChoices, BaseModel, ConfigDict, Field, ValidationError, field_validator

from ..materials import PROPERTY_KEYS, MaterialLibrary, to_canonical
from ..materials.hardness import normalize_scale

logger = logging.getLogger(__name__)

_NAN = float("nan")


@dataclass
class ValidationConfig:
    renormalise: Literal["always", "above_one"] = "always"
    """Renormalise kept confidences to sum 1 always, or only when they sum above 1."""
    max_text_chars: int = 100_000
    """Longer answers are rejected outright."""
    max_candidates: int = 5
    """Candidates beyond this many (in the answer's order) are ignored."""
    absurd_factor: float = 10.0
    """Values outside [library min / f, library max * f] are rejected."""
    ambiguous_density_below: float = 30.0
    """Bare densities below this may be g/cm^3 (see module docstring)."""
    ambiguous_modulus_below: float = 1e4
    """Bare Young's moduli below this may be MPa or GPa."""
    thickness_mm_from: float = 0.2
    """Bare thicknesses at or above this are read as millimetres."""


@dataclass
class Candidate:
    """One validated material hypothesis for a mask; properties in canonical units, NaN = missing."""

    material: str
    confidence: float
    properties: dict[str, float]
    thickness_m: float | None = None
    raw_material: str = ""

    def values(self) -> list[float]:
        return [self.properties.get(k, _NAN) for k in PROPERTY_KEYS]


@dataclass
class ValidatedResponse:
    candidates: list[Candidate]
    reasons: list[str]
    caption: str = ""
    object: str | None = None
    """the whole object the answer says the part belongs to (:func:`object_name`); None: not said"""

    def __iter__(self) -> Iterator[Any]:  # ``candidates, reasons = validate_response(...)``
        return iter((self.candidates, self.reasons))


# ---------------------------------------------------------------------------------------------------------
# JSON extraction
# ---------------------------------------------------------------------------------------------------------

_PARTIAL = "partial"
_FENCE = re.compile(r"```(?:json|JSON)?\s*(.*?)```", re.DOTALL)


def extract_json(text: str) -> tuple[Any, str | None]:
    """First JSON value (object or list) found in ``text`` -> (value, None) when the text (or a fenced
    block) is exactly that JSON, (value, "partial") when it was found inside other text, (None, reason)."""
    if not isinstance(text, str):
        return None, f"answer is not text ({type(text).__name__})"
    stripped = text.strip()
    if not stripped:
        return None, "empty answer"
    attempts = [m.group(1).strip() for m in _FENCE.finditer(stripped)] + [stripped]
    decoder = json.JSONDecoder()
    for chunk in attempts:
        try:
            value = json.loads(chunk)
            if isinstance(value, (dict, list)):
                return value, None
        except (ValueError, RecursionError):
            pass
        starts = [i for i, c in enumerate(chunk) if c in "{["][:64]
        for i in starts:
            try:
                value, _ = decoder.raw_decode(chunk, i)
            except (ValueError, RecursionError):
                continue
            if isinstance(value, dict) or (
                isinstance(value, list) and value and all(isinstance(v, dict) for v in value)
            ):
                return value, _PARTIAL
    return None, f"no JSON object found in the answer ({_short(stripped)})"


def _short(value: Any, n: int = 60) -> str:
    s = value if isinstance(value, str) else repr(value)
    s = s.replace("\n", " ")
    return s if len(s) <= n else s[: n - 3] + "..."


# ---------------------------------------------------------------------------------------------------------
# pydantic models (lenient types; numbers are parsed by hand to report per-field reasons)
# ---------------------------------------------------------------------------------------------------------


class _RawCandidate(BaseModel):
    model_config = ConfigDict(extra="ignore")

    material: str = Field(validation_alias=AliasChoices("material", "name", "material_name"))
    confidence: Any = Field(
        default=None, validation_alias=AliasChoices("confidence", "probability", "score", "p")
    )
    density: Any = Field(
        default=None, validation_alias=AliasChoices("density", "density_kg_m3", "density_kg_per_m3")
    )
    kinetic_friction: Any = Field(
        default=None,
        validation_alias=AliasChoices("kinetic_friction", "friction", "friction_coefficient", "mu"),
    )
    shore_hardness: Any = Field(default=None, validation_alias=AliasChoices("shore_hardness", "hardness"))
    shore_scale: Any = Field(
        default=None, validation_alias=AliasChoices("shore_scale", "hardness_scale", "scale")
    )
    youngs_modulus: Any = Field(
        default=None,
        validation_alias=AliasChoices(
            "youngs_modulus", "young_modulus", "youngs_modulus_pa", "stiffness", "elastic_modulus"
        ),
    )
    thickness_m: Any = Field(
        default=None, validation_alias=AliasChoices("thickness_m", "thickness", "wall_thickness_m")
    )

    @field_validator("material", mode="before")
    @classmethod
    def _material_is_text(cls, v: Any) -> Any:
        if not isinstance(v, str):
            raise ValueError(f"material must be a string, got {type(v).__name__}")
        return v


class _Envelope(BaseModel):
    model_config = ConfigDict(extra="ignore")

    caption: str = ""
    object: str | None = None
    candidates: list[Any] = Field(
        default_factory=list, validation_alias=AliasChoices("candidates", "materials", "predictions")
    )

    @field_validator("caption", mode="before")
    @classmethod
    def _caption_text(cls, v: Any) -> str:
        return "" if v is None else str(v)[:500]

    @field_validator("object", mode="before")
    @classmethod
    def _object_name(cls, v: Any) -> str | None:
        return object_name(v)


_ARTICLES = ("a ", "an ", "the ")


def object_name(v: Any) -> str | None:
    """The answer's ``object`` as a comparable name: lower case, words separated by one space, no punctuation
    around them and no leading article ("The Table." -> "table"); None for anything else, an empty name or one
    over 60 characters (an object's name, not a sentence)."""
    if not isinstance(v, str):
        return None
    name = " ".join(re.sub(r"[^\w\s-]", " ", v.lower()).split())
    for a in _ARTICLES:
        if name.startswith(a):
            name = name[len(a):]
    return name if 0 < len(name) <= 60 else None


# ---------------------------------------------------------------------------------------------------------
# numbers and units
# ---------------------------------------------------------------------------------------------------------

_NUM_UNIT = re.compile(r"^\s*(?P<num>[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(?P<unit>.*?)\s*$")

_DENSITY_UNITS = {
    "kg/m3": 1.0,
    "kg/m^3": 1.0,
    "kg m-3": 1.0,
    "kg·m-3": 1.0,
    "kg/m³": 1.0,
    "kgm-3": 1.0,
    "g/l": 1.0,
    "g/cm3": 1000.0,
    "g/cm^3": 1000.0,
    "g/cm³": 1000.0,
    "g/cc": 1000.0,
    "g/ml": 1000.0,
    "kg/l": 1000.0,
    "lb/ft3": 16.0185,
    "lb/ft^3": 16.0185,
}
_MODULUS_UNITS = {
    "pa": 1.0,
    "n/m2": 1.0,
    "n/m^2": 1.0,
    "kpa": 1e3,
    "mpa": 1e6,
    "gpa": 1e9,
    "tpa": 1e12,
    "psi": 6894.757,
    "ksi": 6.894757e6,
}
_LENGTH_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "µm": 1e-6, "μm": 1e-6}
_HARDNESS_IN_TEXT = re.compile(r"(?i)(?:shore\s*)?(00|oo|a|d)\b|(?:shore\s*)(00|oo|a|d)")


def _parse_number(value: Any) -> tuple[float | None, str, str | None]:
    """-> (number, unit text lower-cased without spaces, problem). number None = missing/invalid."""
    if value is None:
        return None, "", None
    if isinstance(value, bool):
        return None, "", f"a boolean ({value})"
    if isinstance(value, (int, float)):
        try:
            return float(value), "", None
        except OverflowError:
            return None, "", "an integer too large for a float"
    if isinstance(value, dict):
        if "value" not in value and "typical" not in value:
            return None, "", f"an object without a 'value' ({_short(value, 40)})"
        v = value.get("value", value.get("typical"))
        unit = value.get("unit", "")
        num, u, problem = _parse_number(v)
        if num is not None and not u and isinstance(unit, str):
            u = unit.strip().lower().replace(" ", "")
        return num, u, problem
    if isinstance(value, str):
        s = value.strip().replace(",", "")
        if s.lower() in ("", "null", "none", "n/a", "na", "unknown", "-"):
            return None, "", None
        m = _NUM_UNIT.match(s[:200])
        if not m:
            if s.lower() in ("nan", "inf", "-inf", "infinity"):
                return float(s.lower().replace("infinity", "inf")), "", None
            return None, "", f"not a number ({_short(value, 40)})"
        try:
            num = float(m.group("num"))
        except ValueError:  # pragma: no cover - the regex only matches floats
            return None, "", f"not a number ({_short(value, 40)})"
        return num, m.group("unit").lower().replace(" ", ""), None
    return None, "", f"a {type(value).__name__}, not a number"


def _closest_in_log(candidates: dict[str, float], typical: float) -> tuple[str, float]:
    t = math.log(typical)
    return min(candidates.items(), key=lambda kv: abs(math.log(kv[1]) - t) if kv[1] > 0 else math.inf)


class _Bounds:
    """Per-property absurdity bounds [global min / f, global max * f] of a library (canonical units)."""

    def __init__(self, library: MaterialLibrary, factor: float):
        self.lo: dict[str, float] = {}
        self.hi: dict[str, float] = {}
        for key in PROPERTY_KEYS:
            lows = [m.properties[key].low for m in library.materials]
            highs = [m.properties[key].high for m in library.materials]
            lo, hi = min(lows), max(highs)
            if key == "shore_hardness":  # additive scale: readings are range-checked on their own scale
                self.lo[key], self.hi[key] = float(to_canonical(0.0, "00")), float(to_canonical(100.0, "D"))
            else:
                self.lo[key], self.hi[key] = lo / factor, hi * factor


# ---------------------------------------------------------------------------------------------------------
# validation
# ---------------------------------------------------------------------------------------------------------


class Validator:
    """Validates answers against one material library (bounds are computed once)."""

    def __init__(self, library: MaterialLibrary, config: ValidationConfig | None = None):
        self.library = library
        self.config = config or ValidationConfig()
        self.bounds = _Bounds(library, self.config.absurd_factor)

    def __call__(self, text: Any, context: str = "") -> ValidatedResponse:
        reasons: list[str] = []
        try:
            result = self._validate(text, reasons)
        except Exception as err:  # never abort a run on one answer
            reasons.append(
                f"internal validation error ({type(err).__name__}: {_short(str(err), 120)}); answer dropped"
            )
            result = ValidatedResponse([], reasons)
        for r in result.reasons:
            logger.info("%s%s", f"{context}: " if context else "", r)
        return result

    # -- pieces --------------------------------------------------------------------------------------
    def _validate(self, text: Any, reasons: list[str]) -> ValidatedResponse:
        env = self._envelope(text, reasons)
        if env is None:
            return ValidatedResponse([], reasons)
        raw_list = env.candidates
        if not raw_list:
            reasons.append("no candidates in the answer")
            return ValidatedResponse([], reasons, env.caption, env.object)
        limit = self.config.max_candidates
        if len(raw_list) > limit:
            reasons.append(f"{len(raw_list)} candidates; only the first {limit} are used")
            raw_list = raw_list[:limit]
        parsed = [p for i, raw in enumerate(raw_list) if (p := self._candidate(i, raw, reasons)) is not None]
        if not parsed:
            if not any("dropped" in r for r in reasons):
                reasons.append("no usable candidate")
            return ValidatedResponse([], reasons, env.caption, env.object)
        return ValidatedResponse(self._normalise(parsed, reasons), reasons, env.caption, env.object)

    def _envelope(self, text: Any, reasons: list[str]) -> _Envelope | None:
        """The answer's JSON as the schema's envelope (a bare list or a single candidate is wrapped); None,
        with the reason, when it has none."""
        cfg = self.config
        if isinstance(text, str) and len(text) > cfg.max_text_chars:
            reasons.append(f"answer too long ({len(text)} > {cfg.max_text_chars} characters); dropped")
            return None
        obj, problem = extract_json(text)
        if problem == _PARTIAL:
            reasons.append("answer is not a single JSON object; used the first complete JSON value inside it")
        elif problem:
            reasons.append(problem)
            return None
        if isinstance(obj, list):
            obj = {"candidates": obj}
        elif (
            isinstance(obj, dict)
            and "material" in obj
            and not any(k in obj for k in ("candidates", "materials", "predictions"))
        ):
            obj = {"caption": obj.get("caption", ""), "object": obj.get("object"), "candidates": [obj]}
        try:
            return _Envelope.model_validate(obj)
        except ValidationError as err:
            reasons.append(f"answer does not match the schema: {_pydantic_summary(err)}")
            return None

    def _candidate(self, i: int, raw: Any, reasons: list[str]) -> tuple[Candidate, bool] | None:
        """Candidate `i` checked against the schema and the library, and whether it gave a confidence; None,
        with the reason, when it is dropped."""
        if not isinstance(raw, dict):
            reasons.append(f"candidate {i}: not an object ({_short(raw)}); dropped")
            return None
        try:
            rc = _RawCandidate.model_validate(raw)
        except ValidationError as err:
            reasons.append(f"candidate {i}: {_pydantic_summary(err)}; dropped")
            return None
        name = self.library.resolve(rc.material)
        if name is None:
            reasons.append(
                f"candidate {i}: unknown material {_short(rc.material)!r} (not in the {self.library.env} library); dropped"
            )
            return None
        conf, given = self._confidence(rc.confidence, i, reasons)
        if given and conf <= 0:
            reasons.append(f"candidate {i} ({name}): confidence 0; dropped")
            return None
        props = self._properties(rc, name, i, reasons)
        thickness = self._thickness(rc.thickness_m, name, i, reasons)
        return Candidate(name, conf, props, thickness, raw_material=_short(rc.material, 80)), given

    def _normalise(self, parsed: list[tuple[Candidate, bool]], reasons: list[str]) -> list[Candidate]:
        """Missing confidences share 1 equally, duplicates merge, and confidences are renormalised (always, or
        when they sum above 1, per `renormalise`) and clipped to [0, 1]."""
        missing = [c for c, given in parsed if not given]
        for c in missing:
            c.confidence = 1.0 / len(parsed)
        cands = self._merge([c for c, _ in parsed], reasons)
        total = sum(c.confidence for c in cands)
        if total <= 0 or not math.isfinite(total):  # pragma: no cover - zero confidences were dropped
            reasons.append("all confidences are 0; answer dropped")
            return []
        if self.config.renormalise == "always" or total > 1:
            if total > 1 + 1e-3:
                reasons.append(f"confidences summed to {total:.3g}; renormalised to 1")
            for c in cands:
                c.confidence = c.confidence / total
        for c in cands:
            c.confidence = min(1.0, max(0.0, c.confidence))
        return cands

    def _confidence(self, value: Any, i: int, reasons: list[str]) -> tuple[float, bool]:
        num, unit, problem = _parse_number(value)
        if num is not None and unit == "%":
            num = num / 100.0
        if num is None or not math.isfinite(num):
            what = problem or ("missing" if value is None else f"not finite ({_short(value, 20)})")
            reasons.append(f"candidate {i}: confidence {what}; given an equal share")
            return _NAN, False
        if num > 1 or num < 0:
            clipped = min(1.0, max(0.0, num))
            reasons.append(f"candidate {i}: confidence {num:g} outside [0, 1]; clipped to {clipped:g}")
            num = clipped
        return num, True

    def _properties(self, rc: _RawCandidate, material: str, i: int, reasons: list[str]) -> dict[str, float]:
        mat = self.library[material]
        out: dict[str, float] = {}
        for key in PROPERTY_KEYS:
            raw = getattr(rc, key)
            where = f"candidate {i} ({material}) {key}"
            num, unit, problem = _parse_number(raw)
            if problem:
                reasons.append(f"{where}: {problem}; set missing")
                out[key] = _NAN
                continue
            if num is None:
                out[key] = _NAN
                continue
            if not math.isfinite(num):
                reasons.append(f"{where}: non-finite value {num!r}; set missing")
                out[key] = _NAN
                continue
            typical = mat.properties[key].typical
            if key == "density":
                value = self._density(num, unit, typical, where, reasons)
            elif key == "youngs_modulus":
                value = self._modulus(num, unit, typical, where, reasons)
            elif key == "shore_hardness":
                value = self._hardness(num, unit, rc.shore_scale, mat.hardness_scale, where, reasons)
            else:
                value = num
                if unit:
                    reasons.append(f"{where}: ignored unit {unit!r} of a dimensionless value")
            if value is None:
                out[key] = _NAN
                continue
            positive_only = key != "shore_hardness"  # canonical hardness is negative on the soft 00 end
            if not math.isfinite(value) or (positive_only and value <= 0):
                reasons.append(f"{where}: non-positive value {value:g}; set missing")
                out[key] = _NAN
                continue
            lo, hi = self.bounds.lo[key], self.bounds.hi[key]
            if not lo <= value <= hi:
                reasons.append(
                    f"{where}: {value:g} outside the plausible range [{lo:.3g}, {hi:.3g}]; set missing"
                )
                out[key] = _NAN
                continue
            out[key] = float(value)
        return out

    def _density(self, num: float, unit: str, typical: float, where: str, reasons: list[str]) -> float | None:
        if unit:
            factor = _DENSITY_UNITS.get(unit)
            if factor is None:
                reasons.append(f"{where}: unknown density unit {unit!r}; set missing")
                return None
            return num * factor
        if 0 < num < self.config.ambiguous_density_below:
            label, value = _closest_in_log({"kg/m^3": num, "g/cm^3": num * 1000.0}, typical)
            if label != "kg/m^3":
                reasons.append(f"{where}: {num:g} read as g/cm^3 -> {value:g} kg/m^3")
            return value
        return num

    def _modulus(self, num: float, unit: str, typical: float, where: str, reasons: list[str]) -> float | None:
        if unit:
            factor = _MODULUS_UNITS.get(unit)
            if factor is None:
                reasons.append(f"{where}: unknown modulus unit {unit!r}; set missing")
                return None
            return num * factor
        if 0 < num < self.config.ambiguous_modulus_below:
            label, value = _closest_in_log({"Pa": num, "MPa": num * 1e6, "GPa": num * 1e9}, typical)
            if label != "Pa":
                reasons.append(f"{where}: {num:g} read as {label} -> {value:g} Pa")
            return value
        return num

    def _hardness(
        self, num: float, unit: str, scale_raw: Any, default_scale: str, where: str, reasons: list[str]
    ) -> float | None:
        scale = None
        for source in (unit, scale_raw):  # a scale written with the value wins
            if isinstance(source, str) and source.strip():
                try:
                    scale = normalize_scale(source)
                    break
                except ValueError:
                    m = _HARDNESS_IN_TEXT.search(source)
                    if m:
                        try:
                            scale = normalize_scale(m.group(1) or m.group(2))
                            break
                        except ValueError:
                            pass
            elif isinstance(source, (int, float)) and not isinstance(source, bool) and source == 0:
                scale = "00"  # an unquoted 00 in JSON reads as the number 0
                break
        if scale is None:
            if scale_raw not in (None, "") or unit:
                reasons.append(
                    f"{where}: unknown Shore scale {_short(scale_raw if scale_raw not in (None, '') else unit, 20)!r}; assumed {default_scale}"
                )
            else:
                reasons.append(f"{where}: no shore_scale; assumed the library's scale {default_scale}")
            scale = default_scale
        if not 0 <= num <= 100:
            reasons.append(f"{where}: Shore {scale} reading {num:g} outside [0, 100]; set missing")
            return None
        return float(to_canonical(num, scale))

    def _thickness(self, value: Any, material: str, i: int, reasons: list[str]) -> float | None:
        where = f"candidate {i} ({material}) thickness_m"
        num, unit, problem = _parse_number(value)
        if problem:
            reasons.append(f"{where}: {problem}; treated as solid (null)")
            return None
        if num is None:
            return None
        if not math.isfinite(num) or num < 0:
            reasons.append(f"{where}: invalid value {num!r}; treated as solid (null)")
            return None
        if num == 0:
            return None
        if unit:
            factor = _LENGTH_UNITS.get(unit)
            if factor is None:
                reasons.append(f"{where}: unknown length unit {unit!r}; treated as solid (null)")
                return None
            num = num * factor
        elif num >= self.config.thickness_mm_from:
            reasons.append(f"{where}: {num:g} read as millimetres")
            num = num / 1000.0
        if not 1e-5 <= num < self.config.thickness_mm_from:
            reasons.append(f"{where}: {num:g} m is not a plausible wall thickness; treated as solid (null)")
            return None
        return float(num)

    def _merge(self, cands: list[Candidate], reasons: list[str]) -> list[Candidate]:
        by_name: dict[str, list[Candidate]] = {}
        for c in cands:
            by_name.setdefault(c.material, []).append(c)
        out = []
        for name, group in by_name.items():
            if len(group) == 1:
                out.append(group[0])
                continue
            reasons.append(f"{len(group)} candidates resolve to {name!r}; merged")
            group = sorted(group, key=lambda c: -c.confidence)
            best = group[0]
            props = dict(best.properties)
            for other in group[1:]:
                for k, v in other.properties.items():
                    if math.isnan(props.get(k, _NAN)) and not math.isnan(v):
                        props[k] = v
            thickness = next((c.thickness_m for c in group if c.thickness_m is not None), None)
            out.append(Candidate(name, sum(c.confidence for c in group), props, thickness, best.raw_material))
        return out


def _pydantic_summary(err: ValidationError) -> str:
    parts = []
    for e in err.errors()[:3]:
        loc = ".".join(str(x) for x in e.get("loc", ())) or "answer"
        parts.append(f"{loc}: {_short(e.get('msg', ''), 80)}")
    return "; ".join(parts)


def validate_response(
    text: Any, library: MaterialLibrary, config: ValidationConfig | None = None, context: str = ""
) -> ValidatedResponse:
    """Validate one answer (see the module docstring). Unpacks as ``(candidates, reasons)``."""
    return Validator(library, config)(text, context)
