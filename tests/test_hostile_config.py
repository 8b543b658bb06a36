"""Crafted run configs: the loader is bounded (aliases) and builds only what a run's config holds (issue 72,
serious 1 and 2). Oracles: the node counts of hand-built alias trees, the classes nerfstudio's own configs name,
a folder a writer built from the config would create."""

from __future__ import annotations

import copy
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from physgs_nerfstudio.runfiles.loader import _checked_dataparser
from physgs_nerfstudio.safe_yaml import (
    MAX_ALIASES,
    MAX_EXPANDED_NODES,
    UnsafeConfigError,
    load_config_tree,
    load_config_yaml,
)

REPO = Path(__file__).resolve().parents[1]
_DP = "!!python/name:physgs_nerfstudio.nerfstudio.dataparser.PhysGSDataParser ''"


def _physgs_config(tmp_path: Path) -> Path:
    """A config.yml written by nerfstudio itself for the physgs-lite method (as ns-train does)."""
    from nerfstudio.configs.method_configs import all_methods

    cfg = copy.deepcopy(all_methods["physgs-lite"])
    cfg.pipeline.datamanager.data = tmp_path / "scene"
    cfg.output_dir, cfg.experiment_name, cfg.timestamp = tmp_path / "outputs", "scene", "t"
    cfg.save_config()
    return cfg.get_base_dir() / "config.yml"


def _bomb(levels: int, width: int, indent: str = "      ") -> str:
    lines = [f"{indent}zz_l0: &l0 [{', '.join(['lol'] * width)}]"]
    lines += [f"{indent}zz_l{n}: &l{n} [{', '.join([f'*l{n - 1}'] * width)}]" for n in range(1, levels)]
    return "\n".join(lines)


@pytest.fixture(scope="module")
def real_config(tmp_path_factory) -> str:
    text = _physgs_config(tmp_path_factory.mktemp("cfg")).read_text()
    assert _DP in text
    return text


def test_a_real_config_is_far_inside_the_budgets(real_config, tmp_path):
    path = tmp_path / "config.yml"
    path.write_text(real_config)
    assert real_config.count("*id") < MAX_ALIASES // 2
    assert load_config_tree(path).method_name == "physgs-lite"
    assert load_config_yaml(path).method_name == "physgs-lite"


@pytest.mark.parametrize("levels,width,what", [
    (10, 9, "aliases"),  # the file: 81 aliases, 9**10 nodes
    (5, 12, "nodes"),  # 48 aliases, under the alias budget, 12**5 = 248832 nodes expanded
])  # fmt: skip
@pytest.mark.parametrize("dataparser", ["physgs_nerfstudio.nerfstudio.dataparser.PhysGSDataParserConfig",
                                        "nerfstudio.data.dataparsers.nerfstudio_dataparser.NerfstudioDataParserConfig"])
def test_an_alias_bomb_is_refused_at_once_with_one_line(real_config, tmp_path, levels, width, what, dataparser):
    assert (levels - 1) * width <= MAX_ALIASES or what == "aliases"
    assert width**levels > MAX_EXPANDED_NODES
    text = real_config.replace("physgs_nerfstudio.nerfstudio.dataparser.PhysGSDataParserConfig", dataparser)
    path = tmp_path / "config.yml"
    path.write_text(text.replace(f"_target: {_DP}", f"_target: {_DP}\n{_bomb(levels, width)}"))
    for load in (load_config_tree, load_config_yaml):
        t0 = time.perf_counter()
        with pytest.raises(UnsafeConfigError) as ei:
            load(path)
        assert time.perf_counter() - t0 < 5.0
        msg = str(ei.value)
        assert "\n" not in msg and str(path) in msg and "alias bomb" in msg and what in msg, msg


@pytest.mark.parametrize("target", ["nerfstudio.utils.writer.TensorboardWriter", "nerfstudio.engine.trainer.Trainer",
                                    "nerfstudio.data.dataparsers.nerfstudio_dataparser.Nerfstudio"])
def test_a_dataparser_target_of_another_class_is_refused_before_anything_is_built(real_config, tmp_path,
                                                                                  monkeypatch, target):
    path = tmp_path / "config.yml"
    path.write_text(real_config.replace(_DP, f"!!python/name:{target} ''"))
    monkeypatch.chdir(tmp_path)
    with pytest.raises(UnsafeConfigError) as ei:
        load_config_yaml(path)
    assert target in str(ei.value) and "PhysGSDataParser" in str(ei.value)
    tree = load_config_tree(path)  # names only: accepted; its dataparser is refused before it is built
    with pytest.raises(UnsafeConfigError) as ei:
        _checked_dataparser(tree.pipeline.datamanager.dataparser)
    assert target in str(ei.value) and "\n" not in str(ei.value)
    with pytest.raises(UnsafeConfigError):
        tree.build()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["config.yml"]  # no writer's folders


def test_only_the_allowed_dataparser_config_is_built(real_config, tmp_path):
    nerfstudio_dp = "nerfstudio.data.dataparsers.nerfstudio_dataparser.NerfstudioDataParserConfig"
    path = tmp_path / "config.yml"
    path.write_text(real_config.replace("physgs_nerfstudio.nerfstudio.dataparser.PhysGSDataParserConfig", nerfstudio_dp)
                    .replace(_DP, "!!python/name:nerfstudio.data.dataparsers.nerfstudio_dataparser.Nerfstudio ''"))
    tree = load_config_tree(path)
    with pytest.raises(UnsafeConfigError) as ei:
        _checked_dataparser(tree.pipeline.datamanager.dataparser)
    assert "refused dataparser " + nerfstudio_dp in str(ei.value)
    good = tmp_path / "good.yml"
    good.write_text(real_config)
    built = _checked_dataparser(load_config_tree(good).pipeline.datamanager.dataparser)
    assert type(built).__name__ == "PhysGSDataParserConfig" and built._target.__name__ == "PhysGSDataParser"


def test_export_of_a_crafted_target_is_one_line_and_builds_nothing(real_config, tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yml").write_text(real_config.replace(_DP, "!!python/name:nerfstudio.utils.writer.TensorboardWriter ''"))
    env = dict(os.environ, PYTHONPATH=str(REPO), PYTHONWARNINGS="ignore")
    proc = subprocess.run([sys.executable, "-m", "physgs_nerfstudio.cli", "export", "--load-config",
                           str(run / "config.yml"), "--output-dir", "out"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=120, check=False)  # fmt: skip
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "TensorboardWriter" in proc.stderr.strip().splitlines()[-1]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
