"""Click a point: what is it made of, what are its properties and how sure are we.

A click is a pixel (u, v) of the viewer's camera. :func:`ray_weights` computes, for that one pixel and in one
vectorised pass over all Gaussians, the blending weight each Gaussian receives there: the EWA projection of
the renderer (:func:`physgs_nerfstudio.render.projection.project_gaussians`), alpha at the pixel centre,
depth order, transmittance, and the rasterizer's cut-offs (alpha < 1/255 skipped, alpha <= 0.999, the ray
stops before its transmittance would fall to 1e-4). These are exactly the weights that make the rendered
pixel, so the answer agrees with what the viewer shows.

:func:`query_pixel` turns them into the answer (:class:`PointQuery`):

* **first surface**: the depth at which the ray's accumulated opacity first reaches one half (the depth of
  the Gaussian that crosses it); the 3-D point marked in the viewer is the ray at that depth. The expected
  depth (the rendered `depth` output) is reported too.
* **materials**: the pixel's material mixture ``sum_g w_g m_g pi_g / sum_g w_g m_g`` over the Gaussians that
  carry material evidence (``m_g``, :mod:`.display`), top-3 with probabilities;
* **properties**: mean, aleatoric and epistemic standard deviation of that mixture (law of total variance, the
  materials' posteriors), in each property's units; Shore hardness also on its own scale (A, or D above A 90);
* **evidence**: the blending-weighted number of training views that saw those Gaussians, their lifted
  evidence (confidence-weighted labelled views) and the share of the ray's opacity that was measured.

If the measured Gaussians' opacity along the ray is below ``min_coverage`` the point is reported as not
measured (no properties), as the viewer leaves such pixels uncoloured.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import torch
from jaxtyping import Float, Int
from torch import Tensor

from ..bayes import NIG, mixture_fields
from ..render.composite import ALPHA_MAX, ALPHA_MIN, LOG_T_MIN
from ..render.projection import covariance_3d, project_gaussians
from .display import GaussianMaterials
from .scales import UNITS, format_value, shore_reading

__all__ = ["PointQuery", "RayWeights", "query_pixel", "ray_weights"]


@dataclass
class RayWeights:
    ids: Int[Tensor, " m"]
    """Gaussians that contribute to the pixel, front to back"""
    depths: Float[Tensor, " m"]
    """their camera-space depths (z)"""
    weights: Float[Tensor, " m"]
    """their blending weights alpha_g * T_g"""

    @property
    def accumulation(self) -> float:
        return float(self.weights.sum())

    def expected_depth(self) -> float:
        a = self.weights.sum()
        return float((self.weights * self.depths).sum() / a) if float(a) > 0 else math.nan

    def surface_depth(self, level: float = 0.5) -> float:
        """Depth of the Gaussian at which the accumulated opacity first reaches ``level`` (nan if never)."""
        cum = torch.cumsum(self.weights.double(), 0)
        hit = torch.nonzero(cum >= level).squeeze(-1)
        return float(self.depths[hit[0]]) if len(hit) else math.nan


@torch.no_grad()
def ray_weights(
    means: Float[Tensor, "n 3"],
    quats: Float[Tensor, "n 4"],
    scales: Float[Tensor, "n 3"],
    opacities: Float[Tensor, " n"],
    viewmat: Float[Tensor, "4 4"],
    K: Float[Tensor, "3 3"],
    width: int,
    height: int,
    pixel: tuple[float, float],
) -> RayWeights:
    """Blending weights of every Gaussian at pixel ``(u, v)`` (column, row; the pixel's centre is
    ``(u + 0.5, v + 0.5)``) of a ``width`` x ``height`` pinhole camera (module doc)."""
    u, v = pixel
    if not (0 <= u < width and 0 <= v < height):
        raise ValueError(f"pixel {pixel} is outside the {width}x{height} image.")
    dev = means.device
    proj = project_gaussians(means.float(), covariance_3d(quats.float(), scales.float()), viewmat[None].float(),
                             K[None].float(), width, height)  # fmt: skip
    vis = torch.nonzero(proj.radii[0] > 0).squeeze(-1)
    depth = proj.depths[0, vis]
    vis = vis[torch.sort(depth, stable=True).indices]  # depth order, ties by index (as the rasterizers)
    d = proj.means2d[0, vis] - torch.tensor([math.floor(u) + 0.5, math.floor(v) + 0.5], device=dev)
    a, b, c = proj.conics[0, vis].unbind(-1)
    sig = 0.5 * (a * d[:, 0] ** 2 + c * d[:, 1] ** 2) + b * d[:, 0] * d[:, 1]
    alpha = (opacities.float()[vis] * torch.exp(-sig)).clamp_max(ALPHA_MAX)
    keep = (sig >= 0) & (alpha >= ALPHA_MIN)
    vis, alpha = vis[keep], alpha[keep]
    log_1m = torch.log1p(-alpha.double())
    log_t_excl = torch.cumsum(log_1m, 0) - log_1m
    inside = (log_t_excl + log_1m) > LOG_T_MIN  # monotone: a prefix of the depth order
    n = int(inside.sum())
    w = (alpha[:n].double() * torch.exp(log_t_excl[:n])).float()
    return RayWeights(vis[:n], proj.depths[0, vis[:n]], w)


@dataclass
class PointQuery:
    """The answer to a click (module doc); :meth:`to_dict` is the JSON the panel copies."""

    pixel: tuple[float, float]
    hit: bool
    point: list[float] | None
    """first surface, scene (dataset) units"""
    point_m: list[float] | None
    """the same in metres (times the run's metres per unit)"""
    surface_depth: float | None
    expected_depth: float | None
    accumulation: float
    measured_share: float
    """share of the ray's opacity on Gaussians with material evidence"""
    measured: bool
    coverage: float = 0.0
    """opacity of the measured Gaussians along the ray (the pixel is coloured above ``min_coverage``)"""
    min_coverage: float = 0.5
    materials: list[dict[str, Any]] = field(default_factory=list)
    properties: dict[str, dict[str, Any]] = field(default_factory=dict)
    evidence: dict[str, float] = field(default_factory=dict)
    simulated: bool = False

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def lines(self) -> list[str]:
        """Markdown lines for the panel."""
        if not self.hit:
            u, v = self.pixel
            return [f"No surface at pixel {u:.0f}, {v:.0f} (ray opacity {self.accumulation:.2f})."]
        p = ", ".join(f"{x:.3f}" for x in (self.point_m or []))
        out = [f"**Point** ({p}) m, ray opacity {self.accumulation:.2f}, measured {self.measured_share:.0%}"]
        if not self.measured:
            why = (f"Not measured: Gaussians with material evidence give {self.coverage:.2f} of the ray's opacity, "
                   f"below {self.min_coverage:.2f}; the viewer leaves this pixel uncoloured.")
            return [*out, why]
        tag = " [SIMULATED VLM]" if self.simulated else ""
        out.append("**Materials**" + tag + ": " + ", ".join(f"{m['name']} {m['probability']:.0%}"
                                                           for m in self.materials))  # fmt: skip
        for key, pr in self.properties.items():
            unit = f" {pr['unit']}" if pr["unit"] else ""
            line = (f"**{key}** {format_value(key, pr['mean'])}{unit} (aleatoric +/- "
                    f"{format_value(key, pr['aleatoric_std'])}, epistemic +/- {format_value(key, pr['epistemic_std'])})")
            if "shore" in pr:
                s = pr["shore"]
                line += (f" = Shore {s['scale']} {s['reading']:.0f} (+/- {s['aleatoric_std']:.1f} aleatoric, "
                         f"{s['epistemic_std']:.1f} epistemic)")  # fmt: skip
            out.append(line)
        e = self.evidence
        out.append(f"**Evidence**: seen in {e['views']:.1f} training views, {e['evidence']:.1f} confidence-weighted "
                   f"labelled views, {e['labelled_share']:.0%} of its weight on labelled pixels "
                   f"({int(e['gaussians'])} Gaussians)")  # fmt: skip
        return out


def _shore(mean: float, ale: float, epi: float) -> dict[str, Any]:
    scale, reading = shore_reading(mean)
    from ..materials.hardness import from_canonical

    def std_on_scale(s: float) -> float:  # local slope of the piecewise-linear conversion
        return abs(float(from_canonical(mean + s, scale)) - float(from_canonical(mean - s, scale))) / 2

    return {"scale": scale, "reading": reading, "aleatoric_std": std_on_scale(ale), "epistemic_std": std_on_scale(epi)}


def _mixture(rw: RayWeights, gm: GaussianMaterials) -> tuple[Tensor, float, float]:
    """(pi [K] of the measured Gaussians on the ray, their opacity, the ray's total)."""
    m = gm.measured[rw.ids].float()
    w = rw.weights * m
    cov = float(w.sum())
    pi = (w[:, None] * gm.pi[rw.ids]).sum(0) / max(cov, 1e-10)
    return pi, cov, rw.accumulation


def query_pixel(
    rw: RayWeights,
    gm: GaussianMaterials,
    nig: NIG,
    log_space: Sequence[bool],
    *,
    property_keys: Sequence[str],
    material_names: Sequence[str],
    camera_to_world: Float[Tensor, "3 4"],
    K: Float[Tensor, "3 3"],
    pixel: tuple[float, float],
    metres_per_unit: float = 1.0,
    min_coverage: float = 0.5,
    top_k: int = 3,
    simulated: bool = False,
) -> PointQuery:
    """The answer for one pixel (module doc); ``camera_to_world`` is nerfstudio's (OpenGL axes)."""
    acc = rw.accumulation
    surface = rw.surface_depth(0.5)
    if not math.isfinite(surface):
        return PointQuery(pixel, False, None, None, None, None, acc, 0.0, False, simulated=simulated)
    u, v = pixel
    x = (math.floor(u) + 0.5 - float(K[0, 2])) / float(K[0, 0])
    y = (math.floor(v) + 0.5 - float(K[1, 2])) / float(K[1, 1])
    c2w = camera_to_world.double().cpu()
    d_cam = torch.tensor([x, -y, -1.0], dtype=torch.float64)  # OpenCV (x, y, z=1) in OpenGL axes
    point = (c2w[:, :3] @ d_cam) * surface + c2w[:, 3]
    pi, cov, total = _mixture(rw, gm)
    measured = cov > min_coverage
    q = PointQuery(pixel, True, point.tolist(), (point * metres_per_unit).tolist(), surface, rw.expected_depth(),
                   acc, cov / max(total, 1e-10), measured, cov, min_coverage, simulated=simulated)  # fmt: skip
    if not measured:
        return q
    top = torch.argsort(pi, descending=True)[:top_k]
    q.materials = [{"name": material_names[int(i)], "id": int(i) + 1, "probability": float(pi[i])} for i in top]
    f = mixture_fields(pi[None].double(), nig.to("cpu"), log_space)
    for i, key in enumerate(property_keys):
        mean = float(f["mean"][0, i])
        ale, epi = (float(f[k][0, i].clamp_min(0).sqrt()) for k in ("aleatoric", "epistemic"))
        entry: dict[str, Any] = {"mean": mean, "aleatoric_std": ale, "epistemic_std": epi,
                                 "total_std": math.hypot(ale, epi), "unit": UNITS.get(key, "")}  # fmt: skip
        if key == "shore_hardness":
            entry["shore"] = _shore(mean, ale, epi)
        q.properties[key] = entry
    w = rw.weights * gm.measured[rw.ids].float()
    avg = lambda t: float((w * t[rw.ids]).sum() / max(cov, 1e-10))
    q.evidence = {"views": avg(gm.views), "evidence": avg(gm.evidence), "labelled_share": avg(gm.labelled),
                  "gaussians": float(int((w > 0).sum()))}  # fmt: skip
    return q
