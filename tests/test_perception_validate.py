"""Strict validation of VLM answers, including a fuzz test of malformed answers."""

from __future__ import annotations

import json
import logging
import math
import random

import pytest

from physgs_nerfstudio.materials import load_library, to_canonical
from physgs_nerfstudio.perception.validate import ValidationConfig, Validator, extract_json, validate_response


@pytest.fixture(scope="module")
def lib():
    return load_library("indoor")


def cand(**kw):
    base = {
        "material": "steel",
        "confidence": 0.8,
        "density": 7800,
        "kinetic_friction": 0.5,
        "shore_hardness": 60,
        "shore_scale": "D",
        "youngs_modulus": 2e11,
        "thickness_m": None,
    }
    base.update(kw)
    return base


def test_clean_answer_in_fences_with_chatter(lib):
    text = (
        "Sure! Here it is:\n```json\n"
        + json.dumps({"caption": "a pan", "candidates": [cand(), cand(material="Aluminum", confidence=0.2)]})
        + "\n```\nHope it helps."
    )
    res = validate_response(text, lib)
    cands, reasons = res
    assert [c.material for c in cands] == ["steel", "aluminium"]  # alias resolved
    assert sum(c.confidence for c in cands) == pytest.approx(1.0)
    assert cands[0].properties["density"] == 7800
    assert cands[0].properties["shore_hardness"] == pytest.approx(to_canonical(60, "D"))
    assert res.caption == "a pan" and reasons == []


def test_unit_rules(lib):
    text = json.dumps(
        {
            "candidates": [
                cand(density=7.8, youngs_modulus=200, shore_scale=None, thickness_m=3),
                cand(
                    material="polyurethane_foam",
                    confidence=0.1,
                    density=25,
                    youngs_modulus="5 MPa",
                    shore_hardness="40 Shore 00",
                ),
            ]
        }
    )
    cands, reasons = validate_response(text, lib)
    steel, foam = cands
    assert steel.properties["density"] == pytest.approx(7800)  # g/cm^3 -> kg/m^3
    assert steel.properties["youngs_modulus"] == pytest.approx(2e11)  # GPa
    assert steel.thickness_m == pytest.approx(0.003)  # mm
    assert foam.properties["density"] == pytest.approx(25)  # a foam's 25 stays kg/m^3
    assert foam.properties["youngs_modulus"] == pytest.approx(5e6)
    assert foam.properties["shore_hardness"] == pytest.approx(to_canonical(40, "00"))
    assert any("g/cm^3" in r for r in reasons) and any("GPa" in r for r in reasons)
    assert any("no shore_scale" in r for r in reasons) and any("millimetres" in r for r in reasons)


def test_rejections_per_field(lib):
    text = json.dumps(
        {
            "candidates": [
                cand(density=-5, kinetic_friction="slippery", youngs_modulus=1e30),
                cand(material="unobtainium"),
                cand(material="glass", confidence=7),
            ]
        }
    )
    cands, reasons = validate_response(text, lib)
    names = [c.material for c in cands]
    assert names == ["steel", "glass"]
    steel = cands[0]
    assert math.isnan(steel.properties["density"]) and math.isnan(steel.properties["kinetic_friction"])
    assert math.isnan(steel.properties["youngs_modulus"]) and not math.isnan(
        steel.properties["shore_hardness"]
    )
    assert any("unobtainium" in r for r in reasons) and any("clipped" in r for r in reasons)
    assert all(0 <= c.confidence <= 1 for c in cands) and sum(c.confidence for c in cands) == pytest.approx(1)


def test_nan_and_missing_confidence(lib):
    cands, reasons = validate_response(
        '{"candidates": [{"material": "oak", "density": NaN}, {"material": "pine"}]}', lib
    )
    assert [c.confidence for c in cands] == [pytest.approx(0.5), pytest.approx(0.5)]
    assert math.isnan(cands[0].properties["density"]) and any("non-finite" in r for r in reasons)


def test_renormalise_modes(lib):
    text = json.dumps({"candidates": [cand(confidence=0.6)]})
    assert validate_response(text, lib).candidates[0].confidence == pytest.approx(1.0)
    keep = validate_response(text, lib, ValidationConfig(renormalise="above_one")).candidates[0]
    assert keep.confidence == pytest.approx(0.6)


