"""`PhysGSPipeline`: nerfstudio's VanillaPipeline plus the lifting of the material maps onto the Gaussians.

The pipeline owns the work done at set steps (docs/architecture.md, "The nerfstudio method"): when
densification stops (`lifting_step`, default the model's `stop_split_at`), every `lifting_every` steps if set,
and at the last training iteration (`lift_at_end`) it computes the evidence with `physgs_nerfstudio.lifting.lift_evidence` over the
datamanager's training views (`lift_material_maps`) and hands it to the model through its one public method,
`PhysGSModel.set_material_evidence`. `PhysGSPipeline.lift()` does the same on demand.

Evidence map of a view: the confidence-weighted one-hot of its labels (label 0 contributes nothing), plus one
channel of labelled pixels (label != 0, whatever the confidence). `lift_evidence` sums each Gaussian's
blending weight times the map over all pixels, and its total blending weight, so that
`labelled_fraction = labelled_weight / lifting_weight` tells Gaussians seen mostly in labelled pixels from
those seen mostly in unknown (label 0) pixels.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import torch
from jaxtyping import Float
from nerfstudio.cameras.cameras import Cameras
from nerfstudio.engine.callbacks import TrainingCallback, TrainingCallbackAttributes, TrainingCallbackLocation
from nerfstudio.pipelines.base_pipeline import VanillaPipeline, VanillaPipelineConfig
from nerfstudio.utils.rich_utils import CONSOLE
from torch import Tensor

from physgs_nerfstudio.geometry.capture import viewmat_from_c2w
from physgs_nerfstudio.lifting import group_views, label_evidence_maps, lift_views

from .datamanager import PhysGSDatamanagerConfig
from .model import MaterialEvidence, PhysGSModel, PhysGSModelConfig


@dataclass
class PhysGSPipelineConfig(VanillaPipelineConfig):
    """VanillaPipeline with the physgs datamanager and model, plus when and how to lift the material maps."""

    _target: type = field(default_factory=lambda: PhysGSPipeline)
    datamanager: PhysGSDatamanagerConfig = field(default_factory=PhysGSDatamanagerConfig)
    model: PhysGSModelConfig = field(default_factory=PhysGSModelConfig)
    lifting_step: int | None = None
    """Step at which to lift the material maps onto the Gaussians; None = the model's `stop_split_at`
    (densification end)."""
    lift_at_end: bool = True
    """Lift again at the last training iteration (so the checkpoint's evidence matches the final Gaussians)."""
    lifting_every: int = 500
    """Also lift every this many steps during training (0 = off), so that the viewer shows the lifted materials
    and properties while training runs (with `material_head="lifted"`, the only material map there is). Each
    lifting costs one K+2 channel render and backward per training view (benchmarks/README.md, "Training")."""
    lifting_every_needs_viewer: bool = True
    """The `lifting_every` liftings are previews, for the viewer (with `material_head="lifted"`, the final material
    field is the last iteration's lifting whatever they did): they run only when the trainer has a viewer (`--vis`
    viewer, viewer+tensorboard, ...), and a headless run lifts once before an evaluation that is due after a skipped
    one, so evaluations read materials as fresh. False: they run in every run."""
    lift_channel_chunk: int = 8
    """Channels per lifting render (`lift_evidence`'s channel_chunk; K evidence + labelled + visibility channels in
    all): fewer channels per render lower its peak memory and cost more renders. gsplat renders 1-5, 8, 9, 16,
    17, 32, 33, ... channels as they are and pads any other count to the next power of two."""
    lift_views_per_call: int = 1
    """Training views rendered in one rasterizer call per lifting (`lift_views`): more save the per-call work on a
    GPU (projection, tile sorting, launches) and raise the lifting's peak memory with the views in flight
    (benchmarks/README.md, "Training")."""
    evidence_per_view: Literal["view", "pixels"] = "view"
    """How a view's lifted evidence counts in the Dirichlet. "view": divided by the Gaussian's blending weight in
    that view, so every view that sees the Gaussian (weight above `min_view_weight`) is one confidence-weighted
    observation, split over the labels of the pixels it covers: the concentration grows with the number of
    consistent views, not with the Gaussian's size on screen. "pixels": the raw pixel sum (every covered pixel
    counts as an observation: far more confident for large Gaussians, far less for sub-pixel ones)."""
    min_view_weight: float = 0.05
    """With evidence_per_view="view": a view counts for a Gaussian only if its total blending weight there (in
    pixels) exceeds this; below it the Gaussian is treated as unseen in that view."""
    min_evidence: float = 1e-3
    """Gaussians with less total lifted evidence than this keep the exact prior (never seen)."""
    precompute_geometry: Literal["auto", "on", "off"] = "auto"
    """After the final checkpoint, compute the object's geometry that `physgs export` would compute with its
    default settings and store it in the run's physgs_cache/ (physgs_nerfstudio/export/geometry_cache.py), so that
    the first export only loads the run and integrates the mass. "auto": on a CUDA device only (on the CPU the
    carving of a large capture takes minutes, which an export asked for mass pays instead). A failure (no object
    masks, say) is logged and never fails the training."""


def _view_maps(data: dict[str, Tensor], K: int, device: torch.device) -> tuple[Float[Tensor, "1 h w c"], bool]:
    """A view's evidence maps (K confidence-weighted one-hot channels + the labelled indicator) and whether
    it has any label."""
    labels = data["material"][..., 0].to(device).long()
    conf = data["material_confidence"][..., 0].to(device).float() / 255.0
    maps = label_evidence_maps(labels[None], conf[None], K)  # [1, H, W, K]
    return torch.cat([maps, (labels > 0)[None, ..., None].to(maps)], -1), bool((labels > 0).any())


@torch.no_grad()
def lift_material_maps(
    model: PhysGSModel,
    cameras: Cameras,
    views: Sequence[dict[str, Tensor]],
    *,
    evidence_per_view: Literal["view", "pixels"] = "view",
    min_view_weight: float = 0.05,
    min_evidence: float = 1e-3,
    channel_chunk: int = 32,
    views_per_call: int = 1,
) -> MaterialEvidence:
    """The material maps of `views` (cached data with `material` / `material_confidence`, [H, W, 1] uint8,
    one per camera of `cameras`) lifted onto the model's Gaussians as they stand (module doc). Views without
    a map still count for every Gaussian's total weight (labelled_fraction). ``views_per_call``: views of one size
    rendered in one rasterizer call (:func:`physgs_nerfstudio.lifting.lift_views`); the same evidence, added view
    by view in order."""
    K, N, device = model.num_materials, model.num_points, model.device
    geometry = (model.means.detach(), model.quats.detach(), torch.exp(model.scales.detach()),
                torch.sigmoid(model.opacities.detach()).squeeze(-1))  # fmt: skip
    evidence = torch.zeros(N, K, device=device)
    weight = torch.zeros(N, 1, device=device)
    labelled = torch.zeros(N, 1, device=device)
    used = 0
    sizes = [(int(cameras.width[i]), int(cameras.height[i])) for i in range(len(views))]
    for group in group_views(sizes, views_per_call):
        maps, viewmats, Ks = [], [], []
        for idx in group:
            view_maps, has_labels = _view_maps(views[idx], K, device)
            maps.append(view_maps)
            used += int(has_labels)
            cam = cameras[idx : idx + 1].to(device)
            cam.metadata = {"cam_idx": idx}
            viewmats.append(viewmat_from_c2w(model.camera_optimizer.apply_to_camera(cam)))
            Ks.append(cam.get_intrinsics_matrices().to(device))
        width, height = int(cameras.width[group[0]]), int(cameras.height[group[0]])
        for _, ev, vis in lift_views(
            *geometry, torch.cat(viewmats), torch.cat(Ks), width, height, torch.cat(maps),
            backend=model.config.rasterize_backend, rasterize_mode=model.config.rasterize_mode,
            channel_chunk=channel_chunk, views_per_call=len(group),
        ):  # fmt: skip
            for k in range(vis.shape[0]):  # view by view, in order
                view_evidence, view_labelled = ev[k, :, :K].to(evidence), ev[k, :, K:].to(labelled)
                view_weight = vis[k].to(weight)[:, None]
                if evidence_per_view == "view":
                    seen = view_weight > min_view_weight
                    norm = torch.where(seen, view_weight, torch.full_like(view_weight, float("inf")))
                    view_evidence, view_weight, view_labelled = (view_evidence / norm, view_weight / norm,
                                                                 view_labelled / norm)  # fmt: skip
                evidence += view_evidence
                weight += view_weight
                labelled += view_labelled
    evidence = evidence.clamp_min(0.0)
    evidence[evidence.sum(-1) < min_evidence] = 0.0
    return MaterialEvidence(evidence, weight, labelled.clamp_min(0.0), used)


GeometryStep = Callable[[Path, str], tuple[Path | None, str]]
"""The end-of-run geometry step: (the run's config.yml, the device type) -> (where the geometry was stored, or None
when the run folder is not writable; what was computed). ``physgs_nerfstudio.export.run.precompute_geometry``."""
_GEOMETRY_STEP: GeometryStep | None = None


def hand_in_geometry_step(step: GeometryStep | None) -> None:
    """Set the step :attr:`PhysGSPipelineConfig.precompute_geometry` runs after the final checkpoint. The plugin's
    method configs (``method_configs/physgs_config.py``) hand in the exporter's ``precompute_geometry``, so this
    package never imports the exporter (which reads runs that this package trains). None: no step."""
    global _GEOMETRY_STEP
    _GEOMETRY_STEP = step


class PhysGSPipeline(VanillaPipeline):
    """VanillaPipeline that lifts the training views' material maps onto the model at set steps."""

    config: PhysGSPipelineConfig
    model: PhysGSModel

    @property
    def lifting_step(self) -> int:
        step = self.config.lifting_step
        return self.model.config.stop_split_at if step is None else step

    def lift(self) -> MaterialEvidence:
        """Lift the training views' material maps onto the Gaussians now and hand the result to the model."""
        cameras, views = self.datamanager.material_views("train")  # type: ignore[attr-defined]
        c = self.config
        lifted = lift_material_maps(self.model, cameras, views, evidence_per_view=c.evidence_per_view,
                                    min_view_weight=c.min_view_weight, min_evidence=c.min_evidence,
                                    channel_chunk=c.lift_channel_chunk,
                                    views_per_call=c.lift_views_per_call)  # fmt: skip
        self.model.set_material_evidence(lifted)
        return lifted

    def get_training_callbacks(
        self, training_callback_attributes: TrainingCallbackAttributes
    ) -> list[TrainingCallback]:
        cbs = super().get_training_callbacks(training_callback_attributes)
        trainer = training_callback_attributes.trainer
        iterations = trainer.config.max_num_iterations if trainer is not None else None
        self._viewer = trainer is not None and "viewer" in str(getattr(trainer.config, "vis", ""))
        cbs.append(
            TrainingCallback(
                [TrainingCallbackLocation.AFTER_TRAIN_ITERATION], self._lift_on_schedule, args=[iterations]
            )
        )
        if trainer is not None:
            self._write_manifest(Path(trainer.config.get_base_dir()))
            cbs.append(TrainingCallback([TrainingCallbackLocation.AFTER_TRAIN], self._precompute_geometry,
                                        args=[Path(trainer.config.get_base_dir()) / "config.yml"]))  # fmt: skip
        return cbs

    def _write_manifest(self, run_dir: Path) -> None:
        """The run manifest (:mod:`physgs_nerfstudio.runfiles.manifest`): the legend, posteriors and maps this run
        trains with, which export and the viewer check the dataset against."""
        from physgs_nerfstudio.runfiles.manifest import dataset_dir, write_manifest

        dpo = self.datamanager.train_dataparser_outputs
        data_dir = dataset_dir(self.datamanager.config.data or getattr(self.datamanager.config.dataparser, "data", None))
        if data_dir is not None and "material_legend" in dpo.metadata:
            run_dir.mkdir(parents=True, exist_ok=True)
            write_manifest(run_dir, data_dir, dpo.metadata)

    def _precompute_geometry(self, config_path: Path, step: int) -> None:
        """`precompute_geometry` (config doc), after nerfstudio saved the final checkpoint."""
        mode = self.config.precompute_geometry
        device = torch.device(self.model.device)
        if mode == "off" or (mode == "auto" and device.type != "cuda") or not config_path.is_file():
            return
        if _GEOMETRY_STEP is None:  # nothing handed in (hand_in_geometry_step): the export computes it when asked
            return
        import time

        t0 = time.perf_counter()
        try:
            path, what = _GEOMETRY_STEP(config_path, device.type)
        except Exception as err:  # noqa: BLE001 - the run is complete and saved; the export computes it instead
            CONSOLE.log(f"[yellow]PhysGS: the object's geometry was not precomputed ({' '.join(str(err).split())[:300]});"
                        " `physgs export` computes it when asked[/yellow]")  # fmt: skip
            return
        CONSOLE.log(f"PhysGS geometry for `physgs export` ({what}) in {time.perf_counter() - t0:.1f} s"
                    + (f": {path}" if path is not None else ": not stored (the run folder is not writable)"))

    def _lift_on_schedule(self, iterations: int | None, step: int) -> None:
        """At `lifting_step`, every `lifting_every` steps (if > 0) and, with `lift_at_end`, at the last of the
        run's `iterations` (counted from the first step this run trained, so a resumed run ends where the trainer
        does); once per step at most."""
        if getattr(self, "_first_step", None) is None:
            self._first_step = step
        last = None if iterations is None else self._first_step + iterations - 1
        every = self.config.lifting_every
        periodic = every > 0 and step > 0 and step % every == 0
        if periodic and self.config.lifting_every_needs_viewer and not getattr(self, "_viewer", False):
            periodic = False  # a preview that nobody sees (config doc): the next evaluation lifts instead
            self._stale = True
        if step == self.lifting_step or periodic or (self.config.lift_at_end and step == last):
            # the iteration's parameter gradients are spent (the optimizers stepped; the next iteration zeroes
            # them): free them so that the lifting's peak memory does not stack on them
            self.model.zero_grad(set_to_none=True)
            self.lift()
            self._stale = False

    def _lift_if_stale(self) -> None:
        """Lift before an evaluation when a periodic lifting was skipped since the last one (headless runs)."""
        if getattr(self, "_stale", False):
            self.lift()
            self._stale = False

    def get_eval_image_metrics_and_images(self, step: int):  # type: ignore[no-untyped-def]
        self._lift_if_stale()
        return super().get_eval_image_metrics_and_images(step)

    def get_average_eval_image_metrics(self, step: int | None = None, output_path: Path | None = None,
                                       get_std: bool = False):  # type: ignore[no-untyped-def]  # fmt: skip
        self._lift_if_stale()
        return super().get_average_eval_image_metrics(step, output_path, get_std)
