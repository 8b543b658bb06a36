"""PhysGSPipeline's lifting schedule and the model's one entry point for lifted evidence."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch

from physgs_nerfstudio.nerfstudio.model import MaterialEvidence, PhysGSModel
from physgs_nerfstudio.nerfstudio.pipeline import PhysGSPipeline, PhysGSPipelineConfig


def _pipeline(**config) -> tuple[PhysGSPipeline, list[int]]:
    """A pipeline without a datamanager or model (only the schedule runs): `lift` records the step."""
    pipe = PhysGSPipeline.__new__(PhysGSPipeline)  # skips VanillaPipeline.__init__ (data, model)
    pipe.config = PhysGSPipelineConfig(**config)
    lifted: list[int] = []
    freed: list[int] = []  # steps whose parameter gradients were freed (before the lifting)
    pipe._model = SimpleNamespace(config=SimpleNamespace(stop_split_at=15),
                                  zero_grad=lambda set_to_none: freed.append(pipe._step) if set_to_none else None)
    pipe.lift = lambda: lifted.append(pipe._step) if freed[-1:] == [pipe._step] else None  # type: ignore[method-assign]
    return pipe, lifted


def _train(pipe: PhysGSPipeline, start: int, iterations: int) -> None:
    for step in range(start, start + iterations):  # nerfstudio's Trainer.train loop
        pipe._step = step
        pipe._lift_on_schedule(iterations, step)


@pytest.mark.parametrize(
    ("config", "start", "iterations", "expected"),
    [
        ({}, 0, 30, [15, 29]),  # densification end (model's stop_split_at) and the last iteration
        ({"lifting_step": 4}, 0, 30, [4, 29]),
        ({"lift_at_end": False}, 0, 30, [15]),
        ({}, 20, 30, [49]),  # resumed after the lifting step: the last step counts from the resumed start
        ({}, 0, 16, [15]),  # the lifting step is the last iteration: lifted once
        ({"lifting_every": 10}, 0, 30, [10, 15, 20, 29]),  # periodic lifting on top of the others
        ({"lifting_every": 15}, 0, 31, [15, 30]),  # a step that is due twice lifts once
    ],
)
def test_lifting_schedule(config, start, iterations, expected) -> None:
    pipe, lifted = _pipeline(**config)
    _train(pipe, start, iterations)
    assert lifted == expected


def test_set_material_evidence_checks_shapes() -> None:
    model = SimpleNamespace(num_points=4, num_materials=2)  # N = 4 Gaussians, K = 2 materials
    stale = MaterialEvidence(torch.zeros(3, 2), torch.zeros(3, 1), torch.zeros(3, 1), 1)  # lifted before a prune
    with pytest.raises(ValueError, match=r"evidence has shape \(3, 2\), the model has \(4, 2\)"):
        PhysGSModel.set_material_evidence(model, stale)  # type: ignore[arg-type]
