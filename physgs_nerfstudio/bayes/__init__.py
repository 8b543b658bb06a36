"""Pure-torch Bayesian math of PhysGS (paper section 3, supplement A): Dirichlet-Categorical material
fusion, Normal-Inverse-Gamma property fusion and the per-entity mixture predictive.

No nerfstudio or materials imports; everything is batched over entities and works in float32/float64.
"""

from .dirichlet import (
    dirichlet_posterior,
    dirichlet_strength,
    dominance_probability,
    evidence_from_observations,
    expected_entropy,
    mutual_information,
    predictive,
    predictive_entropy,
    vacuity,
)
from .mixture import (
    component_scale,
    material_mixture_weights,
    mixture_cdf,
    mixture_fields,
    mixture_interval,
    mixture_logpdf,
    mixture_moments,
    mixture_quantile,
    mixture_sample,
    property_fields,
    property_intervals,
)
from .nig import NIG, Moments, nig_posterior, nig_update, student_t_logpdf

__all__ = [
    "NIG",
    "Moments",
    "component_scale",
    "dirichlet_posterior",
    "dirichlet_strength",
    "dominance_probability",
    "evidence_from_observations",
    "expected_entropy",
    "material_mixture_weights",
    "mixture_cdf",
    "mixture_fields",
    "mixture_interval",
    "mixture_logpdf",
    "mixture_moments",
    "mixture_quantile",
    "mixture_sample",
    "mutual_information",
    "nig_posterior",
    "nig_update",
    "predictive",
    "predictive_entropy",
    "property_fields",
    "property_intervals",
    "student_t_logpdf",
    "vacuity",
]
