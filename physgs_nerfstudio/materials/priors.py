"""Normal-Inverse-Gamma priors from the material library (docs/architecture.md, "`bayes/`").

Per material i and property k, in the fused space f (log for log-space properties, identity otherwise):

    tau0   = f(typical)
    sigma0 = (f(high) - f(low)) / spread_divisor          (a range of +-2 sigma by default)
    kappa0 = PriorConfig.kappa0                           (the prior mean counts as kappa0 observations)
    a0     = PriorConfig.a0                               (> 1 so that E[sigma^2] exists)
    b0     = sigma0^2 (a0 - 1)                            so that E[sigma^2] = b0 / (a0 - 1) = sigma0^2

Log space uses the natural logarithm.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import torch

from .keys import PROPERTY_KEYS

__all__ = ["DEFAULT_LOG_SPACE", "PriorConfig", "log_space_flags", "prior_params"]

DEFAULT_LOG_SPACE: dict[str, bool] = {
    "density": True,
    "kinetic_friction": False,
    "shore_hardness": False,
    "youngs_modulus": True,
}


@dataclass
class PriorConfig:
    """How library ranges become NIG priors. Every field is a documented, overridable setting."""

    kappa0: float = 1.0
    """Prior pseudo-count of the mean: the library's typical value counts as this many observations."""
    a0: float = 2.0
    """Inverse-Gamma shape; must be > 1 so that the prior E[sigma^2] = b0/(a0-1) exists (2.0: weakest
    prior with a finite mean of sigma^2)."""
    spread_divisor: float = 4.0
    """sigma0 = (high - low) / spread_divisor in the fused space: 4 reads the library range as +-2 sigma."""
    log_space: dict[str, bool] = field(default_factory=lambda: dict(DEFAULT_LOG_SPACE))
    """Per property key: fuse log(value) instead of value (default: density and Young's modulus)."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.kappa0) and self.kappa0 > 0):
            raise ValueError(f"PriorConfig.kappa0 must be > 0 (a pseudo-count); got {self.kappa0}.")
        if not (math.isfinite(self.a0) and self.a0 > 1):
            raise ValueError(f"PriorConfig.a0 must be > 1 so that the prior E[sigma^2] exists; got {self.a0}.")
        if not (math.isfinite(self.spread_divisor) and self.spread_divisor > 0):
            raise ValueError(f"PriorConfig.spread_divisor must be > 0; got {self.spread_divisor}.")
        unknown = sorted(set(self.log_space) - set(PROPERTY_KEYS))
        if unknown:
            raise ValueError(
                f"PriorConfig.log_space has unknown property keys {unknown}; known: {list(PROPERTY_KEYS)}."
            )


def log_space_flags(config: PriorConfig | None = None) -> tuple[bool, ...]:
    """Per PROPERTY_KEYS entry: is it fused in log space? (keys missing from config.log_space: default)."""
    cfg = config if config is not None else PriorConfig()
    return tuple(bool(cfg.log_space.get(k, DEFAULT_LOG_SPACE[k])) for k in PROPERTY_KEYS)


def prior_params(materials: Sequence[Any], config: PriorConfig | None = None) -> dict[str, torch.Tensor]:
    """NIG prior tensors ``{"tau", "kappa", "a", "b"}``, each [K, P] float64 (K = len(materials),
    P = len(PROPERTY_KEYS)), in the fused space. ValueError if a log-space property has a range <= 0."""
    cfg = config if config is not None else PriorConfig()
    flags = log_space_flags(cfg)
    K, P = len(materials), len(PROPERTY_KEYS)
    tau = torch.empty(K, P, dtype=torch.float64)
    sigma0 = torch.empty(K, P, dtype=torch.float64)
    for i, m in enumerate(materials):
        for k, (key, use_log) in enumerate(zip(PROPERTY_KEYS, flags)):
            r = m.properties[key]
            t, lo, hi = r.typical, r.low, r.high
            if use_log:
                if lo <= 0:
                    raise ValueError(
                        f"material {m.name!r}: cannot fuse {key} in log space, its range starts at {lo:g} <= 0; "
                        f"set PriorConfig.log_space[{key!r}] = False or raise the library's low value."
                    )
                t, lo, hi = math.log(t), math.log(lo), math.log(hi)
            tau[i, k] = t
            sigma0[i, k] = (hi - lo) / cfg.spread_divisor
    kappa = torch.full((K, P), float(cfg.kappa0), dtype=torch.float64)
    a = torch.full((K, P), float(cfg.a0), dtype=torch.float64)
    b = sigma0.square() * (cfg.a0 - 1.0)
    return {"tau": tau, "kappa": kappa, "a": a, "b": b}
