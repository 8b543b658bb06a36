"""Rigid-body mass properties (mass, centre of mass, inertia tensor) from the export's voxels and Monte Carlo.

The mass report's Monte Carlo (:func:`physgs_nerfstudio.mass.mass_draws`) gives, per sample, every part's mass per
material and whether the part is solid or a wall. Where that mass lies comes from the voxels of the nominal solid
(:class:`MassCarriers`): a solid part's material ``k`` fills its voxels in proportion to ``fill x mixture_k``
(each voxel a uniform cube); a wall's mass lies on the part's faces onto the outside (each exposed voxel face a
uniform square plate, weighted by ``mixture_k``), so a hollow mug weighs in its walls, not in its inside (a part
with no face onto the outside, enclosed by others, carries its wall in its voxels).

A body is then ``sum_pk m_pk`` with first and second moments ``sum_pk m_pk c_pk`` and ``sum_pk m_pk S_pk``
(exact sums over the voxels, nothing fitted): :func:`body_from_masses`. The mean body uses the samples' mean part
masses, so its mass is the report's mean; a sample's body uses that sample's masses
(:mod:`.samples`). The carving variant of a sample changes its part masses, not where they lie (the nominal
voxels). Units: kg, metres, kg m^2, in the object frame (:class:`ObjectFrame`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .frame import ObjectFrame

__all__ = ["Elements", "MassCarriers", "MassProperties", "body_from_masses", "element_masses", "elements",
           "mass_carriers", "mean_masses"]


@dataclass
class MassCarriers:
    """Where each part's mass of each material lies, per unit mass (module doc), in the object frame."""

    first: np.ndarray
    """[2, P, K, 3]: first moment per unit mass (the carrier's centroid), metres; [0] solid, [1] wall"""
    second: np.ndarray
    """[2, P, K, 3, 3]: second moment ``E[x x^T]`` per unit mass about the origin, m^2"""


@dataclass
class MassProperties:
    """A rigid body's mass properties in the object frame."""

    mass_kg: float
    com_m: np.ndarray
    """[3] centre of mass"""
    inertia: np.ndarray
    """[3, 3] inertia tensor about the centre of mass, object axes, kg m^2"""

    @property
    def principal(self) -> tuple[np.ndarray, np.ndarray]:
        """(principal moments [3] ascending, axes [3, 3] as columns, a proper rotation)."""
        w, v = np.linalg.eigh(self.inertia)
        if np.linalg.det(v) < 0:
            v[:, 2] = -v[:, 2]
        return w, v

    def to_dict(self) -> dict:
        w, v = self.principal
        return {"mass_kg": self.mass_kg, "com_m": self.com_m.tolist(), "inertia_kg_m2": self.inertia.tolist(),
                "principal_moments_kg_m2": w.tolist(), "principal_axes": v.tolist()}  # fmt: skip


@dataclass
class Elements:
    """The pieces a carrier is made of: the voxels (solid parts) or the exposed voxel faces (walls)."""

    voxel: np.ndarray
    """int [N, 3]: the grid index of the voxel each element belongs to"""
    part: np.ndarray
    """int [N]"""
    weight: np.ndarray
    """[N, K]: each element's weight per material (fill x mixture for voxels, mixture for faces)"""
    centre_m: np.ndarray
    """[N, 3]: the element's centre, object frame"""
    own: np.ndarray
    """[N, 3, 3]: the element's own second moment about its centre per unit mass, object frame"""

    def shares(self, P: int) -> np.ndarray:
        """[N, K]: each element's share of its part's carrier of each material (columns sum to 1 over a part's
        elements); where a material has no weight in a part, the part's whole carrier stands in (its mass, if any,
        lies where the part does)."""
        K = self.weight.shape[1]
        W = np.stack([np.bincount(self.part, self.weight[:, k], minlength=P) for k in range(K)], 1)  # [P, K]
        total = self.weight.sum(1)
        Wp = np.bincount(self.part, total, minlength=P)
        own = self.weight / np.maximum(W[self.part], 1e-300)
        whole = (total / np.maximum(Wp[self.part], 1e-300))[:, None]
        return np.where(W[self.part] > 0, own, whole)


def _labels(solid: np.ndarray, parts: np.ndarray, mixture: np.ndarray, fill: np.ndarray):
    """Every voxel with fill > 0 takes the part and mixture of its nearest solid voxel (the partial voxels just
    outside the solid carry no part of their own)."""
    idx = ndimage.distance_transform_edt(~solid, return_distances=False, return_indices=True)
    near = tuple(idx)
    keep = fill > 0
    return np.argwhere(keep), parts[near][keep], mixture[near][keep], fill[keep]


