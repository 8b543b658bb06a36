"""Object mass with uncertainty from a :class:`PropertyField` (DESIGN.md section 3, "Mass").

Two volume models, chosen per material (``auto``: the material's ``thickness_m`` is None -> ``solid``, else
``shell``; ``volume_model`` forces one for all, ``volume_models`` per material name):

* ``solid``: M = sum_v rho(v) dV over the object's filled volume (:mod:`.occupancy`: opacity field on a
  voxel grid, threshold, interior fill, largest component or bounding box; thin-sheet voxels between a
  filled cavity and the outside count half, :func:`.occupancy.volume_weights`).
* ``shell``: M = A x t x rho, with A the wall area from marching cubes (:mod:`.surface`: the filled
  object's boundary, counted once where the object is bulky under it, e.g. a closed hollow object whose
  inside was filled, and half where the object is a sheet no thicker than about twice the largest wall
  thickness, e.g. an open wall whose two sides were both reconstructed), each surface element assigned to materials by the mixture of the Gaussians near it,
  and t the material's wall thickness: the VLM's ``thickness_m`` fused into materials.json, else the
  material library's typical value (``default_thickness_m`` when forced on a material without one).

NeRF2Physics (Zhai et al., CVPR 2024) integrates density over points sampled on the reconstructed surface
times an LLM-proposed thickness, with a fixed 0.6 correction factor for hollow objects. We instead measure the
wall area explicitly (sheet or bulk decided per surface element, so open and closed walls both work), take the thickness per material from perception and the library, carry its uncertainty into the
interval, and use the filled volume for solid materials; no global correction factor.

Per voxel, the material mixture pi_v is the opacity-weighted mean of the Gaussians' posterior predictive
(:func:`.occupancy.voxel_materials`); the density mean of material i is its predictive mean (log-space:
exp(tau + v/2), the moment-matched lognormal of :func:`physgs_nerfstudio.bayes.property_fields`). The
reported ``mean`` is the plug-in M = sum_i E[rho_i] (V_i or t_i A_i), with V_i = sum_v pi_vi dV and
A_i = sum_faces pi_fi area_f.

Monte Carlo interval (``n_samples`` draws, ``seed``-ed numpy Generator). Correlation structure:

* Material assignment: the object is cut into segments, the connected components (26-connectivity) of
  voxels sharing a dominant (argmax) material (``segments="dominant"``), or one segment for the whole object
  (``"object"``). Each segment draws ONE material per sample from its volume-weighted mixture; segments
  draw independently. Voxel-independent draws would average the ambiguity away (variance ~ 1/#voxels),
  although neighbouring voxels' mixtures come from the same few observations; a segment is the unit the
  perception labels as a whole (a part). Segments smaller than ``min_segment_fraction`` of the object are
  pooled into one residual segment. When segment s draws material c its contribution is
  (V_sc or t_c A_sc) / pi_sc x rho_c (importance weight), so the Monte Carlo mean equals the plug-in mean.
* Density: one draw per material per sample from the material's NIG predictive Student-t(2a, tau,
  sqrt(b (kappa+1) / (a kappa))) (``density_draw="posterior"``: the posterior of the material mean,
  scale sqrt(b / (a kappa))), in log space where configured (then exponentiated; linear draws are clipped
  at 0). Every voxel of that material uses the same draw: densities are fully correlated across the object.
* Thickness: one draw per shell material per sample, log-normal with median t_i and log-sd
  ln(thickness_spread) / 1.645 (90% of draws within [t / spread, t x spread]); fully correlated.

Reported: median and central ``level`` interval of the draws (the Student-t in log space has no finite
mean, so the Monte Carlo mean is not used), per material volume share, area, mass mean and interval.
Geometric uncertainty (threshold, reconstruction) is not sampled.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import numpy as np
import torch
from scipy import ndimage
from tqdm.auto import tqdm

from .field import PropertyField
from .occupancy import Occupancy, OccupancyConfig, compute_occupancy, volume_weights, voxel_materials
from .surface import extract_surface

logger = logging.getLogger(__name__)

__all__ = ["MassConfig", "MassGeometry", "MassReport", "MaterialMass", "integrate_mass", "mass_geometry",
           "resolve_volume_models"]

_Z90 = 1.6448536269514722  # standard normal 95% quantile


@dataclass
class MassConfig:
    """Mass integration settings (module doc)."""

    occupancy: OccupancyConfig = field(default_factory=OccupancyConfig)
    volume_model: Literal["auto", "solid", "shell"] = "auto"
    volume_models: dict[str, str] = field(default_factory=dict)
    """per material name: "solid" | "shell" (overrides volume_model)"""
    shell_surface: Literal["auto", "mid", "outer"] = "auto"
    """auto: filled-object boundary, halved where the object is a sheet (:mod:`.surface`); mid: half the
    opacity layer's boundary; outer: the filled object's boundary"""
    default_thickness_m: float = 0.003
    """wall thickness for a material forced to shell without a thickness of its own"""
    thickness_spread: float = 2.0
    """90% of thickness draws lie within [t / spread, t x spread]"""
    density_key: str = "density"
    density_draw: Literal["predictive", "posterior"] = "posterior"
    sheet_depth: float | None = None
    """auto shell surface: the object is a sheet where it is at most twice this deep (scene units); None =
    half the largest wall thickness + 2.5 x the Gaussians' median thinnest sigma (filtered) + 1.5 voxels,
    i.e. half a reconstructed wall"""
    segments: Literal["dominant", "object"] = "dominant"
    min_segment_fraction: float = 1e-3
    level: float = 0.9
    """central interval probability"""
    n_samples: int = 4000
    seed: int = 0

    def __post_init__(self) -> None:
        if not 0 < self.level < 1:
            raise ValueError(f"MassConfig.level must be in (0, 1), got {self.level}.")
        if self.n_samples < 10:
            raise ValueError(f"MassConfig.n_samples must be >= 10, got {self.n_samples}.")
        if self.thickness_spread < 1:
            raise ValueError(f"MassConfig.thickness_spread must be >= 1, got {self.thickness_spread}.")
        if self.volume_model not in ("auto", "solid", "shell"):
            raise ValueError(f"volume_model must be auto|solid|shell, got {self.volume_model!r}.")
        for name, m in self.volume_models.items():
            if m not in ("solid", "shell"):
                raise ValueError(f"volume_models[{name!r}] must be solid|shell, got {m!r}.")


@dataclass
class MaterialMass:
    name: str
    volume_model: str
    thickness_m: float | None
    volume_m3: float
    """filled volume assigned to the material (sum pi dV)"""
    volume_share: float
    area_m2: float
    """wall area assigned to the material (sum pi dA)"""
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


def resolve_volume_models(pf: PropertyField, cfg: MassConfig) -> tuple[list[str], list[float | None]]:
    """Per material (volume model, thickness in metres or None for solid)."""
    models, thick = [], []
    unknown = set(cfg.volume_models) - set(pf.material_names)
    if unknown:
        raise ValueError(f"volume_models names {sorted(unknown)} are not in the legend {pf.material_names}.")
    for name, t in zip(pf.material_names, pf.thickness_m):
        m = cfg.volume_models.get(name, cfg.volume_model)
        if m == "auto":
            m = "solid" if t is None else "shell"
        if m == "shell" and t is None:
            logger.warning("material %r forced to shell without a thickness: using %.4g m", name,
                           cfg.default_thickness_m)  # fmt: skip
            t = cfg.default_thickness_m
        models.append(m)
        thick.append(t if m == "shell" else None)
    return models, thick


def _sheet_depth(pf: PropertyField, cfg: MassConfig, occ: Occupancy) -> float:
    if cfg.sheet_depth is not None:
        return float(cfg.sheet_depth)
    _, thick = resolve_volume_models(pf, cfg)
    t_max = max([t for t in thick if t is not None], default=0.0) / pf.metres_per_unit
    keep = occ.gaussians if occ.gaussians is not None else pf.opacities >= cfg.occupancy.min_opacity
    thin = pf.scales[keep].amin(-1).float()
    sigma = torch.sqrt(thin.median() ** 2 + occ.filter_sigma**2).item() if thin.numel() else occ.filter_sigma
    return 0.5 * t_max + 2.5 * sigma + 1.5 * occ.grid.voxel_size


def _segments(occ: Occupancy, pi_solid: np.ndarray, dv: np.ndarray, cfg: MassConfig) -> np.ndarray:
    """Segment id per solid voxel (in ``np.nonzero(occ.solid)`` order)."""
    n = pi_solid.shape[0]
    if cfg.segments == "object":
        return np.zeros(n, dtype=np.int64)
    if cfg.segments != "dominant":
        raise ValueError(f"segments must be dominant|object, got {cfg.segments!r}.")
    dom = np.argmax(pi_solid, axis=1)
    grid = np.full(occ.solid.shape, -1, dtype=np.int64)
    idx = np.nonzero(occ.solid)
    grid[idx] = dom
    seg = np.zeros(n, dtype=np.int64)
    offset = 0
    structure = np.ones((3, 3, 3), dtype=bool)
    for k in np.unique(dom):  # loop over materials present, not voxels
        lab, nk = ndimage.label(grid == k, structure=structure)
        vox = dom == k
        seg[vox] = lab[idx][vox] - 1 + offset
        offset += nk
    # pool tiny segments into one residual segment
    vol = np.bincount(seg, weights=dv, minlength=offset)
    small = vol < cfg.min_segment_fraction * vol.sum()
    if small.any() and (~small).any():
        remap = np.cumsum(~small) - 1
        remap[small] = int((~small).sum())
        seg = remap[seg]
    elif small.all():
        seg[:] = 0
    return seg


def _density_draws(pf: PropertyField, cfg: MassConfig, rng: np.random.Generator) -> np.ndarray:
    """[S, K] density draws (linear units), one per material per sample."""
    p = pf.property_index(cfg.density_key)
    nig = pf.nig.to(torch.float64)
    df, loc, scale = (t[:, p].cpu().numpy() for t in nig.student_t())
    if cfg.density_draw == "posterior":
        scale = np.sqrt(nig.b[:, p].cpu().numpy() / (nig.a[:, p].cpu().numpy() * nig.kappa[:, p].cpu().numpy()))
    elif cfg.density_draw != "predictive":
        raise ValueError(f"density_draw must be predictive|posterior, got {cfg.density_draw!r}.")
    t = rng.standard_t(df[None, :], size=(cfg.n_samples, len(df)))
    x = loc[None, :] + scale[None, :] * t
    if pf.log_space[p]:
        return np.exp(np.clip(x, -700, 700))
    return np.clip(x, 0.0, None)


@dataclass
class MassGeometry:
    """What the mass needs from the Gaussians' geometry and material mixtures (independent of the NIG
    posteriors and thicknesses, so one geometry serves many property hypotheses)."""

    occupancy: Occupancy
    V_sk: np.ndarray
    """[segments, K] filled volume per segment and material, m^3 (sum pi dV)"""
    A_sk: np.ndarray | None
    """[segments, K] wall area per segment and material, m^2 (None: no surface extracted)"""
    metres_per_unit: float
    num_faces: int = 0
    shell_surface: str = "mid"

    @property
    def num_segments(self) -> int:
        return int(self.V_sk.shape[0])


def mass_geometry(pf: PropertyField, cfg: MassConfig | None = None, *, surface: bool | None = None) -> MassGeometry:
    """Occupancy, per-voxel mixtures, segments, and (if any material is a shell, or ``surface``) the wall
    area per segment and material."""
    cfg = cfg or MassConfig()
    mpu = pf.metres_per_unit
    K = pf.num_materials
    if surface is None:
        surface = "shell" in resolve_volume_models(pf, cfg)[0]
    occ = compute_occupancy(pf, cfg.occupancy)
    mats = voxel_materials(pf, occ)
    idx = np.nonzero(occ.solid)
    dv = volume_weights(occ)[idx].astype(np.float64) * occ.voxel_volume * mpu**3  # [Ns] m^3
    pi_solid = mats.pi[mats.rows[idx]]  # [Ns, K]
    seg = _segments(occ, pi_solid, dv, cfg)
    n_seg = int(seg.max()) + 1
    V_sk = np.zeros((n_seg, K))
    np.add.at(V_sk, seg, pi_solid * dv[:, None])
    A_sk = None
    n_faces = 0
    if surface:
        surf = extract_surface(occ, cfg.shell_surface, sheet_depth=_sheet_depth(pf, cfg, occ))
        n_faces = len(surf.faces)
        pi_face = mats.at(surf.face_voxel)
        da = surf.face_area * surf.side_factor * mpu**2
        seg_grid = np.full(occ.solid.shape, -1, dtype=np.int64)
        seg_grid[idx] = seg
        _, near = ndimage.distance_transform_edt(~occ.solid, return_indices=True)  # face -> nearest solid voxel
        fv = surf.face_voxel
        nv = tuple(near[a][fv[:, 0], fv[:, 1], fv[:, 2]] for a in range(3))
        A_sk = np.zeros((n_seg, K))
        np.add.at(A_sk, seg_grid[nv], pi_face * da[:, None])
    return MassGeometry(occ, V_sk, A_sk, mpu, n_faces, cfg.shell_surface)


def integrate_mass(
    pf: PropertyField,
    cfg: MassConfig | None = None,
    *,
    geometry: MassGeometry | None = None,
    keep_samples: bool = False,
) -> MassReport:
    """Mass mean, median and interval of the object (module doc). ``geometry`` reuses a
    :func:`mass_geometry` of the same Gaussians (e.g. to compare property posteriors)."""
    cfg = cfg or MassConfig()
    mpu = pf.metres_per_unit
    models, thick = resolve_volume_models(pf, cfg)
    K = pf.num_materials
    is_shell = np.array([m == "shell" for m in models])
    if geometry is None or (is_shell.any() and geometry.A_sk is None):
        geometry = mass_geometry(pf, cfg)
    if abs(geometry.metres_per_unit - mpu) > 1e-12 * mpu:
        raise ValueError("integrate_mass: geometry was computed at another metres_per_unit; recompute it.")
    V_sk = geometry.V_sk
    A_sk = geometry.A_sk if geometry.A_sk is not None else np.zeros_like(V_sk)
    n_seg = geometry.num_segments
    t_nom = np.array([t if t is not None else 0.0 for t in thick])
    geom_sk = np.where(is_shell[None, :], A_sk * t_nom[None, :], V_sk)  # m^3 at nominal thickness
    # draw probabilities: volume-weighted mixture per segment; importance weights keep the plug-in mean
    pi_seg = V_sk / V_sk.sum(1, keepdims=True)
    G = np.where(pi_seg > 0, geom_sk / np.where(pi_seg > 0, pi_seg, 1.0), 0.0)
    p = pf.property_index(cfg.density_key)
    rho_mean = pf.material_means()[:, p].cpu().numpy()
    mass_k_mean = geom_sk.sum(0) * rho_mean  # [K]
    mean = float(mass_k_mean.sum())

    rng = np.random.default_rng(cfg.seed)
    S = cfg.n_samples
    rho = _density_draws(pf, cfg, rng)  # [S, K]
    sigma_t = math.log(cfg.thickness_spread) / _Z90
    tratio = np.where(is_shell[None, :], np.exp(sigma_t * rng.standard_normal((S, K))), 1.0)
    factor = rho * tratio  # [S, K]
    cum = np.cumsum(pi_seg, 1)
    cum[:, -1] = 1.0
    total = np.zeros(S)
    per_mat = np.zeros((S, K))
    chunk = max(1, (1 << 22) // max(n_seg * K, 1))
    seg_ix = np.arange(n_seg)[None, :]
    for s0 in tqdm(range(0, S, chunk), desc="mass samples", leave=False, disable=not cfg.occupancy.progress):
        s1 = min(S, s0 + chunk)
        u = rng.random((s1 - s0, n_seg))
        c = np.minimum((u[:, :, None] > cum[None, :, :]).sum(-1), K - 1)  # [s, n_seg] drawn material
        contrib = G[seg_ix, c] * np.take_along_axis(factor[s0:s1], c, axis=1)
        total[s0:s1] = contrib.sum(1)
        for k in range(K):  # materials, not voxels
            per_mat[s0:s1, k] = np.where(c == k, contrib, 0.0).sum(1)
    lo_q, hi_q = (1 - cfg.level) / 2, (1 + cfg.level) / 2
    interval = (float(np.quantile(total, lo_q)), float(np.quantile(total, hi_q)))
    V_k = V_sk.sum(0)
    A_k = A_sk.sum(0)
    v_total = float(V_k.sum())
    materials = []
    for k in range(K):
        materials.append(MaterialMass(
            name=pf.material_names[k], volume_model=models[k], thickness_m=thick[k], volume_m3=float(V_k[k]),
            volume_share=float(V_k[k] / v_total) if v_total > 0 else 0.0, area_m2=float(A_k[k]),
            density_mean=float(rho_mean[k]),
            density_interval=(float(np.quantile(rho[:, k], lo_q)), float(np.quantile(rho[:, k], hi_q))),
            mass_mean_kg=float(mass_k_mean[k]),
            mass_interval_kg=(float(np.quantile(per_mat[:, k], lo_q)), float(np.quantile(per_mat[:, k], hi_q))),
            mass_share=float(mass_k_mean[k] / mean) if mean > 0 else 0.0,
        ))  # fmt: skip
    occ = geometry.occupancy
    oc = occ.config
    geometry_info = {
        "grid_shape": list(occ.grid.shape), "voxel_size_m": occ.grid.voxel_size * mpu,
        "origin_scene": list(occ.grid.origin), "field_level": occ.level, "fill": oc.fill,
        "threshold_mode": oc.threshold_mode, "threshold": oc.threshold, "select": occ.select,
        "select_config": oc.select, "min_labelled": oc.min_labelled, "min_evidence": oc.min_evidence,
        "selected_gaussians": occ.num_selected,
        "bbox_scene": list(oc.bbox) if oc.bbox is not None else None, "shell_surface": geometry.shell_surface,
        "num_segments": n_seg, "segments": cfg.segments, "density_draw": cfg.density_draw,
        "thickness_spread": cfg.thickness_spread, "num_gaussians": pf.num_gaussians,
        "solid_voxels": int(occ.solid.sum()), "surface_faces": geometry.num_faces,
    }  # fmt: skip
    return MassReport(
        mean_kg=mean, median_kg=float(np.median(total)), interval_kg=interval, level=cfg.level, n_samples=S,
        seed=cfg.seed, volume_m3=v_total, area_m2=float(A_k.sum()), materials=materials, metres_per_unit=mpu,
        scale_source=pf.scale_source, simulated=pf.simulated, geometry=geometry_info,
        samples=total if keep_samples else None,
    )  # fmt: skip
