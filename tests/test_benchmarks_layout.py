"""benchmarks/ a maintainer can navigate: at most 8 entry points, all in its README's table, and no benchmark
importing another (what they share is benchmarks/common.py)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
MAX_ENTRY_POINTS = 8
SHARED = "common"
"""the one module every benchmark may import"""


def entry_points(root: Path) -> list[str]:
    """The top-level scripts of ``root`` other than the shared module, and gpu/run_gpu.sh (the scripts in gpu/
    are the parts it runs)."""
    found = sorted(p.name for p in root.glob("*.py") if p.stem != SHARED)
    return found + (["gpu/run_gpu.sh"] if (root / "gpu" / "run_gpu.sh").exists() else [])


def sibling_imports(root: Path) -> list[str]:
    """``file imports name`` for every import, inside functions too, of another benchmark module."""
    files = sorted(root.glob("*.py")) + sorted(root.glob("gpu/*.py"))
    stems = {p.stem for p in files} - {SHARED}
    out = []
    for path in files:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names = [a.name.split(".")[0] for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module.split(".")[0]]
            else:
                continue
            out += [f"{path.relative_to(root)} imports {n}" for n in names if n in stems]
    return out


def test_at_most_eight_entry_points() -> None:
    assert len(entry_points(BENCHMARKS)) <= MAX_ENTRY_POINTS, entry_points(BENCHMARKS)


def test_every_entry_point_is_in_the_readme_table() -> None:
    text = (BENCHMARKS / "README.md").read_text()
    table = text[text.index("| entry point |"):].split("\n\n")[0]  # the first table: one row per entry point
    named = {t.split()[0] for t in re.findall(r"^\| `([^`]+)`", table, re.MULTILINE)}
    assert named == set(entry_points(BENCHMARKS))


def test_no_benchmark_imports_another() -> None:
    assert sibling_imports(BENCHMARKS) == [], f"move what is shared to benchmarks/{SHARED}.py"


def test_the_checks_count_and_find(tmp_path: Path) -> None:
    (tmp_path / "gpu").mkdir()
    (tmp_path / "gpu" / "run_gpu.sh").write_text("")
    (tmp_path / "gpu" / "part.py").write_text("import json\n")
    (tmp_path / "common.py").write_text("")
    (tmp_path / "a.py").write_text("import common\n")
    (tmp_path / "b.py").write_text("def f():\n    import a\n    from part import x\n")
    assert entry_points(tmp_path) == ["a.py", "b.py", "gpu/run_gpu.sh"]
    assert sibling_imports(tmp_path) == ["b.py imports a", "b.py imports part"]
