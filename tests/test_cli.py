"""The `physgs` console script and the nerfstudio method registration, through the real entry points."""

import subprocess
import sys


def _run(*args: str, timeout: int = 300) -> subprocess.CompletedProcess:
    return subprocess.run(list(args), capture_output=True, text=True, timeout=timeout)


def test_physgs_help_lists_subcommands():
    from physgs_nerfstudio.cli import COMMANDS

    out = _run(sys.executable, "-m", "physgs_nerfstudio.cli", "--help")
    assert out.returncode == 0, out.stderr
    for name in COMMANDS:
        assert name in out.stdout


def test_physgs_info_runs():
    out = _run(sys.executable, "-m", "physgs_nerfstudio.cli", "info")
    assert out.returncode == 0, out.stderr
    assert "rasterizer" in out.stdout


def test_ns_train_physgs_help():
    out = _run("ns-train", "physgs", "--help")
    assert out.returncode == 0, out.stderr[-2000:]
    assert "physgs" in out.stdout.lower()
