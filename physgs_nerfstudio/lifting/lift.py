"""Lift per-pixel evidence maps onto Gaussians through their alpha-blending weights.

For Gaussian g and view v, the lifted evidence is sum_pixels w_g(p) * e_v(p), where w_g(p) = T * alpha is
g's compositing weight at pixel p. Rendering a feature tensor F [N, C] gives I(p) = sum_g w_g(p) F_g, so
d/dF_g of sum_p <I(p), e_v(p)> is exactly that sum: one backward pass of a C-channel render per view yields
the evidence of every Gaussian at once. Geometry is detached; no gradient reaches it.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Sequence
from typing import NamedTuple

import torch
from jaxtyping import Float, Int
from torch import Tensor

from ..render import Backend, rasterize


class LiftResult(NamedTuple):
    """Unpacks as `(evidence, visibility)`, the tuple of the architecture contract."""

    evidence: Float[Tensor, "N C"]  # sum over views and pixels of weight * evidence
    visibility: Float[Tensor, " N"]  # sum over views and pixels of weight (times pixel_weights if given)


def lift_evidence(
    means: Float[Tensor, "N 3"],
    quats: Float[Tensor, "N 4"],
    scales: Float[Tensor, "N 3"],
    opacities: Float[Tensor, " N"],
    viewmats: Float[Tensor, "V 4 4"],
    Ks: Float[Tensor, "V 3 3"],
    width: int,
    height: int,
    evidence_maps: Float[Tensor, "V H W C"],
    *,
    backend: Backend = "auto",
    channel_chunk: int = 32,
    pixel_weights: Float[Tensor, "V H W"] | None = None,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    eps2d: float = 0.3,
    rasterize_mode: str = "classic",
) -> LiftResult:
    """Per-Gaussian evidence and visibility from V views (activated scales/opacities, as for rendering), summed
    over the views (:func:`lift_views` gives them view by view).

    `pixel_weights` (e.g. a validity mask) multiplies each pixel's evidence and its visibility count.
    Channels are rendered `channel_chunk` at a time (the visibility channel rides along with the first).
    """
    N = means.shape[0]
    evidence = torch.zeros(N, evidence_maps.shape[-1] if evidence_maps.dim() == 4 else 0, dtype=means.dtype,
                           device=means.device)  # fmt: skip
    visibility = torch.zeros(N, dtype=means.dtype, device=means.device)
    for _views, ev, vis in lift_views(means, quats, scales, opacities, viewmats, Ks, width, height, evidence_maps,
                                      backend=backend, channel_chunk=channel_chunk, pixel_weights=pixel_weights,
                                      near_plane=near_plane, far_plane=far_plane, eps2d=eps2d,
                                      rasterize_mode=rasterize_mode):  # fmt: skip
        evidence += ev[0]
        visibility += vis[0]
    return LiftResult(evidence=evidence, visibility=visibility)


def group_views(sizes: Sequence[tuple[int, int]], per_call: int) -> list[list[int]]:
    """Indices of the consecutive runs of at most ``per_call`` views of one size ``(width, height)``, in order: the
    groups that :func:`lift_views` (or any rasterizer call of several cameras) can take in one call."""
    groups: list[list[int]] = []
    for i, size in enumerate(sizes):
        if groups and len(groups[-1]) < per_call and sizes[groups[-1][0]] == size:
            groups[-1].append(i)
        else:
            groups.append([i])
    return groups


def lift_views(
    means: Float[Tensor, "N 3"],
    quats: Float[Tensor, "N 4"],
    scales: Float[Tensor, "N 3"],
    opacities: Float[Tensor, " N"],
    viewmats: Float[Tensor, "V 4 4"],
    Ks: Float[Tensor, "V 3 3"],
    width: int,
    height: int,
    evidence_maps: Float[Tensor, "V H W C"],
    *,
    backend: Backend = "auto",
    channel_chunk: int = 32,
    pixel_weights: Float[Tensor, "V H W"] | None = None,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    eps2d: float = 0.3,
    rasterize_mode: str = "classic",
    views_per_call: int = 1,
) -> Iterator[tuple[range, Float[Tensor, "c N C"], Float[Tensor, "c N"]]]:
    """The lifted evidence view by view: yields ``(views, evidence [c, N, C], visibility [c, N])`` for consecutive
    groups of ``views_per_call`` views, each rendered in one rasterizer call (one camera batch, each camera with
    its own feature rows, so that the gradient keeps the views apart). Several views per call save the per-call
    work (projection, tile sorting, kernel launches) on a GPU; the reference rasterizer loops over cameras anyway.
    """
    N, V = means.shape[0], viewmats.shape[0]
    if evidence_maps.dim() != 4 or evidence_maps.shape[:3] != (V, height, width):
        raise ValueError(
            f"evidence_maps must be [V={V}, H={height}, W={width}, C], got {tuple(evidence_maps.shape)}"
        )
    if Ks.shape != (V, 3, 3) or viewmats.shape != (V, 4, 4):
        raise ValueError(
            f"viewmats must be [V, 4, 4] and Ks [V, 3, 3], got {tuple(viewmats.shape)}, {tuple(Ks.shape)}"
        )
    if pixel_weights is not None and pixel_weights.shape != (V, height, width):
        raise ValueError(
            f"pixel_weights must be [V={V}, H={height}, W={width}], got {tuple(pixel_weights.shape)}"
        )
    if channel_chunk < 1:
        raise ValueError(f"channel_chunk must be >= 1, got {channel_chunk}")
    if views_per_call < 1:
        raise ValueError(f"views_per_call must be >= 1, got {views_per_call}")
    geometry = [t.detach() for t in (means, quats, scales, opacities, viewmats, Ks)]
    means, quats, scales, opacities, viewmats, Ks = geometry
    C = evidence_maps.shape[-1]
    dtype, dev = means.dtype, means.device
    bounds = list(range(0, C + 1, channel_chunk))
    if bounds[-1] != C + 1:
        bounds.append(C + 1)

    for v0 in range(0, V, views_per_call):
        vs = range(v0, min(v0 + views_per_call, V))
        c = len(vs)
        # channels 0..C-1: evidence; channel C: ones (visibility)
        target = torch.cat(
            [evidence_maps[vs.start : vs.stop].to(dtype), torch.ones(c, height, width, 1, dtype=dtype, device=dev)], -1
        )
        if pixel_weights is not None:
            target = target * pixel_weights[vs.start : vs.stop, ..., None].to(dtype)
        evidence = torch.zeros(c, N, C, dtype=dtype, device=dev)
        visibility = torch.zeros(c, N, dtype=dtype, device=dev)
        for lo, hi in itertools.pairwise(bounds):
            # one feature row per camera and Gaussian ([N, ch] when one camera: the call of one view is unchanged)
            shape = (N, hi - lo) if c == 1 else (c, N, hi - lo)
            feats = torch.zeros(*shape, dtype=dtype, device=dev, requires_grad=True)
            with torch.enable_grad():
                render, _, _ = rasterize(
                    means, quats, scales, opacities, feats, viewmats[vs.start : vs.stop], Ks[vs.start : vs.stop],
                    width, height, near_plane=near_plane, far_plane=far_plane, eps2d=eps2d, packed=False,
                    rasterize_mode=rasterize_mode, backend=backend,
                )  # fmt: skip
                (grad,) = torch.autograd.grad((render * target[..., lo:hi]).sum(), feats, allow_unused=True)
            if grad is None:  # nothing visible in these views
                continue
            grad = grad.reshape(c, N, hi - lo)
            if hi == C + 1:
                visibility += grad[..., -1]
            top = min(hi, C)
            if top > lo:
                evidence[..., lo:top] += grad[..., : top - lo]
        yield vs, evidence, visibility


def label_evidence_maps(
    labels: Int[Tensor, "V H W"], confidence: Float[Tensor, "V H W"], num_classes: int
) -> Float[Tensor, "V H W K"]:
    """One-hot evidence maps from material label maps (0 = unknown -> no evidence, 1..K = class id)
    scaled by the per-pixel confidence."""
    if labels.shape != confidence.shape:
        raise ValueError(
            f"labels {tuple(labels.shape)} and confidence {tuple(confidence.shape)} differ in shape"
        )
    if labels.dtype.is_floating_point:
        raise TypeError(f"labels must be an integer tensor, got {labels.dtype}")
    if labels.numel() and (int(labels.min()) < 0 or int(labels.max()) > num_classes):
        raise ValueError(f"labels must lie in [0, {num_classes}] (0 = unknown), got [{int(labels.min())}, "
                         f"{int(labels.max())}]")  # fmt: skip
    onehot = torch.nn.functional.one_hot(labels.long(), num_classes + 1)[..., 1:]
    dtype = confidence.dtype if confidence.dtype.is_floating_point else torch.float32
    return onehot.to(dtype) * confidence[..., None].to(dtype)
