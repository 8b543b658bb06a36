"""Solid or hollow, and the wall thickness, per 3-D part, fused from what perception said per mask.

The triplet prompt asks, per mask, for ``thickness_m``: the wall thickness if the part is a hollow shell, null if
solid (observations.jsonl, docs/architecture.md). One observation is a candidate of material ``c`` with
confidence ``p`` of one mask. Its share of 3-D part ``s``, ``share_s``, is the share of the mask's pixels where
that part is the visible surface (a z-buffer of the solid's boundary voxels in the mask's view, :func:`part_maps`),
and ``pi_sc`` is the part's mixture weight of ``c``.

Evidence (``StructureConfig.evidence``):

* The thickness is an answer about one material ("if this is cast iron, it is a 4 mm shell"). A candidate's
  thickness counts for part ``s`` with ``p x share_s x pi_sc``: as far as the part is made of that material.
* The call "hollow" or "solid" is one judgment per mask ("mask", the default): what the part
  shows, whatever it is made of. The simulated VLM makes one per mask, and its candidates share it. Part ``s``
  hears it with ``w_s = P x share_s x max(cover_s, share_s)``. ``P`` is the mask's summed confidence (at most 1).
  ``cover_s`` is the part's mixture weight of the materials the mask named: the call is about the part as far as
  the part is of one of them, or as far as the part is what the mask shows (it fills the mask). The larger of
  the two is how far at least one of them holds. ``w_s`` is split among the candidates (they may call it
  differently) by ``p x pi_sc``, or by ``p`` where no candidate's material is in the part's mixture.
* ``w_s`` is never less than ``sum_c p_c x share_s x pi_sc`` (the weight of "material": the call counted like
  the thickness), and never more than ``share_s``.

Why: with "material", a part whose material the views split between two names heard only a fraction of what
the views said about it: a part of a closed cardboard box that is 0.63 paper and 0.28 cardboard, while its masks
mostly name cardboard first, hears 2.2 observations' weight (solid with p = 0.19, the box several times its mass
by the mean); with "mask" it hears 5.3 (solid with p = 0.05). Its share alone, with no material test, would give it
more, but then a shoe's rubber sole would hear "hollow" from its leather upper's masks, which spill onto it in the
z-buffer, and weigh as hollow. The material test keeps such spill out. The share lets a mask that is mostly the part
speak for it.

* Hollowness of part ``s``: Beta(a, b) with ``a = a0 + sum w_s [hollow]``, ``b = b0 + sum w_s [solid]``, the
  posterior of ``theta_s``, the rate at which a view of the part answers "hollow". The prior has
  ``prior_strength`` pseudo-observations with mean ``prior_hollow_if_library_shell`` when the part's dominant
  material has a typical wall thickness in the material library, else ``prior_hollow_otherwise``.
* The part itself is hollow or solid, not a blend: it is hollow when most views would say so,
  ``theta_s > 1/2``, and ``p_hollow = P(theta_s > 1/2)`` under the Beta posterior. Why not ``E[theta_s]``:
  that is the chance that the *next answer* says hollow. With answers wrong at a rate ``e`` (the simulated
  VLM flips 10%), ``E[theta]`` stays near ``1 - e`` however many views agree, and a vase whose cavity is 8x
  its wall volume would carry a 10% "solid" branch worth ~0.8x its mass. ``P(theta > 1/2)`` goes to 1 as
  agreeing answers accumulate and stays near 1/2 when they split, which is the uncertainty we want.
* Wall thickness: a Normal-Inverse-Gamma posterior on ``log t`` (:func:`physgs_nerfstudio.bayes.nig_posterior`)
  from the hollow answers (weights ``p x share_s x pi_sc``), with prior mean the log of the library's typical
  thickness (else ``default_thickness_m``), ``kappa0`` = 1 and a prior spread of a factor
  ``prior_thickness_spread`` (90%).

So a table with solid steel legs and a steel pan both come out right: the legs' masks are answered solid, the
pan's hollow, whatever their material has in the library.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch

from ..bayes.nig import NIG, Moments, nig_posterior
from .capture import CaptureView, MaskObservation
from .grid import VoxelGrid
from .part_evidence import observation_shares, part_maps

__all__ = ["PartStructure", "StructureConfig", "fuse_structure", "part_maps"]

_Z90 = 1.6448536269514722


@dataclass
class StructureConfig:
    prior_strength: float = 1.0
    prior_hollow_if_library_shell: float = 0.6
    prior_hollow_otherwise: float = 0.3
    default_thickness_m: float = 0.003
    prior_thickness_spread: float = 2.0
    """90% of the prior's thickness mass within [t / spread, t x spread]"""
    evidence: Literal["mask", "material"] = "mask"
    """how much of an answer's hollow-or-solid call concerns a part (module doc, "Evidence"): "mask", the mask's one
    judgment, as far as the part fills the mask or is of a material the mask named; "material", each candidate by its confidence times the part's mixture weight of its material"""

    def __post_init__(self) -> None:
        if self.prior_strength <= 0:
            raise ValueError(f"StructureConfig.prior_strength must be > 0, got {self.prior_strength}.")
        if self.prior_thickness_spread <= 1:
            raise ValueError("StructureConfig.prior_thickness_spread must be > 1.")
        if self.evidence not in ("mask", "material"):
            raise ValueError(f"StructureConfig.evidence must be 'mask' or 'material', got {self.evidence!r}.")


