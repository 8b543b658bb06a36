"""`ns-train physgs` and `ns-train physgs-lite` (registered through the `nerfstudio.method_configs` entry point).

- physgs: splatfacto-big's settings and optimizers + the paper's random scale 2.0 / random background + the
  material / property head (PhysGSModel), 30000 iterations (the paper trained 20000).
- physgs-lite: the same method sized for a CPU: fewer Gaussians and iterations, full-resolution training,
  densification every 20 steps from step 60 to 100, lifting at step 120 and at the last iteration. E.g.
  `ns-train physgs-lite --data D --machine.device-type cpu --max-num-iterations 60`.
"""

from __future__ import annotations

from nerfstudio.configs.base_config import ViewerConfig
from nerfstudio.engine.optimizers import AdamOptimizerConfig
from nerfstudio.engine.trainer import TrainerConfig
from nerfstudio.plugins.types import MethodSpecification

from physgs_nerfstudio.nerfstudio.datamanager import PhysGSDatamanagerConfig
from physgs_nerfstudio.nerfstudio.dataparser import PhysGSDataParserConfig
from physgs_nerfstudio.nerfstudio.model import PhysGSModelConfig
from physgs_nerfstudio.nerfstudio.pipeline import PhysGSPipelineConfig
from physgs_nerfstudio.nerfstudio.schedulers import FloatExponentialDecaySchedulerConfig


def _optimizers(max_steps: int, material_lr: float) -> dict[str, dict]:
    """splatfacto-big's optimizers (nerfstudio 1.1.5) plus one for the per-Gaussian material logits."""
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


def physgs_trainer_config() -> TrainerConfig:
    return TrainerConfig(
        method_name="physgs",
        steps_per_eval_image=100,
        steps_per_eval_batch=0,
        steps_per_save=2000,
        steps_per_eval_all_images=1000,
        max_num_iterations=30000,
        mixed_precision=False,
        pipeline=PhysGSPipelineConfig(
            datamanager=PhysGSDatamanagerConfig(
                dataparser=PhysGSDataParserConfig(load_3D_points=True),
                cache_images_type="uint8",
            ),
            model=PhysGSModelConfig(),
        ),
        optimizers=_optimizers(30000, material_lr=0.005),
        viewer=ViewerConfig(num_rays_per_chunk=1 << 15),
        vis="viewer",
    )


def physgs_lite_trainer_config() -> TrainerConfig:
    iters = 300
    return TrainerConfig(
        method_name="physgs-lite",
        steps_per_eval_image=100,
        steps_per_eval_batch=0,
        steps_per_save=100,
        steps_per_eval_all_images=1_000_000,
        max_num_iterations=iters,
        mixed_precision=False,
        pipeline=PhysGSPipelineConfig(
            datamanager=PhysGSDatamanagerConfig(
                dataparser=PhysGSDataParserConfig(load_3D_points=True),
                cache_images_type="uint8",
            ),
            model=PhysGSModelConfig(
                num_random=3000,
                num_downscales=0,
                sh_degree=1,
                sh_degree_interval=100,
                warmup_length=30,
                refine_every=20,
                stop_split_at=120,
                densify_grad_thresh=0.001,
                stop_screen_size_at=0,  # no screen-size splitting: small images would split everything
                reset_alpha_every=1000,
                cull_alpha_thresh=0.05,
                material_loss_weight=0.2,
                material_every=4,  # CPU-sized runs are short: supervise the material head more often
            ),
        ),
        optimizers=_optimizers(iters, material_lr=0.02),
        viewer=ViewerConfig(num_rays_per_chunk=1 << 15),
        vis="viewer",
    )


physgs_method = MethodSpecification(
    config=physgs_trainer_config(),
    description="PhysGS: splatfacto-big + Bayesian material / physical-property head (needs `physgs perceive`).",
)
physgs_lite_method = MethodSpecification(
    config=physgs_lite_trainer_config(),
    description="PhysGS sized for CPU: few Gaussians, 300 iterations, early densification and lifting.",
)
