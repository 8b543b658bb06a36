"""Special functions torch lacks: regularized incomplete beta and the Student-t CDF (batched, float32/64)."""

from __future__ import annotations

import math

import torch
from torch import Tensor


def betainc(
    a: Tensor, b: Tensor, x: Tensor, *, one_minus_x: Tensor | None = None, max_iter: int = 500
) -> Tensor:
    """Regularized incomplete beta I_x(a, b) by Lentz's continued fraction (broadcasting).

    Uses the symmetry I_x(a, b) = 1 - I_{1-x}(b, a) where x > (a+1)/(a+b+2) so the fraction converges fast.
    ``one_minus_x`` may pass 1 - x computed without cancellation.
    Iterates until every entry has converged to machine precision or ``max_iter`` is reached.
    """
    if one_minus_x is None:
        one_minus_x = 1 - x
    a, b, x, one_minus_x = torch.broadcast_tensors(a, b, x, one_minus_x)
    eps = torch.finfo(x.dtype).eps
    tiny = torch.finfo(x.dtype).tiny * 1e4
    swap = x > (a + 1) / (a + b + 2)
    aa = torch.where(swap, b, a)
    bb = torch.where(swap, a, b)
    xx = torch.where(swap, one_minus_x, x)
    yy = torch.where(swap, x, one_minus_x)
    log_front = (
        aa * torch.log(xx) + bb * torch.log(yy) - (torch.lgamma(aa) + torch.lgamma(bb) - torch.lgamma(aa + bb))
    )
    front = torch.exp(log_front) / aa

    def _clip(t: Tensor) -> Tensor:
        return torch.where(t.abs() < tiny, torch.full_like(t, tiny), t)

    c = torch.ones_like(xx)
    d = 1 / _clip(1 - (aa + bb) * xx / (aa + 1))
    f = d.clone()
    for m in range(1, max_iter + 1):
        m2 = 2 * m
        num = m * (bb - m) * xx / ((aa + m2 - 1) * (aa + m2))
        d = 1 / _clip(1 + num * d)
        c = _clip(1 + num / c)
        f = f * c * d
        num = -(aa + m) * (aa + bb + m) * xx / ((aa + m2) * (aa + m2 + 1))
        d = 1 / _clip(1 + num * d)
        c = _clip(1 + num / c)
        delta = c * d
        f = f * delta
        if bool(((delta - 1).abs() <= 4 * eps).all()):
            break
    res = torch.where(xx <= 0, torch.zeros_like(front), front * f)
    return torch.where(swap, 1 - res, res)


def student_t_cdf(z: Tensor, df: Tensor) -> Tensor:
    """CDF of the standard Student-t with ``df`` degrees of freedom at ``z`` (broadcasting)."""
    out_dtype = torch.promote_types(z.dtype, df.dtype)
    # float64 inside: lgamma(a) + lgamma(b) - lgamma(a + b) cancels badly in float32 for large df.
    z, df = torch.broadcast_tensors(z.to(torch.float64), df.to(torch.float64))
    denom = df + z * z
    x = df / denom
    tail = 0.5 * betainc(df / 2, torch.full_like(df, 0.5), x, one_minus_x=z * z / denom)
    return torch.where(z > 0, 1 - tail, tail).to(out_dtype)


def normal_cdf(z: Tensor) -> Tensor:
    return torch.special.ndtr(z)


def normal_logpdf(z: Tensor) -> Tensor:
    return -0.5 * z * z - 0.5 * math.log(2 * math.pi)
