"""The carved surface's offset from the true one, measured: the spread behind ``MassConfig.surface_offset_voxels``.

    python benchmarks/surface_offset.py /tmp/suite3535 /tmp/suite3737 --name s13base --json out.json

Each argument is a folder of `benchmarks/mass_suite.py` runs (``OBJECT_sSEED/scene/ground_truth.json`` and
``OBJECT_sSEED/export_NAME/report.json``, or ``export/`` without ``--name``) or a suite's JSON (its rows). Per
object that has a part whose true volume model is solid, the residual offset in resolution units is

    d = (V_true_solid - V_solid) / (S_solid * u)

``V_true_solid``: the true solid parts' volume; ``V_solid`` and ``S_solid``: the carved parts' volumes and whole
surface areas weighted by P(solid) = 1 - p_hollow; ``u``: the carving's resolution, the larger of the voxel and the
views' pixel footprint (``geometry.pixel_footprint_voxels``). ``d`` is how far every face of the
carved solid would have to move (outwards when positive) for its volume to be the truth. The spread printed at the
end is the root mean square of ``d`` over the objects (their bias included): the standard deviation that the
mass's Monte Carlo gives the offset. Hollow parts are left out: their mass is their wall (area x thickness), which an
offset of the enclosed volume does not move. So are objects whose solid parts carry less than half of the true mass
(``--min-solid-mass-share``): a mug's handle or a pan's, a bottle's cap. There the residual measures which part the
carving gave the solid's voxels to (the handle's inside went to the hollow cup), not where the surface lies, and
the offset moves little of their mass. Use development seeds only, never the seeds that the figures are
reported at.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path


def residual(parts: list[dict], true_parts: list[dict], voxel_m: float, footprint_voxels: float | None,
             min_share: float = 0.5) -> dict | None:
    """The object's residual offset (module doc). ``parts``: the carved parts (``volume_m3``, ``surface_area_m2``,
    ``p_hollow``); ``true_parts``: the ground truth's (``volume_model``, ``volume_m3``, ``mass_kg``). None where
    the true solid parts carry less than ``min_share`` of the mass."""
    v_true = sum(p["volume_m3"] for p in true_parts if p["volume_model"] == "solid")
    m_solid = sum(p["mass_kg"] for p in true_parts if p["volume_model"] == "solid")
    if v_true <= 0 or m_solid < min_share * sum(p["mass_kg"] for p in true_parts):
        return None
    u = voxel_m * max(1.0, footprint_voxels or 1.0)
    v = sum((1 - p["p_hollow"]) * p["volume_m3"] for p in parts)
    s = sum((1 - p["p_hollow"]) * (p.get("surface_area_m2") or 0.0) for p in parts)
    if s <= 0:
        return None
    return {"true_solid_m3": v_true, "carved_solid_m3": v, "surface_m2": s, "unit_m": u,
            "offset_voxels": (v_true - v) / (s * u), "ratio": v / v_true}


def _runs(path: Path, name: str | None, min_share: float):
    """(run name, residual) of a suite folder's reports, or of a mass_suite JSON's rows."""
    if path.is_file():
        for r in json.loads(path.read_text())["rows"]:
            if "error" not in r and r.get("voxel_size_m"):
                yield f"{r['object']}_s{r['seed']}", residual(r["parts"], r["true_parts"], r["voxel_size_m"],
                                                              r.get("pixel_footprint_voxels"), min_share)
        return
    for d in sorted(p for p in path.iterdir() if p.is_dir()):
        rep = d / (f"export_{name}" if name else "export") / "report.json"
        gt = d / "scene" / "ground_truth.json"
        if rep.is_file() and gt.is_file():
            m = json.loads(rep.read_text())["mass"]
            parts = [{**p, "p_hollow": p["structure"]["p_hollow"]} for p in m["parts"]]
            yield d.name, residual(parts, json.loads(gt.read_text())["parts"], m["geometry"]["voxel_size_m"],
                                   m["geometry"].get("pixel_footprint_voxels"), min_share)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("suites", nargs="+", type=Path)
    ap.add_argument("--name", default=None, help="the re-export's name (export_NAME/); default: export/")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--min-solid-mass-share", type=float, default=0.5)
    a = ap.parse_args()
    rows = []
    for suite in a.suites:
        for run, r in _runs(suite, a.name, a.min_solid_mass_share):
            if r is not None:
                rows.append({"run": run, **r})
                print(f"{run:16s} carved/true solid {r['ratio']:5.2f}  offset {r['offset_voxels']:+5.2f} units "
                      f"(unit {1000 * r['unit_m']:.1f} mm)")
    if not rows:
        raise SystemExit("no run with a solid part and a report found")
    d = [r["offset_voxels"] for r in rows]
    rms = math.sqrt(sum(x * x for x in d) / len(d))
    mean = sum(d) / len(d)
    print(f"{len(d)} objects: mean offset {mean:+.3f} units, root mean square {rms:.3f} units")
    if a.json:
        a.json.write_text(json.dumps({"rows": rows, "mean_voxels": mean, "rms_voxels": rms}, indent=2))


if __name__ == "__main__":
    main()
