"""A trained run loaded for export (:func:`load_run`), and the object's geometry of a loaded run
(:func:`object_geometry`; :func:`precompute_geometry` stores it for later exports, :mod:`.geometry_cache`)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..geometry import (
    CaptureView,
    GeometryConfig,
    MaskObservation,
    ObjectGeometry,
    load_capture,
    load_observations,
    reconstruct_object,
)
from ..geometry.capture import clear_mask_cache
from ..mass import library_thickness
from ..runfiles.check import check_run
from . import geometry_cache
from .field import PropertyField

__all__ = ["MAX_VIEW_WIDTH", "LoadedRun", "RunSource", "load_run", "object_geometry", "precompute_geometry",
           "run_from_pipeline"]


@dataclass
class LoadedRun:
    """A trained run as the exporters need it."""

    field: PropertyField
    cameras: Any
    """training Cameras (scene frame) or None"""
    views: list[CaptureView]
    """the training cameras with their object masks (:func:`physgs_nerfstudio.geometry.load_capture`)"""
    observations: list[MaskObservation]
    data_dir: Path | None
    source: RunSource | None = None
    """the run's files (None: a run built in memory)"""
    capture_loader: Callable[[], tuple[list[CaptureView], list[MaskObservation]]] | None = None
    """loads ``views`` and ``observations`` when :func:`load_run` was asked not to (``capture=False``)"""

    def load_capture(self) -> None:
        """Load the views' masks and perception's answers now if :func:`load_run` left them out."""
        if self.capture_loader is not None and not self.views:
            self.views, self.observations = self.capture_loader()
        self.capture_loader = None


@dataclass(frozen=True)
class RunSource:
    """The files a loaded run came from (the geometry cache's key, :mod:`.geometry_cache`)."""

    config_path: Path
    run_dir: Path
    checkpoint: Path


MAX_VIEW_WIDTH = 640
"""the widest mask an export carves with (:func:`load_run`); wider views are downscaled"""


def load_run(
    config_path: Path,
    *,
    scale: float | None = None,
    known_length: Sequence[float] | None = None,
    env: str | None = None,
    max_view_width: int | None = MAX_VIEW_WIDTH,
    capture: bool = True,
) -> LoadedRun:
    """Load a trained run after the run checks (:func:`physgs_nerfstudio.runfiles.check.check_run`: safe YAML, method, checkpoint beside
    a moved config): its property field and cameras (:func:`physgs_nerfstudio.runfiles.loader.load_run_state`: the checkpoint's tensors, no
    model built, no datamanager, no image opened) and, with ``capture``, the object masks and perception's
    per-mask answers (mass and voxels need them; the PLY and the maps do not)."""
    from ..runfiles.loader import load_run_state

    run_files = check_run(Path(config_path))  # safe YAML, method, checkpoint (beside the config if moved)
    rs = load_run_state(run_files.config, run_files.checkpoint, run_files.run_dir)
    data = getattr(run_files.config.pipeline.datamanager, "data", None)
    pf = PropertyField.from_run_state(rs, run_files.run_dir, scale=scale, known_length=known_length, env=env)
    run = _assemble_run(pf, rs.dataparser_outputs, data, max_view_width=max_view_width, capture=capture)
    run.source = RunSource(Path(config_path), Path(run_files.run_dir), Path(run_files.checkpoint))
    if not capture:
        dpo = rs.dataparser_outputs
        run.capture_loader = lambda: _load_capture(dpo, run.data_dir, max_view_width)
    return run


