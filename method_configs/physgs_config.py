"""Placeholder method registration (replaced by the physgs method)."""
from nerfstudio.data.datamanagers.full_images_datamanager import FullImageDatamanagerConfig
from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig
from nerfstudio.engine.trainer import TrainerConfig
from nerfstudio.models.splatfacto import SplatfactoModelConfig
from nerfstudio.pipelines.base_pipeline import VanillaPipelineConfig
from nerfstudio.plugins.types import MethodSpecification


def _config(name: str) -> TrainerConfig:
    return TrainerConfig(
        method_name=name,
        pipeline=VanillaPipelineConfig(
            datamanager=FullImageDatamanagerConfig(dataparser=NerfstudioDataParserConfig()),
            model=SplatfactoModelConfig(),
        ),
    )


physgs_method = MethodSpecification(config=_config("physgs"), description="PhysGS (placeholder)")
physgs_lite_method = MethodSpecification(config=_config("physgs-lite"), description="PhysGS lite (placeholder)")