def test_duplicates_merged(lib):
    cands, reasons = validate_response(
        json.dumps(
            {"candidates": [cand(confidence=0.5), cand(material="Steel", confidence=0.3, density=None)]}
        ),
        lib,
    )
    assert (
        len(cands) == 1 and cands[0].confidence == pytest.approx(1.0) and any("merged" in r for r in reasons)
    )


def test_extract_json_variants():
    assert extract_json('noise {"a": 1} more {"b": 2}') == ({"a": 1}, "partial")
    assert extract_json("[]")[0] == []
    assert extract_json("nothing")[0] is None


def _malformed(rng: random.Random, lib_names: list[str]) -> str:
    """One answer that is wrong in at least one way."""
    good = {
        "caption": "x",
        "candidates": [cand(material=rng.choice(lib_names), confidence=rng.random() * 0.9 + 0.05)],
    }
    kind = rng.randrange(16)
    if kind == 0:
        return json.dumps(good)[: rng.randrange(1, len(json.dumps(good)))]  # truncated
    if kind == 1:
        return "".join(rng.choice('{}[]":,abc123 \n') for _ in range(rng.randrange(0, 200)))
    if kind == 2:
        good["candidates"] = []
    elif kind == 3:
        good["candidates"][0]["material"] = (
            "".join(rng.choice("xyzqwj") for _ in range(rng.randrange(1, 30))) + "ium"
        )
    elif kind == 4:
        good["candidates"][0]["confidence"] = rng.choice([7, -3, 1e9, "high", None, [0.5], float("nan")])
    elif kind == 5:
        good["candidates"][0]["density"] = rng.choice(
            [-1000, 0, float("nan"), float("inf"), 1e12, "heavy", [1], {"x": 1}]
        )
    elif kind == 6:
        good["candidates"][0]["material"] = rng.choice([None, 5, ["steel"], {"name": "steel"}, True])
    elif kind == 7:
        good["candidates"] = rng.choice(["steel", 5, None, {"material": "steel"}, [1, 2, 3], [[], "a"]])
    elif kind == 8:
        good["caption"] = "A" * rng.randrange(100_001, 150_000)
    elif kind == 9:
        good["candidates"][0]["youngs_modulus"] = rng.choice(
            [-1, 1e40, "stiff", float("-inf"), "12 furlongs"]
        )
    elif kind == 10:
        good["candidates"][0]["shore_hardness"] = rng.choice([150, -5, "soft", 1e6])
    elif kind == 11:
        good["candidates"][0]["shore_scale"] = rng.choice(["Z", "Rockwell", "", 17])
        good["candidates"][0]["shore_hardness"] = 50
    elif kind == 12:
        good["candidates"][0]["kinetic_friction"] = rng.choice([-0.5, 0, 50.0, "grippy", True])
    elif kind == 13:
        good["candidates"][0]["thickness_m"] = rng.choice([-1, 5000, "thick", 1e-9, float("nan")])
    elif kind == 14:
        return rng.choice(
            ["", "   ", "null", "42", '"just a string"', "```json\n```", "{" * 5000 + "}" * 5000]
        )
    else:
        good["candidates"] = [
            cand(material=rng.choice(lib_names), confidence=1.0) for _ in range(rng.randrange(2, 9))
        ]
    return json.dumps(good)


def test_fuzz_malformed_answers(lib, caplog):
    caplog.set_level(logging.INFO, logger="physgs_nerfstudio.perception.validate")
    rng = random.Random(1234)
    validator = Validator(lib)
    n = 1200
    for i in range(n):
        text = _malformed(rng, lib.names)
        caplog.clear()
        cands, reasons = validator(text, context=f"fuzz {i}")
        assert reasons, f"no reason for malformed answer {text[:200]!r}"
        assert len(caplog.records) == len(reasons)
        for c in cands:
            assert c.material in lib.names and 0 <= c.confidence <= 1
            for k, v in c.properties.items():
                assert math.isnan(v) or math.isfinite(v)
        if cands:
            assert sum(c.confidence for c in cands) == pytest.approx(1.0)
