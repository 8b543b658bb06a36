"""What `physgs <command> --help` shows: few options, each with one plain sentence of help.

The help text is read as printed (one column, 100 characters wide) and split into its options: an option
starts on a line that begins with ``-``; its help is what follows the flags and their metavar, less the
``(default: ...)`` / ``(required)`` hints tyro adds.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Annotated

import pytest
import tyro

from physgs_nerfstudio.advanced import Advanced, has_advanced, is_advanced
from physgs_nerfstudio.cli import COMMANDS, entrypoint

LIMITS = {"export": 25, "perceive": 30}
"""The most options `--help` may show (perceive: on its default route, vlm:openai segmenter:builtin)."""
ROUTES = {"perceive": [(), ("vlm:openai",), ("vlm:openai", "segmenter:builtin")]}
"""The help pages of a command's default route, whose options add up."""
_VLM_PAGES = [(), ("vlm:openai",), ("vlm:openai", "segmenter:builtin"), ("vlm:openai", "segmenter:sam"),
              ("vlm:replay",), ("vlm:simulated",)]  # fmt: skip
PAGES = {"perceive": _VLM_PAGES, "image": _VLM_PAGES}
"""Every help page of a command, checked for plain help."""
FORBIDDEN = {
    "a Sphinx role": re.compile(r":(func|class|mod|meth|attr|data|obj|exc|ref|doc):`"),
    "a pointer to a module doc": re.compile(r"module doc", re.IGNORECASE),
    "history": re.compile(r"\bsessions?\b|\bround \d|\b20\d\d-\d\d-\d\d\b", re.IGNORECASE),
}
HINTS = re.compile(r"\((default|fixed to): .*?\)|\(required\)|\(fixed\)", re.DOTALL)


def help_text(capsys, monkeypatch, *args: str) -> str:
    """What `physgs ARGS --help` prints."""
    monkeypatch.setenv("COLUMNS", "100")
    with pytest.raises(SystemExit) as done:
        entrypoint([*args, "--help"])
    assert done.value.code in (0, None)
    return capsys.readouterr().out


def options(text: str) -> dict[str, str]:
    """The options of a help text: first flag -> help (hints removed). tyro draws boxes on a terminal and plain
    headed sections elsewhere; a box's line is read as the plain layout's (its content indented by two)."""
    entries: list[list[str]] = []
    current: list[str] | None = None
    for line in text.splitlines():
        line = line.rstrip()
        if line.startswith("│ ") and line.endswith("│"):
            line = "  " + line[2:line.rindex("│")].rstrip()
        content = line[2:]
        if not line.startswith("  ") or content.startswith(("─" * 3, "-" * 3)):
            current = None  # a blank line, a section's header or border, a separator
        elif content.startswith("-") and not (current and current[-1].endswith(",")):
            current = [content]
            entries.append(current)
        elif current is not None:
            current.append(content)
    out = {}
    for lines in entries:
        flags, first_help = ([*re.split(r"\s{2,}", lines[0], maxsplit=1), ""])[:2]
        rest = [ln for ln in lines[1:] if ln.startswith("  ")]
        wrapped_flags = [ln for ln in lines[1:] if not ln.startswith("  ")]
        flags = " ".join([flags, *wrapped_flags])
        name = flags.split()[0].rstrip(",")
        if name in ("-h", "-H"):
            continue
        out[name] = HINTS.sub("", " ".join([first_help, *(ln.strip() for ln in rest)])).strip()
    return out


def route_options(capsys, monkeypatch, command: str) -> dict[str, str]:
    shown: dict[str, str] = {}
    for route in ROUTES.get(command, [()]):
        shown.update(options(help_text(capsys, monkeypatch, command, *route)))
    return shown


def test_the_option_parser_reads_both_layouts():
    lines = [
        "╭─ options ─╮",
        "│ -h, --help        show this help message and exit │",
        "│ --a INT           the a. (default: 1)               │",
        "│ --long-flag, --no-long-flag,                        │",
        "│ --x.no-long-flag                                    │",
        "│       whether. (default: True)                      │",
        "│ --b {None}|{FLOAT FLOAT                             │",
        "│ FLOAT}                                              │",
        "│       (default: None)                               │",
        "╰───────────╯",
    ]
    assert options("\n".join(lines)) == {"--a": "the a.", "--long-flag": "whether.", "--b": ""}
    plain = [" options", " " + "-" * 20, "  -h, --help    show this help message and exit",
             "  --c PATH      the c. (required)", "", " g options", " " + "-" * 20, "  A group.", "  " + "-" * 20,
             "  --g.d INT", "                the d, on", "                two lines (default: 2)"]  # fmt: skip
    assert options("\n".join(plain)) == {"--c": "the c.", "--g.d": "the d, on two lines"}


@pytest.mark.parametrize("command", sorted(LIMITS))
def test_help_shows_at_most_the_limit_of_options(capsys, monkeypatch, command):
    shown = route_options(capsys, monkeypatch, command)
    assert 5 <= len(shown) <= LIMITS[command], sorted(shown)


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_shown_option_has_plain_help(capsys, monkeypatch, command):
    texts = [help_text(capsys, monkeypatch, command, *page) for page in PAGES.get(command, [()])]
    shown = {k: v for text in texts for k, v in options(text).items()}
    assert [k for k, v in shown.items() if not v] == [], f"physgs {command}: options without help"
    for what, pattern in FORBIDDEN.items():
        hits = [line.strip() for text in texts for line in text.splitlines() if pattern.search(line)]
        assert hits == [], f"physgs {command} --help prints {what}"


def test_advanced_settings_are_hidden_from_help_but_still_parse(capsys, monkeypatch):
    """`--mass.geometry.*` is hidden from `physgs export --help`, listed by --help-all, and still set."""
    from physgs_nerfstudio.advanced import HELP_ALL, cli
    from physgs_nerfstudio.export.command import ExportCommand

    shown = route_options(capsys, monkeypatch, "export")
    assert "--mass.geometry.resolution" not in shown and "--load-config" in shown
    monkeypatch.setenv("COLUMNS", "100")
    with pytest.raises(SystemExit):
        entrypoint(["export", HELP_ALL])
    every = options(capsys.readouterr().out)
    assert "--mass.geometry.resolution" in every and len(every) > len(shown)
    cmd = cli(ExportCommand, prog="physgs export",
              args=["--load-config", "c.yml", "--mass.geometry.resolution", "96", "--mass.geometry.carve.min-votes",
                    "3", "--mass.seam-offset-voxels", "0.5"])  # fmt: skip
    assert cmd.mass.geometry.resolution == 96 and cmd.mass.geometry.carve.min_votes == 3
    assert cmd.mass.seam_offset_voxels == 0.5



@dataclass
class _Leaf:
    x: Advanced[int] = 1


@dataclass
class _Plain:
    y: int = 2


@dataclass
class _Outer:
    choice: Annotated[_Plain, tyro.conf.subcommand("p")] | Annotated[_Leaf, tyro.conf.subcommand("l")] = field(
        default_factory=_Plain)


def test_has_advanced_looks_through_nesting_and_unions():
    assert is_advanced(Advanced[int]) and not is_advanced(int) and not is_advanced(Annotated[int, "x"])
    assert has_advanced(_Leaf) and not has_advanced(_Plain) and has_advanced(_Outer)
    assert has_advanced(_Plain | _Leaf) and not has_advanced(_Plain | None)
