"""Posterior samples for domain randomisation: ``samples/<i>/`` bodies drawn from the mass report's Monte Carlo.

Sample ``i`` is row ``i`` of the report's Monte Carlo (:class:`physgs_nerfstudio.mass.MassDraws`, the same seed):
its carving variant, each part's material assignment, the materials' densities, each part's structure and wall
thickness, hence its part masses; its body is those masses on the object's carriers (:mod:`.body`), so the samples'
masses are draws of the distribution whose quantiles are the report's interval. Friction is drawn per material
from the posterior of its mean (the density's rule: Student-t of the NIG), with its own generator (the mass draws
stay those of the report), and mixed per part by the sample's material assignment.
"""

from __future__ import annotations

import numpy as np

from .body import MassProperties, body_from_masses
from .build import FRICTION_KEY, SimBuild, part_materials
from .simobject import PartMaterial

__all__ = ["friction_draws", "sample_bodies"]


def friction_draws(pf, n: int, seed: int) -> np.ndarray:
    """[n, K] kinetic friction per material: the posterior of each material's mean, clipped to [0, 2]."""
    import torch

    rng = np.random.default_rng([seed, 74])
    p = pf.property_index(FRICTION_KEY)
    nig = pf.nig.to(torch.float64)
    tau, kappa, a, b = (getattr(nig, k)[:, p].cpu().numpy() for k in ("tau", "kappa", "a", "b"))
    x = tau[None, :] + np.sqrt(b / (a * kappa))[None, :] * rng.standard_t(2 * a[None, :], size=(n, len(tau)))
    if pf.log_space[p]:
        x = np.exp(np.clip(x, -700, 700))
    return np.clip(x, 0.0, 2.0)


def sample_bodies(pf, build: SimBuild, draws, n: int, seed: int
                  ) -> list[tuple[MassProperties, dict[int, PartMaterial], dict]]:  # fmt: skip
    """The first ``n`` Monte Carlo rows as (body, part materials, what was drawn)."""
    if n > len(draws.variant):
        raise ValueError(f"--sim.samples {n} exceeds the Monte Carlo's {len(draws.variant)} samples "
                         "(--mass.n-samples).")  # fmt: skip
    fr = friction_draws(pf, n, seed)
    out = []
    for s in range(n):
        h = draws.hollow[s][:, None].astype(np.float64)
        m = draws.part_mass_kg[s]
        body = body_from_masses(np.stack([m * (1.0 - h), m * h]), build.carriers)
        mats = part_materials(pf, draws.share[s], fr[s], m.sum(1), draws.volume_m3[s])
        drawn = {"variant": int(draws.variant[s]), "density_kg_m3": draws.density[s].tolist(),
                 "friction": fr[s].tolist(), "hollow": draws.hollow[s].tolist(),
                 "wall_thickness_m": draws.thickness_m[s].tolist()}  # fmt: skip
        out.append((body, mats, drawn))
    return out
