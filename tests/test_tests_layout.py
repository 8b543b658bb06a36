"""The tests' own layout: no test module imports another module of tests/ (a test module, conftest.py or a loose
helper file); what they share is in conftest.py (fixtures) or the tests/helpers package (plain functions)."""

from __future__ import annotations

import ast
from pathlib import Path

TESTS = Path(__file__).resolve().parent


def _imported(path: Path) -> set[str]:
    """The top-level names of the absolute imports anywhere in the file, inside functions too."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def _offenders(root: Path) -> list[str]:
    loose = {p.stem for p in root.glob("*.py")} | {"tests"}
    files = sorted(root.glob("*.py")) + sorted((root / "helpers").glob("*.py"))
    return [f"{p.relative_to(root)} imports {name}" for p in files for name in sorted(_imported(p) & loose)]


def test_no_test_module_imports_another() -> None:
    assert _offenders(TESTS) == [], "move what is shared to conftest.py or tests/helpers/"


def test_the_check_finds_an_import_between_test_modules(tmp_path: Path) -> None:
    (tmp_path / "helpers").mkdir()
    (tmp_path / "helpers" / "shapes.py").write_text("import math\n")
    (tmp_path / "test_a.py").write_text("def f():\n    from test_b import g\n")
    (tmp_path / "test_b.py").write_text("from helpers.shapes import ring\nimport tests.test_a\n")
    (tmp_path / "shared.py").write_text("")
    (tmp_path / "test_c.py").write_text("from shared import x\n")
    assert _offenders(tmp_path) == ["test_a.py imports test_b", "test_b.py imports tests", "test_c.py imports shared"]
