"""nerfstudio integration: material-map data handling and `PhysGSModel` (splatfacto-big + property head)."""

from .datamanager import PhysGSDatamanager, PhysGSDatamanagerConfig
from .dataparser import PhysGSDataParser, PhysGSDataParserConfig
from .dataset import PhysGSDataset
from .legend import MaterialLegend, MaterialsFileError, load_legend
from .model import PhysGSModel, PhysGSModelConfig

__all__ = [
    "MaterialLegend",
    "MaterialsFileError",
    "PhysGSDataParser",
    "PhysGSDataParserConfig",
    "PhysGSDatamanager",
    "PhysGSDatamanagerConfig",
    "PhysGSDataset",
    "PhysGSModel",
    "PhysGSModelConfig",
    "load_legend",
]