@dataclass
class PartStructure:
    hollow_a: np.ndarray
    hollow_b: np.ndarray
    thickness: NIG
    """NIG on log(thickness in metres), shape [P]"""
    observations: np.ndarray
    """[P] summed weights ``w_s`` of the hollow-or-solid calls that concern each part (module doc, "Evidence")"""

    @property
    def p_hollow(self) -> np.ndarray:
        """P(theta > 1/2): the probability that the part is hollow (module doc)."""
        from scipy.special import betainc  # lazily: a PLY-only export needs no SciPy
        return 1.0 - betainc(self.hollow_a, self.hollow_b, 0.5)

    @property
    def answer_rate(self) -> np.ndarray:
        """E[theta]: the posterior mean rate of "hollow" answers."""
        return self.hollow_a / (self.hollow_a + self.hollow_b)

    def sample_hollow(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """bool [n, P]: hollow per sample and part, theta ~ Beta(a, b), hollow = theta > 1/2."""
        return rng.beta(self.hollow_a[None, :], self.hollow_b[None, :], size=(n, len(self.hollow_a))) > 0.5

    def thickness_m(self) -> np.ndarray:
        """Posterior median thickness per part (metres)."""
        return np.exp(self.thickness.tau.double().cpu().numpy())

    def to_list(self) -> list[dict]:
        t = self.thickness
        ph, rate = self.p_hollow, self.answer_rate
        return [{"p_hollow": float(ph[i]), "hollow_answer_rate": float(rate[i]),
                 "beta": [float(self.hollow_a[i]), float(self.hollow_b[i])],
                 "thickness_m": float(math.exp(float(t.tau[i]))),
                 "log_thickness_nig": {"tau": float(t.tau[i]), "kappa": float(t.kappa[i]), "a": float(t.a[i]),
                                       "b": float(t.b[i])},
                 "observation_weight": float(self.observations[i])} for i in range(len(self.hollow_a))]  # fmt: skip


def _evidence_weights(shares: Sequence[tuple[int, np.ndarray]], observations: Sequence[MaskObservation],
                      part_mixture: np.ndarray, mat_index: dict[str, int], evidence: str
                      ) -> list[tuple[np.ndarray, np.ndarray] | None]:  # fmt: skip
    """Per shared observation, float64 [P] weights per part of its hollow-or-solid answer and of its thickness
    (None: its material is not among the parts'), as the module doc's "Evidence" defines them."""
    fit: list[np.ndarray | None] = []  # p_c share_s pi_sc: the answer as far as the part is of its material
    for i, share in shares:
        k = mat_index.get(observations[i].material)
        fit.append(None if k is None else observations[i].confidence * share * part_mixture[:, k])
    if evidence == "material":
        return [None if f is None else (f, f) for f in fit]
    groups: dict[tuple, list[int]] = {}  # the candidates of one mask
    for j, (i, _) in enumerate(shares):
        ob = observations[i]
        if fit[j] is not None:
            groups.setdefault((ob.view, ob.mask_id if ob.mask_id is not None else id(ob.mask)), []).append(j)
    out: list[tuple[np.ndarray, np.ndarray] | None] = [None] * len(shares)
    for js in groups.values():
        cands = [observations[shares[j][0]] for j in js]
        p = np.array([ob.confidence for ob in cands])
        match = np.stack([fit[j] for j in js])  # type: ignore[misc]  # [n, P]
        total = match.sum(0)
        share = shares[js[0]][1]
        cover = part_mixture[:, sorted({mat_index[ob.material] for ob in cands})].sum(1)
        mask_w = min(p.sum(), 1.0) * share * np.maximum(cover, share)  # [P] the mask's call, the part's share
        # split among the candidates by how well each one fits the part; where none does, by their confidences
        by_conf = (p / max(p.sum(), 1e-300))[:, None]
        resp = np.where(total > 0, match / np.where(total > 0, total, 1.0), by_conf)
        for r, j in zip(resp, js):
            out[j] = (mask_w * r, fit[j])  # type: ignore[assignment]
    return out


def fuse_structure(
    grid: VoxelGrid,
    parts: np.ndarray,
    num_parts: int,
    views: Sequence[CaptureView],
    observations: Sequence[MaskObservation],
    library_thickness: Sequence[float | None],
    part_mixture: np.ndarray,
    material_names: Sequence[str],
    cfg: StructureConfig | None = None,
    *,
    shares: Sequence[tuple[int, np.ndarray]] | None = None,
) -> PartStructure:
    """Per-part Beta hollowness and NIG log-thickness (module doc). ``library_thickness[s]``: the library's
    typical wall thickness of part ``s``'s dominant material (None: the library calls it solid). ``shares``:
    :func:`physgs_nerfstudio.geometry.part_evidence.observation_shares` of these parts, views and observations,
    when already computed."""
    cfg = cfg or StructureConfig()
    P = num_parts
    lib = np.array([t is not None for t in library_thickness], dtype=bool)
    p0 = np.where(lib, cfg.prior_hollow_if_library_shell, cfg.prior_hollow_otherwise)
    a = cfg.prior_strength * p0
    b = cfg.prior_strength * (1 - p0)
    W = np.zeros(P)
    S = np.zeros(P)
    Q = np.zeros(P)
    seen = np.zeros(P)
    mat_index = {n: i for i, n in enumerate(material_names)}
    if shares is None:
        shares = observation_shares(grid, parts, P, views, observations)
    weights = _evidence_weights(shares, observations, part_mixture, mat_index, cfg.evidence)
    for (i, _share), w in zip(shares, weights):
        ob = observations[i]
        if w is None:
            continue
        wt, wthick = w
        seen += wt
        if ob.thickness_m is not None:
            a += wt
            lt = math.log(ob.thickness_m)
            W += wthick
            S += wthick * lt
            Q += wthick * lt * lt
        else:
            b += wt
    t0 = np.array([math.log(t if t is not None else cfg.default_thickness_m) for t in library_thickness])
    s0 = math.log(cfg.prior_thickness_spread) / _Z90
    a0 = 2.0
    prior = NIG(torch.as_tensor(t0), torch.ones(P, dtype=torch.float64), torch.full((P,), a0, dtype=torch.float64),
                torch.full((P,), s0**2 * (a0 - 1), dtype=torch.float64))  # fmt: skip
    post = nig_posterior(prior, Moments(torch.as_tensor(W), torch.as_tensor(S), torch.as_tensor(Q)))
    return PartStructure(a, b, post, seen)
