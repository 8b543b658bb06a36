"""PhysGS for nerfstudio: Bayesian physical property estimation on 3D Gaussian splats.

Kept import-light on purpose: sub-packages import torch/nerfstudio themselves.
"""

__version__ = "0.1.0"
