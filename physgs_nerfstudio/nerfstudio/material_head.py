"""The material head of `PhysGSModel`: what each Gaussian carries for the rendered `material` map.

`PhysGSModelConfig.material_head` picks one (docs/architecture.md, "Material head"):

- "logits": K trainable logits per Gaussian (`material_logits` [N, K], with Adam moments), rendered as K channels
  every `material_every` steps and trained with the confidence-weighted cross-entropy. gsplat pads K channels to
  the next size it has a kernel for (K = 18 -> 32).
- "latent": d trainable features per Gaussian (`material_features` [N, d], d = `material_latent_dim`) rendered
  as d channels and decoded per pixel into K logits by a Linear d -> K (`material_decoder`, its own optimizer
  param group); same loss, same schedule. A linear decoder commutes with alpha compositing, so this is a rank-d
  factorisation of the logits: d = 8 is a channel count gsplat renders unpadded.
- "lifted": nothing trainable and no material pass. The map is the argmax of the composited Dirichlet predictive
  alpha / sum(alpha) of the lifted evidence (`dirichlet_evidence`, which every head keeps for the physical
  properties). The predictive rather than the raw evidence: each Gaussian then contributes a probability vector
  (bounded, tempered by the prior where it was seen in few views), so a large Gaussian seen in many views does
  not outvote the pixel's other Gaussians, and prior-only Gaussians add the same amount to every material (they
  never change the argmax). Before the first lifting there is no material (label 0).

A checkpoint carries the head it was trained with (`checkpoint_head`): the model switches to it on load, so a
run written by one head loads under a config (or default) naming another.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Literal

import torch
from jaxtyping import Float
from torch import Tensor

from ..runfiles.keys import EVIDENCE_KEY, FEATURES_KEY, LOGITS_KEY

MaterialHead = Literal["logits", "latent", "lifted"]
HEADS: tuple[MaterialHead, ...] = ("logits", "latent", "lifted")
HEAD_TENSORS: dict[str, str | None] = {"logits": LOGITS_KEY, "latent": FEATURES_KEY, "lifted": None}
"""the trainable per-Gaussian tensor of each head (in `gauss_params`), None for none"""


def head_width(head: str, num_materials: int, latent_dim: int) -> int:
    """Channels of the head's per-Gaussian tensor (0: none)."""
    if head not in HEADS:
        raise ValueError(f"material_head must be one of {HEADS}, got {head!r}")
    return {"logits": num_materials, "latent": latent_dim, "lifted": 0}[head]


def checkpoint_head(state: Mapping[str, Tensor], prefix: str = "gauss_params.") -> tuple[str, int] | None:
    """The head a checkpoint's model state was written with and its tensor's width, or None when the state has
    no physgs Gaussians (nothing to decide)."""
    for head, key in HEAD_TENSORS.items():
        if key is not None and f"{prefix}{key}" in state:
            return head, int(state[f"{prefix}{key}"].shape[1])
    if f"{prefix}{EVIDENCE_KEY}" in state:
        return "lifted", 0
    return None


def predictive(alpha: Float[Tensor, "n k"]) -> Float[Tensor, "n k"]:
    """Per-Gaussian Dirichlet predictive alpha / sum(alpha): the channels the "lifted" head composites."""
    return alpha / alpha.sum(-1, keepdim=True).clamp_min(1e-12)


def make_decoder(latent_dim: int, num_materials: int) -> torch.nn.Linear:
    """The "latent" head's per-pixel decoder, features [..., d] -> logits [..., K]."""
    if latent_dim < 1:
        raise ValueError(f"material_latent_dim must be >= 1, got {latent_dim}")
    return torch.nn.Linear(latent_dim, num_materials)
