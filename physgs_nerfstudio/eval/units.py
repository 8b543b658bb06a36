"""Units of evaluated quantities: every value is converted to its property's canonical unit before scoring.

Canonical units follow ``docs/architecture.md`` (density kg/m^3, Young's modulus Pa, friction dimensionless)
plus ``mass`` in kg and ``bending_stiffness`` in lbf*in^2 (the MIT fabric data's unit). Shore hardness has
no unit but a *scale* (A, D, 00); it is never converted here: the scorer compares it in the measurement's
own scale (see :mod:`physgs_nerfstudio.materials.hardness`). Properties not listed here are allowed (users'
own measurements) but then ground truth and predictions must name the same unit.
"""

from __future__ import annotations

__all__ = ["CANONICAL_UNITS", "PROPERTY_ALIASES", "canonical_property", "normalize_unit", "unit_factor"]

CANONICAL_UNITS: dict[str, str] = {
    "mass": "kg",
    "density": "kg/m^3",
    "kinetic_friction": "",
    "shore_hardness": "",
    "youngs_modulus": "Pa",
    "bending_stiffness": "lbf*in^2",
    "material": "",
}

PROPERTY_ALIASES: dict[str, str] = {
    "mass": "mass", "weight": "mass", "mass_kg": "mass",
    "density": "density", "mass_density": "density",
    "friction": "kinetic_friction", "kinetic_friction": "kinetic_friction", "cof": "kinetic_friction",
    "coefficient_of_friction": "kinetic_friction",
    "hardness": "shore_hardness", "shore_hardness": "shore_hardness", "shore": "shore_hardness",
    "stiffness": "youngs_modulus", "youngs_modulus": "youngs_modulus", "young_modulus": "youngs_modulus",
    "elastic_modulus": "youngs_modulus",
    "bending_stiffness": "bending_stiffness",
    "material": "material",
}

_DIMENSIONLESS = {"", "-", "1", "none", "dimensionless", "unitless", "mu"}

# unit spelling (lower case, spaces removed) -> factor to the canonical unit of its property
_FACTORS: dict[str, dict[str, float]] = {
    "mass": {"kg": 1.0, "g": 1e-3, "mg": 1e-6, "t": 1e3, "lb": 0.45359237, "lbs": 0.45359237,
             "oz": 0.028349523125},
    "density": {"kg/m^3": 1.0, "kg/m3": 1.0, "kgm^-3": 1.0, "g/cm^3": 1e3, "g/cm3": 1e3, "g/cc": 1e3,
                "g/ml": 1e3, "lb/ft^3": 16.01846337, "lb/ft3": 16.01846337},
    "youngs_modulus": {"pa": 1.0, "kpa": 1e3, "mpa": 1e6, "gpa": 1e9, "psi": 6894.757293168,
                       "ksi": 6894757.293168, "n/m^2": 1.0, "n/mm^2": 1e6},
    "bending_stiffness": {"lbf*in^2": 1.0, "lbf-in^2": 1.0, "lbfin^2": 1.0, "lbf·in^2": 1.0, "lbf-in2": 1.0,
                          "n*m^2": 1.0 / (4.4482216152605 * 0.0254**2), "n-m^2": 1.0 / (4.4482216152605 * 0.0254**2)},
}


def canonical_property(name: str) -> str | None:
    """Canonical property key for a user spelling ("Friction", "Young's modulus", ...); None if unknown."""
    key = name.strip().lower().replace("'", "").replace("-", "_").replace(" ", "_")
    return PROPERTY_ALIASES.get(key)


def normalize_unit(unit: str | None) -> str:
    return "" if unit is None else unit.strip().lower().replace(" ", "").replace("³", "^3").replace("²", "^2")


def unit_factor(prop: str, unit: str | None) -> float | None:
    """Factor taking a value in ``unit`` to the canonical unit of ``prop``; None if the unit is not known.

    Dimensionless properties (friction, hardness, material) accept only a blank/dimensionless unit.
    """
    u = normalize_unit(unit)
    if prop in ("kinetic_friction", "shore_hardness", "material"):
        if u in _DIMENSIONLESS or (prop == "shore_hardness" and u in {"shore", "shorea", "shored", "shore00"}):
            return 1.0
        return None
    table = _FACTORS.get(prop)
    if table is None:
        return None
    if u == "" :
        return 1.0  # blank = canonical unit
    return table.get(u)
