"""nerfstudio integration: material-map data handling, `PhysGSModel` (splatfacto-big + property head) and
`PhysGSPipeline` (lifts the material maps onto the model at set steps)."""

import importlib
from typing import Any

_WHERE = {  # name -> submodule; imported on first use, so that `.dataparser` alone stays light (an export reads
    # the dataset through the dataparser and never imports the model, i.e. splatfacto and the viewer); the legend is
    # the run files' (physgs_nerfstudio.runfiles.legend)
    "PhysGSDatamanager": "datamanager", "PhysGSDatamanagerConfig": "datamanager",
    "PhysGSDataParser": "dataparser", "PhysGSDataParserConfig": "dataparser", "PhysGSDataset": "dataset",
    "MaterialLegend": "..runfiles.legend", "MaterialsFileError": "..runfiles.legend", "load_legend": "..runfiles.legend",
    "MaterialEvidence": "model", "PhysGSModel": "model", "PhysGSModelConfig": "model",
    "PhysGSPipeline": "pipeline", "PhysGSPipelineConfig": "pipeline", "lift_material_maps": "pipeline",
}  # fmt: skip


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    where = _WHERE[name]
    return getattr(importlib.import_module(where if where.startswith(".") else f".{where}", __name__), name)


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
