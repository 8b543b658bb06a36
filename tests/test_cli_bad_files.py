"""Every `physgs` command on a set of bad files ends with one line, `physgs <command>: error: ...`, and exit
status 1: never a traceback, never the boundary's "unexpected" line (an input no check caught). Issue 72, "one
line for every bad file". The files are written here: missing, empty, binary, nested 200000 levels deep, a CSV
field of 300 kB (over csv's 128 KiB limit), NUL and CR bytes, a folder where a file goes and a file where a
folder goes."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from physgs_nerfstudio.cli import COMMANDS, entrypoint, one_line, one_line_errors
from physgs_nerfstudio.errors import PhysGSError

REPO = Path(__file__).resolve().parents[1]


def _bad_files(d: Path) -> dict[str, Path]:
    d.mkdir(parents=True, exist_ok=True)
    files = {
        "empty": ("empty.json", b""),
        "binary": ("junk.bin", bytes(range(256)) * 4),
        "deep_list": ("deep.json", b"[" * 200_000 + b"]" * 200_000),
        "deep_map": ("deepobj.json", b'{"a":' * 100_000 + b"1" + b"}" * 100_000),
        "huge_field": ("big.csv", b"item,property,mean,unit\na,mass,\"" + b"1" * 300_000 + b"\",kg\n"),
        "control_bytes": ("ctrl.csv", b"item,property,value,unit\n\x00a\r,mass,1,kg\n"),
        "nan": ("nan.json", b'{"predictions": [{"item": "a", "mass_kg": NaN}]}'),
    }
    out = {}
    for key, (name, data) in files.items():
        (d / name).write_bytes(data)
        out[key] = d / name
    (d / "a_folder").mkdir(exist_ok=True)
    out["folder"] = d / "a_folder"
    out["missing"] = d / "missing.json"
    return out


@pytest.fixture(scope="module")
def bad(tmp_path_factory) -> dict[str, Path]:
    return _bad_files(tmp_path_factory.mktemp("bad"))


@pytest.fixture(scope="module")
def good_table(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("good") / "truth.csv"
    p.write_text("item,property,value,unit\na,mass,1,kg\n")
    return p


def _datasets(bad: dict[str, Path], root: Path) -> dict[str, Path]:
    """Dataset folders whose transforms.json is each bad file."""
    out = {}
    for key in ("empty", "binary", "deep_list", "deep_map", "nan"):
        d = root / f"ds_{key}"
        d.mkdir(exist_ok=True)
        (d / "transforms.json").write_bytes(bad[key].read_bytes())
        out[key] = d
    return out


def _runs(bad: dict[str, Path], root: Path) -> dict[str, Path]:
    """Run folders whose config.yml is each bad file."""
    out = {}
    for key in ("empty", "binary", "deep_list", "deep_map", "control_bytes", "huge_field"):
        d = root / f"run_{key}"
        d.mkdir(exist_ok=True)
        (d / "config.yml").write_bytes(bad[key].read_bytes())
        out[key] = d / "config.yml"
    return out


def _cases(bad: dict[str, Path], good_table: Path, root: Path) -> list[tuple[str, list[str]]]:
    files = [bad[k] for k in ("missing", "empty", "binary", "deep_list", "deep_map", "huge_field", "control_bytes",
                              "nan", "folder")]  # fmt: skip
    out = root / "out"
    cases: list[tuple[str, list[str]]] = []
    for f in files:
        cases += [
            ("perceive", ["--data", str(f)]),
            ("image", [str(f), "--output-dir", str(out / "image")]),
            ("export", ["--load-config", str(f), "--output-dir", str(out / "export")]),
            ("eval", ["--ground-truth", str(f), "--predictions", str(good_table), "--output-dir", str(out / "e")]),
            ("eval", ["--ground-truth", str(good_table), "--predictions", str(f), "--output-dir", str(out / "e")]),
            ("batch", ["--scenes", str(f), "--output-dir", str(out / "batch")]),
            ("materials", ["--env", str(f)]),
            ("materials", ["--extra-files", str(f)]),
        ]
    for f in files:  # a file where a folder goes
        if f.is_file():
            cases += [("synth", ["--out", str(f), "--views", "2", "--resolution", "8"]),
                      ("demo", ["--output-dir", str(f), "--views", "2", "--resolution", "8", "--iterations", "2"])]
    cases += [("perceive", ["--data", str(d)]) for d in _datasets(bad, root).values()]
    cases += [("export", ["--load-config", str(c), "--output-dir", str(out / "export")]) for c in _runs(bad, root).values()]
    return cases


def test_every_command_is_tried(bad, good_table, tmp_path):
    tried = {name for name, _ in _cases(bad, good_table, tmp_path)}
    assert tried >= set(COMMANDS) - {"info"}  # info reads no file


def test_every_command_on_every_bad_file_is_one_line(bad, good_table, tmp_path, capsys):
    failures = []
    for name, args in _cases(bad, good_table, tmp_path):
        try:
            entrypoint([name, *args])
            code: object = 0
        except SystemExit as exit_:
            code = exit_.code
        except BaseException as err:  # noqa: BLE001 - what the test looks for
            code = f"raised {type(err).__name__}"
        err = capsys.readouterr().err
        lines = [ln for ln in err.splitlines() if ln.strip()]
        last = lines[-1] if lines else ""
        ok = (code == 1 and last.startswith(f"physgs {name}: error: ") and "unexpected" not in last
              and "Traceback" not in err and last.isprintable())  # fmt: skip
        if not ok:
            failures.append(f"physgs {name} {' '.join(a[-40:] for a in args)} -> {code}: {last[:300]}")
    assert failures == [], "\n".join(failures)


def test_the_boundary_says_unexpected_for_what_no_check_caught(capsys, monkeypatch):
    """The oracle of the test above: an exception no check turned into a user error is named as unexpected."""
    monkeypatch.delenv("PHYSGS_TRACEBACK", raising=False)
    with pytest.raises(SystemExit) as ei, one_line_errors("physgs x"):
        raise KeyError("gauss_params.x")
    assert ei.value.code == 1
    assert capsys.readouterr().err.strip() == ("physgs x: error: KeyError: 'gauss_params.x' (unexpected: set "
                                               "PHYSGS_TRACEBACK=1 for where it came from, and report it)")  # fmt: skip
    monkeypatch.setenv("PHYSGS_TRACEBACK", "1")
    with pytest.raises(KeyError), one_line_errors("physgs x"):
        raise KeyError("k")


def test_control_bytes_never_reach_the_terminal(capsys):
    with pytest.raises(SystemExit), one_line_errors("physgs x"):
        raise PhysGSError("server said \x00HTTP/1.1 \r\x1b[2J 999 garbage\nnext")
    err = capsys.readouterr().err
    assert err == "physgs x: error: server said HTTP/1.1 [2J 999 garbage next\n"
    assert one_line("a\x00b") == "a b" and len(one_line("x" * 10_000)) <= 2000


def test_a_message_exit_gets_the_error_prefix_and_status_1(capsys):
    with pytest.raises(SystemExit) as ei, one_line_errors("physgs image"):
        raise SystemExit("physgs image: no such thing")
    assert ei.value.code == 1 and capsys.readouterr().err == "physgs image: error: no such thing\n"
    with pytest.raises(SystemExit) as ei, one_line_errors("physgs x"):
        raise SystemExit(2)  # tyro's own exit for a bad option passes through
    assert ei.value.code == 2


def test_eval_exits_1_with_error_in_a_real_process(bad, good_table, tmp_path):
    env = dict(os.environ, PYTHONPATH=str(REPO), PYTHONWARNINGS="ignore")
    proc = subprocess.run([sys.executable, "-m", "physgs_nerfstudio.cli", "eval", "--ground-truth", str(good_table),
                           "--predictions", str(bad["deep_list"]), "--output-dir", str(tmp_path / "e")],
                          capture_output=True, text=True, timeout=120, check=False, env=env)  # fmt: skip
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("physgs eval: error: ")
    assert "nested too deeply" in proc.stderr
