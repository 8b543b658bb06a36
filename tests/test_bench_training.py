"""benchmarks/gpu/bench_training.py's pieces that run without a GPU: method overrides and static memory."""

from __future__ import annotations

import pytest
import torch
from helpers.benchmarks import load_benchmark

from method_configs.physgs_config import physgs_trainer_config


@pytest.fixture(scope="module")
def bench():
    return load_benchmark("gpu/bench_training.py", "physgs_bench_training")


def test_overrides_name_model_then_pipeline_fields(bench) -> None:
    config = physgs_trainer_config()
    bench.apply_overrides(config, "material_head=lifted,material_every=4,lifting_every=500,lifting_step=7,"
                                  "lift_at_end=false,dirichlet_alpha0=0.5")  # fmt: skip
    model, pipe = config.pipeline.model, config.pipeline
    assert (model.material_head, model.material_every, model.dirichlet_alpha0) == ("lifted", 4, 0.5)
    assert (pipe.lifting_every, pipe.lifting_step, pipe.lift_at_end) == (500, 7, False)
    with pytest.raises(SystemExit, match="neither a model nor a pipeline"):
        bench.apply_overrides(config, "no_such_field=1")
    with pytest.raises(SystemExit, match="key=value"):
        bench.apply_overrides(config, "material_head")


def test_static_memory_counts_parameters_and_adam_moments(bench) -> None:
    class Model(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.gauss_params = torch.nn.ParameterDict({
                "means": torch.nn.Parameter(torch.zeros(1000, 3)),
                "evidence": torch.nn.Parameter(torch.zeros(1000, 4), requires_grad=False),
            })  # fmt: skip

    model = Model()
    opt = torch.optim.Adam([model.gauss_params["means"]])
    model.gauss_params["means"].grad = torch.ones(1000, 3)
    opt.step()
    mem = bench.static_memory(model, {"means": opt})
    mb = 2**20
    assert mem["params_mb"] == pytest.approx(1000 * 7 * 4 / mb)
    moments = 2 * 1000 * 3 * 4  # exp_avg + exp_avg_sq (+ a scalar step)
    assert mem["optimizer_mb"] == pytest.approx(moments / mb, rel=1e-3)
    assert mem["per_gaussian_tensor"]["evidence"] == {"param_mb": 1000 * 4 * 4 / mb, "optimizer_mb": 0.0}


def test_ratios_are_taken_within_each_round_and_their_median_reported(bench) -> None:
    def row(ms, mb):
        return {"iter_s_median": ms / 1000, "peak_mem_mb": mb}

    rounds = [[row(10.0, 300.0), row(11.0, 360.0)],
              [row(12.0, 300.0), row(12.6, 330.0)],
              [row(11.0, 300.0), {"error": "died"}]]  # fmt: skip
    out = bench.round_ratios(rounds)
    assert out["ratio_vs_first_by_round"][0] == [1.0, 1.0, 1.0]
    assert out["ratio_vs_first_by_round"][1][:2] == pytest.approx([1.1, 1.05])
    assert out["ratio_vs_first_by_round"][1][2] is None  # the failed run is no ratio
    assert out["ratio_vs_first"] == pytest.approx([1.0, 1.075])  # the median of 1.1 and 1.05, not of the times
    assert out["peak_mem_ratio_vs_first"] == pytest.approx([1.0, 1.15])
