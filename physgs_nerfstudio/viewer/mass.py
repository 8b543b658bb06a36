"""Select for mass: the viewer's crop box or a rectangle -> the mass of `physgs export`, restricted to it.

The selection becomes an axis-aligned box in scene units, the ``bbox`` of
:class:`physgs_nerfstudio.geometry.SelectConfig` (``physgs export --mass.geometry.select.bbox``), and the last
clicked point, when it lies in the box, becomes its ``point``. Then the export's own functions run, unchanged:
:func:`physgs_nerfstudio.export.command.object_geometry` (selection, carving, parts, structure) and
:func:`physgs_nerfstudio.mass.integrate_mass`, and :func:`physgs_nerfstudio.export.report.write_report` writes
``report.json`` into ``viewer_mass/<time>/`` beside the run's config.yml. So the viewer's answer is the export's
answer for the same box (tests/test_viewer.py checks this).

* **crop box**: nerfstudio's *Crop Viewport* box (centre, rotation, scale). A rotated box is replaced by the
  axis-aligned box around it (the panel says so).
* **rectangle**: the Gaussians with material evidence whose centres project inside the rectangle of the
  current view; the box around them.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from jaxtyping import Bool, Float
from torch import Tensor

from ..mass import MassConfig, MassReport, integrate_mass

__all__ = ["Selection", "box_from_obb", "box_from_rectangle", "selection_mass", "selection_mass_config"]


@dataclass
class Selection:
    """An axis-aligned box in scene units and where it came from."""

    bbox: tuple[float, float, float, float, float, float]
    source: str
    """"crop box" | "rectangle" """
    note: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {"bbox_scene": list(self.bbox), "source": self.source, "note": self.note}


def box_from_obb(centre: Tensor, rotation: Tensor, size: Tensor) -> Selection:
    """The crop box (nerfstudio ``OrientedBox``: ``T`` centre, ``R`` rotation, ``S`` full side lengths) as an
    axis-aligned box: its own if unrotated, otherwise the box around its 8 corners."""
    T, R, S = (torch.as_tensor(x, dtype=torch.float64).cpu() for x in (centre, rotation, size))
    signs = torch.tensor([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=torch.float64)
    corners = (signs * S.reshape(1, 3) / 2) @ R.reshape(3, 3).T + T.reshape(1, 3)
    lo, hi = corners.amin(0), corners.amax(0)
    rotated = not torch.allclose(R.reshape(3, 3), torch.eye(3, dtype=torch.float64), atol=1e-6)
    note = "the crop box is rotated: its axis-aligned bounding box is used" if rotated else ""
    return Selection((*lo.tolist(), *hi.tolist()), "crop box", note)  # type: ignore[arg-type]


def box_from_rectangle(
    means: Float[Tensor, "n 3"],
    measured: Bool[Tensor, " n"],
    viewmat: Float[Tensor, "4 4"],
    K: Float[Tensor, "3 3"],
    width: int,
    height: int,
    rect: tuple[tuple[float, float], tuple[float, float]],
) -> Selection:
    """Box around the measured Gaussians whose centres project into ``rect`` = ((u0, v0), (u1, v1)), screen
    coordinates normalised to [0, 1] (OpenCV: origin top left)."""
    (u0, v0), (u1, v1) = rect
    pc = means.float() @ viewmat[:3, :3].T.float() + viewmat[:3, 3].float()
    z = pc[:, 2]
    u = (K[0, 0] * pc[:, 0] / z.clamp_min(1e-9) + K[0, 2]) / width
    v = (K[1, 1] * pc[:, 1] / z.clamp_min(1e-9) + K[1, 2]) / height
    inside = (z > 0) & (u >= min(u0, u1)) & (u <= max(u0, u1)) & (v >= min(v0, v1)) & (v <= max(v0, v1))
    pick = inside & measured.to(inside.device)
    if not bool(pick.any()):
        raise ValueError("the rectangle holds no Gaussian with material evidence: draw it around a labelled "
                         "(coloured) object.")  # fmt: skip
    m = means[pick].double()
    lo, hi = m.amin(0), m.amax(0)
    return Selection((*lo.tolist(), *hi.tolist()), "rectangle", f"{int(pick.sum())} measured Gaussians in the "
                     "rectangle")  # type: ignore[arg-type]  # fmt: skip


def selection_mass_config(mass: MassConfig, selection: Selection, point: Any = None) -> MassConfig:
    """``mass`` with the selection's box (and the clicked point, if inside it) in its object selection."""
    b = np.asarray(selection.bbox, dtype=np.float64)
    pt = None
    if point is not None:
        p = np.asarray(point, dtype=np.float64).reshape(3)
        pt = tuple(float(x) for x in p) if bool(((p >= b[:3]) & (p <= b[3:])).all()) else None
    g = mass.geometry
    sel = replace(g.select, bbox=tuple(float(x) for x in b), point=pt)
    return replace(mass, geometry=replace(g, select=sel))


def selection_mass(
    run: Any,
    mass: MassConfig,
    selection: Selection,
    report_dir: Path,
    *,
    point: Any = None,
    progress: Callable[[str], None] | None = None,
) -> tuple[MassReport, Path]:
    """`physgs export`'s mass of the object inside ``selection`` (module doc); writes ``report_dir/report.json``
    and returns (report, path)."""
    from ..export.command import object_geometry
    from ..export.report import write_report

    say = progress or (lambda s: None)
    cfg = selection_mass_config(mass, selection, point)
    t0 = time.perf_counter()
    say("object geometry: selecting, carving")
    geo = object_geometry(run, cfg.geometry, progress=lambda s: say(f"object geometry: {s} "
                                                                    f"({time.perf_counter() - t0:.0f} s)"))
    say(f"Monte Carlo: {cfg.n_samples} samples ({time.perf_counter() - t0:.0f} s)")
    report = integrate_mass(run.field, geo, cfg)
    extra = {"legend": run.field.legend(), "simulated": run.field.simulated, "selection": selection.to_dict(),
             "point_scene": list(cfg.geometry.select.point) if cfg.geometry.select.point else None,
             "seconds": time.perf_counter() - t0, "source": "physgs viewer (Mass button)"}  # fmt: skip
    path = write_report(report, Path(report_dir) / "report.json", extra)
    return report, path
