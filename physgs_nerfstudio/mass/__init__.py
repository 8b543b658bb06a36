"""Object mass from the object's geometry (:mod:`physgs_nerfstudio.geometry`) and the property field's
posteriors, with a Monte Carlo interval over everything uncertain (docs/architecture.md, "Mass")."""

from .integrate import MassConfig, MassReport, MaterialMass, integrate_mass, library_thickness

__all__ = ["MassConfig", "MassReport", "MaterialMass", "integrate_mass", "library_thickness"]
