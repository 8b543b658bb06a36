"""Normal-Inverse-Gamma fusion of continuous properties (paper sec. 3.3, supplement A.5-A.7).

Per material i and property k, (mu, sigma^2) ~ NIG(tau, kappa, a, b):
    mu | sigma^2 ~ N(tau, sigma^2 / kappa),   sigma^2 ~ Inv-Gamma(a, b).
Observation m of material i contributes its value psi_m with weight p_m (its confidence); the weighted
likelihood is N(psi_m | mu, sigma^2)^{p_m}. With the weighted sufficient statistics

    W = sum p_m,   S = sum p_m psi_m,   Q = sum p_m psi_m^2       (over observations of material i)

the posterior is closed form (:func:`nig_posterior`, docs/architecture.md, "`bayes/`"):

    kappa = kappa0 + W;  tau = (kappa0 tau0 + S) / kappa;  a = a0 + W / 2;
    b = b0 + (Q - S^2/W) / 2 + kappa0 W (S/W - tau0)^2 / (2 kappa)        (b = b0 when W = 0)

and equals the paper's one-observation update A.5 (:func:`nig_update`) applied in any order.
Aleatoric = E[sigma^2] = b / (a - 1); epistemic = Var[mu] = aleatoric / kappa; MMSE estimate = tau;
predictive = Student-t(df=2a, loc=tau, scale^2 = b (kappa + 1) / (a kappa)).

Tensors of one NIG/Moments share one broadcast shape, typically ``[K, P]`` (materials x properties).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import torch
from jaxtyping import Float, Int
from torch import Tensor

from ._checks import (
    as_float_tensor,
    check_class_indices,
    check_finite,
    check_nonnegative,
    check_positive,
    raise_if,
    result_dtype,
)

__all__ = ["NIG", "Moments", "nig_posterior", "nig_update", "student_t_logpdf"]

_FIELDS_NIG = ("tau", "kappa", "a", "b")
_FIELDS_MOM = ("W", "S", "Q")


def _broadcast_fields(obj: Any, names: tuple[str, ...]) -> None:
    vals = [getattr(obj, n) for n in names]
    dtype = result_dtype(*vals)
    device = next((v.device for v in vals if isinstance(v, Tensor)), torch.device("cpu"))
    ts = [as_float_tensor(v, dtype=dtype).to(device) for v in vals]
    try:
        ts = torch.broadcast_tensors(*ts)
    except RuntimeError as err:
        shapes = {n: tuple(t.shape) for n, t in zip(names, ts)}
        raise ValueError(f"{type(obj).__name__}: fields do not broadcast to one shape: {shapes}.") from err
    for n, t in zip(names, ts):
        object.__setattr__(obj, n, t)


@dataclass
class NIG:
    """Normal-Inverse-Gamma parameters (tau, kappa, a, b), tensors of one broadcast shape.

    Construction broadcasts the four fields, promotes them to one floating dtype and checks them:
    finite, ``kappa > 0``, ``a > 0``, ``b > 0`` (ValueError naming the field and index otherwise).
    ``a > 1`` is only required by the variance accessors (:meth:`aleatoric` and friends).
    """

    tau: Tensor
    kappa: Tensor
    a: Tensor
    b: Tensor

    def __post_init__(self) -> None:
        _broadcast_fields(self, _FIELDS_NIG)
        check_finite(self.tau, where="NIG(tau)")
        fix = "NIG needs kappa > 0, a > 0 and b > 0; check the prior config (PriorConfig) and the inputs."
        check_positive(self.kappa, where="NIG(kappa)", fix=fix)
        check_positive(self.a, where="NIG(a)", fix=fix)
        check_positive(self.b, where="NIG(b)", fix=fix)

    # ---- container helpers -------------------------------------------------------------------
    @property
    def shape(self) -> torch.Size:
        return self.tau.shape

    @property
    def dtype(self) -> torch.dtype:
        return self.tau.dtype

    @property
    def device(self) -> torch.device:
        return self.tau.device

    def __getitem__(self, idx: Any) -> NIG:
        return NIG(self.tau[idx], self.kappa[idx], self.a[idx], self.b[idx])

    def to(self, *args: Any, **kwargs: Any) -> NIG:
        return NIG(*(getattr(self, n).to(*args, **kwargs) for n in _FIELDS_NIG))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict ``{"tau", "kappa", "a", "b"}`` of floats (scalar NIG) or nested lists."""
        return {n: getattr(self, n).detach().cpu().tolist() for n in _FIELDS_NIG}

    @classmethod
    def from_dict(
        cls, d: Mapping[str, Any], *, dtype: torch.dtype | None = None, device: Any = None
    ) -> NIG:
        """Inverse of :meth:`to_dict` (floats or nested lists; missing keys raise a KeyError naming them)."""
        missing = [n for n in _FIELDS_NIG if n not in d]
        if missing:
            raise KeyError(f"NIG.from_dict: missing key(s) {missing}; expected {list(_FIELDS_NIG)}, got {list(d)}.")
        dtype = dtype or torch.get_default_dtype()
        return cls(*(torch.as_tensor(d[n], dtype=dtype, device=device) for n in _FIELDS_NIG))

    # ---- moments -----------------------------------------------------------------------------
    def _require_a_gt_1(self, what: str) -> None:
        raise_if(
            self.a <= 1,
            self.a,
            where=f"NIG.{what}",
            what="shape a <= 1, so E[sigma^2] = b/(a-1) is undefined",
            fix="Use a prior with a0 > 1 (e.g. a0 = 2 or more) so every posterior has a finite variance.",
        )

    def mean(self) -> Tensor:
        """MMSE estimate of the property, E[mu] = tau (supplement A.7)."""
        return self.tau

    def aleatoric(self) -> Tensor:
        """E[sigma^2] = b / (a - 1). Raises ValueError if any a <= 1."""
        self._require_a_gt_1("aleatoric")
        return self.b / (self.a - 1)

    def epistemic(self) -> Tensor:
        """Var[mu] = E[sigma^2] / kappa. Raises ValueError if any a <= 1."""
        return self.aleatoric() / self.kappa

    def variance(self) -> Tensor:
        """Total predictive variance aleatoric + epistemic = b (kappa + 1) / (kappa (a - 1))."""
        return self.aleatoric() * (1 + 1 / self.kappa)

    def student_t(self) -> tuple[Tensor, Tensor, Tensor]:
        """Posterior predictive Student-t as ``(df, loc, scale)``: ``(2a, tau, sqrt(b (kappa+1)/(a kappa)))``."""
        scale = torch.sqrt(self.b * (self.kappa + 1) / (self.a * self.kappa))
        return 2 * self.a, self.tau, scale

    def predictive_logpdf(self, x: Tensor) -> Tensor:
        """Log-density of ``x`` (broadcast against the NIG shape) under the Student-t predictive."""
        df, loc, scale = self.student_t()
        return student_t_logpdf(as_float_tensor(x, like=self.tau), df, loc, scale)


