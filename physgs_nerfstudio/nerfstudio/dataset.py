"""Dataset returning each image together with its material label map and confidence.

Batch keys added to nerfstudio's `InputDataset.get_data` dict (both uint8, `[H, W, 1]`, the image's size):

- `material`: label id per pixel, 0 = unknown (no loss, no evidence), 1..K = `materials.json` ids,
- `material_confidence`: the perception confidence * 255.

Maps are resized to the image with nearest-neighbour sampling, which covers nerfstudio's downscaled image
folders (`images_2/`, ... while the maps stay at full resolution under `materials/`) and the datamanager's
`camera_res_scale_factor`. Images without a map get all-zero maps, so they train RGB only.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from jaxtyping import UInt8
from nerfstudio.data.datasets.base_dataset import InputDataset
from PIL import Image
from torch import Tensor

from ..runfiles.legend import PERCEIVE_HINT, MaterialsFileError


def load_label_png(path: Path, height: int, width: int) -> UInt8[Tensor, "h w 1"]:
    """An 8-bit single-channel PNG resized (nearest) to height x width."""
    from ..image_files import BadImage, open_image

    try:
        with open_image(path, what=f"material map {path}") as opened:
            img = opened.copy()
    except BadImage as err:
        raise MaterialsFileError(f"{err}. {PERCEIVE_HINT}") from None
    if img.mode not in ("L", "P", "I", "I;16"):
        raise MaterialsFileError(
            f"{path}: a material/confidence map must be a single-channel PNG, got mode {img.mode}"
        )
    if img.size != (width, height):
        w0, h0 = img.size
        if abs(w0 / h0 - width / height) > 0.02:
            raise MaterialsFileError(
                f"{path}: map is {w0}x{h0} but its image is {width}x{height} (different aspect ratio)"
            )
        img = img.resize((width, height), resample=Image.Resampling.NEAREST)
    arr = np.asarray(img)
    if arr.max(initial=0) > 255:
        raise MaterialsFileError(f"{path}: values above 255 in an 8-bit map")
    return torch.from_numpy(arr.astype(np.uint8))[..., None]


class PhysGSDataset(InputDataset):
    """`InputDataset` + `material` / `material_confidence` (see module doc)."""

    def __init__(self, dataparser_outputs, scale_factor: float = 1.0):
        super().__init__(dataparser_outputs, scale_factor)
        meta = dataparser_outputs.metadata
        if "material_filenames" not in meta or "material_legend" not in meta:
            raise MaterialsFileError(
                "PhysGSDataset needs the physgs dataparser (material_filenames/material_legend in its metadata). "
                + PERCEIVE_HINT
            )
        self.material_filenames: list[Path | None] = meta["material_filenames"]
        self.material_confidence_filenames: list[Path | None] = meta["material_confidence_filenames"]
        self.num_materials: int = meta["material_legend"].num_materials

    def get_metadata(self, data: dict) -> dict:
        idx = data["image_idx"]
        h, w = data["image"].shape[:2]
        path = self.material_filenames[idx]
        if path is None:
            zeros = torch.zeros(h, w, 1, dtype=torch.uint8)
            return {"material": zeros, "material_confidence": zeros.clone()}
        labels = load_label_png(path, h, w)
        if int(labels.max()) > self.num_materials:
            raise MaterialsFileError(
                f"{path}: label {int(labels.max())} but materials.json lists {self.num_materials} materials"
            )
        conf_path = self.material_confidence_filenames[idx]
        if conf_path is None:  # no confidence map: full confidence where labelled
            conf = torch.where(labels > 0, 255, 0).to(torch.uint8)
        else:
            conf = load_label_png(conf_path, h, w)
        return {"material": labels, "material_confidence": conf}
