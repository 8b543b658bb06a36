"""Front-to-back alpha compositing of projected Gaussians on one image, as sparse (Gaussian, pixel) pairs.

Semantics follow gsplat 1.4.0's tile rasterizer:
- a Gaussian is considered only for pixels of the 16x16 tiles that its 3-sigma square (radius) touches;
- alpha = min(0.999, opacity * exp(-sigma)), pairs with alpha < 1/255 are skipped;
- per pixel, Gaussians are composited in depth order (ties: lower index first) until the transmittance
  after a Gaussian would drop to <= 1e-4; that Gaussian and all behind it are left out.

Implementation: for each visible Gaussian, candidate pixels are the intersection of its tile rectangle
with the bounding box of the ellipse where alpha >= 1/255 (exact, with a one-pixel margin; the alpha test
is applied per pair). Pairs are sorted by pixel (stable, Gaussians already depth-sorted) and the
transmittance is an exclusive segmented cumulative sum of log(1 - alpha) in float64. Gaussians are split
into depth-ordered chunks of bounded pair count; the transmittance is carried between chunks, and chunks
can be gradient-checkpointed so memory stays bounded for large scenes. A chunk's backward is analytic
(:class:`_CompositePairs`: gsplat's back-to-front sweep, vectorised with one cumulative sum per chunk),
so autograd keeps no per-pair graph.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from typing import NamedTuple

import torch
from jaxtyping import Bool, Float, Int
from torch import Tensor
from torch.utils.checkpoint import checkpoint

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.999
T_MIN = 1e-4
LOG_T_MIN = math.log(T_MIN)


def candidate_boxes(
    means2d: Float[Tensor, "M 2"],
    covars2d: Float[Tensor, "M 3"],
    opacities: Float[Tensor, " M"],
    radii: Int[Tensor, " M"],
    width: int,
    height: int,
    tile_size: int,
) -> tuple[Int[Tensor, " M"], Int[Tensor, " M"], Int[Tensor, " M"], Int[Tensor, " M"]]:
    """Pixel boxes [x0, x1) x [y0, y1) holding every pixel a Gaussian can contribute to (no grad)."""
    with torch.no_grad():
        m = means2d.double()
        rad = radii.double()
        tiles_w, tiles_h = math.ceil(width / tile_size), math.ceil(height / tile_size)
        tx0 = torch.floor((m[:, 0] - rad) / tile_size).clamp(0, tiles_w)
        tx1 = torch.ceil((m[:, 0] + rad) / tile_size).clamp(0, tiles_w)
        ty0 = torch.floor((m[:, 1] - rad) / tile_size).clamp(0, tiles_h)
        ty1 = torch.ceil((m[:, 1] + rad) / tile_size).clamp(0, tiles_h)
        # alpha >= 1/255  <=>  sigma <= log(255 * opacity): an ellipse with these half extents.
        level = torch.log((255.0 * opacities.double()).clamp_min(1e-30))
        ok = level >= 0
        ex = (2.0 * level.clamp_min(0) * covars2d[:, 0].double()).sqrt()
        ey = (2.0 * level.clamp_min(0) * covars2d[:, 2].double()).sqrt()
        x0 = torch.maximum(torch.floor(m[:, 0] - ex - 0.5) - 1, tx0 * tile_size).clamp(0, width)
        x1 = torch.minimum(torch.ceil(m[:, 0] + ex - 0.5) + 2, (tx1 * tile_size).clamp_max(width))
        y0 = torch.maximum(torch.floor(m[:, 1] - ey - 0.5) - 1, ty0 * tile_size).clamp(0, height)
        y1 = torch.minimum(torch.ceil(m[:, 1] + ey - 0.5) + 2, (ty1 * tile_size).clamp_max(height))
        empty = ~ok | (x1 <= x0) | (y1 <= y0) | (radii <= 0)
        x1 = torch.where(empty, x0, x1)
        y1 = torch.where(empty, y0, y1)
        return x0.long(), x1.long(), y0.long(), y1.long()


def _enumerate_pairs(boxes: tuple[Tensor, Tensor, Tensor, Tensor], width: int) -> tuple[Tensor, Tensor]:
    """All (gaussian, pixel) pairs in the boxes, Gaussian-major, as int32 (gid, pixel id = y * width + x)."""
    x0, x1, y0, y1 = boxes
    bw = x1 - x0
    counts = bw * (y1 - y0)
    total = int(counts.sum())
    dev = counts.device
    gid = torch.repeat_interleave(
        torch.arange(len(counts), device=dev, dtype=torch.int32), counts, output_size=total
    )
    info = torch.stack([x0 + y0 * width, bw, torch.cumsum(counts, 0) - counts], 1).to(torch.int32)
    info = info.index_select(0, gid)
    local = torch.arange(total, device=dev, dtype=torch.int32) - info[:, 2]
    row = torch.div(local, info[:, 1], rounding_mode="floor")
    pix = info[:, 0] + row * width + (local - row * info[:, 1])
    return gid, pix


def _composite_chunk(
    params: Float[Tensor, "G 6"],
    colors: Float[Tensor, "G D"],
    log_t_in: Float[Tensor, " HW"],
    done_in: Bool[Tensor, " HW"],
    boxes: tuple[Tensor, Tensor, Tensor, Tensor],
    width: int,
    absgrad_hook: Callable[[Tensor, Tensor], None] | None,
) -> tuple[Float[Tensor, "HW D"], Float[Tensor, " HW"], Bool[Tensor, " HW"]]:
    """Composite depth-sorted Gaussians (params = mean x, mean y, conic a, b, c, opacity) behind a
    per-pixel transmittance exp(log_t_in).

    `done_in` marks pixels already terminated by an earlier chunk (a Gaussian would have pushed the
    transmittance to <= 1e-4). Returns (colour sum, log transmittance after, done after)."""
    pairs = _sorted_pairs(params, done_in, boxes, width)
    return _CompositePairs.apply(params, colors, log_t_in, done_in, pairs, absgrad_hook)


def _pixel_centres(pix: Int[Tensor, " P"], width: int, dtype: torch.dtype) -> Float[Tensor, "P 2"]:
    py = torch.div(pix, width, rounding_mode="floor")
    return torch.stack([pix - py * width, py], -1).to(dtype) + 0.5


class _Pairs(NamedTuple):
    """Candidate (Gaussian, pixel) pairs of one chunk that pass the alpha test, sorted by pixel (stable, so in
    depth order within a pixel): Gaussian (int64), pixel id (int64), pixel centre, alpha and sigma."""

    gid: Tensor
    pix: Tensor
    pxy: Tensor
    alpha: Tensor
    sig: Tensor


@torch.no_grad()
def _sorted_pairs(params: Float[Tensor, "G 6"], done: Bool[Tensor, " HW"], boxes, width: int) -> _Pairs:
    """The (Gaussian, pixel) pairs in the boxes of depth-sorted Gaussians that pass the alpha test, on pixels
    not yet `done`, sorted by pixel (stable: depth order within a pixel)."""
    gid, pix = _enumerate_pairs(boxes, width)
    pxy = _pixel_centres(pix, width, params.dtype)
    alpha, sig = _pair_alpha(params.detach().index_select(0, gid), pxy)
    ok = (sig >= 0) & (alpha >= ALPHA_MIN) & ~done.index_select(0, pix)  # finished pixels are out
    sel = ok.nonzero().squeeze(-1)
    pix, order = torch.sort(pix.index_select(0, sel), stable=True)  # per pixel, depth order is kept
    sel = sel.index_select(0, order)
    return _Pairs(gid.index_select(0, sel).long(), pix.long(), pxy.index_select(0, sel),
                  alpha.index_select(0, sel), sig.index_select(0, sel))  # fmt: skip


def _transmittance_before(pairs: _Pairs, log_t_in: Float[Tensor, " HW"]) -> tuple[Tensor, Tensor, Tensor]:
    """Per pair, log(1 - alpha) and the log transmittance in front of it (float64), and whether it is
    composited (the transmittance after it stays above 1e-4: a prefix of each pixel's pairs)."""
    log_1m = torch.log1p(-pairs.alpha.double())
    counts = torch.bincount(pairs.pix, minlength=log_t_in.shape[0])
    seg_start = (torch.cumsum(counts, 0) - counts).index_select(0, pairs.pix)
    csum = torch.cumsum(log_1m, 0) - log_1m  # exclusive, global
    log_t_excl = csum - csum.index_select(0, seg_start) + log_t_in.index_select(0, pairs.pix)
    return log_1m, log_t_excl, (log_t_excl + log_1m) > LOG_T_MIN


class _CompositePairs(torch.autograd.Function):
    """Front-to-back compositing of sorted pairs behind a per-pixel log transmittance; analytic backward.

    Per pixel, with the pairs in depth order, l_j = log(1 - alpha_j), the transmittance before pair i is
    T_i = exp(log_t_in + sum_{j<i} l_j), its weight w_i = alpha_i T_i, the colour sum C = sum_i w_i c_i
    and the log transmittance after all of them log_t_in + sum_i l_i. Pairs after the one that would push
    the transmittance to <= 1e-4 are left out (a prefix is kept per pixel). The backward is the reverse
    sweep of gsplat's kernel, vectorised: dL/dl_j = sum_{i>j} s_i w_i + dL/dlog_t_out, with
    s_i = dL/dC . c_i, a suffix sum per pixel taken from one cumulative sum."""

    @staticmethod
    def forward(ctx, params, colors, log_t_in, done_in, pairs: _Pairs, absgrad_hook):  # type: ignore
        n_pix = log_t_in.shape[0]
        log_1m, log_t_excl, included = _transmittance_before(pairs, log_t_in)
        done_out = done_in.clone()
        done_out[pairs.pix[~included]] = True
        idx = included.nonzero().squeeze(-1)
        gid, pix = pairs.gid.index_select(0, idx), pairs.pix.index_select(0, idx)
        alpha = pairs.alpha.index_select(0, idx)
        trans = torch.exp(log_t_excl.index_select(0, idx)).to(alpha.dtype)
        weights = alpha * trans
        pair_colors = colors.index_select(0, gid)
        out_colors = torch.zeros(n_pix, colors.shape[-1], dtype=colors.dtype, device=colors.device)
        out_colors.index_add_(0, pix, weights[:, None] * pair_colors)
        out_log_t = log_t_in.index_add(0, pix, log_1m.index_select(0, idx))
        ctx.mark_non_differentiable(done_out)
        ctx.save_for_backward(params, colors, gid, pix, pairs.pxy.index_select(0, idx), alpha, trans,
                              pairs.sig.index_select(0, idx))  # fmt: skip
        ctx.absgrad_hook = absgrad_hook
        return out_colors, out_log_t, done_out

    @staticmethod
    def backward(ctx, g_colors, g_log_t, _g_done):  # type: ignore[override]
        params, colors, gid, pix, pxy, alpha, trans, sig = ctx.saved_tensors
        n_pix = g_colors.shape[0]
        pair_colors = colors.index_select(0, gid)
        g_pair = g_colors.index_select(0, pix)  # dL/dC at each pair's pixel
        weights = alpha * trans
        s_pair = (g_pair * pair_colors).sum(-1)  # s_i = dL/dC . c_i
        sw = (s_pair * weights).double()
        total = torch.zeros(n_pix, dtype=torch.float64, device=pix.device).index_add_(0, pix, sw)
        before = torch.cumsum(total, 0) - total  # sum of s w over the pixels before each pixel
        upto = torch.cumsum(sw, 0) - before.index_select(0, pix)  # inclusive prefix within the pixel
        g_l = total.index_select(0, pix) - upto + g_log_t.index_select(0, pix)  # dL/dl_i
        g_alpha = (s_pair * trans).double() - g_l / (1.0 - alpha.double())
        pair_grads = _alpha_backward(params, gid, pxy, sig, g_alpha.to(params.dtype), ctx.absgrad_hook)
        # one scatter for both inputs: [P, 6 + D] into [G, 6 + D]
        both = torch.cat([pair_grads, (weights[:, None] * g_pair).to(pair_grads.dtype)], -1)
        out = torch.zeros(params.shape[0], both.shape[1], dtype=both.dtype, device=both.device)
        out.index_add_(0, gid, both)
        grad_params, grad_colors = out[:, :6], out[:, 6:].to(colors.dtype)
        return grad_params, grad_colors, total + g_log_t, None, None, None


def _alpha_backward(params: Tensor, gid: Tensor, pxy: Tensor, sig: Tensor, g: Tensor, absgrad_hook) -> Tensor:
    """Per-pair d loss / d params [P, 6] from d loss / d alpha of (Gaussian, pixel) pairs (alpha =
    min(0.999, o exp(-sigma))); reports per-pair |d loss / d means2d| to `absgrad_hook` when given."""
    pair_params = params.index_select(0, gid)
    _mx, _my, a, b, c, o = pair_params.unbind(-1)
    dx, dy = (pair_params[:, :2] - pxy).unbind(-1)
    vis = torch.exp(-sig)
    g = torch.where(o * vis <= ALPHA_MAX, g, torch.zeros_like(g))  # clamp: no gradient
    g_sig = -g * o * vis
    grads = torch.stack(
        [g_sig * (a * dx + b * dy), g_sig * (b * dx + c * dy), 0.5 * g_sig * dx * dx, g_sig * dx * dy,
         0.5 * g_sig * dy * dy, g * vis], dim=-1,
    )  # fmt: skip
    if absgrad_hook is not None:
        absgrad_hook(grads[:, :2].abs(), gid)
    return grads


def _pair_alpha(pair_params: Float[Tensor, "P 6"], pxy: Float[Tensor, "P 2"]) -> tuple[Tensor, Tensor]:
    """alpha = min(0.999, o * exp(-sigma)) and sigma for (Gaussian, pixel) pairs."""
    d = pair_params[:, :2] - pxy
    dx, dy = d.unbind(-1)
    a, b, c, o = pair_params[:, 2:].unbind(-1)
    sig = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
    return (o * torch.exp(-sig)).clamp_max(ALPHA_MAX), sig


def _live_pixels_in_boxes(done: Bool[Tensor, " HW"], boxes, width: int, height: int) -> Int[Tensor, " G"]:
    """Number of unfinished pixels in each box, from a summed-area table."""
    live = (~done).reshape(height, width).to(torch.int64)
    sat = torch.zeros(height + 1, width + 1, dtype=torch.int64, device=done.device)
    sat[1:, 1:] = live.cumsum(0).cumsum(1)
    x0, x1, y0, y1 = boxes
    return sat[y1, x1] - sat[y0, x1] - sat[y1, x0] + sat[y0, x0]


def composite_image(
    means2d: Float[Tensor, "M 2"],
    conics: Float[Tensor, "M 3"],
    opacities: Float[Tensor, " M"],
    colors: Float[Tensor, "M D"],
    depths: Float[Tensor, " M"],
    radii: Int[Tensor, " M"],
    covars2d: Float[Tensor, "M 3"],
    width: int,
    height: int,
    *,
    tile_size: int = 16,
    max_pairs: int = 1 << 21,
    chunk_pairs: int | None = None,
    force_checkpoint: bool | None = None,
    absgrad_hook: Callable[[Tensor, Tensor], None] | None = None,
) -> tuple[Float[Tensor, "H W D"], Float[Tensor, "H W 1"]]:
    """Render one image from the Gaussians with radii > 0. Returns (colors without background, alphas).

    Gaussians are processed front to back in chunks of about `chunk_pairs` candidate pairs (default
    32 per pixel); Gaussians whose box holds no unfinished pixel are skipped. When the image has more than
    `max_pairs` candidate pairs in all, chunks are gradient-checkpointed (or per `force_checkpoint`).
    `absgrad_hook(abs_grad_pairs [P, 2], ids)` is called in the backward pass with each chunk's per-pair
    |d loss / d means2d| (`ids` index the M inputs), to accumulate absolute 2D gradients per Gaussian.
    """
    n_pix = width * height
    if chunk_pairs is None:
        chunk_pairs = min(max(32 * n_pix, 1 << 14), max_pairs)
    with torch.no_grad():
        vis = torch.nonzero(radii > 0).squeeze(-1)
        # depth order, ties broken by index (stable sort of index-ordered input), like gsplat's radix sort
        vis = vis[torch.sort(depths.detach()[vis], stable=True).indices]
        boxes = candidate_boxes(means2d[vis], covars2d[vis], opacities.detach()[vis], radii[vis],
                                width, height, tile_size)  # fmt: skip
        csum = torch.cumsum((boxes[1] - boxes[0]) * (boxes[3] - boxes[2]), 0)
        total = int(csum[-1]) if len(csum) else 0
        n_chunks = max(1, math.ceil(total / chunk_pairs))
        cuts = torch.searchsorted(csum, torch.arange(1, n_chunks, device=csum.device) * chunk_pairs)
        bounds = [0, *cuts.tolist(), len(vis)]
    use_ckpt = (total > max_pairs) if force_checkpoint is None else force_checkpoint
    use_ckpt = use_ckpt and torch.is_grad_enabled()

    params = torch.cat([means2d, conics, opacities[:, None].to(means2d.dtype)], dim=-1)
    acc_colors = torch.zeros(n_pix, colors.shape[-1], dtype=colors.dtype, device=colors.device)
    log_t = torch.zeros(n_pix, dtype=torch.float64, device=colors.device)
    done = torch.zeros(n_pix, dtype=torch.bool, device=colors.device)
    for lo, hi in itertools.pairwise(bounds):
        if hi <= lo:
            continue
        ids = vis[lo:hi]
        chunk_boxes = tuple(b[lo:hi] for b in boxes)
        if lo > 0:  # skip Gaussians that only cover finished pixels
            with torch.no_grad():
                alive = torch.nonzero(_live_pixels_in_boxes(done, chunk_boxes, width, height) > 0).squeeze(-1)
            if len(alive) == 0:
                continue
            if len(alive) < len(ids):
                ids = ids[alive]
                chunk_boxes = tuple(b[alive] for b in chunk_boxes)
        hook = None if absgrad_hook is None else _offset_hook(absgrad_hook, ids)
        args = (params[ids], colors[ids], log_t, done, chunk_boxes, width, hook)
        if use_ckpt:
            c, log_t, done = checkpoint(_composite_chunk, *args, use_reentrant=False)
        else:
            c, log_t, done = _composite_chunk(*args)
        acc_colors = acc_colors + c
    alphas = 1.0 - torch.exp(log_t).to(colors.dtype)
    return acc_colors.reshape(height, width, -1), alphas.reshape(height, width, 1)


def _offset_hook(hook: Callable[[Tensor, Tensor], None], ids: Tensor) -> Callable[[Tensor, Tensor], None]:
    def wrapped(abs_grads: Tensor, local_gid: Tensor) -> None:
        hook(abs_grads, ids.index_select(0, local_gid))

    return wrapped


@torch.no_grad()
def crossing_depth_image(
    means2d: Float[Tensor, "M 2"],
    conics: Float[Tensor, "M 3"],
    opacities: Float[Tensor, " M"],
    depths: Float[Tensor, " M"],
    radii: Int[Tensor, " M"],
    covars2d: Float[Tensor, "M 3"],
    width: int,
    height: int,
    *,
    level: float = 0.5,
    tile_size: int = 16,
    chunk_pairs: int | None = None,
    values: Float[Tensor, " M"] | None = None,
) -> Float[Tensor, "H W"]:
    """Per pixel, the depth of the Gaussian at which the transmittance first drops to ``level`` or below, with
    :func:`composite_image`'s compositing (same pairs, order and termination); +inf where it never does. With
    ``level`` 0.5 this is the *median depth* of 3DGS surface reconstruction: the depth where the ray has
    accumulated half its opacity, which, unlike the expected depth, a semi-transparent layer behind does not
    move. ``values``: that Gaussian's value instead of its depth (its index, as float64 ``arange(M)``)."""
    n_pix = width * height
    if chunk_pairs is None:
        chunk_pairs = max(16 * n_pix, 1 << 14)
    log_level = math.log(level)
    vis = torch.nonzero(radii > 0).squeeze(-1)
    vis = vis[torch.sort(depths[vis], stable=True).indices]
    boxes = candidate_boxes(means2d[vis], covars2d[vis], opacities[vis], radii[vis], width, height, tile_size)
    csum = torch.cumsum((boxes[1] - boxes[0]) * (boxes[3] - boxes[2]), 0)
    total = int(csum[-1]) if len(csum) else 0
    n_chunks = max(1, math.ceil(total / chunk_pairs))
    cuts = torch.searchsorted(csum, torch.arange(1, n_chunks, device=csum.device) * chunk_pairs)
    bounds = [0, *cuts.tolist(), len(vis)]
    params = torch.cat([means2d, conics, opacities[:, None].to(means2d.dtype)], dim=-1)
    log_t = torch.zeros(n_pix, dtype=torch.float64, device=means2d.device)
    done = torch.zeros(n_pix, dtype=torch.bool, device=means2d.device)
    values = depths if values is None else values
    out = torch.full((n_pix,), float("inf"), dtype=values.dtype, device=depths.device)
    for lo, hi in itertools.pairwise(bounds):
        if hi <= lo:
            continue
        ids = vis[lo:hi]
        pairs = _sorted_pairs(params[ids], done, tuple(b[lo:hi] for b in boxes), width)
        gid, pix = pairs.gid, pairs.pix
        log_1m, log_t_excl, included = _transmittance_before(pairs, log_t)
        # the included pairs are a prefix of each pixel's (the transmittance only falls): at most one crosses
        cross = included & (log_t_excl > log_level) & (log_t_excl + log_1m <= log_level)
        out[pix[cross]] = values[ids][gid[cross]]
        done[pix[~included]] = True
        log_t = log_t.index_add(0, pix[included], log_1m[included])
    return out.reshape(height, width)
