"""Object mass with an honest interval: Monte Carlo over geometry, materials, densities, structure and thickness.

Per sample (``n_samples``, ``seed``-ed numpy Generator), all draws from one joint model:

* **Geometry**: one carving variant (:mod:`physgs_nerfstudio.geometry.reconstruct`), uniformly; it fixes every
  part's volume ``V_p`` and wall area ``A_p``.
* **Material**: each part draws one quantile level ``u``; each of its voxels takes the material at ``u`` of its
  own mixture (:func:`physgs_nerfstudio.geometry.parts.material_quantiles`): equally unsure voxels switch
  together (the ambiguity stays in the interval), sure but different voxels keep their own materials (a part's
  5% steel share stays 5% of its volume).
* **Density**: one draw per material from the posterior of its mean (NIG: Student-t(2a, tau, sqrt(b/(a kappa))),
  in log space where configured; ``density_draw="predictive"`` uses the full predictive). Every part of that
  material uses the same draw (densities are fully correlated across the object).
* **Structure**: each part draws its "hollow" answer rate ``theta_p`` from its Beta posterior
  (:mod:`physgs_nerfstudio.geometry.structure`) and is hollow when ``theta_p > 1/2``; a hollow part draws its
  wall thickness ``t_p`` from the posterior of its log-thickness mean.
* **Seams** (``seam_offset_voxels``): where two parts meet inside the object (a shoe's rubber sole under its
  leather upper, a hammer's steel head on its oak handle), no view sees the boundary: each inside voxel takes the
  material of the nearest surface evidence (:func:`physgs_nerfstudio.geometry.parts.voxel_mixture`), so the seam is
  the seen one carried inwards, placed to about the carving's resolution ``u``. Each seam between parts ``i`` and
  ``j``, of area ``a_ij`` (:func:`physgs_nerfstudio.geometry.walls.seam_areas`), moves by its own offset
  ``e ~ N(0, (s_seam u)^2)`` per sample: ``a_ij e`` of volume passes from ``j`` to ``i`` (or back), the object's
  volume unchanged (no part below 0). Which side of a seam holds the volume decides its density and whether it
  weighs at all (the inside of a hollow part does not), so this moves the mass where parts of unlike weight meet
  and not elsewhere.
* **Unseen boundary** (:func:`physgs_nerfstudio.geometry.hidden.hidden_boundary`): the kept voxels on the boundary
  with the hidden open space (a top's unseen underside: :mod:`physgs_nerfstudio.geometry.hidden`, "The boundary with
  hidden open space") hold the object's surface somewhere inside them, or just past them. ``V_p`` counts them at
  half a voxel; each sample draws their occupancy ``o ~ U(0, 1)``, one for every such voxel of the object (one
  unseen face, one offset), so a solid part's volume becomes ``V_p + (o - 1/2) B_p``, ``B_p`` the part's volume of
  them as whole voxels (drawn after the seams: the draws above stay unchanged).
* **Surface placement** (``surface_offset_voxels``): where the carving put the object's surface is known to about
  its resolution ``u`` (a mask a pixel wider or narrower, a vote decided by one view, a depth a voxel off), and
  one such error moves every face of the object the same way. Each sample draws one offset
  ``e ~ N(0, (s_surf u)^2)`` for the whole object (drawn last: the draws above stay unchanged). A solid part's
  volume grows by ``S_p e`` outwards (``S_p`` its surface area) and shrinks to ``V_p exp(S_p e / V_p)`` inwards (the
  same slope at 0; an eroded part shrinks towards nothing, never below it), and so does a hollow part's cap; a
  hollow part's wall area moves the same way by ``2 M_p e`` (``M_p`` the integrated mean curvature of its fully
  counted faces: ``d(4 pi R^2) = 8 pi R dR`` on a sphere). Each is divided by its mean growth over the offsets
  (:func:`_grown`), so that the offset widens the interval without moving the mean: over the suite the carving's
  volume is not biased one way (``SURFACE_OFFSET_VOXELS``), and the mean is the reported estimate. Thin parts (a
  chair's legs, a plank), which hold much of their volume in one unit of surface, widen the interval most; a hollow
  part's wall mass barely moves.
* Part mass: ``rho x V_p`` (solid) or ``rho x min(V*_p, W_p(t_p))`` (hollow); the object's mass is the sum. The
  cap ``V*_p`` is the part's largest volume over the variants: the wall lies inside the
  object, and the carving that kept the most of it bounds it, while a variant that carves more only samples where
  the surface lies (with its own ``V_p`` as the cap, a cup carved down to its wall came out 4-7% light). The
  wall's volume ``W_p`` (:func:`wall_volume`) is ``A_p t_p`` where the faces are sheets (both sides of the wall
  reconstructed: their half areas add up to its middle surface) and shrinks with the mean curvature where the wall
  lies inside a fully counted face (a closed bottle's glass, a tube's wall).

The reported mean, median and central ``level`` interval all come from these same samples. The report also
gives, per part, ``surface_layer_share`` = ``S u / V`` (:func:`_layer_share`): how much of its volume one
resolution unit of surface holds, i.e. how far its mass moves when its faces are placed a unit off (about
``2 / n`` for a slab ``n`` units thick); the object's is the solid parts' shares weighted by their mass, over
the whole mass (:func:`_mass_layer_share`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import numpy as np
import torch

from ..advanced import Advanced
from ..geometry import GeometryConfig, ObjectGeometry

__all__ = ["MassConfig", "MassDraws", "MassReport", "MaterialMass", "integrate_mass", "mass_draws", "seam_transfer",
           "wall_volume"]


SURFACE_OFFSET_VOXELS = 0.6
"""How far off the carved surface lies, one standard deviation in resolution units (module doc, "Surface
placement"). Over the objects of the development families whose every part is solid, in CPU demo runs (three run
sets: path traced at two seeds, the project's renderer at one; 18 objects), ``z = (V - V_true) / (S u)``, the volume
error in units of one resolution unit of surface, has a robust spread (1.4826 x its median absolute value) of 0.60
and a median near 0 (path traced alone: 0.81 and -0.12; the project's renderer alone: 0.31 and +0.16):
``benchmarks/mass_stability.py --surface-offset``, ``benchmarks/results/surface_offset_cpu.json``."""


@dataclass
class MassConfig:
    """Mass settings: the geometry and the Monte Carlo (module doc)."""

    geometry: Advanced[GeometryConfig] = field(default_factory=GeometryConfig)
    structure: Literal["auto", "solid", "hollow"] = "auto"
    """How parts are filled: auto decides solid or hollow per part from perception; solid or hollow forces all."""
    density_key: Advanced[str] = "density"
    density_draw: Advanced[Literal["posterior", "predictive"]] = "posterior"
    level: float = 0.9
    """Probability of the central mass interval."""
    n_samples: int = 4000
    """Monte Carlo samples of the mass."""
    seed: int = 0
    """Seed of the Monte Carlo samples."""
    seam_offset_voxels: Advanced[float] = 1.0
    """spread (one standard deviation) of each seam between two parts inside the object, in units of the carving's
    resolution, one draw per seam and sample (module doc, "Seams"). 1.0: the root mean square of the seams' offsets
    against the truth, each seam weighted by its area (0.95 over the seams of CPU demo runs of the development objects); 0: the seams stay where the geometry put them"""
    surface_offset_voxels: Advanced[float] = SURFACE_OFFSET_VOXELS
    """spread (one standard deviation) of the object's surface placement, in units of the carving's resolution, one
    draw per sample for all its faces (module doc, "Surface placement"); 0: the surface stays where the carving put
    it"""

    def __post_init__(self) -> None:
        if not 0 < self.level < 1:
            raise ValueError(f"MassConfig.level must be in (0, 1), got {self.level}.")
        if not (math.isfinite(self.seam_offset_voxels) and self.seam_offset_voxels >= 0):
            raise ValueError(f"MassConfig.seam_offset_voxels must be finite and >= 0, got {self.seam_offset_voxels}.")
        if not (math.isfinite(self.surface_offset_voxels) and self.surface_offset_voxels >= 0):
            raise ValueError(f"MassConfig.surface_offset_voxels must be finite and >= 0, got "
                             f"{self.surface_offset_voxels}.")  # fmt: skip
        if self.n_samples < 10:
            raise ValueError(f"MassConfig.n_samples must be >= 10, got {self.n_samples}.")
        if self.structure not in ("auto", "solid", "hollow"):
            raise ValueError(f"MassConfig.structure must be auto|solid|hollow, got {self.structure!r}.")
        if self.density_draw not in ("posterior", "predictive"):
            raise ValueError(f"density_draw must be posterior|predictive, got {self.density_draw!r}.")


@dataclass
class MaterialMass:
    name: str
    volume_model: str
    """solid | shell | mixed: how the parts of this material were integrated (majority of the samples)"""
    thickness_m: float | None
    volume_m3: float
    volume_share: float
    area_m2: float
    density_mean: float
    density_interval: tuple[float, float]
    mass_mean_kg: float
    mass_interval_kg: tuple[float, float]
    mass_share: float


@dataclass
class MassReport:
    mean_kg: float
    median_kg: float
    interval_kg: tuple[float, float]
    level: float
    n_samples: int
    seed: int
    volume_m3: float
    area_m2: float
    materials: list[MaterialMass]
    metres_per_unit: float
    scale_source: str
    simulated: bool
    geometry: dict[str, Any]
    parts: list[dict[str, Any]] = field(default_factory=list)
    units: dict[str, str] = field(default_factory=lambda: {
        "mass": "kg", "volume": "m^3", "area": "m^2", "density": "kg/m^3", "thickness": "m",
        "voxel_size": "m"})  # fmt: skip
    samples: np.ndarray | None = field(default=None, repr=False)

    def covers(self, value: float) -> bool:
        return self.interval_kg[0] <= value <= self.interval_kg[1]

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d.pop("samples")
        return d

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> MassReport:
        d = dict(data)
        d["materials"] = [MaterialMass(**m) for m in d.get("materials", [])]
        d["interval_kg"] = tuple(d["interval_kg"])
        return cls(**{k: v for k, v in d.items() if k in cls.__dataclass_fields__})


def _density_draws(pf: Any, cfg: MassConfig, rng: np.random.Generator) -> np.ndarray:
    """[S, K] density draws (linear units), one per material per sample."""
    p = pf.property_index(cfg.density_key)
    nig = pf.nig.to(torch.float64)
    df, loc, scale = (t[:, p].cpu().numpy() for t in nig.student_t())
    if cfg.density_draw == "posterior":
        scale = np.sqrt(nig.b[:, p].cpu().numpy() / (nig.a[:, p].cpu().numpy() * nig.kappa[:, p].cpu().numpy()))
    x = loc[None, :] + scale[None, :] * rng.standard_t(df[None, :], size=(cfg.n_samples, len(df)))
    if pf.log_space[p]:
        return np.exp(np.clip(x, -700, 700))
    return np.clip(x, 0.0, None)


def wall_volume(area: np.ndarray, full_area: np.ndarray, curvature: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Volume of a wall of thickness ``t`` (arrays broadcast; any consistent length unit). ``area``: the part's wall
    area (sheet faces at half weight); ``full_area`` of it lies on fully counted faces, whose wall lies inside them,
    with integrated mean curvature ``curvature`` (:mod:`physgs_nerfstudio.geometry.walls`). Under those faces the
    area at depth ``s`` is taken as ``A (1 - s / R)^2`` with ``R = A / M``, which gives ``A t - M t^2 + ...``, the
    first two terms of the wall's exact volume for any surface, and is exact for a sphere:
    ``A t (1 - x + x^2 / 3)`` with ``x = t M / A``, and ``A^2 / (3 M)`` (the whole inside) once ``x >= 1``. Where
    ``M <= 0`` (a concave face) the wall holds more than ``A t``. The rest of the area holds ``area x t``."""
    area, full_area, curvature, t = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64)
                                                          for v in (area, full_area, curvature, t)))  # fmt: skip
    full = np.clip(full_area, 0.0, area)
    x = np.divide(t * curvature, full, out=np.zeros_like(t), where=full > 0)
    g = np.where(x <= 1.0, 1.0 - x + x * x / 3.0, 1.0 / (3.0 * np.maximum(x, 1.0)))
    return (area - full) * t + full * t * g