def student_t_logpdf(x: Tensor, df: Tensor, loc: Tensor, scale: Tensor) -> Tensor:
    """Log-density of a location-scale Student-t (broadcasting)."""
    z = (x - loc) / scale
    return (
        torch.lgamma((df + 1) / 2)
        - torch.lgamma(df / 2)
        - 0.5 * torch.log(df * math.pi)
        - torch.log(scale)
        - (df + 1) / 2 * torch.log1p(z * z / df)
    )


@dataclass
class Moments:
    """Confidence-weighted sufficient statistics (W, S, Q) per (material, property), additive.

    ``W = sum p``, ``S = sum p psi``, ``Q = sum p psi^2``. :meth:`merge` (or ``+``) adds two sets of
    statistics, so statistics of disjoint observation sets (views, workers, resumed runs) combine exactly.
    Accumulate in float64 when raw values are large relative to their spread (Q - S^2/W cancels).
    """

    W: Tensor
    S: Tensor
    Q: Tensor

    def __post_init__(self) -> None:
        _broadcast_fields(self, _FIELDS_MOM)
        check_nonnegative(self.W, where="Moments(W)", fix="W is a sum of confidences and must be >= 0.")
        check_finite(self.S, where="Moments(S)")
        check_nonnegative(self.Q, where="Moments(Q)", fix="Q is a sum of p psi^2 and must be >= 0.")

    @property
    def shape(self) -> torch.Size:
        return self.W.shape

    @classmethod
    def zeros(cls, shape: tuple[int, ...], *, dtype: torch.dtype | None = None, device: Any = None) -> Moments:
        z = torch.zeros(shape, dtype=dtype or torch.get_default_dtype(), device=device)
        return cls(z, z.clone(), z.clone())

    def merge(self, other: Moments) -> Moments:
        """Statistics of the union of both observation sets (elementwise sum, broadcasting)."""
        return Moments(self.W + other.W, self.S + other.S, self.Q + other.Q)

    __add__ = merge

    def __getitem__(self, idx: Any) -> Moments:
        return Moments(self.W[idx], self.S[idx], self.Q[idx])

    def to(self, *args: Any, **kwargs: Any) -> Moments:
        return Moments(*(getattr(self, n).to(*args, **kwargs) for n in _FIELDS_MOM))

    def to_dict(self) -> dict[str, Any]:
        return {n: getattr(self, n).detach().cpu().tolist() for n in _FIELDS_MOM}

    @classmethod
    def from_dict(
        cls, d: Mapping[str, Any], *, dtype: torch.dtype | None = None, device: Any = None
    ) -> Moments:
        missing = [n for n in _FIELDS_MOM if n not in d]
        if missing:
            raise KeyError(f"Moments.from_dict: missing key(s) {missing}; got {list(d)}.")
        dtype = dtype or torch.get_default_dtype()
        return cls(*(torch.as_tensor(d[n], dtype=dtype, device=device) for n in _FIELDS_MOM))

    def empirical(self, eps: float = 1e-12) -> tuple[Tensor, Tensor]:
        """The paper's plain Gaussian estimate (A.3): ``mu = S/W``, ``sigma^2 = max(Q/W - mu^2, eps)``.

        Entries with W = 0 are NaN (no data). Useful for the non-Bayesian ablation.
        """
        has = self.W > 0
        w = torch.where(has, self.W, torch.ones_like(self.W))
        mu = self.S / w
        var = (self.Q / w - mu * mu).clamp_min(eps)
        nan = torch.full_like(mu, float("nan"))
        return torch.where(has, mu, nan), torch.where(has, var, nan)

    @classmethod
    def from_observations(
        cls,
        classes: Int[Tensor, "m"],  # noqa: F821, UP037
        confidence: Float[Tensor, "m"],  # noqa: F821, UP037
        values: Float[Tensor, "m p"] | Float[Tensor, "m"],  # noqa: F821, UP037
        num_classes: int,
    ) -> Moments:
        """Scatter-add the weighted statistics of M observations into ``[K, P]`` (or ``[K]`` for 1-D values).

        Args:
            classes: ``[M]`` material ids in ``[0, num_classes)``.
            confidence: ``[M]`` weights p_m in [0, 1].
            values: ``[M, P]`` (or ``[M]``) property values in fusion units (log units for log-space
                properties). NaN means "not reported": that observation is left out of that property's
                statistics only. +-inf is an error.
            num_classes: K.
        """
        where = "Moments.from_observations"
        classes_t = check_class_indices(torch.as_tensor(classes), num_classes, where=f"{where}(classes)")
        dtype = result_dtype(confidence, values)
        conf = as_float_tensor(confidence, dtype=dtype).to(classes_t.device)
        vals = as_float_tensor(values, dtype=dtype).to(classes_t.device)
        m = classes_t.shape[0]
        if conf.shape != (m,) or vals.dim() not in (1, 2) or vals.shape[0] != m:
            raise ValueError(
                f"{where}: expected classes [M], confidence [M], values [M, P] or [M] with one M; got "
                f"{tuple(classes_t.shape)}, {tuple(conf.shape)}, {tuple(vals.shape)}."
            )
        check_finite(conf, where=f"{where}(confidence)")
        raise_if(
            (conf < 0) | (conf > 1),
            conf,
            where=f"{where}(confidence)",
            what="confidence outside [0, 1]",
            fix="Confidences are probabilities; clip or renormalise them before fusion.",
        )
        raise_if(
            torch.isinf(vals),
            vals,
            where=f"{where}(values)",
            what="infinite property value",
            fix="Use NaN for a property the VLM did not report; +-inf is never valid (log of 0?).",
        )
        present = ~torch.isnan(vals)
        v = torch.where(present, vals, torch.zeros_like(vals))
        w = (conf.reshape((m,) + (1,) * (vals.dim() - 1)) * present).to(dtype)
        out_shape = (num_classes,) + tuple(vals.shape[1:])
        zeros = torch.zeros(out_shape, dtype=dtype, device=vals.device)
        W = zeros.index_add(0, classes_t, w)
        S = zeros.index_add(0, classes_t, w * v)
        Q = zeros.index_add(0, classes_t, w * v * v)
        return cls(W, S, Q)


