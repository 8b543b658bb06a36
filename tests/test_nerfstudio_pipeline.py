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
        ({"lifting_every": 10}, 0, 30, [15, 29]),  # periodic liftings are previews: none without a viewer
        ({"lifting_every": 10, "lifting_every_needs_viewer": False}, 0, 30, [10, 15, 20, 29]),  # on top of the others
        ({"lifting_every": 15, "lifting_every_needs_viewer": False}, 0, 31, [15, 30]),  # due twice: lifts once
    ],
)
def test_lifting_schedule(config, start, iterations, expected) -> None:
    pipe, lifted = _pipeline(**config)
    _train(pipe, start, iterations)
    assert lifted == expected


def test_periodic_liftings_run_with_a_viewer_and_before_a_headless_evaluation(monkeypatch) -> None:
    """With a viewer the `lifting_every` previews run; headless, a skipped one makes the next evaluation lift first
    (once), and an evaluation with nothing skipped does not lift."""
    from nerfstudio.pipelines.base_pipeline import VanillaPipeline

    pipe, lifted = _pipeline(lifting_every=10)
    pipe._viewer = True
    _train(pipe, 0, 30)
    assert lifted == [10, 15, 20, 29]
    monkeypatch.setattr(VanillaPipeline, "get_eval_image_metrics_and_images", lambda self, step: ({}, {}))
    monkeypatch.setattr(VanillaPipeline, "get_average_eval_image_metrics", lambda self, *a: {})
    pipe, lifted = _pipeline(lifting_every=10, lift_at_end=False)
    for step in range(12):
        pipe._step = step
        pipe._lift_on_schedule(40, step)
    assert lifted == []  # step 10's preview skipped
    pipe.lift = lambda: lifted.append(pipe._step)  # type: ignore[method-assign]
    pipe.get_eval_image_metrics_and_images(12)
    pipe.get_average_eval_image_metrics(12)
    assert lifted == [11]  # one lifting, before the first evaluation
    pipe._step = 13
    pipe.get_eval_image_metrics_and_images(13)
    assert lifted == [11]


def test_set_material_evidence_checks_shapes() -> None:
    model = SimpleNamespace(num_points=4, num_materials=2)  # N = 4 Gaussians, K = 2 materials
    stale = MaterialEvidence(torch.zeros(3, 2), torch.zeros(3, 1), torch.zeros(3, 1), 1)  # lifted before a prune
    with pytest.raises(ValueError, match=r"evidence has shape \(3, 2\), the model has \(4, 2\)"):
        PhysGSModel.set_material_evidence(model, stale)  # type: ignore[arg-type]
