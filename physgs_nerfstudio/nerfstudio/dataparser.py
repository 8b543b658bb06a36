"""Nerfstudio dataparser that also finds each frame's material map and reads `materials.json`.

Thin subclass of nerfstudio's `Nerfstudio` dataparser: the frames, split, poses, downscaled image folders
and seed points are nerfstudio's. On top it returns, in `DataparserOutputs.metadata`:

- `material_filenames`, `material_confidence_filenames`: one entry per image of the split (None where the
  frame has no map: such images train RGB only),
- `material_legend`: the parsed `materials.json` (`legend.MaterialLegend`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from nerfstudio.data.dataparsers.base_dataparser import DataparserOutputs
from nerfstudio.data.dataparsers.nerfstudio_dataparser import Nerfstudio, NerfstudioDataParserConfig

from ..runfiles.legend import MATERIALS_FILENAME, check_material_paths, frame_material_maps, load_legend


@dataclass
class PhysGSDataParserConfig(NerfstudioDataParserConfig):
    """Nerfstudio dataset plus the material maps and `materials.json` written by `physgs perceive`."""

    _target: type = field(default_factory=lambda: PhysGSDataParser)
    load_3D_points: bool = True
    """Seed the Gaussians from the dataset's point cloud (`ply_file_path`), as splatfacto does."""
    materials_file: Path = Path(MATERIALS_FILENAME)
    """Material legend and per-material property posteriors, relative to the dataset root."""


@dataclass
class PhysGSDataParser(Nerfstudio):
    """`Nerfstudio` dataparser + material maps (see module doc)."""

    config: PhysGSDataParserConfig

    def _data_dir_and_meta(self) -> tuple[Path, dict]:
        if self.config.data.suffix == ".json":
            return self.config.data.parent, json.loads(self.config.data.read_text())
        return self.config.data, json.loads((self.config.data / "transforms.json").read_text())

    def _generate_dataparser_outputs(self, split: str = "train") -> DataparserOutputs:
        outputs = super()._generate_dataparser_outputs(split)
        data_dir, meta = self._data_dir_and_meta()

        frames = meta.get("frames", [])
        # nerfstudio sorts and splits the frames; match them back through the resolved image filename.
        by_image: dict[Path, dict] = {self._get_fname(Path(f["file_path"]), data_dir): f for f in frames}
        check_material_paths(frames, data_dir)
        legend = load_legend(data_dir / self.config.materials_file)
        material_files, confidence_files = frame_material_maps(by_image, outputs.image_filenames, data_dir)

        outputs.metadata.update(
            material_filenames=material_files,
            material_confidence_filenames=confidence_files,
            material_legend=legend,
        )
        return outputs

    def _load_3D_points(self, ply_file_path: Path, transform_matrix: torch.Tensor, scale_factor: float):
        """Seed points from a PLY (x, y, z and optional red, green, blue), read with plyfile.

        Same transform as nerfstudio's loader, which needs open3d (and its system libraries) only for this.
        """
        from plyfile import PlyData

        vertex = PlyData.read(str(ply_file_path))["vertex"]
        if vertex.count == 0:
            return None
        xyz = torch.from_numpy(np.stack([vertex[c] for c in ("x", "y", "z")], axis=-1).astype(np.float32))
        names = vertex.data.dtype.names
        if all(c in names for c in ("red", "green", "blue")):
            rgb = np.stack([vertex[c] for c in ("red", "green", "blue")], axis=-1)
            if rgb.dtype != np.uint8:  # float colours in [0, 1]
                rgb = np.clip(rgb.astype(np.float64) * 255.0, 0, 255)
            rgb = torch.from_numpy(rgb.astype(np.uint8))
        else:
            rgb = torch.full((vertex.count, 3), 128, dtype=torch.uint8)
        xyz = torch.cat([xyz, torch.ones_like(xyz[:, :1])], dim=-1) @ transform_matrix.T * scale_factor
        return {"points3D_xyz": xyz, "points3D_rgb": rgb}
