"""Input conversion and validation shared by the ``bayes`` modules.

Every guard raises :class:`ValueError` with the offending index, its value, how many entries are bad and
what to do about it, so a failure deep inside a fusion run points at the observation that caused it.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor


def as_float_tensor(x: Any, *, like: Tensor | None = None, dtype: torch.dtype | None = None) -> Tensor:
    """Return ``x`` as a floating tensor.

    Floating tensors keep their dtype and device unless ``dtype``/``like`` say otherwise; integers, bools,
    Python scalars and numpy arrays become ``torch.get_default_dtype()`` (or ``like``'s dtype).
    """
    device = like.device if like is not None else None
    if dtype is None and like is not None:
        dtype = like.dtype
    if isinstance(x, Tensor):
        t = x
    elif dtype is not None:  # build directly in the target dtype (0.3 -> float32 -> float64 would lose digits)
        t = torch.as_tensor(x, dtype=dtype, device=device)
    else:
        t = torch.as_tensor(x)
        if not t.is_floating_point():
            t = torch.as_tensor(x, dtype=torch.get_default_dtype())
    if dtype is None:
        dtype = t.dtype if t.is_floating_point() else torch.get_default_dtype()
    return t.to(device=device if device is not None else t.device, dtype=dtype)


def result_dtype(*xs: Any) -> torch.dtype:
    """Common floating dtype of the tensors among ``xs`` (default dtype if none is floating)."""
    dts = [x.dtype for x in xs if isinstance(x, Tensor) and x.is_floating_point()]
    if not dts:
        return torch.get_default_dtype()
    out = dts[0]
    for d in dts[1:]:
        out = torch.promote_types(out, d)
    return out


def first_index(mask: Tensor) -> tuple[int, ...]:
    """Index (as a tuple) of the first ``True`` entry of ``mask``."""
    return tuple(int(i) for i in torch.nonzero(mask, as_tuple=False)[0])


def raise_if(bad: Tensor, values: Tensor, *, where: str, what: str, fix: str) -> None:
    """Raise ``ValueError`` if any entry of the boolean ``bad`` is set.

    Args:
        bad: boolean mask, same shape as ``values``.
        values: the tensor being checked (its offending value is quoted).
        where: the function/argument being checked, e.g. ``"nig_update(value)"``.
        what: what is wrong, e.g. ``"non-finite value"``.
        fix: what the caller should do.
    """
    if bool(bad.any()):
        idx = first_index(bad)
        val = values[idx].item() if values.dim() else values.item()
        n = int(bad.sum())
        loc = f"index {idx if len(idx) != 1 else idx[0]}" if idx else "the (scalar) value"
        raise ValueError(f"{where}: {what} at {loc} (value {val!r}; {n} offending entr{'y' if n == 1 else 'ies'}). {fix}")


def check_finite(t: Tensor, *, where: str, fix: str = "Remove or repair non-finite inputs (NaN/inf).") -> None:
    raise_if(~torch.isfinite(t), t, where=where, what="non-finite value", fix=fix)


def check_positive(t: Tensor, *, where: str, fix: str) -> None:
    check_finite(t, where=where)
    raise_if(t <= 0, t, where=where, what="value must be > 0", fix=fix)


def check_nonnegative(t: Tensor, *, where: str, fix: str) -> None:
    check_finite(t, where=where)
    raise_if(t < 0, t, where=where, what="value must be >= 0", fix=fix)


def check_class_indices(classes: Tensor, num_classes: int, *, where: str) -> Tensor:
    """Validate a 1-D integer tensor of class ids in ``[0, num_classes)`` and return it as int64."""
    if num_classes < 1:
        raise ValueError(f"{where}: num_classes must be >= 1, got {num_classes}.")
    if classes.is_floating_point() or classes.dtype == torch.bool or classes.is_complex():
        raise ValueError(
            f"{where}: class ids must be an integer tensor, got dtype {classes.dtype}. "
            "Convert material names to ids with MaterialLibrary.index first."
        )
    if classes.dim() != 1:
        raise ValueError(f"{where}: class ids must be 1-D [M], got shape {tuple(classes.shape)}.")
    raise_if(
        (classes < 0) | (classes >= num_classes),
        classes,
        where=where,
        what=f"class id out of range [0, {num_classes})",
        fix="Use ids in 0..K-1 (0-based material index) and pass the right num_classes.",
    )
    return classes.long()
