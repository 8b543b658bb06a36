"""The lifting pass of `PhysGSModel` (`PhysGSModel.run_lifting`): training views' material maps onto the
Gaussians. `PhysGSModel.run_lifting` calls it with itself as ``model``; the tensor names come from the
leaf module `keys.py`, so this module does not import `model.py`.
"""

from __future__ import annotations

import torch
from nerfstudio.utils.rich_utils import CONSOLE
from torch import Tensor

from .keys import EVIDENCE_KEY, LABELLED_KEY, WEIGHT_KEY, world_to_camera


@torch.no_grad()
def lift_material_maps(model, datamanager) -> Tensor:
    """Lifts the training views' material maps onto the Gaussians (replaces `dirichlet_evidence`).

    Evidence map of a view: confidence-weighted one-hot of its labels (label 0 contributes nothing);
    `lift_evidence` sums each Gaussian's blending weight times the map over all pixels, and its total
    blending weight (`lifting_weight`) and its weight on labelled pixels (`labelled_weight`, one more
    channel of the same pass), so that `labelled_fraction = labelled_weight / lifting_weight` tells
    Gaussians seen mostly in labelled pixels from those seen mostly in unknown (label 0) pixels.
    """
    from physgs_nerfstudio.lifting import label_evidence_maps, lift_evidence

    cameras, cached = datamanager.material_views("train")
    K = model.num_materials
    means = model.means.detach()
    quats = model.quats.detach()
    scales = torch.exp(model.scales.detach())
    opacities = torch.sigmoid(model.opacities.detach()).squeeze(-1)
    evidence = torch.zeros(model.num_points, K, device=model.device)
    weight = torch.zeros(model.num_points, 1, device=model.device)
    labelled = torch.zeros(model.num_points, 1, device=model.device)
    used = 0
    for idx, data in enumerate(cached):
        labels = data["material"][..., 0].to(model.device).long()  # views without a map still count
        used += int(bool((labels > 0).any()))  # for every Gaussian's total weight (labelled_fraction)
        conf = data["material_confidence"][..., 0].to(model.device).float() / 255.0
        maps = label_evidence_maps(labels[None], conf[None], K)  # [1, H, W, K]
        maps = torch.cat([maps, (labels > 0)[None, ..., None].to(maps)], -1)  # + labelled indicator
        cam = cameras[idx : idx + 1].to(model.device)
        cam.metadata = {"cam_idx": idx}
        c2w = model.camera_optimizer.apply_to_camera(cam)
        lifted = lift_evidence(
            means,
            quats,
            scales,
            opacities,
            world_to_camera(c2w),
            cam.get_intrinsics_matrices().to(model.device),
            int(cam.width.item()),
            int(cam.height.item()),
            maps,
            backend=model.config.rasterize_backend,
            rasterize_mode=model.config.rasterize_mode,
        )
        view_evidence = lifted.evidence[:, :K].to(evidence)
        view_labelled = lifted.evidence[:, K:].to(labelled)
        view_weight = lifted.visibility.to(weight)[:, None]
        if model.config.evidence_per_view == "view":
            seen = view_weight > model.config.min_view_weight
            norm = torch.where(seen, view_weight, torch.full_like(view_weight, float("inf")))
            view_evidence, view_weight = view_evidence / norm, view_weight / norm
            view_labelled = view_labelled / norm
        evidence += view_evidence
        weight += view_weight
        labelled += view_labelled
    evidence = evidence.clamp_min(0.0)
    evidence[evidence.sum(-1) < model.config.min_evidence] = 0.0
    model.gauss_params[EVIDENCE_KEY].data = evidence
    model.gauss_params[WEIGHT_KEY].data = weight
    model.gauss_params[LABELLED_KEY].data = labelled.clamp_min(0.0)
    model._labelled_legacy = False
    model.lifted_views.fill_(used)
    CONSOLE.log(
        f"PhysGS lifting: {used} views -> evidence on {(evidence.sum(-1) > 0).sum().item()}"
        f"/{model.num_points} Gaussians"
    )
    return evidence
