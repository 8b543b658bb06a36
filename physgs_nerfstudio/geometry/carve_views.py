"""Each view's empty votes for voxel centres, the per-view half of the carving (the rule: carve.py's module
doc). A centre is projected into every view and its signed distance to the view's mask boundary read
bilinearly (:func:`signed_mask_distance`); the rendered surface depth (:func:`.gaussians.render_depth`) is looked
up there, with its slack, the lookup's error bound (:func:`depth_slack`).
Views of one image size are looked up together (:class:`_ViewBatch`), and :class:`_Rule` turns what they
read into the votes of several settings at once: :func:`.carve.carve_votes_many` counts them per voxel,
:func:`mask_view_votes` gives each view's mask votes alone.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor

from .capture import CaptureView

if TYPE_CHECKING:
    from .carve_config import CarveConfig

__all__ = [
    "default_batch_points",
    "depth_slack",
    "mask_view_votes",
    "signed_mask_distance",
    "signed_mask_distances",
]


def signed_mask_distance(mask: np.ndarray | Tensor) -> Float[Tensor, "H W"]:
    """Signed distance in pixels at pixel centres, > 0 outside and < 0 inside, offset by half a pixel so that
    its bilinear interpolation (:func:`_sample`) crosses 0 on the pixel edges between inside and outside.

    Exact Euclidean distances (OpenCV's ``DIST_MASK_PRECISE``, the same values as SciPy's
    ``distance_transform_edt``, tested against it; about 5x faster at 512 px, and it releases the GIL, so
    :func:`signed_mask_distances` computes many views at once)."""
    import cv2

    m = np.asarray(mask.cpu() if isinstance(mask, Tensor) else mask, dtype=bool)
    if not m.any():
        return torch.full(m.shape, 1e6)
    if m.all():
        return torch.full(m.shape, -1e6)
    u8 = np.ascontiguousarray(m).view(np.uint8)
    out = cv2.distanceTransform(1 - u8, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    inside = cv2.distanceTransform(u8, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return torch.from_numpy(np.where(m, 0.5 - inside, out - 0.5).astype(np.float32))


def signed_mask_distances(masks: Sequence[np.ndarray | Tensor], workers: int | None = None) -> list[Tensor]:
    """:func:`signed_mask_distance` of every mask, on a thread pool (OpenCV releases the GIL)."""
    from concurrent.futures import ThreadPoolExecutor

    masks = list(masks)
    if len(masks) < 4:
        return [signed_mask_distance(m) for m in masks]
    with ThreadPoolExecutor(max_workers=workers or min(16, os.cpu_count() or 1)) as pool:
        return list(pool.map(signed_mask_distance, masks))


def _shift(t: Tensor, dim: int, step: int, fill: float | bool) -> Tensor:
    """``t`` moved by ``step`` pixels along ``dim`` (out[i] = t[i - step]), ``fill`` where nothing moved in."""
    n = t.shape[dim]
    body = t.narrow(dim, 0, n - step) if step > 0 else t.narrow(dim, -step, n + step)
    pad = torch.full_like(t.narrow(dim, 0, abs(step)), fill)
    return torch.cat([pad, body] if step > 0 else [body, pad], dim)


def depth_slack(depth: Tensor, alpha: Tensor, min_alpha: float = 0.5, lookup: str = "bilinear") -> Tensor:
    """float [H, W]: a bound on the error of the depth looked up at a point inside each pixel, from the depth's
    differences to opaque neighbours (alpha >= ``min_alpha``), summed over the two image axes:

    * ``lookup="nearest"`` (the pixel's own depth): half a pixel's first difference, the larger one-sided one;
    * ``lookup="bilinear"``: where both neighbours along an axis are opaque, linear interpolation's error bound
      |second difference| / 8, zero on a plane however obliquely it is seen; next to a transparent neighbour
      (the interpolation falls back to the opaque side) half the one-sided first difference.
    """
    op = alpha >= min_alpha
    d = torch.where(op, depth, torch.zeros_like(depth))
    out = torch.zeros_like(d)
    for dim in (0, 1):
        prev, nxt = _shift(d, dim, 1, 0.0), _shift(d, dim, -1, 0.0)
        p_ok, n_ok = _shift(op, dim, 1, False) & op, _shift(op, dim, -1, False) & op
        first = 0.5 * torch.maximum(torch.where(p_ok, (d - prev).abs(), 0.0), torch.where(n_ok, (nxt - d).abs(), 0.0))
        if lookup == "bilinear":
            first = torch.where(p_ok & n_ok, (prev - 2 * d + nxt).abs() / 8, first)
        out += first
    return out


def _corners(shape: tuple[int, ...], u: Tensor, v: Tensor) -> list[tuple[Tensor, Tensor, Tensor]]:
    """(row, column, bilinear weight) of the four pixels around continuous pixel coordinates (pixel i covers
    [i, i+1)), clamped to the image."""
    H, W = shape
    x = (u - 0.5).clamp(0, W - 1)
    y = (v - 0.5).clamp(0, H - 1)
    x0 = x.floor().long().clamp(0, W - 1)
    y0 = y.floor().long().clamp(0, H - 1)
    x1, y1 = (x0 + 1).clamp(max=W - 1), (y0 + 1).clamp(max=H - 1)
    fx, fy = x - x0, y - y0
    return [(y0, x0, (1 - fx) * (1 - fy)), (y0, x1, fx * (1 - fy)), (y1, x0, (1 - fx) * fy), (y1, x1, fx * fy)]


def _sample(img: Tensor, u: Tensor, v: Tensor) -> Tensor:
    """Bilinear sample of ``img`` [H, W] at continuous pixel coordinates (pixel i covers [i, i+1))."""
    return sum(img[yy, xx] * w for yy, xx, w in _corners(img.shape, u, v))


def default_batch_points(device: torch.device | str) -> int:
    """(point, view) pairs looked up at once: many on a GPU (fewer kernel launches), one view at a time on the CPU
    (no faster batched there)."""
    return 1 << 23 if torch.device(device).type == "cuda" else 1


def _add_views(total: Tensor, votes: Tensor) -> None:
    """``total`` [..., n] += the votes [..., B, n] summed over their B views."""
    if votes.shape[-2] == 1:
        total += votes.squeeze(-2)
    else:
        total += votes.sum(-2, dtype=total.dtype)


class _ViewBatch:
    """Views whose images share their sizes and types, voted on together: their images stacked (per size and type,
    so that one gather reads all of them at a pixel) and their cameras' numbers as [B, 1] columns. Every operation
    is, pair for pair, the one that a view on its own gets (:func:`.carve.carve_votes_many`)."""

    def __init__(self, views: list[CaptureView], cams: list[tuple[Tensor, Tensor, Tensor]],
                 around: dict[str, list[Tensor]], held: dict[str, list[Tensor]], bilinear: bool,
                 index: list[int] | None = None) -> None:  # fmt: skip
        self.views, self.cams, self.bilinear = views, cams, bilinear
        self.index = index if index is not None else list(range(len(views)))
        """each view's position in the views the batches were grouped from (:meth:`group`)"""
        self._around, self._held = around, held
        self._stacked: tuple[list, list] | None = None  # stacked when first looked up
        self._parts: dict[tuple[int, int], _ViewBatch] = {}
        dev = cams[0][0].device
        K = torch.stack([c[2] for c in cams])
        self.fx, self.cx, self.fy, self.cy = (K[:, i, j][:, None] for i, j in ((0, 0), (0, 2), (1, 1), (1, 2)))
        self.width = torch.tensor([v.width for v in views], device=dev)[:, None]
        self.height = torch.tensor([v.height for v in views], device=dev)[:, None]

    def __len__(self) -> int:
        return len(self.views)

    @classmethod
    def group(cls, views: Sequence[CaptureView], cams: list[tuple[Tensor, Tensor, Tensor]], sdf: list[Tensor],
              depth: list, bilinear: bool) -> list[_ViewBatch]:  # fmt: skip
        """The views grouped by the sizes and types of their images (in their order)."""
        groups: dict[tuple, list[int]] = {}
        per_view = []
        for i, (sd, dz) in enumerate(zip(sdf, depth)):
            around = {"sdf": sd}
            held: dict[str, Tensor] = {}
            if dz is not None:
                held = {"depth": dz[0], "alpha": dz[1]}
                if dz[2] is not None:
                    held["slack"] = dz[2]
                if bilinear:
                    around.update({k: v for k, v in held.items() if k != "slack"})
            per_view.append((around, held))
            key = tuple((k, tuple(v.shape), v.dtype) for d in (around, held) for k, v in d.items())
            key += (cams[i][0].dtype, cams[i][2].dtype)
            groups.setdefault(key, []).append(i)
        out = []
        for idx in groups.values():
            around = {k: [per_view[i][0][k] for i in idx] for k in per_view[idx[0]][0]}
            held = {k: [per_view[i][1][k] for i in idx] for k in per_view[idx[0]][1]}
            out.append(cls([views[i] for i in idx], [cams[i] for i in idx], around, held, bilinear, idx))
        return out

    @staticmethod
    def parts(batches: list[_ViewBatch], n: int, batch_points: int) -> Iterator[_ViewBatch]:
        """The batches cut to at most ``batch_points`` (point, view) pairs for ``n`` points (one view at least)."""
        per = max(1, batch_points // max(n, 1))
        for batch in batches:
            for b0 in range(0, len(batch), per):
                yield batch.part(b0, b0 + per)

    def part(self, b0: int, b1: int) -> _ViewBatch:
        if b0 == 0 and b1 >= len(self):
            return self
        if (b0, b1) in self._parts:  # (the next chunk of voxels)
            return self._parts[(b0, b1)]
        sub = lambda d: {k: v[b0:b1] for k, v in d.items()}
        part = _ViewBatch(self.views[b0:b1], self.cams[b0:b1], sub(self._around), sub(self._held), self.bilinear,
                          self.index[b0:b1])  # fmt: skip
        self._parts[(b0, b1)] = part
        return part

    @property
    def around(self) -> list[tuple[Tensor, tuple[int, ...], list[str]]]:
        """The stacks of the images read at the four pixels around a point."""
        if self._stacked is None:
            self._stacked = (self._stacks(self._around), self._stacks(self._held))
        return self._stacked[0]

    @property
    def held(self) -> list[tuple[Tensor, tuple[int, ...], list[str]]]:
        """The stacks of the images read at the pixel that holds a point."""
        self.around  # noqa: B018  (stacks both)
        return self._stacked[1]  # type: ignore[index]

    @staticmethod
    def _stacks(images: dict[str, list[Tensor]]) -> list[tuple[Tensor, tuple[int, ...], list[str]]]:
        """[B * H * W, C] per size and type of image (a pixel's C values side by side), with the names of its C
        images."""
        groups: dict[tuple, list[str]] = {}
        for name, ims in images.items():
            groups.setdefault((tuple(ims[0].shape), ims[0].dtype), []).append(name)
        return [(torch.stack([torch.stack(images[n]).reshape(-1) for n in names], -1), key[0], names)
                for key, names in groups.items()]  # fmt: skip

    def _gather(self, stack: Tensor, shape: tuple[int, ...], rows: Tensor, cols: Tensor) -> Tensor:
        """[C, B, n]: the C images of each view at pixels (``rows``, ``cols``) [B, n] (one gather)."""
        if stack.shape[1] == 1 and len(self) == 1:  # one image: indexed as such (no flat index to compute)
            return stack.view(shape)[rows, cols][None]
        flat = rows * shape[1] + cols
        if len(self) > 1:  # view b's images start at b * H * W
            flat = flat + torch.arange(len(self), device=flat.device)[:, None] * (shape[0] * shape[1])
        return stack.index_select(0, flat.reshape(-1)).T.reshape(stack.shape[1], *rows.shape)

    def lookup(self, x: Tensor) -> tuple[Tensor, ...]:
        """[B, n] each, for voxel centres ``x`` [n, 3]: whether the view frames the centre, its camera depth, the mask
        distance there (:func:`_sample`), and the depth, alpha and slack that the vote reads (None where not
        rendered): the depth bilinear from the opaque pixels (alpha >= 0.5) among the four around the point, their
        bilinear weights renormalised (+inf where none is opaque), or else the pixel's own; the alpha and the slack
        the pixel's own."""
        pc = (torch.stack([x @ R.T + t for R, t, _ in self.cams]) if len(self) > 1
              else (x @ self.cams[0][0].T + self.cams[0][1])[None])  # [B, n, 3], each view's as on its own
        z = pc[..., 2]
        u = self.fx * pc[..., 0] / z.clamp_min(1e-9) + self.cx
        v = self.fy * pc[..., 1] / z.clamp_min(1e-9) + self.cy
        if len(self) == 1:  # the view's numbers as such (one clamp where a column takes two)
            W, H = self.views[0].width, self.views[0].height
            ok = (z > 1e-6) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
            uc, vc = u.clamp(0, W), v.clamp(0, H)
        else:
            W, H = self.width.to(u.dtype), self.height.to(u.dtype)
            ok = (z > 1e-6) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
            uc, vc = u.clamp_min(0).minimum(W), v.clamp_min(0).minimum(H)
        at: dict[str, tuple[list[Tensor], list[Tensor]]] = {}  # name: (values at the four corners, their weights)
        for stack, shape, names in self.around:
            corners = _corners(shape, uc, vc)  # type: ignore[arg-type]
            got = [self._gather(stack, shape, yy, xx) for yy, xx, _ in corners]
            for i, n in enumerate(names):
                at[n] = ([g[i] for g in got], [cw for _, _, cw in corners])
        vals, weights = at["sdf"]
        dist = sum(s * cw for s, cw in zip(vals, weights))
        if not self.held:
            return ok, z, dist, None, None, None  # type: ignore[return-value]
        if len(self) == 1:
            ui = u.floor().long().clamp(0, self.views[0].width - 1)
            vi = v.floor().long().clamp(0, self.views[0].height - 1)
        else:
            ui = u.floor().long().clamp_min(0).minimum(self.width - 1)
            vi = v.floor().long().clamp_min(0).minimum(self.height - 1)
        px: dict[str, Tensor] = {}
        for stack, shape, names in self.held:
            px.update(zip(names, self._gather(stack, shape, vi, ui)))
        d, a, sl = px["depth"], px["alpha"], px.get("slack")
        if self.bilinear:
            depth, weights = at["depth"]
            alpha = at["alpha"][0]
            num = torch.zeros_like(u)
            den = torch.zeros_like(u)
            for k, cw in enumerate(weights):
                good = alpha[k] >= 0.5
                cw = torch.where(good, cw, 0.0)
                num += cw * torch.where(good, depth[k], 0.0)
                den += cw
            d = torch.where(den > 0, num / den.clamp_min(1e-12), torch.full_like(num, float("inf")))
        return ok, z, dist, d, a, sl

class _Rule:
    """The carving rule of several settings at once, as [G, n] comparisons against [G, 1] columns of the settings'
    thresholds: row g is, value for value, what the rule of setting g alone computes (the same operations, the
    thresholds rounded to the compared tensor's type as a Python number would be)."""

    def __init__(self, cfgs: Sequence[CarveConfig], voxel_size: float) -> None:
        self.values: dict[str, list] = {
            "mask_margin": [c.mask_margin_px for c in cfgs],
            "margin_abs": [c.depth_margin_voxels * voxel_size for c in cfgs],
            "margin_rel": [c.depth_margin_rel for c in cfgs],
            "slope": [c.depth_slope_margin for c in cfgs],
            "min_alpha": [c.min_alpha for c in cfgs],
            "use_depth": [c.use_depth for c in cfgs],
            "has_slope": [c.depth_slope_margin > 0 for c in cfgs],
            "near_band": [c.near_band_voxels * voxel_size for c in cfgs],
            "consensus": [c.depth_consensus > 0 for c in cfgs],
            "near_inset": [c.near_inset_px for c in cfgs],
        }
        self._cols: dict[tuple, Tensor] = {}

    def col(self, name: str, like: Tensor, dtype: torch.dtype | None = None) -> Tensor:
        """[G, 1, ...]: the settings' values of ``name``, in ``like``'s type (or ``dtype``), to broadcast against
        ``like``; [1, 1, ...] when every setting has the same value (the operation then runs once, not G times)."""
        dtype = dtype or like.dtype
        key = (name, dtype, like.dim(), like.device)
        if key not in self._cols:
            vals = self.values[name]
            vals = vals[:1] if all(v == vals[0] for v in vals) else vals
            self._cols[key] = torch.tensor(vals, dtype=dtype, device=like.device).reshape(-1, *([1] * like.dim()))
        return self._cols[key]

    def every(self, name: str) -> bool | None:
        """True (False) when the flag ``name`` is set (unset) for every setting, None when it differs."""
        vals = self.values[name]
        return bool(vals[0]) if all(v == vals[0] for v in vals) else None

    def silhouette(self, ok: Tensor, dist: Tensor) -> Tensor:
        """bool [G, n]: the mask votes."""
        return ok & (dist > self.col("mask_margin", dist))

    def votes(self, ok: Tensor, dist: Tensor, z: Tensor, d: Tensor, a: Tensor, sl: Tensor | None
              ) -> tuple[Tensor, Tensor, Tensor | None]:  # fmt: skip
        """bool [G, n] each (or [1, n] where every setting gives the same): the empty votes, the depth votes among
        them, and whether the view sees the voxel near its surface (None when no setting asks for the depth
        consensus)."""
        like = d  # [B, n]: the columns' shape ([G, 1, 1])
        margin = self.col("margin_abs", like) + self.col("margin_rel", like) * d
        slope = self.every("has_slope")
        if sl is not None and slope is not False:
            sloped = margin + self.col("slope", sl) * sl
            margin = sloped if slope else torch.where(self.col("has_slope", sl, torch.bool), sloped, margin)
        inside = ok & (dist <= self.col("mask_margin", dist)) & (a >= self.col("min_alpha", a))
        if not self.every("use_depth"):
            inside = inside & self.col("use_depth", ok, torch.bool)
        dvote = inside & (z < d - margin)
        near = None
        if self.every("consensus") is not False:
            # a view has a say about the voxel only where it could have voted: the voxel falls clearly inside its
            # mask (not on the silhouette's edge pixels, whose depth is the edge's) and its depth is sharp there
            # (the lookup's slack no wider than the band)
            band = self.col("near_band", like)
            deep = dist <= self.col("mask_margin", dist) - self.col("near_inset", dist)
            near = inside & deep & (z <= d + margin + band) & (margin <= band)
        return self.silhouette(ok, dist) | dvote, dvote, near



def mask_view_votes(x: Tensor, views: Sequence[CaptureView], sdf: Sequence[Tensor], margin_px: float,
                    batch_points: int | None = None) -> tuple[Tensor, Tensor]:  # fmt: skip
    """bool [V, n] each, for points ``x`` [n, 3] (float32, on the views' device), in the order of ``views``: whether
    each view frames each point (in front of the camera, inside the image), and whether it frames it and the point
    lies outside its mask by more than ``margin_px`` (``sdf``: the masks' signed distances,
    :func:`signed_mask_distances`, on that device); the carving's projection and mask lookup
    (:func:`.carve.carve_votes_many`), views of one image size together."""
    dev = x.device
    cams = [(v.viewmat[:3, :3].to(dev), v.viewmat[:3, 3].to(dev), v.K.to(dev)) for v in views]
    batches = _ViewBatch.group(views, cams, list(sdf), [None] * len(views), False)
    framed = torch.zeros(len(views), len(x), dtype=torch.bool, device=dev)
    outside = torch.zeros_like(framed)
    points = batch_points if batch_points is not None else default_batch_points(dev)
    for part in _ViewBatch.parts(batches, len(x), points):
        ok, _, dist, *_ = part.lookup(x)
        rows = torch.tensor(part.index, device=dev)
        framed[rows] = ok
        outside[rows] = ok & (dist > margin_px)
    return framed, outside
