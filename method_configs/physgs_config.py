"""`ns-train physgs` and `ns-train physgs-lite` (registered through the `nerfstudio.method_configs` entry point):
one preset, `trainer_config(preset)`, and the overrides that make each method (`Preset`).

- physgs (`PHYSGS`): splatfacto-big's settings and optimizers + the paper's random scale 2.0 / random
  background + the material / property head (PhysGSModel), lifting in PhysGSPipeline, 30000 iterations
  (the paper trained 20000).
- physgs-lite (`PHYSGS_LITE`): the same method sized for a CPU: fewer Gaussians and iterations, full-resolution
  training, densification every 20 steps from step 30 to 120, lifting at step 120 and at the last iteration.
  E.g. `ns-train physgs-lite --data D --machine.device-type cpu --max-num-iterations 60`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from nerfstudio.configs.base_config import ViewerConfig
from nerfstudio.engine.optimizers import AdamOptimizerConfig
from nerfstudio.engine.trainer import TrainerConfig
from nerfstudio.plugins.types import MethodSpecification

from physgs_nerfstudio.nerfstudio.datamanager import PhysGSDatamanagerConfig
from physgs_nerfstudio.nerfstudio.dataparser import PhysGSDataParserConfig
from physgs_nerfstudio.nerfstudio.model import PhysGSModelConfig
from physgs_nerfstudio.nerfstudio.pipeline import PhysGSPipelineConfig, hand_in_geometry_step
from physgs_nerfstudio.nerfstudio.schedulers import FloatExponentialDecaySchedulerConfig


def _optimizers(max_steps: int, material_lr: float) -> dict[str, dict]:
    """splatfacto-big's optimizers (nerfstudio 1.1.5) plus those of the material heads (the groups of the head
    a run does not use are never built)."""
    return {
        "means": {
            "optimizer": AdamOptimizerConfig(lr=1.6e-4, eps=1e-15),
            "scheduler": FloatExponentialDecaySchedulerConfig(lr_final=1.6e-6, max_steps=max_steps),
        },
        "features_dc": {"optimizer": AdamOptimizerConfig(lr=0.0025, eps=1e-15), "scheduler": None},
        "features_rest": {"optimizer": AdamOptimizerConfig(lr=0.0025 / 20, eps=1e-15), "scheduler": None},
        "opacities": {"optimizer": AdamOptimizerConfig(lr=0.05, eps=1e-15), "scheduler": None},
        "scales": {"optimizer": AdamOptimizerConfig(lr=0.005, eps=1e-15), "scheduler": None},
        "quats": {"optimizer": AdamOptimizerConfig(lr=0.001, eps=1e-15), "scheduler": None},
        "material_logits": {"optimizer": AdamOptimizerConfig(lr=material_lr, eps=1e-15), "scheduler": None},
        # the "latent" material head (PhysGSModelConfig.material_head): per-Gaussian features and their decoder
        "material_features": {"optimizer": AdamOptimizerConfig(lr=material_lr, eps=1e-15), "scheduler": None},
        "material_decoder": {"optimizer": AdamOptimizerConfig(lr=material_lr, eps=1e-15), "scheduler": None},
        "camera_opt": {
            "optimizer": AdamOptimizerConfig(lr=1e-4, eps=1e-15),
            "scheduler": FloatExponentialDecaySchedulerConfig(
                lr_final=5e-7, max_steps=max_steps, warmup_steps=1000, lr_pre_warmup=0
            ),
        },
        "bilateral_grid": {
            "optimizer": AdamOptimizerConfig(lr=5e-3, eps=1e-15),
            "scheduler": FloatExponentialDecaySchedulerConfig(
                lr_final=1e-4, max_steps=max_steps, warmup_steps=1000, lr_pre_warmup=0
            ),
        },
    }


@dataclass(frozen=True)
class Preset:
    """What one method changes in the physgs preset (`trainer_config`)."""

    method_name: str = "physgs"
    description: str = ""
    max_num_iterations: int = 30000
    steps_per_save: int = 2000
    steps_per_eval_all_images: int = 1000
    material_lr: float = 0.005
    """learning rate of the per-Gaussian material logits (or latent features and their decoder)"""
    model: dict[str, Any] = field(default_factory=dict)
    """PhysGSModelConfig fields that differ from its defaults (splatfacto-big + the property head)"""


PHYSGS = Preset(
    description="PhysGS: splatfacto-big + Bayesian material / physical-property head (needs `physgs perceive`)."
)
PHYSGS_LITE = Preset(
    method_name="physgs-lite",
    description="PhysGS sized for CPU: few Gaussians, 300 iterations, early densification and lifting.",
    max_num_iterations=300,
    steps_per_save=100,
    steps_per_eval_all_images=1_000_000,
    material_lr=0.02,
    model={
        "num_random": 3000,
        "num_downscales": 0,
        "sh_degree": 1,
        "sh_degree_interval": 100,
        "warmup_length": 30,
        "refine_every": 20,
        "stop_split_at": 120,
        "densify_grad_thresh": 0.001,
        "stop_screen_size_at": 0,  # no screen-size splitting: small images would split everything
        "reset_alpha_every": 1000,
        "cull_alpha_thresh": 0.05,
        "material_loss_weight": 0.2,
        "material_every": 4,  # CPU-sized runs are short: supervise the material head more often
    },
)


def trainer_config(preset: Preset = PHYSGS) -> TrainerConfig:
    """The physgs preset with `preset`'s overrides."""
    return TrainerConfig(
        method_name=preset.method_name,
        steps_per_eval_image=100,
        steps_per_eval_batch=0,
        steps_per_save=preset.steps_per_save,
        steps_per_eval_all_images=preset.steps_per_eval_all_images,
        max_num_iterations=preset.max_num_iterations,
        mixed_precision=False,
        pipeline=PhysGSPipelineConfig(
            datamanager=PhysGSDatamanagerConfig(
                dataparser=PhysGSDataParserConfig(load_3D_points=True),
                cache_images_type="uint8",
            ),
            model=PhysGSModelConfig(**preset.model),
        ),
        optimizers=_optimizers(preset.max_num_iterations, material_lr=preset.material_lr),
        viewer=ViewerConfig(num_rays_per_chunk=1 << 15),
        vis="viewer",
    )


def physgs_trainer_config() -> TrainerConfig:
    return trainer_config(PHYSGS)


def physgs_lite_trainer_config() -> TrainerConfig:
    return trainer_config(PHYSGS_LITE)


def _precompute_geometry(config_path: Any, device: str) -> Any:
    """The end-of-run geometry step of training (PhysGSPipelineConfig.precompute_geometry): the exporter's, imported
    when a run ends (it is not needed before)."""
    from physgs_nerfstudio.export.run import precompute_geometry

    return precompute_geometry(config_path, device)


hand_in_geometry_step(_precompute_geometry)

physgs_method = MethodSpecification(config=physgs_trainer_config(), description=PHYSGS.description)
physgs_lite_method = MethodSpecification(config=physgs_lite_trainer_config(), description=PHYSGS_LITE.description)