def nig_posterior(prior: NIG, moments: Moments) -> NIG:
    """Closed-form NIG posterior from weighted statistics (docs/architecture.md, "`bayes/`").

    Computed in float64 and returned in the promoted dtype of ``prior`` and ``moments``. The scatter term
    ``Q - S^2/W`` is evaluated as ``Q - S * (S/W)`` and tiny negatives from rounding are clamped to 0.
    Where ``W == 0`` the prior is returned unchanged (b = b0).
    """
    out_dtype = torch.promote_types(prior.dtype, moments.W.dtype)
    f64 = torch.float64
    tau0, k0, a0, b0 = (getattr(prior, n).to(f64) for n in _FIELDS_NIG)
    W, S, Q = (getattr(moments, n).to(device=prior.device, dtype=f64) for n in _FIELDS_MOM)
    has = W > 0
    w_safe = torch.where(has, W, torch.ones_like(W))
    xbar = S / w_safe
    scatter = (Q - S * xbar).clamp_min(0)
    kappa = k0 + W
    tau = (k0 * tau0 + S) / kappa
    a = a0 + W / 2
    b = b0 + 0.5 * scatter + k0 * W * (xbar - tau0) ** 2 / (2 * kappa)
    b = torch.where(has, b, b0.expand_as(b))
    tau = torch.where(has, tau, tau0.expand_as(tau))
    return NIG(tau.to(out_dtype), kappa.to(out_dtype), a.to(out_dtype), b.to(out_dtype))


