"""The rendering of `PhysGSModel`'s outputs (docs/architecture.md, "The nerfstudio method"):
`PhysGSOutputsMixin` holds the model's `get_outputs` (one camera: the training pass or the evaluation / viewer
pass), `get_empty_outputs` and their helpers; `training_downscale` the training resolution.

The `material` output shows the argmax of the rendered logits (the "lifted" head: of the composited Dirichlet
predictive, nothing before the first lifting) where the accumulated opacity exceeds
`material_alpha_thresh` and, once lifted, where the composited labelled fraction exceeds
`material_min_labelled`; elsewhere the background colour (label 0). `material_id` (float label, [H, W, 1])
carries the same map for metrics.

Rendering is one call of `physgs_nerfstudio.render.rasterize` (gsplat on CUDA, the pure-torch reference
rasterizer on CPU) with per-Gaussian colours [N, 3 + K (+ property channels)]; view-dependent RGB is
evaluated from the SH coefficients before rasterization so that RGB and the extra channels share one pass.

The mixin has no state or parameters of its own: it reads the model's (`config`, `gauss_params`, `strategy`,
`lifted_views`, `material_head`, `material_decoder`, `material_colors`) and calls the Bayesian head's methods
(`labelled_fraction`, `dirichlet_alpha`, `_property_channels`) that `model.PhysGSModel` defines. model.py imports
this module, never the reverse.
"""

from __future__ import annotations

from typing import Any

import torch
from jaxtyping import Float
from nerfstudio.cameras.cameras import Cameras
from nerfstudio.models.splatfacto import SplatfactoModel
from nerfstudio.utils.rich_utils import CONSOLE
from torch import Tensor

from physgs_nerfstudio.geometry.capture import viewmat_from_c2w
from physgs_nerfstudio.render import eval_sh_colors, rasterize
from physgs_nerfstudio.viewer.display import viewer_outputs

from ..runfiles.keys import LOGITS_KEY
from ..runfiles.legend import VIEWER_NAMES
from .material_head import HEAD_TENSORS, predictive

PROPERTY_OUTPUTS = ("density", "friction", "hardness", "stiffness")
UNCERTAINTY_OUTPUTS = ("aleatoric", "epistemic", "total_uncertainty")

MIN_SPLIT_RADIUS_PX = 6.0
"""A rendered Gaussian's radius is at least 2 pixels (gsplat: 3 sigma of the 0.3 px^2 blur, rounded up). The
screen-size split (`split_screen_size`, a fraction of the image's longer side) is only meaningful where it asks for
3 times that: below it every Gaussian qualifies and splits at every refinement."""


def training_downscale(scheduled: int, long_side: int, split_screen_size: float, screen_split_on: bool) -> int:
    """splatfacto's scheduled training downscale ``scheduled`` (a power of 2), reduced while the screen-size split
    is on so that ``long_side / d * split_screen_size >= MIN_SPLIT_RADIUS_PX``: at 1/4 of a 128 px capture (32 px)
    every Gaussian was "large on screen", the count doubled every 100 steps (45k at step 800, 949k at step 1,400
    on CPU) and a 3,000-step GPU run ran out of 80 GB (benchmarks/README.md)."""
    d = max(1, int(scheduled))
    if not screen_split_on or split_screen_size <= 0:
        return d
    while d > 1 and long_side / d * split_screen_size < MIN_SPLIT_RADIUS_PX:
        d //= 2
    return d


