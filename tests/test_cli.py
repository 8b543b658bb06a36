"""The `physgs` console script and the nerfstudio method registration, through the real entry points."""

import os
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


def test_main_ends_a_fast_exit_command_at_once_after_flushing(monkeypatch, capsys):
    """`physgs export` (``fast_exit``) ends through os._exit(0) after its output is flushed, with the cyclic garbage
    collector off while it ran; PHYSGS_NO_FAST_EXIT=1 and commands without ``fast_exit`` return normally."""
    import gc

    from physgs_nerfstudio import cli

    class Exited(Exception):
        pass

    def fake_exit(code):
        raise Exited(code)

    seen = {}

    class Export:
        fast_exit = True

    def fake_entrypoint():
        seen["gc"] = gc.isenabled()
        print("report printed")
        return Export()

    monkeypatch.setattr(os, "_exit", fake_exit)
    monkeypatch.setattr(cli, "entrypoint", fake_entrypoint)
    monkeypatch.setattr(sys, "argv", ["physgs", "export", "--load-config", "x.yml"])
    monkeypatch.delenv("PHYSGS_NO_FAST_EXIT", raising=False)
    try:
        try:
            cli.main()
            raise AssertionError("main() returned: the export did not end the process")
        except Exited as e:
            assert e.args == (0,)
        assert seen["gc"] is False
        assert "report printed" in capsys.readouterr().out
        gc.enable()
        monkeypatch.setenv("PHYSGS_NO_FAST_EXIT", "1")
        cli.main()  # returns
        assert seen["gc"] is True
        monkeypatch.delenv("PHYSGS_NO_FAST_EXIT")
        monkeypatch.setattr(sys, "argv", ["physgs", "info"])
        Export.fast_exit = False
        cli.main()  # a command without fast_exit returns, collector on
        assert seen["gc"] is True
    finally:
        gc.enable()
