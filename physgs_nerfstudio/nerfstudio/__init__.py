"""nerfstudio integration: material-map data handling, `PhysGSModel` (splatfacto-big + property head) and
`PhysGSPipeline` (lifts the material maps onto the model at set steps)."""

from .datamanager import PhysGSDatamanager, PhysGSDatamanagerConfig
from .dataparser import PhysGSDataParser, PhysGSDataParserConfig
from .dataset import PhysGSDataset
from .legend import MaterialLegend, MaterialsFileError, load_legend
from .model import MaterialEvidence, PhysGSModel, PhysGSModelConfig
from .pipeline import PhysGSPipeline, PhysGSPipelineConfig, lift_material_maps

__all__ = [
    "MaterialEvidence",
    "MaterialLegend",
    "MaterialsFileError",
    "PhysGSDataParser",
    "PhysGSDataParserConfig",
    "PhysGSDatamanager",
    "PhysGSDatamanagerConfig",
    "PhysGSDataset",
    "PhysGSModel",
    "PhysGSModelConfig",
    "PhysGSPipeline",
    "PhysGSPipelineConfig",
    "lift_material_maps",
    "load_legend",
]
