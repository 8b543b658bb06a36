"""Where one fresh `physgs export` process spends its wall time, function by function (issue 13).

    python benchmarks/export_timeline.py --load-config RUN/config.yml --output-dir /tmp/tl --outputs mass --overwrite

Everything after this script's name is passed to `physgs export` unchanged, and the export runs in this process as
the CLI runs it. The timer starts before ``import torch``. The pipeline's functions (loading, the geometry's steps,
the Monte Carlo, the writers) are wrapped wherever the package holds them, with a device synchronisation on both
sides, so a function's time includes the kernels it launched and the first-use costs it paid: the imports it made
lazily (SciPy, scikit-image), CUDA's lazily loaded kernels, thread pools. Nested calls are indented; each line
is a call's wall seconds and the process clock when it ended. The timeline goes to stderr and, with
``TIMELINE_JSON=path`` in the environment, to that file. A profiler would charge its own overhead to the
Python-heavy parts; this adds two synchronisations per wrapped call and nothing else.
"""

from __future__ import annotations

import functools
import json
import os
import sys
import threading
import time
from pathlib import Path

T0 = time.perf_counter()
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

WRAPPED = {
    "physgs_nerfstudio.runfiles.check": ["check_run"],
    "physgs_nerfstudio.runfiles.loader": ["load_run_state"],
    "physgs_nerfstudio.export.field": ["PropertyField.from_run_state", "PropertyField.pi", "PropertyField.pi_rows",
                                       "PropertyField.to"],
    "physgs_nerfstudio.export.command": ["load_run", "object_geometry", "write_export", "run_export"],
    "physgs_nerfstudio.export.run": ["_assemble_run", "_load_capture"],
    "physgs_nerfstudio.export.geometry_cache": ["cache_for_run", "GeometryCache.load", "GeometryCache.save"],
    "physgs_nerfstudio.geometry.capture": ["load_capture", "load_observations"],
    "physgs_nerfstudio.geometry.select": ["select_object", "lift_masks", "lift_masks_and_labels", "band_labels",
                                          "split_close", "outside_mask_hull"],
    "physgs_nerfstudio.geometry.clusters": ["cluster_labels"],
    "physgs_nerfstudio.geometry.support": ["find_support_plane", "find_resting_plane"],
    "physgs_nerfstudio.geometry.reconstruct": ["_object_views", "_domain", "_carve_variants", "_within_hull",
                                               "_cut_below"],
    "physgs_nerfstudio.geometry.carve": ["signed_mask_distances", "carve_votes_many", "solid_from_votes"],
    "physgs_nerfstudio.geometry.extent": ["support_excess"],
    "physgs_nerfstudio.geometry.parts": ["voxel_mixture", "part_labels", "part_areas", "concavities",
                                         "material_quantiles", "_plate_like", "pooled_part_alpha", "sum_rows"],
    "physgs_nerfstudio.geometry.part_evidence": ["observation_shares", "part_maps", "fuse_part_materials",
                                                 "absorb_unobserved", "merge_same_material"],
    "physgs_nerfstudio.render.gsplat_build": ["prepare_gsplat"],
    "physgs_nerfstudio.geometry.structure": ["fuse_structure"],
    "physgs_nerfstudio.mass": ["integrate_mass"],
    "physgs_nerfstudio.export.report": ["write_report", "print_mass_table"],
}
_events: list[dict] = []
_local = threading.local()  # the nesting depth, per thread (the geometry's variants run on a thread pool)


def _now() -> float:
    return time.perf_counter() - T0


def _sync() -> None:
    torch = sys.modules.get("torch")
    if torch is not None and torch.cuda.is_available() and torch.cuda.is_initialized():
        torch.cuda.synchronize()


def _wrap(name: str, f):
    @functools.wraps(f)
    def timed(*a, **k):
        _sync()
        start = _now()
        depth = getattr(_local, "depth", 0)
        _local.depth = depth + 1
        try:
            return f(*a, **k)
        finally:
            _sync()
            _local.depth = depth
            _events.append({"name": name, "depth": depth, "thread": threading.get_ident(), "start": start,
                            "end": _now()})

    timed.__wrapped_by_timeline__ = True
    return timed


def _install() -> None:
    """Wrap every function of WRAPPED in its module and wherever another package module imported it by name."""
    import importlib
    import inspect

    targets: list[tuple[object, str, object, str]] = []
    for modname, names in WRAPPED.items():
        mod = importlib.import_module(modname)
        for dotted in names:
            owner, attr = mod, dotted
            if "." in dotted:
                cls, attr = dotted.split(".")
                owner = getattr(mod, cls)
            f = inspect.getattr_static(owner, attr, None)
            if f is None:
                print(f"[timeline] {modname}.{dotted} not found (renamed?); not timed", file=sys.stderr)
                continue
            targets.append((owner, attr, f, f"{modname.rsplit('.', 1)[-1]}.{dotted}"))
    for owner, attr, f, label in targets:
        if isinstance(f, (classmethod, staticmethod)):
            setattr(owner, attr, type(f)(_wrap(label, f.__func__)))
            continue
        timed = _wrap(label, f)
        setattr(owner, attr, timed)
        if isinstance(owner, type):
            continue
        for m in list(sys.modules.values()):  # `from .x import f` copies
            if getattr(m, "__name__", "").startswith("physgs_nerfstudio") and getattr(m, attr, None) is f:
                setattr(m, attr, timed)


def main() -> int:
    import torch  # noqa: F401 - timed as the import it is in every export

    t_torch = _now()
    from physgs_nerfstudio import cli

    t_cli = _now()
    _install()
    sys.argv = ["physgs", "export", *sys.argv[1:]]
    rc = 0
    try:
        cli.entrypoint()
    except SystemExit as err:
        rc = int(err.code or 0)
    _sync()
    total = _now()
    lines = [f"{'import torch':48s} {t_torch:7.3f}   ends {t_torch:7.3f}",
             f"{'import the CLI':48s} {t_cli - t_torch:7.3f}   ends {t_cli:7.3f}"]  # fmt: skip
    for e in sorted(_events, key=lambda e: (e["start"], e["depth"])):
        lines.append(f"{'  ' * e['depth'] + e['name']:48s} {e['end'] - e['start']:7.3f}   ends {e['end']:7.3f}")
    lines.append(f"{'total (this process, after the interpreter started)':48s} {total:7.3f}")
    print("\n".join(lines), file=sys.stderr)
    if os.environ.get("TIMELINE_JSON"):
        Path(os.environ["TIMELINE_JSON"]).write_text(json.dumps(
            {"import_torch_s": t_torch, "import_cli_s": t_cli - t_torch, "total_s": total, "events": _events,
             "argv": sys.argv[1:]}, indent=1))  # fmt: skip
    return rc


if __name__ == "__main__":
    sys.exit(main())
