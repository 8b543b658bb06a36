"""Perception's ``object`` answer (the whole object a part belongs to, written to observations.jsonl): the name is
normalised and the validated answer carries it."""

from __future__ import annotations

from physgs_nerfstudio.perception.validate import Validator, object_name


def test_object_names_are_normalised():
    assert object_name("The Table.") == "table"
    assert object_name("  a   Coffee-Mug ") == "coffee-mug"
    assert object_name("") is None and object_name(None) is None and object_name(3) is None
    assert object_name("x" * 61) is None


def test_the_validated_answer_carries_the_object():
    from physgs_nerfstudio.materials import load_library

    check = Validator(load_library("indoor"))
    ans = check('{"caption": "a mug", "object": "Mug", "candidates": [{"material": "ceramic", "confidence": 1}]}')
    assert ans.object == "mug" and ans.candidates
    assert check('{"caption": "x", "candidates": [{"material": "ceramic", "confidence": 1}]}').object is None