class PhysGSOutputsMixin:
    """`PhysGSModel`'s rendering (module doc). First in the model's bases, so that these methods override
    `SplatfactoModel`'s (and `super()` here reaches splatfacto's)."""

    def get_empty_outputs(self, width: int, height: int, background: torch.Tensor) -> dict[str, Any]:  # type: ignore
        out = SplatfactoModel.get_empty_outputs(width, height, background)
        out["material"] = out["rgb"].clone()
        out["material_id"] = out["accumulation"].clone()
        if self.config.render_property_outputs:
            for name in (*[VIEWER_NAMES.get(k, k) for k in self.property_keys], *UNCERTAINTY_OUTPUTS):
                out[name] = out["rgb"].clone()
        return out

    def _get_downscale_factor(self) -> int:
        """splatfacto's schedule, never so coarse that the screen-size split takes every Gaussian
        (:func:`training_downscale`); the full-resolution size is the last training camera's."""
        d = super()._get_downscale_factor()
        long_side = getattr(self, "_train_long_side", None)
        if not self.training or long_side is None:
            return d
        on = self.step < self.strategy.refine_scale2d_stop_iter  # the strategy's: the guard below may switch it off
        return training_downscale(d, long_side, self.config.split_screen_size, on)

    def _camera_size(self, camera: Cameras) -> tuple[int, int]:
        """Full-resolution (width, height) of a one-camera batch. A training camera's size is read from the device
        once and then kept by its `cam_idx`: each `.item()` on a CUDA camera is a host-device synchronisation,
        and four of them per step would leave the GPU idle between them."""
        idx = camera.metadata.get("cam_idx") if camera.metadata else None
        sizes: dict[int, tuple[int, int]] = self.__dict__.setdefault("_camera_sizes", {})
        if isinstance(idx, int) and idx in sizes:
            return sizes[idx]
        size = (int(camera.width.item()), int(camera.height.item()))
        if isinstance(idx, int):
            sizes[idx] = size
        return size

    def _screen_split_guard(self, size: tuple[int, int]) -> None:
        """Record the training image size; below the size where any Gaussian is "large on screen" even at full
        resolution (:data:`MIN_SPLIT_RADIUS_PX`), switch the screen-size split off, once, with a note."""
        long_side = max(size)
        self._train_long_side = long_side
        c = self.config
        if (long_side * c.split_screen_size < MIN_SPLIT_RADIUS_PX and self.strategy.refine_scale2d_stop_iter > 0
                and not getattr(self, "_screen_split_off", False)):  # fmt: skip
            self._screen_split_off = True
            self.strategy.refine_scale2d_stop_iter = 0
            CONSOLE.log(f"[yellow]{long_side} px training images: the screen-size split (split_screen_size "
                        f"{c.split_screen_size}) would split every Gaussian; it is off for this run.[/yellow]")

    def get_outputs(self, camera: Cameras) -> dict[str, torch.Tensor | list]:
        """RGB, depth, accumulation, background; training adds `material_logits` [H, W, K]; evaluation adds
        `material` [H, W, 3] (legend colours, or one material's probability: `viewer_settings`), `material_id`
        [H, W, 1] (0 = background) and, if enabled, the property outputs `density`, `friction`, `hardness`,
        `stiffness`, `aleatoric`, `epistemic`, `total_uncertainty`, each [H, W, 3]: colours on fixed scales
        where Gaussians with material evidence cover the pixel, dimmed RGB elsewhere (docs/viewer.md)."""
        if not isinstance(camera, Cameras):
            CONSOLE.log("Called get_outputs with not a camera")
            return {}
        assert camera.shape[0] == 1, "PhysGSModel renders one camera at a time"
        if self.training:
            size = self._camera_size(camera)
            self._screen_split_guard(size)
            c2w = self.camera_optimizer.apply_to_camera(camera)
            Ks, W, H = self._render_intrinsics(camera, size)
            return self._training_outputs(camera, c2w, Ks, W, H)
        crop_ids = None
        if self.crop_box is not None:
            crop_ids = self.crop_box.within(self.means).squeeze()
            if crop_ids.sum() == 0:
                return self.get_empty_outputs(
                    int(camera.width.item()), int(camera.height.item()), self.background_color.to(self.device)
                )
        Ks, W, H = self._render_intrinsics(camera)
        return self._eval_outputs(camera.camera_to_worlds, Ks, W, H, crop_ids)

    def _render_intrinsics(
        self, camera: Cameras, size: tuple[int, int] | None = None
    ) -> tuple[Float[Tensor, "1 3 3"], int, int]:
        """Intrinsics, width and height of the render (splatfacto's training downscale applied). With the camera's
        full-resolution `size` known on the host, the downscaled size is computed there as nerfstudio does
        (`Cameras.rescale_output_resolution`: the size times 1/d, truncated; d is a power of 2, so exact)."""
        d = self._get_downscale_factor()
        camera.rescale_output_resolution(1 / d)
        Ks = camera.get_intrinsics_matrices().to(self.device)
        if size is None:
            W, H = int(camera.width.item()), int(camera.height.item())
        else:
            W, H = int(size[0] * (1 / d)), int(size[1] * (1 / d))
        self.last_size = (H, W)
        camera.rescale_output_resolution(d)
        return Ks, W, H

    def _view_colors(self, c2w: Tensor, crop) -> Float[Tensor, "n 3"]:
        """View-dependent RGB per Gaussian, evaluated from the SH coefficients (so RGB shares the pass with
        the extra channels)."""
        if self.config.sh_degree <= 0:
            return torch.sigmoid(crop(self.features_dc))
        sh_degree = min(self.step // self.config.sh_degree_interval, self.config.sh_degree)
        coeffs = torch.cat((crop(self.features_dc)[:, None, :], crop(self.features_rest)), dim=1)
        dirs = crop(self.means).detach() - c2w[0, :3, 3].to(self.device)
        return torch.clamp_min(eval_sh_colors(sh_degree, dirs, coeffs) + 0.5, 0.0)

    def _eval_outputs(
        self, c2w: Tensor, Ks: Tensor, W: int, H: int, crop_ids: Tensor | None
    ) -> dict[str, Any]:
        """Evaluation / viewer: one pass of RGB, the K material logits, (once lifted) the labelled fraction
        and the property channels, plus depth."""

        def crop(t: Tensor) -> Tensor:
            return t if crop_ids is None else t[crop_ids]

        lifted = bool(self.lifted_views > 0)
        head = self._eval_head_channels(lifted)
        channels = [self._view_colors(c2w, crop), *([crop(head)] if head is not None else [])]
        if lifted:  # share of labelled pixels among those each Gaussian was seen in
            channels.append(crop(self.labelled_fraction()).float())
        prop_names: list[str] = []
        if self.config.render_property_outputs:
            prop_names, prop_g = self._property_channels()
            channels.append(crop(prop_g))
        render, alpha, self.info = rasterize(
            means=crop(self.means),
            quats=crop(self.quats),
            scales=torch.exp(crop(self.scales)),
            opacities=torch.sigmoid(crop(self.opacities)).squeeze(-1),
            colors=torch.cat(channels, dim=-1),
            viewmats=viewmat_from_c2w(c2w.to(self.device)),
            Ks=Ks, width=W, height=H, packed=False, near_plane=0.01, far_plane=1e10, render_mode="RGB+ED",
            sh_degree=None, sparse_grad=False, absgrad=self.strategy.absgrad,
            rasterize_mode=self.config.rasterize_mode, backend=self.config.rasterize_backend,
        )  # fmt: skip
        render, alpha = render[0], alpha[0]  # [H, W, X], [H, W, 1]
        background = self._get_background_color()
        depth = render[..., -1:]
        out: dict[str, Any] = {
            "rgb": torch.clamp(render[..., :3] + (1 - alpha) * background, 0.0, 1.0),
            "depth": torch.where(alpha > 0, depth, depth.detach().max()),
            "accumulation": alpha,
            "background": background.expand(H, W, 3) if background.shape[0] == 3 else background,
        }
        C = 0 if head is None else head.shape[1]
        extra = render[..., 3 + C : -1]
        if lifted:
            labelled, extra = extra[..., :1] / alpha.clamp_min(1e-10), extra[..., 1:]
        else:
            labelled = None
        logits = None if head is None else self._decode(render[..., 3 : 3 + C])
        out.update(self._material_outputs(logits, labelled, alpha, background))
        out.update(self._property_outputs(prop_names, extra, out["rgb"]))
        return out

    def _eval_head_channels(self, lifted: bool) -> Float[Tensor, "n c"] | None:
        """Per-Gaussian channels the evaluation pass renders for the `material` map: the "logits" head's logits,
        the "latent" head's features (decoded per pixel), the "lifted" head's Dirichlet predictive once lifted
        (None before: no material)."""
        key = HEAD_TENSORS[self.material_head]
        if key is not None:
            return self.gauss_params[key]
        return predictive(self.dirichlet_alpha()) if lifted else None

    def _material_outputs(
        self,
        logits: Float[Tensor, "h w k"] | None,
        labelled: Float[Tensor, "h w 1"] | None,
        alpha: Float[Tensor, "h w 1"],
        background: Tensor,
    ) -> dict[str, Tensor]:
        """`material` (legend colours) and `material_id` (label, 0 = background): the argmax of the rendered
        logits where the opacity exceeds `material_alpha_thresh` and, once lifted (`labelled` given), where the
        composited labelled fraction exceeds `material_min_labelled` (label 0 stays unknown). No `logits` (the
        "lifted" head before its first lifting): label 0 everywhere."""
        known = alpha > self.config.material_alpha_thresh  # [H, W, 1]
        if labelled is not None:
            known = known & (labelled > self.config.material_min_labelled)
        if logits is None:
            label = torch.zeros_like(known[..., 0], dtype=torch.long)
        else:
            label = torch.where(known[..., 0], logits.argmax(-1) + 1, 0)  # [H, W]
        palette = torch.cat([background[None].to(self.material_colors), self.material_colors], dim=0)
        return {"material": palette[label], "material_id": label[..., None].float()}

    def _property_outputs(
        self, names: list[str], composited: Float[Tensor, "h w c"], rgb: Float[Tensor, "h w 3"]
    ) -> dict[str, Tensor]:
        """Coloured [H, W, 3] outputs on fixed scales, only where Gaussians with material evidence cover the
        pixel, dimmed RGB elsewhere (`physgs_nerfstudio.viewer.display.viewer_outputs`)."""
        if not names:
            return {}
        return viewer_outputs(self, composited[..., : len(names)], rgb, VIEWER_NAMES)

    def _training_outputs(self, camera: Cameras, c2w: Tensor, Ks: Tensor, W: int, H: int) -> dict[str, Any]:
        """Training: splatfacto's RGB(+depth) pass (SH evaluated in the rasterizer), plus, every
        `material_every` steps, a pass of the K material logits at 1/`material_downscale` resolution."""
        viewmat = viewmat_from_c2w(c2w.to(self.device))
        geometry = {
            "means": self.means,
            "quats": self.quats,
            "scales": torch.exp(self.scales),
            "opacities": torch.sigmoid(self.opacities).squeeze(-1),
            "viewmats": viewmat,
            "packed": False,
            "near_plane": 0.01,
            "far_plane": 1e10,
            "sparse_grad": False,
            "rasterize_mode": self.config.rasterize_mode,
            "backend": self.config.rasterize_backend,
        }
        if self.config.sh_degree > 0:
            sh_degree = min(self.step // self.config.sh_degree_interval, self.config.sh_degree)
            colors = torch.cat((self.features_dc[:, None, :], self.features_rest), dim=1)
        else:
            sh_degree, colors = None, torch.sigmoid(self.features_dc)
        with_depth = self.config.output_depth_during_training
        render, alpha, self.info = rasterize(
            colors=colors, Ks=Ks, width=W, height=H, render_mode="RGB+ED" if with_depth else "RGB",
            sh_degree=sh_degree, absgrad=self.strategy.absgrad, **geometry,
        )  # fmt: skip
        self.strategy.step_pre_backward(self.gauss_params, self.optimizers, self.strategy_state, self.step, self.info)
        render, alpha = render[0], alpha[0]
        background = self._get_background_color()
        rgb = torch.clamp(render[..., :3] + (1 - alpha) * background, 0.0, 1.0)
        if self.config.use_bilateral_grid and camera.metadata and "cam_idx" in camera.metadata:
            rgb = self._apply_bilateral_grid(rgb[None], camera.metadata["cam_idx"], H, W)[0]
        depth = None
        if with_depth:
            depth = torch.where(alpha > 0, render[..., 3:4], render[..., 3:4].detach().max())
        out: dict[str, Any] = {"rgb": rgb, "depth": depth, "accumulation": alpha, "background": background}
        if self.material_pass_due():
            md = max(1, self.config.material_downscale)
            Wm, Hm = max(1, W // md), max(1, H // md)
            Km = Ks.clone()
            Km[:, :2] *= torch.tensor([Wm / W, Hm / H], device=Ks.device, dtype=Ks.dtype)[:, None]
            (key,) = self.trainable_head_keys
            rendered, _, _ = rasterize(colors=self.gauss_params[key], Ks=Km, width=Wm, height=Hm, render_mode="RGB",
                                       **geometry)  # fmt: skip
            out[LOGITS_KEY] = self._decode(rendered[0])
        return out

    def material_pass_due(self) -> bool:
        """Whether this training step renders the head's trainable tensor (every `material_every` steps, for the
        "logits" and "latent" heads with a material loss; never for "lifted")."""
        every = max(1, self.config.material_every)
        return bool(self.trainable_head_keys) and self.config.material_loss_weight > 0 and self.step % every == 0

    def _decode(self, rendered: Float[Tensor, "h w c"]) -> Float[Tensor, "h w k"]:
        """Per-pixel material logits from the rendered head channels (the "latent" head's decoder; the "logits"
        head's channels are the logits)."""
        return rendered if self.material_decoder is None else self.material_decoder(rendered)
