"""The physical property keys, in the order of every [.., P] tensor (a leaf module: the library and the
priors both import it)."""

PROPERTY_KEYS: tuple[str, ...] = ("density", "kinetic_friction", "shore_hardness", "youngs_modulus")