def nig_update(prior: NIG, value: Any, weight: Any = 1.0) -> NIG:
    """The paper's one-observation update (supplement A.5), elementwise with broadcasting.

        kappa' = kappa + p;  tau' = (kappa tau + p psi) / (kappa + p);  a' = a + p/2;
        b' = b + p kappa (psi - tau)^2 / (2 (kappa + p))

    Args:
        prior: current NIG.
        value: psi, broadcastable to ``prior.shape``. NaN = not observed (that entry stays unchanged).
        weight: p >= 0, broadcastable to ``prior.shape``.
    """
    where = "nig_update"
    v = as_float_tensor(value, like=prior.tau)
    p = as_float_tensor(weight, like=prior.tau)
    raise_if(torch.isinf(v), v, where=f"{where}(value)", what="infinite value", fix="Use NaN for a missing value.")
    check_nonnegative(p, where=f"{where}(weight)", fix="Observation weights (confidences) must be >= 0.")
    missing = torch.isnan(v)
    p = torch.where(missing, torch.zeros_like(p), p)
    v = torch.where(missing, prior.tau, v)
    kappa = prior.kappa + p
    tau = (prior.kappa * prior.tau + p * v) / kappa
    a = prior.a + p / 2
    b = prior.b + p * prior.kappa * (v - prior.tau) ** 2 / (2 * kappa)
    keep = missing | (p == 0)  # bit-exact identity where nothing was observed
    return NIG(*(torch.where(keep, getattr(prior, n), new) for n, new in zip(_FIELDS_NIG, (tau, kappa, a, b))))
