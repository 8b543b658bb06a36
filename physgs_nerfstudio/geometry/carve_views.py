"""Each view's votes for points, the per-view half of the carving (the rules: carve.py's module doc). A point is
projected into every view; the free-space vote reads the view's surface depth there, bilinear between the four pixels
around the projection, and the depth's slack, the lookup's error bound (:func:`depth_slack`), at the pixel that holds
it; the silhouette vote reads the object mask's signed distance (:func:`signed_mask_distance`), bilinear too.
Views of one image size are looked up together (:class:`_ViewBatch`), and :class:`_Rule` turns the depths they read
into the free-space votes of several settings at once: :func:`.carve.carve_votes_many` counts them per voxel,
:func:`mask_view_votes` gives each view's silhouette votes.
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


def depth_slack(depth: Tensor) -> Tensor:
    """float [H, W]: a bound on the error of the depth looked up bilinearly at a point inside each pixel, summed over
    the two image axes: where both neighbours along an axis lie in the image, linear interpolation's error bound
    |second difference| / 8, zero on a plane however obliquely it is seen; on the image's edge (the lookup clamps to
    the edge pixel) half the first difference to the neighbour inside."""
    out = torch.zeros_like(depth)
    inside = torch.ones_like(depth, dtype=torch.bool)
    for dim in (0, 1):
        prev, nxt = _shift(depth, dim, 1, 0.0), _shift(depth, dim, -1, 0.0)
        p_ok, n_ok = _shift(inside, dim, 1, False), _shift(inside, dim, -1, False)
        first = 0.5 * torch.maximum(torch.where(p_ok, (depth - prev).abs(), 0.0),
                                    torch.where(n_ok, (nxt - depth).abs(), 0.0))  # fmt: skip
        out += torch.where(p_ok & n_ok, (prev - 2 * depth + nxt).abs() / 8, first)
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


def _bilinear(read: tuple[list[Tensor], list[Tensor]]) -> Tensor:
    """An image's bilinear sample from its values at the four pixels around a point and their weights
    (:meth:`_ViewBatch.lookup`), as :func:`_sample` computes it."""
    return sum(s * cw for s, cw in zip(*read))  # type: ignore[return-value]


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
                 around: dict[str, list[Tensor]], held: dict[str, list[Tensor]], index: list[int] | None = None
                 ) -> None:  # fmt: skip
        self.views, self.cams = views, cams
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
    def group(cls, views: Sequence[CaptureView], around: list[dict[str, Tensor]],
              held: list[dict[str, Tensor]] | None = None) -> list[_ViewBatch]:  # fmt: skip
        """The views grouped by the sizes and types of their images (in their order): per view, the images read
        bilinearly around a point (``around``) and those read at the pixel that holds it (``held``), all on the
        device of the batches."""
        if not views:
            return []
        held = held if held is not None else [{} for _ in views]
        dev = next(iter(around[0].values())).device
        cams = [(v.viewmat[:3, :3].to(dev), v.viewmat[:3, 3].to(dev), v.K.to(dev)) for v in views]
        groups: dict[tuple, list[int]] = {}
        for i in range(len(views)):
            key = tuple((k, tuple(v.shape), v.dtype) for d in (around[i], held[i]) for k, v in d.items())
            groups.setdefault(key + (cams[i][0].dtype, cams[i][2].dtype), []).append(i)
        stacked = lambda per_view, idx: {k: [per_view[i][k] for i in idx] for k in per_view[idx[0]]}
        return [cls([views[i] for i in idx], [cams[i] for i in idx], stacked(around, idx), stacked(held, idx), idx)
                for idx in groups.values()]  # fmt: skip

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
        part = _ViewBatch(self.views[b0:b1], self.cams[b0:b1], sub(self._around), sub(self._held), self.index[b0:b1])
        self._parts[(b0, b1)] = part
        return part

    @property
    def stacks(self) -> tuple[list, list]:
        """The stacks of the images read around a point and of those read at the pixel that holds it."""
        if self._stacked is None:
            self._stacked = (self._stacks(self._around), self._stacks(self._held))
        return self._stacked

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

    def lookup(self, x: Tensor) -> tuple[Tensor, Tensor, dict[str, tuple[list[Tensor], list[Tensor]]],
                                         dict[str, Tensor]]:  # fmt: skip
        """For points ``x`` [n, 3], [B, n] each: whether the view frames the point and its camera depth; each image
        read around it (its values at the four pixels around the point and their bilinear weights, :func:`_corners`);
        each image read at the pixel that holds it."""
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
        around, held = self.stacks
        at: dict[str, tuple[list[Tensor], list[Tensor]]] = {}
        for stack, shape, names in around:
            corners = _corners(shape, uc, vc)  # type: ignore[arg-type]
            got = [self._gather(stack, shape, yy, xx) for yy, xx, _ in corners]
            for i, name in enumerate(names):
                at[name] = ([g[i] for g in got], [cw for _, _, cw in corners])
        px: dict[str, Tensor] = {}
        if held:
            if len(self) == 1:
                ui = u.floor().long().clamp(0, self.views[0].width - 1)
                vi = v.floor().long().clamp(0, self.views[0].height - 1)
            else:
                ui = u.floor().long().clamp_min(0).minimum(self.width - 1)
                vi = v.floor().long().clamp_min(0).minimum(self.height - 1)
            for stack, shape, names in held:
                px.update(zip(names, self._gather(stack, shape, vi, ui)))
        return ok, z, at, px


class _Rule:
    """The free-space vote of several settings at once, as [G, n] comparisons against [G, 1] columns of the
    settings' thresholds: row g is, value for value, what the rule of setting g alone computes (the same operations,
    the thresholds rounded to the compared tensor's type as a Python number would be)."""

    def __init__(self, cfgs: Sequence[CarveConfig], voxel_size: float) -> None:
        self.values: dict[str, list] = {
            "margin": [c.depth_margin_voxels * voxel_size for c in cfgs],
            "slope": [c.depth_slope_margin for c in cfgs],
            "near_band": [c.near_band_voxels * voxel_size for c in cfgs],
        }
        self._cols: dict[tuple, Tensor] = {}

    def col(self, name: str, like: Tensor) -> Tensor:
        """[G, 1, ...]: the settings' values of ``name``, in ``like``'s type, to broadcast against ``like``;
        [1, 1, ...] when every setting has the same value (the operation then runs once, not G times)."""
        key = (name, like.dtype, like.dim(), like.device)
        if key not in self._cols:
            vals = self.values[name]
            vals = vals[:1] if all(v == vals[0] for v in vals) else vals
            self._cols[key] = torch.tensor(vals, dtype=like.dtype, device=like.device).reshape(-1, *([1] * like.dim()))
        return self._cols[key]

    def votes(self, ok: Tensor, z: Tensor, d: Tensor, slack: Tensor) -> tuple[Tensor, Tensor]:
        """bool [G, n] each (or [1, n] where every setting gives the same), for points framed (``ok``) at camera
        depth ``z`` where the view's surface depth is ``d`` with slack ``slack``: whether the view sees through the
        point (nearer than the surface by more than the margin), and whether it sees the point near its surface
        (in front of it or at most the band behind it, where the depth is sharp: its margin within the band)."""
        margin = self.col("margin", d) + self.col("slope", slack) * slack
        band = self.col("near_band", d)
        return ok & (z < d - margin), ok & (z <= d + margin + band) & (margin <= band)


def mask_view_votes(x: Tensor, views: Sequence[CaptureView], sdf: Sequence[Tensor], margin_px: float,
                    batch_points: int | None = None) -> tuple[Tensor, Tensor]:  # fmt: skip
    """bool [V, n] each, for points ``x`` [n, 3] (float32, on the views' device), in the order of ``views``: whether
    each view frames each point (in front of the camera, inside the image), and whether it frames it and the point
    lies outside its mask by more than ``margin_px`` (``sdf``: the masks' signed distances,
    :func:`signed_mask_distances`, on that device); the carving's projection (:func:`.carve.carve_votes_many`), views
    of one image size together."""
    dev = x.device
    batches = _ViewBatch.group(views, [{"sdf": s} for s in sdf])
    framed = torch.zeros(len(views), len(x), dtype=torch.bool, device=dev)
    outside = torch.zeros_like(framed)
    points = batch_points if batch_points is not None else default_batch_points(dev)
    for part in _ViewBatch.parts(batches, len(x), points):
        ok, _, at, _ = part.lookup(x)
        rows = torch.tensor(part.index, device=dev)
        framed[rows] = ok
        outside[rows] = ok & (_bilinear(at["sdf"]) > margin_px)
    return framed, outside