def _faces(solid: np.ndarray):
    """The solid's faces onto the outside: (voxel index [F, 3], axis [F], sign [F])."""
    pad = np.pad(solid, 1)
    out = []
    for axis in range(3):
        for sign in (-1, 1):
            nb = np.roll(pad, -sign, axis=axis)[1:-1, 1:-1, 1:-1]
            v = np.argwhere(solid & ~nb)
            out.append((v, np.full(len(v), axis), np.full(len(v), sign)))
    return tuple(np.concatenate(x) for x in zip(*out))


def elements(solid: np.ndarray, parts: np.ndarray, mixture: np.ndarray, fill: np.ndarray, origin_m: np.ndarray,
             voxel_m: float, frame: ObjectFrame) -> tuple[Elements, Elements]:  # fmt: skip
    """(solid elements, wall elements) of a voxel grid: ``solid`` bool [X, Y, Z], ``parts`` int (part id on the
    solid), ``mixture`` [X, Y, Z, K], ``fill`` (the share of each voxel the volume counts), the grid's
    ``origin_m`` and ``voxel_m`` in scene metres."""
    R, a = frame.rotation, float(voxel_m)
    vox, part, mix, f = _labels(solid, parts, mixture, fill)
    cube = np.broadcast_to(R.T @ (np.eye(3) * a * a / 12.0) @ R, (len(f), 3, 3))
    solid_e = Elements(vox, part, mix * f[:, None], frame.to_object(origin_m + (vox + 0.5) * a), cube)
    v, axis, sign = _faces(solid)
    offset = np.zeros((len(v), 3))
    offset[np.arange(len(v)), axis] = 0.5 * a * sign
    plate = np.zeros((len(v), 3, 3))
    for i in range(3):
        plate[:, i, i] = np.where(axis == i, 0.0, a * a / 12.0)
    plate = np.einsum("ji,njk,kl->nil", R, plate, R)  # R^T D R per face
    wall_e = Elements(v, parts[tuple(v.T)], mixture[tuple(v.T)], frame.to_object(origin_m + (v + 0.5) * a + offset),
                      plate)  # fmt: skip
    inner = np.isin(solid_e.part, wall_e.part, invert=True)  # a part with no face onto the outside: its voxels
    if inner.any():
        wall_e = Elements(*(np.concatenate([getattr(wall_e, k), getattr(solid_e, k)[inner]])
                            for k in ("voxel", "part", "weight", "centre_m", "own")))  # fmt: skip
    return solid_e, wall_e


def _moments(e: Elements, P: int) -> tuple[np.ndarray, np.ndarray]:
    """Per part and material: first [P, K, 3] and second [P, K, 3, 3] moments per unit mass."""
    s = e.shares(P)  # [N, K]
    xx = e.centre_m[:, :, None] * e.centre_m[:, None, :] + e.own
    K = s.shape[1]
    F = np.zeros((P, K, 3))
    S = np.zeros((P, K, 3, 3))
    for k in range(K):
        for i in range(3):
            F[:, k, i] = np.bincount(e.part, s[:, k] * e.centre_m[:, i], minlength=P)
            for j in range(3):
                S[:, k, i, j] = np.bincount(e.part, s[:, k] * xx[:, i, j], minlength=P)
    return F, S


def mass_carriers(solid_e: Elements, wall_e: Elements, P: int) -> MassCarriers:
    """The carriers (module doc) of the :func:`elements` of a grid with ``P`` parts."""
    (fs, ss), (fw, sw) = _moments(solid_e, P), _moments(wall_e, P)
    return MassCarriers(np.stack([fs, fw]), np.stack([ss, sw]))


def element_masses(e: Elements, masses: np.ndarray, P: int) -> np.ndarray:
    """[N]: each element's mass when the parts' masses per material ``masses`` [P, K] lie on these elements."""
    return (e.shares(P) * masses[e.part]).sum(1)


def mean_masses(part_mass: np.ndarray, hollow: np.ndarray) -> np.ndarray:
    """[2, P, K]: the samples' mean mass per part and material as a solid ([0]) and as a wall ([1]);
    ``part_mass`` [S, P, K], ``hollow`` bool [S, P]."""
    h = hollow[:, :, None].astype(np.float64)
    return np.stack([(part_mass * (1.0 - h)).mean(0), (part_mass * h).mean(0)])


def body_from_masses(masses: np.ndarray, carriers: MassCarriers) -> MassProperties:
    """The body of part masses ``masses`` [2, P, K] (solid, wall) on ``carriers`` (module doc)."""
    m = np.asarray(masses, dtype=np.float64)
    M = float(m.sum())
    if not M > 0:
        raise ValueError("the object has no mass (every part weighs 0 kg)")
    first = np.einsum("hpk,hpki->i", m, carriers.first)
    second = np.einsum("hpk,hpkij->ij", m, carriers.second)
    com = first / M
    C = second - M * np.outer(com, com)
    inertia = np.trace(C) * np.eye(3) - C
    return MassProperties(M, com, 0.5 * (inertia + inertia.T))
