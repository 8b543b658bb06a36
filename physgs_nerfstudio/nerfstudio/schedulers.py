"""Learning-rate schedule whose checkpoints load with `torch.load(weights_only=True)`.

nerfstudio 1.1.5's `ExponentialDecayScheduler` computes its multiplier with numpy, so the optimizer's `lr`
and the scheduler's `_last_lr` become numpy floats; torch >= 2.6 then refuses to load the checkpoint in
`eval_setup` (ns-viewer, ns-eval, ns-export): "Weights only load failed ... numpy.core.multiarray.scalar".
This subclass keeps nerfstudio's schedule and only casts the multiplier to a Python float.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from nerfstudio.engine.schedulers import ExponentialDecayScheduler, ExponentialDecaySchedulerConfig
from torch.optim import Optimizer, lr_scheduler


@dataclass
class FloatExponentialDecaySchedulerConfig(ExponentialDecaySchedulerConfig):
    """nerfstudio's exponential decay with warmup; Python-float learning rates."""

    _target: type = field(default_factory=lambda: FloatExponentialDecayScheduler)


class FloatExponentialDecayScheduler(ExponentialDecayScheduler):
    config: FloatExponentialDecaySchedulerConfig

    def get_scheduler(self, optimizer: Optimizer, lr_init: float) -> lr_scheduler.LRScheduler:
        numpy_multiplier = super().get_scheduler(optimizer, lr_init).lr_lambdas[0]
        return lr_scheduler.LambdaLR(optimizer, lr_lambda=lambda step: float(numpy_multiplier(step)))
