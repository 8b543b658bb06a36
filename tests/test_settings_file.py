"""`physgs COMMAND --settings FILE.yaml`: any setting (the advanced ones --help hides too) from a YAML file,
flags on the command line overriding it, and a bad file refused with one line before anything runs."""

from __future__ import annotations

import typing
from pathlib import Path, PurePath

import pytest
import tyro

from physgs_nerfstudio.advanced import cli
from physgs_nerfstudio.cli import COMMANDS, _load, entrypoint
from physgs_nerfstudio.export.command import ExportCommand
from physgs_nerfstudio.geometry import GeometryConfig
from physgs_nerfstudio.perception.command import PerceiveCommand
from physgs_nerfstudio.settings_file import (
    Mismatch,
    SettingsFileError,
    coerce,
    command_defaults,
    describe,
    read_settings,
    split_flag,
    subcommand_choices,
)

EXPORT = "physgs export"


def settings(tmp_path: Path, text: str, name: str = "settings.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def export(*args: str) -> ExportCommand:
    return cli(ExportCommand, prog=EXPORT, args=["--load-config", "run/config.yml", *args])


def fails(capsys, args: list[str]) -> str:
    """The one stderr line of `physgs ARGS`, which must exit with status 1."""
    with pytest.raises(SystemExit) as done:
        entrypoint(args)
    assert done.value.code == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    return err.strip()


def test_hidden_settings_from_the_file_take_effect(tmp_path, capsys, monkeypatch):
    # the settings are advanced: --help does not show them
    monkeypatch.setenv("COLUMNS", "200")
    with pytest.raises(SystemExit):
        entrypoint(["export", "--help"])
    shown = capsys.readouterr().out
    assert "--mass.density-draw" not in shown and "--mass.geometry.resolution" not in shown
    assert "--settings FILE.yaml" in shown
    default = ExportCommand(load_config=Path("c.yml"))
    assert default.mass.density_draw == "posterior" and default.mass.geometry.resolution != 100
    f = settings(tmp_path, "mass:\n  density_draw: predictive\n  geometry: {resolution: 100}\n")
    cmd = export("--settings", str(f))
    assert cmd.mass.density_draw == "predictive" and cmd.mass.geometry.resolution == 100
    assert isinstance(cmd.mass.geometry, GeometryConfig)
    # the other settings keep their defaults, the file's settings nested one level deeper than the top too
    assert cmd.mass.geometry == GeometryConfig(resolution=100) and cmd.output_dir == default.output_dir


def test_a_flag_overrides_the_file(tmp_path):
    f = settings(tmp_path, "output_dir: from_file\nmass: {geometry: {resolution: 100}}\n")
    cmd = export(f"--settings={f}", "--mass.geometry.resolution", "72", "--output-dir", "from_flag")
    assert cmd.mass.geometry.resolution == 72 and cmd.output_dir == Path("from_flag")
    assert export("--settings", str(f)).output_dir == Path("from_file")  # a path setting is a Path


def test_a_choice_and_its_settings(tmp_path):
    """A subcommand's choice is one key holding its settings; it becomes the default choice, which the command
    line can still change."""
    f = settings(tmp_path, "active_batch_size: 3\nvlm: {simulated: {p_random: 0.3, sigma: {density: 0.5}}}\n")
    cmd = cli(PerceiveCommand, prog="physgs perceive", args=["--data", "d", "--settings", str(f)])
    assert cmd.active_batch_size == 3 and type(cmd.vlm).__name__ == "SimulatedConfig"
    assert cmd.vlm.p_random == 0.3 and cmd.vlm.sigma == {"density": 0.5}
    cmd = cli(PerceiveCommand, prog="physgs perceive",
              args=["--data", "d", "--settings", str(f), "vlm:simulated", "--vlm.p-random", "0.2"])
    assert cmd.vlm.p_random == 0.2 and cmd.vlm.concentration == 1.5
    cmd = cli(PerceiveCommand, prog="physgs perceive", args=["--data", "d", "--settings", str(f), "vlm:openai"])
    assert type(cmd.vlm).__name__ == "OpenAIConfig"


def test_a_required_setting_stays_required_or_comes_from_the_file(tmp_path, capsys):
    empty = settings(tmp_path, "")
    with pytest.raises(SystemExit) as done:
        cli(ExportCommand, prog=EXPORT, args=["--settings", str(empty)])
    assert done.value.code == 2 and "--load-config" in capsys.readouterr().err
    f = settings(tmp_path, "load_config: run/config.yml\n", "given.yaml")
    assert cli(ExportCommand, prog=EXPORT, args=["--settings", str(f)]).load_config == Path("run/config.yml")


@pytest.mark.parametrize(("text", "expected"), [
    ("mass: {geometry: {resolutoin: 100}}\n",
     "unknown setting 'mass.geometry.resolutoin' (did you mean 'mass.geometry.resolution'?)"),
    ("mass: {zzz: 1}\n", "unknown setting 'mass.zzz' (the settings here: "),
    ("mass: {geometry: {resolution: big}}\n", "setting 'mass.geometry.resolution' must be an integer, not 'big'"),
    ("mass: {geometry: {resolution: true}}\n", "setting 'mass.geometry.resolution' must be an integer"),
    ("mass: 3\n", "'mass' holds settings: give a mapping of them, not 3"),
    ("outputs: [ply, mesh]\n", "setting 'outputs' must be a list of one of 'ply'"),
    ("- a\n- b\n", "expected a mapping of settings at the top level"),
    ("mass: {geometry: [\n", "not valid YAML"),
    ("x: !!python/object/apply:os.system [touch pwned]\n", "refused (a tag plain YAML does not have"),
])
def test_a_bad_file_is_one_line_and_nothing_is_written(tmp_path, capsys, monkeypatch, text, expected):
    monkeypatch.chdir(tmp_path)
    f = settings(tmp_path, text)
    line = fails(capsys, ["export", "--load-config", "run/config.yml", "--output-dir", "out", "--settings", str(f)])
    assert line.startswith(f"{EXPORT}: error: {f}: ") and expected in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["settings.yaml"]  # no out/, no pwned


def test_an_alias_bomb_is_refused(tmp_path, capsys):
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(1, 9)]
    f = settings(tmp_path, "\n".join(lines) + "\n")
    line = fails(capsys, ["materials", "--settings", str(f)])
    assert line.startswith(f"physgs materials: error: {f}: refused (") and "alias" in line