def run_from_pipeline(
    run_dir: Path,
    pipeline: Any,
    *,
    scale: float | None = None,
    known_length: Sequence[float] | None = None,
    env: str | None = None,
    max_view_width: int | None = MAX_VIEW_WIDTH,
) -> LoadedRun:
    """:func:`load_run` on a pipeline already loaded (e.g. the viewer's); ``run_dir``: the folder of its
    config.yml and dataparser_transforms.json."""
    from .scale import read_dataparser_scale

    dm = pipeline.datamanager
    dpo = getattr(dm, "train_dataparser_outputs", None)
    from ..runfiles.loader import check_run_manifest

    check_run_manifest(Path(run_dir), getattr(getattr(dm, "config", None), "data", None),
                       getattr(dpo, "metadata", None))  # fmt: skip
    pf = PropertyField.from_model(pipeline.model, read_dataparser_scale(Path(run_dir)), scale=scale,
                                  known_length=known_length, env=env)  # fmt: skip
    return _assemble_run(pf, dpo, getattr(getattr(dm, "config", None), "data", None), max_view_width=max_view_width,
                         cameras=getattr(getattr(dm, "train_dataset", None), "cameras", None))  # fmt: skip


def _assemble_run(pf: PropertyField, dpo: Any, data: Path | None, *, max_view_width: int | None,
                  capture: bool = True, cameras: Any = None) -> LoadedRun:  # fmt: skip
    cameras = dpo.cameras if dpo is not None else cameras
    views: list[CaptureView] = []
    observations: list[MaskObservation] = []
    data_dir = Path(data) if data else None
    if data_dir is not None and data_dir.suffix == ".json":
        data_dir = data_dir.parent
    if capture:
        views, observations = _load_capture(dpo, data_dir, max_view_width)
    return LoadedRun(pf, cameras, views, observations, data_dir)


def _load_capture(dpo: Any, data_dir: Path | None, max_view_width: int | None
                  ) -> tuple[list[CaptureView], list[MaskObservation]]:  # fmt: skip
    """The training views with their object masks and perception's per-mask answers ([] without a dataset)."""
    if dpo is None or data_dir is None or not (data_dir / "transforms.json").exists():
        return [], []
    labels = dpo.metadata.get("material_filenames")
    views = load_capture(dpo.cameras, dpo.image_filenames, data_dir, label_paths=labels, max_width=max_view_width)
    observations = load_observations(data_dir)
    clear_mask_cache()  # the views and observations hold what they need
    return views, observations


def object_geometry(run: LoadedRun, cfg: GeometryConfig, progress: Any = None) -> ObjectGeometry:
    """Carve the object of a loaded run (:func:`physgs_nerfstudio.geometry.reconstruct_object`)."""
    if not run.views:
        raise ValueError("the run has no training cameras with object masks (transforms.json of the dataset not "
                         "found): mass and voxels need them; export --outputs ply maps instead.")  # fmt: skip
    pf = run.field
    return reconstruct_object(pf, pf.pi_rows, run.views, run.observations, library_thickness(pf), cfg,
                              material_names=pf.material_names, alpha=pf.alpha,
                              material_weights=pf.material_weights, dirichlet_prior=pf.dirichlet_prior,
                              progress=progress)  # fmt: skip


def precompute_geometry(config_path: Path, device: str, geometry: GeometryConfig | None = None
                        ) -> tuple[Path | None, str]:  # fmt: skip
    """Compute and store (:mod:`.geometry_cache`) the geometry that ``physgs export`` with its default settings
    would compute for the run of ``config_path`` (its latest checkpoint): what ``ns-train physgs`` does after
    its final checkpoint. Returns (the entry's path, or None when it could not be stored; what happened)."""
    geometry = GeometryConfig() if geometry is None else geometry
    run = load_run(config_path, capture=False)
    cache = geometry_cache.cache_for_run(run, geometry, device,
                                         geometry_cache.load_args(None, None, None, MAX_VIEW_WIDTH))  # fmt: skip
    if cache is None:
        return None, "the run has no source files"
    if cache.path.is_file():
        return cache.path, "already stored"
    run.load_capture()
    run.field = run.field.to(device)
    geo = object_geometry(run, geometry)
    return cache.save(geo), (f"{geo.selection.num_selected} Gaussians selected, {int(geo.solid.sum())} solid "
                             f"voxels, {geo.num_parts} parts")  # fmt: skip