def seam_transfer(seams: np.ndarray, sigma: float, rng: np.random.Generator, n: int) -> np.ndarray:
    """[n, P] volume each part gains (negative: loses) when every seam moves by its own normal offset of spread
    ``sigma`` (module doc, "Seams"); ``seams``: [P, P] symmetric seam areas. Each row sums to zero."""
    i, j = np.nonzero(np.triu(seams, 1))
    if len(i) == 0:
        return np.zeros((n, seams.shape[0]))
    t = seams[i, j][None, :] * sigma * rng.standard_normal((n, len(i)))  # [n, seams]: from j to i
    incidence = np.zeros((len(i), seams.shape[0]))
    incidence[np.arange(len(i)), i], incidence[np.arange(len(i)), j] = 1.0, -1.0
    return t @ incidence


def _structure_draws(geo: ObjectGeometry, cfg: MassConfig, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(hollow bool [S, P], thickness metres [S, P])."""
    S, P = cfg.n_samples, geo.num_parts
    st = geo.structure
    if cfg.structure == "auto":
        hollow = st.sample_hollow(rng, S)
    else:
        hollow = np.full((S, P), cfg.structure == "hollow")
    t = st.thickness
    tau, kappa, a, b = (x.double().cpu().numpy() for x in (t.tau, t.kappa, t.a, t.b))
    scale = np.sqrt(b / (a * kappa))
    thick = np.exp(tau[None, :] + scale[None, :] * rng.standard_t(2 * a[None, :], size=(S, P)))
    return hollow, thick


def _material_shares(geo: ObjectGeometry, rng: np.random.Generator, S: int) -> np.ndarray:
    """[S, P, K] volume share per material of each part in each sample (module doc, "Material")."""
    levels = geo.material_levels
    if levels is None:  # one material per part, drawn from its mixture
        levels = np.eye(geo.part_mixture.shape[1])[None].repeat(geo.num_parts, 0)  # [P, K, K]
        cum = np.cumsum(geo.part_mixture, 1)
        cum[:, -1] = 1.0
        j = np.minimum((rng.random((S, geo.num_parts))[:, :, None] > cum[None]).sum(-1), cum.shape[1] - 1)
    else:
        j = rng.integers(levels.shape[1], size=(S, geo.num_parts))
    return levels[np.arange(geo.num_parts)[None, :], j]


@dataclass
class MassDraws:
    """The Monte Carlo samples behind a :class:`MassReport` (module doc), one row per sample: what the report's
    mean and interval summarise and what simulator bodies are built from (:mod:`physgs_nerfstudio.sim`)."""

    variant: np.ndarray
    """int [S]: the carving variant of each sample (index into ``ObjectGeometry.variant_names``)"""
    share: np.ndarray
    """[S, P, K]: volume share per material of each part"""
    density: np.ndarray
    """[S, K]: density per material, kg/m^3"""
    hollow: np.ndarray
    """bool [S, P]: the part is a wall (its mass lies in its faces) rather than solid"""
    thickness_m: np.ndarray
    """[S, P]: wall thickness drawn for each part, metres (used where ``hollow``)"""
    solid_volume_m3: np.ndarray
    """[S, P]: each part's volume as a solid, m^3"""
    volume_m3: np.ndarray
    """[S, P]: the volume that weighs (the solid's, or the wall's where hollow), m^3"""
    part_mass_kg: np.ndarray
    """[S, P, K]: mass per part and material, kg"""
    unit: float
    """the carving's resolution, scene units"""

    @property
    def total_kg(self) -> np.ndarray:
        """[S]: the object's mass in each sample."""
        return self.part_mass_kg.sum((1, 2))


def mass_draws(pf: Any, geo: ObjectGeometry, cfg: MassConfig | None = None) -> MassDraws:
    """Draw the Monte Carlo samples of the object's mass (module doc); :func:`integrate_mass` summarises them."""
    cfg = cfg or MassConfig()
    mpu = pf.metres_per_unit
    rng = np.random.default_rng(cfg.seed)
    S = cfg.n_samples
    G = geo.volumes.shape[0]
    gi = rng.integers(G, size=S) if G > 1 else np.zeros(S, np.int64)
    V = geo.volumes[gi] * mpu**3  # [S, P] m^3
    A = geo.areas[gi] * mpu**2  # [S, P] m^2
    share = _material_shares(geo, rng, S)  # [S, P, K]
    rho = _density_draws(pf, cfg, rng)  # [S, K]
    hollow, thick = _structure_draws(geo, cfg, rng)
    unit = geo.grid.voxel_size * max(1.0, geo.pixel_voxels)  # the carving's resolution, scene units
    V_solid = V
    cap = geo.volumes.max(0)[None, :] * mpu**3  # a hollow part's wall holds at most the carving that kept the most
    if cfg.seam_offset_voxels > 0 and geo.seam_areas is not None:  # drawn after the others: they stay unchanged
        moved = seam_transfer(geo.seam_areas * mpu**2, cfg.seam_offset_voxels * unit * mpu, rng, S)
        cap, V_solid = (np.maximum(x + moved, 0.0) for x in (cap, V_solid))
    if geo.hidden_boundary is not None:  # drawn after the seams
        o = rng.random(S) - geo.hidden_boundary_fill
        V_solid = np.maximum(V_solid + o[:, None] * geo.hidden_boundary[gi] * mpu**3, 0.0)
    full = geo.full_areas[gi] * mpu**2 if geo.full_areas is not None else None
    curv = geo.curvatures[gi] * mpu if geo.curvatures is not None else None
    if cfg.surface_offset_voxels > 0:  # drawn last: the draws above stay unchanged
        cap, V_solid, A, full = _offset_surface(geo, gi, cfg.surface_offset_voxels * unit, rng, cap, V_solid, A, full,
                                               mpu)
    wall = wall_volume(A, full, curv, thick) if full is not None and curv is not None else A * thick
    vol = np.where(hollow, np.minimum(cap, wall), V_solid)
    m_pk = share * rho[:, None, :] * vol[:, :, None]  # [S, P, K]
    return MassDraws(gi, share, rho, hollow, thick, V_solid, vol, m_pk, unit)


def _grown(x: np.ndarray, rate: np.ndarray, e: np.ndarray, sigma: float) -> np.ndarray:
    """``x`` moved by ``rate x e`` (module doc, "Surface placement"): ``x + rate e`` outwards and ``x exp(rate e / x)``
    inwards (the same slope at 0, never below 0), over its mean growth for offsets of spread ``sigma``, so that its
    mean stays ``x``. With ``a = |rate| sigma / x`` and ``z`` standard normal, the growth ``g(a z)`` has the mean
    ``1/2 + a / sqrt(2 pi) + exp(a^2 / 2) Phi(-a)`` (the last term ``erfcx(a / sqrt 2) / 2``: no overflow)."""
    from scipy.special import erfcx

    d = rate * e
    rel = np.divide(d, x, out=np.zeros_like(d), where=x > 0)
    a = np.divide(np.abs(rate) * sigma, x, out=np.zeros_like(d), where=x > 0)
    mean = 0.5 + a / math.sqrt(2 * math.pi) + 0.5 * erfcx(a / math.sqrt(2))
    return x * np.where(rel >= 0, 1.0 + rel, np.exp(np.minimum(rel, 0.0))) / mean


def _offset_surface(geo: ObjectGeometry, gi: np.ndarray, sigma: float, rng: np.random.Generator, cap: np.ndarray,
                    V: np.ndarray, A: np.ndarray, full: np.ndarray | None, mpu: float) -> tuple[np.ndarray, ...]:  # fmt: skip
    """``cap``, ``V`` (m^3), ``A`` and ``full`` (m^2) after one surface offset per sample of spread ``sigma`` (scene
    units; module doc, "Surface placement")."""
    s = sigma * mpu  # metres
    e = s * rng.standard_normal(len(gi))[:, None]  # [S, 1] metres, outwards
    S = geo.surface_areas[gi] * mpu**2
    cap, V = _grown(np.broadcast_to(cap, V.shape), S, e, s), _grown(V, S, e, s)
    if geo.curvatures is not None and full is not None:
        stretch = np.divide(_grown(A, 2.0 * geo.curvatures[gi] * mpu, e, s), A, out=np.ones_like(A), where=A > 0)
        A, full = A * stretch, full * stretch
    return cap, V, A, full


def integrate_mass(pf: Any, geo: ObjectGeometry, cfg: MassConfig | None = None, *,
                   keep_samples: bool = False, draws: MassDraws | None = None) -> MassReport:  # fmt: skip
    """Mass mean, median and interval of the object (module doc). ``pf``: the property field (materials' NIG
    posteriors, scale); ``geo``: :func:`physgs_nerfstudio.geometry.reconstruct_object` of its Gaussians;
    ``draws``: :func:`mass_draws` of the same field, geometry and ``cfg`` (None: drawn here)."""
    cfg = cfg or MassConfig()
    mpu = pf.metres_per_unit
    draws = draws if draws is not None else mass_draws(pf, geo, cfg)
    S, P, K = cfg.n_samples, geo.num_parts, pf.num_materials
    rho, V_solid, m_pk, unit = draws.density, draws.solid_volume_m3, draws.part_mass_kg, draws.unit
    m = m_pk.sum(-1)  # [S, P]
    total = m.sum(1)
    lo_q, hi_q = (1 - cfg.level) / 2, (1 + cfg.level) / 2
    q = lambda x: (float(np.quantile(x, lo_q)), float(np.quantile(x, hi_q)))
    Vn = geo.volumes[0] * mpu**3
    An = geo.areas[0] * mpu**2
    Sn = geo.surface_areas[0] * mpu**2
    V_k = (geo.part_mixture * Vn[:, None]).sum(0)
    A_k = (geo.part_mixture * An[:, None]).sum(0)
    rho_mean = pf.material_means()[:, pf.property_index(cfg.density_key)].cpu().numpy()
    mean = float(total.mean())
    materials = []
    st = geo.structure
    vk = geo.part_mixture * Vn[:, None]  # [P, K]
    p_h = np.divide((vk * st.p_hollow[:, None]).sum(0), vk.sum(0), out=np.zeros(K), where=vk.sum(0) > 0)
    t_med = st.thickness_m()
    for k in range(K):  # materials, not voxels
        per = m_pk[:, :, k].sum(1)
        model = "shell" if p_h[k] > 0.75 else "solid" if p_h[k] < 0.25 else "mixed"
        w = vk[:, k] * st.p_hollow
        t_k = float(np.exp((w * np.log(t_med)).sum() / w.sum())) if w.sum() > 0 else None
        materials.append(MaterialMass(
            name=pf.material_names[k], volume_model=model, thickness_m=t_k if model != "solid" else None,
            volume_m3=float(V_k[k]), volume_share=float(V_k[k] / max(V_k.sum(), 1e-30)), area_m2=float(A_k[k]),
            density_mean=float(rho_mean[k]), density_interval=q(rho[:, k]), mass_mean_kg=float(per.mean()),
            mass_interval_kg=q(per), mass_share=float(per.mean() / mean) if mean > 0 else 0.0,
        ))  # fmt: skip
    layer = [_layer_share(Sn[p], Vn[p], unit * mpu) for p in range(P)]
    parts = []
    for p, s in enumerate(st.to_list()):
        top = np.argsort(-geo.part_mixture[p])[:3]
        parts.append({"id": p, "material": pf.material_names[int(top[0])],
                      "mixture": {pf.material_names[int(i)]: float(geo.part_mixture[p, i]) for i in top
                                  if geo.part_mixture[p, i] > 1e-3},
                      "volume_m3": float(Vn[p]), "volume_interval_m3": q(V_solid[:, p]), "area_m2": float(An[p]),
                      "surface_area_m2": float(Sn[p]), "seams_m2": _seams(geo, p, mpu),
                      "wall_mean_curvature_per_m": _mean_curvature(geo, p, mpu),
                      "sheet_share": float(geo.sheet_share[p]), "structure": s,
                      "surface_layer_share": layer[p],
                      "mass_mean_kg": float(m[:, p].mean()), "mass_interval_kg": q(m[:, p])})  # fmt: skip
    solid_p = st.p_hollow < 0.5
    info = {**geo.summary(), "voxel_size_m": geo.grid.voxel_size * mpu, "structure_mode": cfg.structure,
            "density_draw": cfg.density_draw, "num_gaussians": int(pf.num_gaussians),
            "seam_offset_voxels": cfg.seam_offset_voxels, "surface_offset_voxels": cfg.surface_offset_voxels,
            "surface_area_m2": float(Sn.sum()), "resolution_unit_m": unit * mpu,
            "surface_layer_share": _mass_layer_share(m.mean(0), layer, solid_p),
            "volume_by_variant_m3": {n: float(v.sum() * mpu**3) for n, v in zip(geo.variant_names, geo.volumes)}}
    return MassReport(
        mean_kg=mean, median_kg=float(np.median(total)), interval_kg=q(total), level=cfg.level, n_samples=S,
        seed=cfg.seed, volume_m3=float(Vn.sum()), area_m2=float(An.sum()), materials=materials,
        metres_per_unit=mpu, scale_source=pf.scale_source, simulated=pf.simulated, geometry=info, parts=parts,
        samples=total if keep_samples else None,
    )  # fmt: skip


def _layer_share(surface_m2: float, volume_m3: float, unit_m: float) -> float | None:
    """The share of a solid's volume that one resolution unit of its surface holds, ``S u / V`` (None without
    volume): how far its mass moves when every face is placed a unit off. A slab ``n`` units thick gives about
    ``2 / n``: a two-voxel table top 1, so half a voxel on each face moves it by half (docs/mass.md)."""
    return float(surface_m2 * unit_m / volume_m3) if volume_m3 > 0 else None


def _mass_layer_share(mass: np.ndarray, layer: list[float | None], solid: np.ndarray) -> float | None:
    """The share of the object's mass that one resolution unit of its solid parts' surface holds: each solid
    part's mean ``mass`` times its ``layer`` share (:func:`_layer_share`), over the whole mean mass (a hollow
    part's wall does not move with its faces). None where no solid part has volume."""
    keep = [p for p, x in enumerate(layer) if solid[p] and x is not None]
    if not keep or mass.sum() <= 0:
        return None
    return float(sum(mass[p] * layer[p] for p in keep) / mass.sum())


def _seams(geo: ObjectGeometry, p: int, mpu: float) -> dict[str, float]:
    """Part ``p``'s seams: the other part's id -> the area between them (m^2)."""
    if geo.seam_areas is None:
        return {}
    return {str(q): float(a * mpu**2) for q, a in enumerate(geo.seam_areas[p]) if a > 0}


def _mean_curvature(geo: ObjectGeometry, p: int, mpu: float) -> float | None:
    """Part ``p``'s mean curvature over its fully counted faces (1/m, nominal solid); None where it has none."""
    if geo.curvatures is None or geo.full_areas is None or geo.full_areas[0, p] <= 0:
        return None
    return float(geo.curvatures[0, p] / geo.full_areas[0, p] / mpu)


def library_thickness(pf: Any) -> list[float | None]:
    """Per material of ``pf`` the typical wall thickness (metres; None = solid) it carries (materials.json,
    else the library: :func:`physgs_nerfstudio.export.field.load_thickness`)."""
    return [None if t is None or not math.isfinite(t) else float(t) for t in pf.thickness_m]
