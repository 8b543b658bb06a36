"""`PhysGSModel`: splatfacto-big plus a Bayesian physical-property head (paper section 3, docs/architecture.md, "The nerfstudio method").

Per Gaussian g, on top of splatfacto's parameters:

- the material head's tensor (`material_head`, module `material_head`): "logits", `material_logits` [N, K]
  (trainable, in `gauss_params`), rendered as K colour channels in a pass of their own every `material_every`
  steps and trained with a confidence-weighted cross-entropy against the material label maps; "latent",
  `material_features` [N, d] rendered the same way and decoded per pixel by `material_decoder` (Linear d -> K);
  "lifted", none (the map is rendered from the lifted evidence below). The rendered logits give the
  `material` output (argmax, legend colours).
- `dirichlet_evidence` [N, K] (not trainable, in `gauss_params` so densification splits / clones / prunes it
  with everything else; children of a split inherit their parent's evidence): the lifted evidence
  e_gk = sum over training pixels of (T * alpha)_g(pixel) * confidence(pixel) * [label(pixel) = k],
  computed by the pipeline (`pipeline.PhysGSPipeline`, through `physgs_nerfstudio.lifting.lift_evidence`) and
  handed to the model by `set_material_evidence`. Posterior
  alpha_g = alpha0 + lambda * e_g; a Gaussian with (near) zero evidence keeps the prior (maximal
  epistemic uncertainty).

How the two combine: the Dirichlet posterior is *the* Bayesian belief used for every physical property and
its uncertainty (mixture predictive over the per-material NIG posteriors of `materials.json`,
`bayes.property_fields`); the logits (or latent features) only drive the rendered material map (they are a
point estimate fit by gradient descent, good at pixel-sharp boundaries, with no calibrated uncertainty). The
pipeline lifts when densification stops (its `lifting_step`, default `stop_split_at`), every `lifting_every`
steps if set, at the last training iteration and on demand (`PhysGSPipeline.lift()`); before the first lifting
every Gaussian shows the prior.

Lifting also records, per Gaussian, its total (per-view normalised) blending weight `lifting_weight` [N, 1]
and the part of it that fell on labelled pixels (label != 0, whatever the confidence) `labelled_weight`
[N, 1]; their ratio `labelled_fraction()` tells Gaussians of the perceived object(s) from environment
Gaussians the material maps leave unknown (`physgs export` selects the object with it). Confidence is kept
out of it on purpose: a labelled pixel of a low-confidence answer is still a pixel of the labelled object.

How the outputs are rendered (`get_outputs`, the `material` map, the training resolution): `model_outputs.py`,
whose `PhysGSOutputsMixin` this model inherits.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, NamedTuple

import torch
import torch.nn.functional as F
from gsplat.strategy import DefaultStrategy
from jaxtyping import Float
from nerfstudio.model_components.lib_bilagrid import BilateralGrid
from nerfstudio.models.splatfacto import (
    RGB2SH,
    SplatfactoModel,
    SplatfactoModelConfig,
    num_sh_bases,
    random_quat_tensor,
)
from nerfstudio.utils.colors import get_color
from nerfstudio.utils.rich_utils import CONSOLE
from pytorch_msssim import SSIM
from torch import Tensor
from torch.nn import Parameter

from physgs_nerfstudio.bayes import NIG, dirichlet_posterior, property_fields
from physgs_nerfstudio.viewer.display import ViewerSettings, gaussian_channels, gaussian_materials

from ..runfiles.keys import (
    DECODER_GROUP,
    EVIDENCE_KEY,
    LABELLED_KEY,
    LOGITS_KEY,
    NON_TRAINABLE_KEYS,
    WEIGHT_KEY,
)
from ..runfiles.legend import PERCEIVE_HINT, VIEWER_NAMES, MaterialLegend
from .material_head import HEAD_TENSORS, MaterialHead, checkpoint_head, head_width, make_decoder
from .model_outputs import (
    MIN_SPLIT_RADIUS_PX,
    PROPERTY_OUTPUTS,
    UNCERTAINTY_OUTPUTS,
    PhysGSOutputsMixin,
    training_downscale,
)

__all__ = [  # (the names imported from this module; those of keys.py and model_outputs.py re-exported)
    "EVIDENCE_KEY",
    "LABELLED_KEY",
    "LOGITS_KEY",
    "MIN_SPLIT_RADIUS_PX",
    "PROPERTY_OUTPUTS",
    "UNCERTAINTY_OUTPUTS",
    "WEIGHT_KEY",
    "MaterialEvidence",
    "PhysGSModel",
    "PhysGSModelConfig",
    "downscale_labels",
    "training_downscale",
]

_SPLATFACTO_PARAMS = ("means", "scales", "quats", "features_dc", "features_rest", "opacities")


@dataclass
class PhysGSModelConfig(SplatfactoModelConfig):
    """splatfacto-big (cull_alpha_thresh 0.005, densify_grad_thresh 0.0005) with the paper's random scale 2.0 and
    random background, plus the material / property head."""

    _target: type = field(default_factory=lambda: PhysGSModel)
    cull_alpha_thresh: float = 0.005
    densify_grad_thresh: float = 0.0005
    random_scale: float = 2.0
    """Size of the cube for random initialisation (paper: 2.0)."""
    background_color: Literal["random", "black", "white"] = "random"
    material_head: MaterialHead = "lifted"
    """What carries each Gaussian's material for the rendered `material` map (`nerfstudio/material_head.py`,
    docs/architecture.md "Material head"): "logits", K trainable logits per Gaussian; "latent",
    `material_latent_dim` trainable features per Gaussian decoded per pixel by a Linear d -> K; "lifted", nothing
    trainable and no material pass: the composited Dirichlet predictive of the lifted evidence (no material before
    the first lifting; see the pipeline's `lifting_every`). A checkpoint loads under any head (it keeps its own)."""
    material_latent_dim: int = 8
    """Features per Gaussian of the "latent" head (8: a channel count gsplat renders without padding)."""
    material_loss_weight: float = 0.1
    """Weight of the confidence-weighted cross-entropy between rendered logits and the label maps."""
    material_every: int = 8
    """Train the material logits every this many steps (their own render pass); the RGB pass is splatfacto's
    own every step, so the head's cost is amortised. On an H100 (benchmarks/README.md) iteration time vs
    splatfacto-big was 1.31x with 4 and 1.13x with 8."""
    material_downscale: int = 2
    """The training render of the material logits is this many times smaller per side than the RGB render
    (labels are piecewise constant, so a coarser supervision grid loses little)."""
    dirichlet_alpha0: float | None = None
    """Dirichlet prior concentration per material; None = `alpha0` of materials.json (1.0 if absent)."""
    dirichlet_lambda: float | None = None
    """Evidence strength lambda (evidence in pixel-weight units); None = `lambda` of materials.json (1.0 if absent)."""
    material_weights: Literal["dominant", "predictive"] = "dominant"
    """How a Gaussian's Dirichlet posterior weights the materials' property posteriors, for the viewer outputs
    and every `physgs export` writer (saved with the run's config): "dominant", the posterior that a material
    is the Gaussian's dominant label (bayes.dominance_probability); "predictive", alpha / sum(alpha)."""
    uncertainty_property: Literal["density", "friction", "hardness", "stiffness"] = "density"
    """Property whose aleatoric / epistemic / total uncertainty the viewer outputs show at start (the viewer
    panel's *Uncertainty of* changes it while the viewer runs)."""
    uncertainty_as_std: bool = True
    """Show uncertainties as standard deviations (property units) instead of variances."""
    material_alpha_thresh: float = 0.5
    """Pixels with less accumulated opacity are background in the `material` output (label 0)."""
    material_min_labelled: float = 0.3
    """After lifting, pixels whose composited labelled fraction (share of the Gaussians' blending weight that fell
    on labelled pixels) is below this show no material (regions the maps leave unknown)."""
    render_property_outputs: bool = True
    """Render the property / uncertainty outputs at evaluation and in the viewer."""
    rasterize_backend: Literal["auto", "gsplat", "reference"] = "auto"
    """auto: gsplat on CUDA, the pure-torch reference rasterizer elsewhere."""
    compute_lpips: bool = True
    """LPIPS in eval metrics, when torchvision's AlexNet weights are on disk (skipped with one line otherwise)."""


class MaterialEvidence(NamedTuple):
    """A lifting pass's result for the Gaussians as they stand (`PhysGSModel.set_material_evidence`)."""

    evidence: Float[Tensor, "n k"]
    """confidence-weighted label evidence (per-view normalised or pixel sums); 0 rows keep the prior"""
    weight: Float[Tensor, "n 1"]
    """total blending weight (`lifting_weight`)"""
    labelled: Float[Tensor, "n 1"]
    """the part of it on labelled pixels (`labelled_weight`)"""
    views: int
    """training views with at least one labelled pixel"""


ALEXNET_WEIGHTS = "alexnet-owt-7be5be79.pth"
"""torchvision's AlexNet weights file (``AlexNet_Weights.IMAGENET1K_V1``), the backbone of torchmetrics' LPIPS"""


def alexnet_weights_path() -> Path:
    """Where torchvision keeps the AlexNet weights (torch hub's ``checkpoints`` folder; ``$TORCH_HOME``)."""
    import torch.hub

    return Path(torch.hub.get_dir()) / "checkpoints" / ALEXNET_WEIGHTS


class _LazyLPIPS:
    """LPIPS built on first use, only when its backbone's weights are already on disk (nothing is downloaded at
    run time): else nan, with one line saying where the file would go.

    Deliberately not an nn.Module, so its weights stay out of checkpoints.
    """

    def __init__(self, enabled: bool):
        self.enabled = enabled
        self.metric = None
        self.failed = not enabled

    def __call__(self, a: Tensor, b: Tensor) -> Tensor:
        if not self.failed and self.metric is None and not alexnet_weights_path().is_file():
            self.failed = True
            CONSOLE.log(f"[yellow]LPIPS skipped: its AlexNet weights are not on disk ({alexnet_weights_path()}); nothing "
                        "is downloaded at run time: put the file there to get LPIPS[/yellow]")  # fmt: skip
        if not self.failed and self.metric is None:
            try:
                from torchmetrics.image.lpip import LearnedPerceptualImagePatchSimilarity

                self.metric = LearnedPerceptualImagePatchSimilarity(normalize=True)
            except Exception as err:  # noqa: BLE001  (offline machines have no AlexNet weights; any failure)
                self.failed = True
                CONSOLE.log(f"[yellow]LPIPS disabled: {type(err).__name__}: {str(err)[:120]}")
        if self.failed:
            return torch.tensor(float("nan"))
        self.metric = self.metric.to(a.device)
        return self.metric(a, b)


def downscale_labels(t: Tensor, d: int, height: int, width: int) -> Tensor:
    """Nearest-neighbour downscale of a [H, W, C] map by d (centre sample of each d x d block)."""
    if d > 1:
        t = t[d // 2 :: d, d // 2 :: d]
    return t[:height, :width]


class PhysGSModel(PhysGSOutputsMixin, SplatfactoModel):
    """Splatfacto with per-Gaussian material logits, lifted Dirichlet evidence and property outputs."""

    config: PhysGSModelConfig

    # ------------------------------------------------------------------ setup
    def populate_modules(self):
        """The material head (legend, Dirichlet prior, per-material NIG buffers), the Gaussians, then
        splatfacto's training modules."""
        legend = self.kwargs.get("metadata", {}).get("material_legend")
        if not isinstance(legend, MaterialLegend):
            raise ValueError(  # noqa: TRY004  (a missing input, reported as a configuration error)
                "PhysGSModel needs the material legend in the dataparser metadata (use the physgs datamanager). "
                + PERCEIVE_HINT
            )
        self.legend = legend
        K = legend.num_materials
        P = len(legend.property_keys)
        self.log_space = legend.log_space
        self.property_keys = legend.property_keys
        alpha0 = self.config.dirichlet_alpha0 if self.config.dirichlet_alpha0 is not None else legend.alpha0
        lam = self.config.dirichlet_lambda if self.config.dirichlet_lambda is not None else legend.lam
        self.alpha0 = 1.0 if alpha0 is None else float(alpha0)
        self.lam = 1.0 if lam is None else float(lam)
        # scene-level per-material property posteriors (persist in checkpoints)
        for f, v in legend.nig.items():
            self.register_buffer(f"nig_{f}", v.clone().reshape(K, P))
        self.register_buffer("material_colors", legend.colors.clone().reshape(K, 3))
        self.register_buffer("lifted_views", torch.zeros((), dtype=torch.long))
        self.gauss_params = self._initial_gaussians(K)
        self.material_decoder: torch.nn.Linear | None = None  # (the "latent" head's; `_set_material_head`)
        self._set_material_head(self.config.material_head, self.config.material_latent_dim)
        self._populate_training_modules()
        self._populate_viewer()

    def _populate_viewer(self) -> None:
        """What the property outputs show (`viewer_settings`) and the viewer's "Physical properties" panel
        (`physgs_nerfstudio.viewer.panel`: parameter-free, nothing in checkpoints)."""
        from physgs_nerfstudio.viewer.panel import PhysicalPropertiesPanel

        self.viewer_settings = ViewerSettings(
            uncertainty_property=self.property_keys[self._uncertainty_index()],
            min_coverage=self.config.material_alpha_thresh, min_labelled=self.config.material_min_labelled,
        )  # fmt: skip
        self.physical_properties = PhysicalPropertiesPanel(self)

    def _initial_gaussians(self, num_materials: int) -> torch.nn.ParameterDict:
        """splatfacto's Gaussians plus the material tensors, seeded device-agnostically (splatfacto's
        populate_modules moves SH to CUDA)."""
        K = num_materials
        seed = self.seed_points
        if seed is not None and not self.config.random_init:
            means = seed[0].detach().float().clone()
        else:
            means = (torch.rand((self.config.num_random, 3)) - 0.5) * self.config.random_scale
        if self.kwargs.get("placeholder_gaussians"):  # a checkpoint replaces them (runfiles/loader.py): no kNN
            means = means[:1]
            scales = torch.zeros_like(means)
        else:
            distances, _ = self.k_nearest_sklearn(means, 3)
            scales = torch.log(
                torch.from_numpy(distances).mean(dim=-1, keepdim=True).clamp_min(1e-7).repeat(1, 3)
            )
        n = means.shape[0]
        dim_sh = num_sh_bases(self.config.sh_degree)
        features_rest = torch.zeros((n, dim_sh - 1, 3))
        if seed is not None and not self.config.random_init and seed[1].shape[0] > 0:
            rgb = seed[1].detach().float().cpu() / 255.0
            features_dc = RGB2SH(rgb) if self.config.sh_degree > 0 else torch.logit(rgb, eps=1e-10)
        else:
            features_dc = torch.rand(n, 3)
        return torch.nn.ParameterDict(
            {
                "means": Parameter(means),
                "scales": Parameter(scales),
                "quats": Parameter(random_quat_tensor(n)),
                "features_dc": Parameter(features_dc),
                "features_rest": Parameter(features_rest),
                "opacities": Parameter(torch.logit(0.1 * torch.ones(n, 1))),
                EVIDENCE_KEY: Parameter(torch.zeros(n, K), requires_grad=False),
                WEIGHT_KEY: Parameter(torch.zeros(n, 1), requires_grad=False),
                LABELLED_KEY: Parameter(torch.zeros(n, 1), requires_grad=False),
            }
        )

    def _populate_training_modules(self) -> None:
        """splatfacto's camera optimizer, metrics, background, bilateral grid and gsplat densification strategy."""
        self.camera_optimizer = self.config.camera_optimizer.setup(
            num_cameras=self.num_train_data, device="cpu"
        )
        if self.kwargs.get("placeholder_gaussians"):  # built to load a checkpoint for export: no eval metrics
            self.psnr = self.ssim = None  # (torchmetrics' import alone is about a second; nothing is saved of them)
        else:
            from torchmetrics.image import PeakSignalNoiseRatio

            self.psnr = PeakSignalNoiseRatio(data_range=1.0)
            self.ssim = SSIM(data_range=1.0, size_average=True, channel=3)
        self.lpips = _LazyLPIPS(self.config.compute_lpips)
        self.step = 0
        self.crop_box = None
        if self.config.background_color == "random":
            # viser's background colour, as splatfacto
            self.background_color = torch.tensor([0.1490, 0.1647, 0.2157])
        else:
            self.background_color = get_color(self.config.background_color)
        if self.config.use_bilateral_grid:
            self.bil_grids = BilateralGrid(
                num=self.num_train_data,
                grid_X=self.config.grid_shape[0],
                grid_Y=self.config.grid_shape[1],
                grid_W=self.config.grid_shape[2],
            )
        c = self.config
        self.strategy = DefaultStrategy(
            prune_opa=c.cull_alpha_thresh,
            grow_grad2d=c.densify_grad_thresh,
            grow_scale3d=c.densify_size_thresh,
            grow_scale2d=c.split_screen_size,
            prune_scale3d=c.cull_scale_thresh,
            prune_scale2d=c.cull_screen_size,
            refine_scale2d_stop_iter=c.stop_screen_size_at,
            refine_start_iter=c.warmup_length,
            refine_stop_iter=c.stop_split_at,
            reset_every=c.reset_alpha_every * c.refine_every,
            refine_every=c.refine_every,
            pause_refine_after_reset=self.num_train_data + c.refine_every,
            absgrad=c.use_absgrad,
            revised_opacity=False,
            verbose=True,
        )
        self.strategy_state = self.strategy.initialize_state(scene_scale=1.0)
        self.optimizers: dict[str, torch.optim.Optimizer] = {}

    def _set_material_head(self, head: str, latent_dim: int) -> None:
        """Make `head` the model's material head (module `material_head`): its per-Gaussian tensor (zeros, as
        many rows as the Gaussians) replaces any other head's, and the decoder exists only for "latent"."""
        K, n, device = self.num_materials, self.num_points, self.gauss_params["means"].device
        width = head_width(head, K, latent_dim)
        key = HEAD_TENSORS[head]
        for other in filter(None, HEAD_TENSORS.values()):
            if other in self.gauss_params and other != key:
                del self.gauss_params[other]
        if key is not None and (key not in self.gauss_params or self.gauss_params[key].shape[1] != width):
            self.gauss_params[key] = Parameter(torch.zeros(n, width, device=device))
        if head != "latent":
            self.material_decoder = None
        elif self.material_decoder is None or self.material_decoder.in_features != width:
            self.material_decoder = make_decoder(width, K).to(device)
        self.material_head = head

    @property
    def num_materials(self) -> int:
        return self.gauss_params[EVIDENCE_KEY].shape[1]

    @property
    def material_logits(self) -> Tensor | None:
        """The "logits" head's per-Gaussian logits [N, K]; None under another head (a property must not raise:
        nerfstudio's viewer reads every attribute of the model)."""
        return self.gauss_params.get(LOGITS_KEY)

    def _head_width(self) -> int:
        key = HEAD_TENSORS[self.material_head]
        return 0 if key is None else int(self.gauss_params[key].shape[1])

    @property
    def trainable_head_keys(self) -> tuple[str, ...]:
        """The head's trainable per-Gaussian tensor in `gauss_params`, if any."""
        key = HEAD_TENSORS[self.material_head]
        return () if key is None else (key,)

    @property
    def dirichlet_evidence(self) -> Tensor:
        return self.gauss_params[EVIDENCE_KEY]

    def labelled_fraction(self) -> Float[Tensor, "n 1"]:
        """Share of each Gaussian's lifted (per-view normalised) blending weight that fell on labelled pixels
        (label != 0, not weighted by confidence); 0 for Gaussians never seen. For a checkpoint written before
        `labelled_weight` existed, the confidence-weighted share (``labelled_fraction_legacy`` is then True)."""
        w = self.gauss_params[WEIGHT_KEY].detach()
        frac = self.gauss_params[LABELLED_KEY].detach() / w.clamp_min(1e-12)
        return torch.where(w > 0, frac, torch.zeros_like(frac)).clamp(0.0, 1.0)

    @property
    def labelled_fraction_legacy(self) -> bool:
        return bool(getattr(self, "_labelled_legacy", False))

    def get_gaussian_param_groups(self) -> dict[str, list[Parameter]]:
        return {name: [self.gauss_params[name]] for name in (*_SPLATFACTO_PARAMS, *self.trainable_head_keys)}

    def get_param_groups(self) -> dict[str, list[Parameter]]:
        """splatfacto's groups (Gaussians, bilateral grid, camera) plus the "latent" head's decoder."""
        groups = super().get_param_groups()
        if self.material_decoder is not None:
            groups[DECODER_GROUP] = list(self.material_decoder.parameters())
        return groups

    def load_state_dict(self, dict, **kwargs):  # type: ignore
        saved = checkpoint_head(dict)
        if saved is not None and (saved[0] != self.material_head or saved[1] != self._head_width()):
            CONSOLE.log(f"checkpoint written with material_head={saved[0]!r}: the model uses it "
                        f"(configured: {self.material_head!r})")  # fmt: skip
            self._set_material_head(saved[0], saved[1] or self.config.material_latent_dim)
        key = f"gauss_params.{LABELLED_KEY}"
        self._labelled_legacy = key not in dict and f"gauss_params.{EVIDENCE_KEY}" in dict
        if self._labelled_legacy:  # checkpoint older than labelled_weight: its confidence-weighted stand-in
            dict = {**dict, key: dict[f"gauss_params.{EVIDENCE_KEY}"].sum(-1, keepdim=True)}
            CONSOLE.log(
                f"[yellow]checkpoint has no {LABELLED_KEY}: labelled fraction falls back to the "
                "confidence-weighted evidence share (re-lift or retrain for the exact one)"
            )
        super().load_state_dict(dict, **kwargs)  # splatfacto resizes every gauss_params entry to the saved N
        for key in NON_TRAINABLE_KEYS:
            self.gauss_params[key].requires_grad_(False)

    # ------------------------------------------------------------------ densification
    def _strategy_optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """nerfstudio's optimizers plus no-op ones for the lifted tensors, since gsplat's strategy ops update
        every `gauss_params` entry through an optimizer (these are never stepped). The no-op optimizers are built
        once and kept while they hold the current tensors (the strategy's ops swap the tensors inside them;
        building three optimizers on every step cost host time in each training iteration)."""
        noop = getattr(self, "_noop_optimizers", None)
        if noop is None or any(noop[k].param_groups[0]["params"][0] is not self.gauss_params[k] for k in noop):
            noop = {k: torch.optim.SGD([self.gauss_params[k]], lr=0.0) for k in NON_TRAINABLE_KEYS}
            self._noop_optimizers = noop
        return {**self.optimizers, **noop}

    def step_post_backward(self, step):
        assert step == self.step
        self.strategy.step_post_backward(
            params=self.gauss_params,
            optimizers=self._strategy_optimizers(),
            state=self.strategy_state,
            step=self.step,
            info=self.info,
            packed=False,
        )
        for key in NON_TRAINABLE_KEYS:
            self.gauss_params[key].requires_grad_(False)

    # ------------------------------------------------------------------ Bayesian head
    @torch.no_grad()
    def set_material_evidence(self, lifted: MaterialEvidence) -> None:
        """Replace the lifted per-Gaussian tensors (`dirichlet_evidence`, `lifting_weight`, `labelled_weight`) and
        the count of lifted views with a lifting pass over the Gaussians as they stand (the pipeline's)."""
        N, K = self.num_points, self.num_materials
        shapes = {"evidence": (N, K), "weight": (N, 1), "labelled": (N, 1)}
        for name, want in shapes.items():
            got = tuple(getattr(lifted, name).shape)
            if got != want:
                raise ValueError(
                    f"set_material_evidence: {name} has shape {got}, the model has {want} "
                    "(lift again after densification changed the Gaussians)"
                )
        self.gauss_params[EVIDENCE_KEY].data = lifted.evidence.to(self.device)
        self.gauss_params[WEIGHT_KEY].data = lifted.weight.to(self.device)
        self.gauss_params[LABELLED_KEY].data = lifted.labelled.to(self.device)
        self._labelled_legacy = False
        self.lifted_views.fill_(int(lifted.views))
        CONSOLE.log(
            f"PhysGS lifting: {int(lifted.views)} views -> evidence on "
            f"{int((lifted.evidence.sum(-1) > 0).sum())}/{N} Gaussians"
        )

    def dirichlet_alpha(self) -> Float[Tensor, "n k"]:
        """Per-Gaussian Dirichlet posterior alpha0 + lambda * evidence (the prior where evidence is 0)."""
        return dirichlet_posterior(self.dirichlet_evidence.detach(), self.alpha0, self.lam)

    def material_nig(self) -> NIG:
        return NIG(self.nig_tau, self.nig_kappa, self.nig_a, self.nig_b)

    @torch.no_grad()
    def gaussian_properties(self) -> dict[str, Float[Tensor, "n p"]]:
        """Mixture predictive per Gaussian: mean, aleatoric, epistemic, total (variances), linear units.

        Cached until the evidence tensor changes (lifting, densification, checkpoint load): the material
        weights (dominance probabilities) cost a quadrature per Gaussian, too much for every rendered frame.
        """
        ev = self.dirichlet_evidence
        weights = self.config.material_weights
        key = (ev.data_ptr(), ev._version, tuple(ev.shape), ev.device, float(self.alpha0), float(self.lam), weights)
        cached = getattr(self, "_properties_cache", None)
        if cached is None or cached[0] != key:
            fields = property_fields(self.dirichlet_alpha(), self.material_nig(), self.log_space, material_weights=weights)
            cached = (key, fields)
            self._properties_cache = cached
        return cached[1]

    def _uncertainty_index(self) -> int:
        want = self.config.uncertainty_property
        for i, key in enumerate(self.property_keys):
            if want in (key, VIEWER_NAMES.get(key)):
                return i
        raise ValueError(f"uncertainty_property {want!r} is not one of {self.property_keys}")

    @torch.no_grad()
    def _property_channels(self) -> tuple[list[str], Float[Tensor, "n c"]]:
        """Per-Gaussian channels composited for the property / uncertainty outputs: the material weights of
        the Gaussians with material evidence and that flag (`physgs_nerfstudio.viewer.display`)."""
        gm = gaussian_materials(self)
        return [f"pi_{i}" for i in range(self.num_materials)] + ["measured"], gaussian_channels(gm)

    # ------------------------------------------------------------------ losses and metrics
    def _batch_material(self, batch: dict[str, Any], height: int, width: int) -> tuple[Tensor, Tensor]:
        """Label ids [H, W] (long) and confidences [H, W] in [0, 1] at the rendered resolution."""
        # the render may be smaller than the image (training downscale, material_downscale): sample labels at
        # the centre of each render pixel's block (nearest neighbour: labels must not be interpolated)
        d = max(1, batch["material"].shape[0] // height)
        labels = downscale_labels(batch["material"], d, height, width)[..., 0].to(self.device).long()
        conf = (
            downscale_labels(batch["material_confidence"], d, height, width)[..., 0].to(self.device).float()
            / 255
        )
        if "mask" in batch:
            mask = downscale_labels(batch["mask"], d, height, width)[..., 0].to(self.device).bool()
            labels = torch.where(mask, labels, 0)
        if labels.shape != (height, width):
            raise RuntimeError(
                f"material map {tuple(labels.shape)} does not match the render {(height, width)}"
            )
        return labels, conf

    def get_loss_dict(self, outputs, batch, metrics_dict=None) -> dict[str, torch.Tensor]:
        loss_dict = super().get_loss_dict(outputs, batch, metrics_dict)
        if self.config.material_loss_weight > 0 and LOGITS_KEY in outputs and "material" in batch:
            logits = outputs[LOGITS_KEY]
            labels, conf = self._batch_material(batch, *logits.shape[:2])
            # dense and sync-free (no boolean indexing): unknown pixels (label 0) get weight 0
            valid = (labels > 0).to(conf)
            ce = F.cross_entropy(logits.permute(2, 0, 1)[None], (labels - 1).clamp_min(0)[None], reduction="none")[0]
            loss = (conf * valid * ce).sum() / valid.sum().clamp_min(1.0)
            loss_dict["material_loss"] = self.config.material_loss_weight * loss
        return loss_dict

    def _material_accuracy(self, pred: Tensor, labels: Tensor) -> float | None:
        valid = labels > 0
        if not bool(valid.any()):
            return None
        return float((pred[valid] == labels[valid]).float().mean())

    def get_metrics_dict(self, outputs, batch) -> dict[str, torch.Tensor]:
        metrics = super().get_metrics_dict(outputs, batch)
        if LOGITS_KEY in outputs and "material" in batch:
            logits = outputs[LOGITS_KEY]
            labels, _ = self._batch_material(batch, *logits.shape[:2])
            valid = labels > 0  # a tensor metric: no host sync in the training step (NaN without labels)
            hits = ((logits.argmax(-1) + 1) == labels) & valid
            metrics["material_acc"] = hits.sum() / valid.sum()
        return metrics

    def get_image_metrics_and_images(
        self, outputs: dict[str, torch.Tensor], batch: dict[str, torch.Tensor]
    ) -> tuple[dict[str, float], dict[str, torch.Tensor]]:
        metrics, images = super().get_image_metrics_and_images(outputs, batch)
        if "material_id" in outputs and "material" in batch:
            pred = outputs["material_id"][..., 0].long()
            labels, _ = self._batch_material(batch, *pred.shape)
            acc = self._material_accuracy(pred, labels)
            if acc is not None:
                metrics["material_acc"] = acc
            palette = torch.cat(
                [outputs["background"][0, 0][None].to(self.material_colors), self.material_colors]
            )
            images["material"] = torch.cat([palette[labels], outputs["material"]], dim=1)
        return metrics, images
