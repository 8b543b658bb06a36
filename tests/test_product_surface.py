"""The product's surfaces describe the product as it is, not the story of its development.

README.md, docs/*.md (except CHANGELOG.md, where history belongs) and the comments and string literals
(docstrings, help texts) of every .py file under physgs_nerfstudio/ and method_configs/ must not name working
sessions, rounds, run dates, or a particular seed of a generated scene as the reason for something. A hit
names the file, the line and the words; move the history into CHANGELOG.md and say instead what the code does
now and, for a default, what it means physically.

docs/results.md may name the seed a figure was measured at (a result's provenance, not a default's reason);
every other rule applies to it too.
"""

from __future__ import annotations

import io
import re
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CODE_DIRS = ("physgs_nerfstudio", "method_configs")

HISTORY = [
    ("session", re.compile(r"\bsessions? \d+|\(session\b|\bsession's\b", re.IGNORECASE)),
    ("round", re.compile(r"\brounds? \d+", re.IGNORECASE)),
    ("run date", re.compile(r"\b20\d\d-\d\d-\d\d\b")),
]
SEEDS = [
    ("seed as a reason",
     re.compile(r"\bat (?:(?:fresh|held-out|development|GPU|CPU|the|its) )*seeds? \d+", re.IGNORECASE)),
    ("a generated object at a seed", re.compile(r"\bthe \w+ at (?:\w+ )?seed\b", re.IGNORECASE)),
    ("a particular seed", re.compile(r"(?<![-\w.=])seeds? \d{3,}", re.IGNORECASE)),
]
SEEDS_ALLOWED = {"docs/results.md"}


def _text_lines(path: Path) -> list[tuple[int, str]]:
    """(line, text) a reader sees: a Markdown file whole, a Python file's comments and string literals."""
    source = path.read_text(encoding="utf-8")
    if path.suffix != ".py":
        return list(enumerate(source.splitlines(), start=1))
    out: list[tuple[int, str]] = []
    kinds = {tokenize.COMMENT, tokenize.STRING}
    kinds |= {tokenize.FSTRING_MIDDLE} if hasattr(tokenize, "FSTRING_MIDDLE") else set()
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type in kinds:
            for k, line in enumerate(tok.string.splitlines()):
                out.append((tok.start[0] + k, line))
    return out


def surface_hits(path: Path, rel: str) -> list[str]:
    rules = HISTORY + ([] if rel in SEEDS_ALLOWED else SEEDS)
    hits = []
    for lineno, line in _text_lines(path):
        for what, pattern in rules:
            for m in pattern.finditer(line):
                hits.append(f"{rel}:{lineno}: {what}: {m.group(0)!r}")
    return hits


def _surfaces() -> list[tuple[Path, str]]:
    files = [ROOT / "README.md"] + sorted(p for p in (ROOT / "docs").glob("*.md") if p.name != "CHANGELOG.md")
    for d in CODE_DIRS:
        files += sorted((ROOT / d).rglob("*.py"))
    return [(p, p.relative_to(ROOT).as_posix()) for p in files if p.is_file()]


def test_surfaces_found():
    rels = {rel for _, rel in _surfaces()}
    assert "README.md" in rels
    assert "physgs_nerfstudio/cli.py" in rels
    assert (ROOT / "CHANGELOG.md").is_file(), "CHANGELOG.md is where the history goes"


@pytest.mark.parametrize("rel", [rel for _, rel in _surfaces()])
def test_no_history_on_product_surface(rel: str):
    hits = surface_hits(ROOT / rel, rel)
    assert not hits, "history on a product surface (move it to CHANGELOG.md):\n" + "\n".join(hits)


def test_scanner_finds_planted_history(tmp_path: Path):
    """The scanner itself: it finds each kind of history in comments, docstrings and Markdown, and leaves code
    and a plain seed option alone."""
    py = tmp_path / "m.py"
    py.write_text(
        '"""Default since session 12."""\n'
        "x = round(3.14159, 2)  # rounded to 2 places\n"
        "seed = 101\n"
        "y = 1  # measured on 2026-11-29\n"
        'def f():\n    """The lamp at seed 9696 took its base for a floor."""\n'
        "# round 7 made it the default\n"
        "z = '--seed 0'\n"
        "# kept for (session 44's) runs\n",
        encoding="utf-8",
    )
    hits = surface_hits(py, "m.py")
    lines = sorted({int(h.split(":")[1]) for h in hits})
    assert lines == [1, 4, 6, 7, 9], hits
    md = tmp_path / "r.md"
    md.write_text("fresh seed 26248: 10 of 12\n`physgs synth --seed 0`\nRound 5 measured it\n",
                  encoding="utf-8")
    assert sorted({int(h.split(":")[1]) for h in surface_hits(md, "docs/x.md")}) == [1, 3]
    assert sorted({int(h.split(":")[1]) for h in surface_hits(md, "docs/results.md")}) == [3]
