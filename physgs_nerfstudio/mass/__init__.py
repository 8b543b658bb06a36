"""Object mass from the object's geometry (:mod:`physgs_nerfstudio.geometry`) and the property field's
posteriors, with a Monte Carlo interval over everything uncertain (docs/architecture.md, "Mass")."""

from .integrate import (
    MassConfig,
    MassDraws,
    MassReport,
    MaterialMass,
    integrate_mass,
    library_thickness,
    mass_draws,
)

__all__ = ["MassConfig", "MassDraws", "MassReport", "MaterialMass", "integrate_mass", "library_thickness", "mass_draws"]
