"""The answer a VLM is asked for, as a pydantic model, and the strict JSON schema built from it.

OpenAI-compatible servers that support structured output (OpenAI, vLLM, Ollama, llama.cpp's server)
constrain the reply to a schema sent as ``response_format={"type": "json_schema", "json_schema": {...,
"strict": true}}``. :func:`strict_json_schema` builds that schema from :class:`Answer`: every property
required (optional values are nullable instead), no additional properties, ``$defs`` inlined, no
``title`` / ``default`` keywords (strict mode refuses some keywords; the bounds of the prompt's schema,
``prompts.RESPONSE_SCHEMA``, stay in the prompt text), and the material names of the run's library as an
``enum``. The field names are those of the prompt's schema; validate.py reads both.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

SCHEMA_NAME = "physgs_material_answer"


class AnswerCandidate(BaseModel):
    model_config = ConfigDict(extra="forbid")

    material: str = Field(description="one name from the material list")
    confidence: float = Field(description="in [0, 1]; the candidates' confidences sum to 1")
    density: float | None = Field(description="kg/m^3")
    kinetic_friction: float | None = Field(description="kinetic friction coefficient")
    shore_hardness: float | None = Field(description="Shore hardness value on shore_scale")
    shore_scale: Literal["A", "D", "00"] | None
    youngs_modulus: float | None = Field(description="Pa")
    thickness_m: float | None = Field(
        description="wall thickness in metres if the part is a hollow shell, else null"
    )


class Answer(BaseModel):
    model_config = ConfigDict(extra="forbid")

    caption: str = Field(description="short description of the highlighted part")
    object: str | None = Field(description="the whole object the highlighted part belongs to, in one or two words; "
                               "null for background")
    candidates: list[AnswerCandidate]


def _inline(node: Any, defs: dict[str, Any]) -> Any:
    """``node`` with every ``$ref`` to ``#/$defs/X`` replaced by X, and title / default dropped."""
    if isinstance(node, list):
        return [_inline(v, defs) for v in node]
    if not isinstance(node, dict):
        return node
    if "$ref" in node:
        return _inline(defs[node["$ref"].rsplit("/", 1)[-1]], defs)
    out = {k: _inline(v, defs) for k, v in node.items() if k not in ("title", "default", "$defs")}
    if out.get("type") == "object" and "properties" in out:
        out["required"] = list(out["properties"])
        out["additionalProperties"] = False
    return out


def strict_json_schema(material_names: Sequence[str] | None = None) -> dict[str, Any]:
    """The strict JSON schema of :class:`Answer`; ``material`` limited to ``material_names`` when given."""
    raw = Answer.model_json_schema()
    schema = _inline(raw, raw.get("$defs", {}))
    if material_names:
        material = schema["properties"]["candidates"]["items"]["properties"]["material"]
        material["enum"] = list(dict.fromkeys(material_names))
    return schema


def response_format(kind: str, material_names: Sequence[str] | None = None) -> dict[str, Any] | None:
    """The ``response_format`` field for ``kind`` json_schema | json_object | none (None: no field)."""
    if kind == "json_schema":
        schema = strict_json_schema(material_names)
        return {"type": "json_schema", "json_schema": {"name": SCHEMA_NAME, "strict": True, "schema": schema}}
    if kind == "json_object":
        return {"type": "json_object"}
    if kind == "none":
        return None
    raise ValueError(f"unknown response format {kind!r}; choose json_schema, json_object or none")
