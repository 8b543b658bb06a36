"""Material libraries (indoor, outdoor, user YAML) with property ranges, units, sources and NIG priors."""

from .hardness import CANONICAL_SCALE, SCALES, convert, from_canonical, to_canonical
from .library import (
    BUILTIN_ENVS,
    PROPERTY_KEYS,
    Material,
    MaterialLibrary,
    MaterialLibraryError,
    PropertyRange,
    load_library,
    normalize_name,
)
from .priors import DEFAULT_LOG_SPACE, PriorConfig, log_space_flags, prior_params

__all__ = [
    "BUILTIN_ENVS",
    "CANONICAL_SCALE",
    "DEFAULT_LOG_SPACE",
    "PROPERTY_KEYS",
    "SCALES",
    "Material",
    "MaterialLibrary",
    "MaterialLibraryError",
    "PriorConfig",
    "PropertyRange",
    "convert",
    "from_canonical",
    "load_library",
    "log_space_flags",
    "normalize_name",
    "prior_params",
    "to_canonical",
]
