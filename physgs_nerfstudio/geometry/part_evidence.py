"""What perception said per mask, assigned to the 3-D parts; and each part's material fused from it.

A part is one piece of one material: perception's masks (one VLM answer each, a handful of candidate materials
with confidences) are the evidence about it, view by view. Observation ``o`` (a candidate of material ``c`` with
confidence ``p`` for a mask of level weight ``l``) concerns part ``s`` with share ``share_os``: the share of the
mask's pixels where ``s`` is the visible surface (a z-buffer of the solid's boundary voxels in the mask's view,
:func:`physgs_nerfstudio.geometry.structure.part_maps`).

**A part's material** is the Dirichlet-Categorical fusion of the paper, done once per 3-D part instead of per
Gaussian: ``alpha_s = alpha0 + lambda sum_o l_o p_o share_os onehot(c_o)``, with the model's own prior
``alpha0`` and evidence strength ``lambda`` (materials.json). Its mixture weights are the field's (dominance
probability by default, :func:`physgs_nerfstudio.bayes.mixture.material_mixture_weights`).

Why not the mean of the part's Gaussians' posteriors (:func:`.parts.pooled_part_alpha`, what a part no observation
reaches keeps): each Gaussian's lifted
evidence is its share of a view's answer, a fraction of one observation, so the mean Gaussian of a part holds
the evidence of about one view, not of the 10-16 views that saw the part. With K candidate materials in a scene
(28 for the generated dumbbell) and a prior of 1 per material, that posterior is near the prior: the dominance
weights spread about half the part's mass over materials that no view named, and the part's density is pulled
towards the mean density of the whole candidate list (the dumbbell's cast iron came out at 0.45 cast iron,
0.6x its density). The views' answers, counted once per view and part, are the evidence the fusion is
defined on.

**A part that no observation reaches** (summed weight below ``min_part_observation``: hidden in every view, or only
in a geometry variant) has no evidence of its own, neither for its material nor for being hollow or solid. It is
a piece of the carved solid that the material split cut off: the filled inside of a closed box whose nearest
labelled surface named another material, a seam between two labelled regions, a sliver that only a looser
carving keeps. :func:`absorb_unobserved` gives its voxels to the observed part nearest each of them (the nearest
observed surface decides, as it does for a voxel's material), within the same connected piece of the solid.
Fused on their own, such parts would take their Gaussians' weak evidence and the structure prior (hollow with
probability about 0.6): a closed 4 mm cardboard box's filled inside splits into fragments that the prior makes
solid 40% of the time, and the box comes out 1.6-1.9x its mass while its observed walls alone are within 7%. A part with no observed part in its piece of the solid
(a separate fragment) is kept, with the pooled posterior of its Gaussians. Afterwards, touching parts whose
views name the same material (:func:`merge_same_material`) are one part: the voxels that separated them were
absorbed (a second cardboard part of a box, seen by about one view, would keep its own chance of being solid
cardboard).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from .capture import CaptureView, MaskObservation
from .grid import VoxelGrid

__all__ = ["absorb_unobserved", "fuse_part_materials", "merge_same_material", "observation_shares", "part_maps"]


@dataclass
class _Boundary:
    """The solid's boundary voxels (a voxel with an empty 6-neighbour): centres and part ids, for :func:`part_maps`
    in many views."""

    x: Tensor
    pid: Tensor

    @classmethod
    def of(cls, grid: VoxelGrid, parts: np.ndarray, device: torch.device | str = "cpu") -> _Boundary:
        solid = parts >= 0
        inner = np.zeros_like(solid)
        inner[1:-1, 1:-1, 1:-1] = (solid[1:-1, 1:-1, 1:-1] & solid[:-2, 1:-1, 1:-1] & solid[2:, 1:-1, 1:-1]
                                   & solid[1:-1, :-2, 1:-1] & solid[1:-1, 2:, 1:-1] & solid[1:-1, 1:-1, :-2]
                                   & solid[1:-1, 1:-1, 2:])  # fmt: skip
        ijk = np.argwhere(solid & ~inner)
        return cls(grid.centres(torch.from_numpy(ijk)).to(device), torch.from_numpy(parts[tuple(ijk.T)]).to(device))


@torch.no_grad()
def part_maps(grid: VoxelGrid, parts: np.ndarray | _Boundary, view: CaptureView, width: int, height: int
              ) -> np.ndarray:  # fmt: skip
    """int [height, width] id of the part whose boundary voxel is nearest the camera at each pixel (-1: none);
    the view's intrinsics are rescaled to ``width`` x ``height``. ``parts``: the part grid, or its boundary
    computed once for many views."""
    b = parts if isinstance(parts, _Boundary) else _Boundary.of(grid, parts)
    if len(b.pid) == 0:
        return np.full((height, width), -1, np.int64)
    return _part_maps_many(b, [view], [(width, height)])[0].cpu().numpy().reshape(height, width)


@torch.no_grad()
def _part_maps_many(b: _Boundary, views: Sequence[CaptureView], sizes: Sequence[tuple[int, int]],
                    chunk: int = 1 << 25) -> list[Tensor]:  # fmt: skip
    """long [h * w] part id maps (-1: none) of ``views[i]`` at ``sizes[i] = (w, h)``, on the boundary's device:
    :func:`part_maps` of many views in one z-buffer (their pixels laid end to end), the views batched up to
    ``chunk`` voxel-view pairs. One view at a time, the 54 views of a GPU run cost about 0.2 s in small kernels
    and host round trips."""
    dev, dt = b.x.device, b.x.dtype
    out: list[Tensor] = []
    step = max(1, chunk // max(len(b.pid), 1))
    for s0 in range(0, len(views), step):
        vs, sz = views[s0 : s0 + step], sizes[s0 : s0 + step]
        R = torch.stack([v.viewmat[:3, :3] for v in vs]).to(dev, dt)
        t = torch.stack([v.viewmat[:3, 3] for v in vs]).to(dev, dt)
        K = torch.stack([v.K for v in vs]).to(dev, dt)
        W = torch.tensor([w for w, _ in sz], device=dev)
        H = torch.tensor([h for _, h in sz], device=dev)
        sx = torch.tensor([w / v.width for (w, _), v in zip(sz, vs)], device=dev, dtype=dt)[:, None]
        sy = torch.tensor([h / v.height for (_, h), v in zip(sz, vs)], device=dev, dtype=dt)[:, None]
        pc = torch.einsum("vij,bj->vbi", R, b.x) + t[:, None, :]  # [V, B, 3] camera coordinates
        z = pc[..., 2]
        u = (K[:, 0, 0, None] * pc[..., 0] / z.clamp_min(1e-9) + K[:, 0, 2, None]) * sx
        v = (K[:, 1, 1, None] * pc[..., 1] / z.clamp_min(1e-9) + K[:, 1, 2, None]) * sy
        ok = (z > 1e-6) & (u >= 0) & (u < W[:, None]) & (v >= 0) & (v < H[:, None])
        n_pix = W * H
        pix = ((torch.cumsum(n_pix, 0) - n_pix)[:, None] + v.floor().long() * W[:, None] + u.floor().long())[ok]
        zz = z[ok]
        pid = b.pid[None, :].expand(len(vs), -1)[ok]
        best = torch.full((int(n_pix.sum()),), float("inf"), device=dev, dtype=zz.dtype)
        best = best.scatter_reduce(0, pix, zz, reduce="amin")
        front = zz <= best[pix]
        ids = torch.full((int(n_pix.sum()),), -1, dtype=torch.long, device=dev)
        ids[pix[front]] = pid[front]
        out.extend(ids.split(n_pix.tolist()))
    return out


def observation_shares(grid: VoxelGrid, parts: np.ndarray, num_parts: int, views: Sequence[CaptureView],
                       observations: Sequence[MaskObservation], device: torch.device | str = "cpu"
                       ) -> list[tuple[int, np.ndarray]]:  # fmt: skip
    """``(i, share [P])`` for each observation ``i`` whose view is among ``views`` and whose mask covers some part:
    the share of the mask's pixels where each part is the visible surface (module doc). ``parts``: int part id per
    voxel, -1 outside the solid. ``device``: where the part maps are rendered and the masks' pixels counted (the
    splat's: a GPU does all views' maps in one z-buffer, and each view's masks as one product with the map's
    one-hot parts)."""
    by_view = {v.name: v for v in views}
    boundary = _Boundary.of(grid, parts, device)
    wanted: dict[tuple[str, int, int], list[int]] = {}  # (view, h, w) -> its observations
    for i, ob in enumerate(observations):
        if ob.view in by_view and ob.confidence > 0:
            wanted.setdefault((ob.view, *ob.mask.shape), []).append(i)
    if not wanted or len(boundary.pid) == 0:
        return []
    keys = list(wanted)
    maps = _part_maps_many(boundary, [by_view[k[0]] for k in keys], [(k[2], k[1]) for k in keys])
    out: list[tuple[int, np.ndarray]] = []
    for key, ids in zip(keys, maps):
        idx = wanted[key]
        masks = torch.from_numpy(np.stack([observations[i].mask.reshape(-1) for i in idx])).to(ids.device)
        onehot = torch.nn.functional.one_hot(ids + 1, num_parts + 1).to(torch.float32)  # column 0: no part
        counts = (masks.to(torch.float32) @ onehot)[:, 1:].double().cpu().numpy()  # exact below 2^24 pixels
        out.extend((i, c / c.sum()) for i, c in zip(idx, counts) if c.sum() > 0)
    return sorted(out, key=lambda s: s[0])


def fuse_part_materials(shares: Sequence[tuple[int, np.ndarray]], observations: Sequence[MaskObservation],
                        material_names: Sequence[str], num_parts: int, alpha0: float, lam: float
                        ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """float64 ``[P, K]`` Dirichlet posterior per part and float64 ``[P]`` its summed observation weight
    ``sum_o l_o p_o share_os`` (module doc). Observations of a material outside ``material_names`` are skipped."""
    K = len(material_names)
    index = {n: k for k, n in enumerate(material_names)}
    ev = np.zeros((num_parts, K))
    for i, share in shares:
        ob = observations[i]
        k = index.get(ob.material)
        if k is not None:
            ev[:, k] += max(float(ob.weight), 0.0) * float(ob.confidence) * share
    return alpha0 + lam * ev, ev.sum(1)


def absorb_unobserved(parts: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """int [X, Y, Z] part grid in which every voxel of a part with ``observed[s]`` False, in a 26-connected piece of the
    solid that holds an observed part, takes the part of the nearest observed voxel (module doc; Euclidean, on the
    solid's box); parts numbered 0..P'-1 again in their old order, -1 outside the solid. ``parts``: int part id
    per voxel, -1 outside; ``observed``: bool [P]."""
    from scipy import ndimage  # lazily: a PLY-only export needs no SciPy

    from .carve import bounding_box

    solid = parts >= 0
    if not solid.any() or observed.all() or not observed.any():
        return parts
    lo, hi = bounding_box(solid)
    box = tuple(slice(a, b) for a, b in zip(lo, hi))
    sub = parts[box]
    inside = sub >= 0
    seen = inside & observed[np.maximum(sub, 0)]
    piece, _ = ndimage.label(inside, structure=np.ones((3, 3, 3), bool))
    reached = np.zeros(int(piece.max()) + 1, bool)
    reached[piece[seen]] = True
    move = inside & ~seen & reached[piece]
    out = sub.copy()
    if move.any():
        near = ndimage.distance_transform_edt(~seen, return_distances=False, return_indices=True)
        out[move] = sub[tuple(n[move] for n in near)]
    kept = np.unique(out[out >= 0])
    remap = np.full(int(parts.max()) + 1, -1, np.int64)
    remap[kept] = np.arange(len(kept))
    full = np.full_like(parts, -1)
    full[box] = np.where(out >= 0, remap[np.maximum(out, 0)], -1)
    return full


def merge_same_material(parts: np.ndarray, material: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(parts', old_to_new)``: parts that touch (26-connected) and have the same ``material[s]`` (int [P]; give each
    part that must stay alone a distinct negative value) become one part, numbered in the order of their first old
    part; ``old_to_new`` int [P]. The grid is returned as is when nothing merges."""
    from .carve import bounding_box
    from .parts import label_by_value

    P = int(parts.max()) + 1
    ident = np.arange(max(P, 0))
    if P <= 1 or len(np.unique(material)) == P:
        return parts, ident
    lo, hi = bounding_box(parts >= 0)
    box = tuple(slice(a, b) for a, b in zip(lo, hi))
    sub = parts[box]
    at = sub >= 0
    comp, _ = label_by_value(material[np.maximum(sub, 0)], at)
    old_comp = np.zeros(P, np.int64)  # the component of each old part (a part is connected: one component)
    old_comp[sub[at]] = comp[at]
    if len(np.unique(old_comp)) == P:
        return parts, ident
    uniq, first_idx = np.unique(old_comp, return_index=True)
    order = np.argsort(first_idx)  # numbered in the order of their first old part
    rank = np.empty(len(uniq), np.int64)
    rank[order] = np.arange(len(uniq))
    old_to_new = rank[np.searchsorted(uniq, old_comp)]
    out = np.full_like(parts, -1)
    out[box] = np.where(at, old_to_new[np.maximum(sub, 0)], -1)
    return out, old_to_new
