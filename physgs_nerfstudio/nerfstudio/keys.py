"""Names of PhysGSModel's per-Gaussian tensors in ``gauss_params`` and the camera convention change, in a
leaf module: the model, the lifting pass and the exporters import them from here."""

from __future__ import annotations

import torch
from jaxtyping import Float
from torch import Tensor

EVIDENCE_KEY = "dirichlet_evidence"
WEIGHT_KEY = "lifting_weight"
LABELLED_KEY = "labelled_weight"
NON_TRAINABLE_KEYS = (EVIDENCE_KEY, WEIGHT_KEY, LABELLED_KEY)
LOGITS_KEY = "material_logits"


def world_to_camera(c2w: Float[Tensor, "C 3 4"]) -> Float[Tensor, "C 4 4"]:
    """nerfstudio camera-to-world (OpenGL axes) -> gsplat world-to-camera (OpenCV axes)."""
    flip = torch.tensor([1.0, -1.0, -1.0], device=c2w.device, dtype=c2w.dtype)
    rot = c2w[:, :3, :3] * flip  # flip camera y and z axes
    rot_t = rot.transpose(1, 2)
    out = torch.eye(4, device=c2w.device, dtype=c2w.dtype).repeat(c2w.shape[0], 1, 1)
    out[:, :3, :3] = rot_t
    out[:, :3, 3:4] = -rot_t @ c2w[:, :3, 3:4]
    return out
