"""One progress display per export stage; one closing line per stage in a non-interactive log."""

from __future__ import annotations

import io
import re

import pytest
from rich.console import Console

from physgs_nerfstudio.export.progress import stage


def _console(terminal: bool) -> tuple[Console, io.StringIO]:
    buf = io.StringIO()
    return Console(file=buf, force_terminal=terminal, width=120, log_path=False), buf


def test_non_terminal_log_gets_one_line_per_stage() -> None:
    console, buf = _console(terminal=False)
    with stage(console, "property maps", total=20, unit="views") as st:
        for i in range(20):
            st.advance(1, f"view{i:03d}")
        st.result = "out/maps"
    with stage(console, "object geometry", unit="steps") as st:
        for name in ("selecting", "carving", "parts"):
            st.advance(1, name)
    lines = [ln for ln in buf.getvalue().splitlines() if ln.strip()]
    assert len(lines) == 2, lines
    assert "property maps: 20/20 views in" in lines[0] and lines[0].rstrip().endswith("out/maps")
    assert "object geometry: 3 steps in" in lines[1]
    assert "view007" not in buf.getvalue()  # no per-item redraws in a log


def test_terminal_display_is_transient_and_closes_with_one_line() -> None:
    console, buf = _console(terminal=True)
    with stage(console, "property maps", total=3, unit="views") as st:
        for i in range(3):
            st.advance(1, f"view{i}")
    text = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", buf.getvalue())
    assert "property maps: 3/3 views in" in text
    assert text.count("property maps: 3/3 views in") == 1


def test_failed_stage_prints_no_closing_line() -> None:
    console, buf = _console(terminal=False)
    with pytest.raises(ValueError, match="boom"), stage(console, "object geometry") as st:
        st.advance(1, "carving")
        raise ValueError("boom")
    assert buf.getvalue().strip() == ""