def test_the_flag_itself(tmp_path, capsys):
    assert split_flag(["--env", "x"]) == (None, ["--env", "x"])
    assert split_flag(["--settings", "a.yaml", "--env", "x"]) == (Path("a.yaml"), ["--env", "x"])
    with pytest.raises(SettingsFileError, match="given 2 times"):
        split_flag(["--settings", "a.yaml", "--settings=b.yaml"])
    assert fails(capsys, ["materials", "--settings"]) == "physgs materials: error: --settings needs a file: " \
                                                          "--settings FILE.yaml"
    assert fails(capsys, ["--settings", "a.yaml", "export"]) == "physgs: error: give --settings after the " \
                                                                 "command: physgs COMMAND --settings FILE.yaml"
    missing = tmp_path / "none.yaml"
    assert f"{missing}: no such settings file" in fails(capsys, ["materials", "--settings", str(missing)])


def test_a_command_runs_with_its_file(tmp_path, capsys):
    f = settings(tmp_path, "env: outdoor\n")
    entrypoint(["materials", "--settings", str(f)])
    assert "outdoor material library" in capsys.readouterr().out


def test_values_and_their_types():
    assert coerce(float, 2) == 2.0 and type(coerce(float, 2)) is float
    assert coerce(int | None, None) is None and coerce(tuple[int, ...], [1, 2]) == (1, 2)
    assert coerce(tuple[float, float] | None, [1, 2.5]) == (1.0, 2.5)
    assert coerce(dict[str, bool], {"a": True}) == {"a": True}
    for tp, value in [(int, 1.5), (bool, 1), (str, 3), (tuple[int, int], [1]), (dict[str, float], {"a": "b"})]:
        with pytest.raises(Mismatch):
            coerce(tp, value)
    assert describe(int | None) == "an integer or null"
    assert describe(tuple[float, ...]) == "a list of a number"


def _plain(value):
    """A default value as a settings file writes it (a choice as one key, its name)."""
    import dataclasses
    import enum

    if dataclasses.is_dataclass(value):
        hints = typing.get_type_hints(type(value), include_extras=True)
        out = {}
        for f in dataclasses.fields(value):
            v = getattr(value, f.name)
            if not f.init or v is tyro.MISSING:
                continue
            choices = subcommand_choices(hints[f.name])
            out[f.name] = {next(n for n, c in choices.items() if isinstance(v, c)): _plain(v)} if choices else _plain(v)
        return out
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, PurePath):
        return str(value)
    if isinstance(value, enum.Enum):
        return value.name
    return value


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_a_file_of_every_default_gives_the_defaults(tmp_path, name):
    """Every setting of every command, nested and advanced ones too, written at its default into a file and read
    back: the same command; so every type the commands use can be given in a file."""
    import yaml

    cls = _load(name)
    defaults = command_defaults(cls, {}, tmp_path / "none.yaml", f"physgs {name}")
    f = settings(tmp_path, yaml.safe_dump(_plain(defaults)))
    assert command_defaults(cls, read_settings(f), f, f"physgs {name}") == defaults
