"""`PropertyField`: the backend-agnostic input of every exporter.

A property field is a set of N Gaussians (geometry and colour, as trained) with, per Gaussian, the Dirichlet
posterior ``alpha`` over the scene's K materials, and per material the Normal-Inverse-Gamma posterior of
every property (``PROPERTY_KEYS`` order) plus the shell wall thickness. Everything the exporters write
(PLY, voxel grid, maps, mass) is computed from this object, so they work the same on a trained PhysGS
checkpoint (:meth:`PropertyField.from_checkpoint`), on an in-memory model (:meth:`PropertyField.from_model`)
and on analytic Gaussians (tests, benchmarks).

Conventions: positions, scales in scene (model) units; ``metres_per_unit`` converts them to metres
(see :mod:`.scale`). Quaternions are (w, x, y, z) like nerfstudio/gsplat. Scales and opacities are
activated (``exp`` / ``sigmoid`` already applied).
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import torch
from jaxtyping import Float
from torch import Tensor

from ..bayes import NIG, mixture_fields
from ..bayes.mixture import MaterialWeights, material_mixture_weights
from .scale import SceneScale, read_dataparser_scale, resolve_scale

logger = logging.getLogger(__name__)

__all__ = ["PropertyField", "load_thickness"]

_DEFAULT_KEYS = ("density", "kinetic_friction", "shore_hardness", "youngs_modulus")


def _property_keys() -> tuple[str, ...]:
    try:
        from ..materials import PROPERTY_KEYS

        return tuple(PROPERTY_KEYS)
    except ImportError:  # pragma: no cover - the materials package is part of the install
        return _DEFAULT_KEYS


@dataclass
class PropertyField:
    """Gaussians + per-Gaussian material posterior + per-material property posteriors (module doc)."""

    means: Float[Tensor, "n 3"]
    quats: Float[Tensor, "n 4"]
    """(w, x, y, z), need not be normalised"""
    scales: Float[Tensor, "n 3"]
    """activated standard deviations, scene units"""
    opacities: Float[Tensor, " n"]
    """activated, in (0, 1)"""
    alpha: Float[Tensor, "n k"]
    """per-Gaussian Dirichlet posterior concentrations (> 0)"""
    nig: NIG
    """per-material property posteriors, [K, P], in fusion units (log for log-space properties)"""
    material_names: list[str]
    material_colors: list[tuple[int, int, int]]
    """legend colours, RGB 0..255"""
    log_space: tuple[bool, ...]
    thickness_m: list[float | None]
    """per material wall thickness (metres) for the shell volume model; None = solid"""
    metres_per_unit: float = 1.0
    scale_source: str = "given"
    sh_dc: Float[Tensor, "n 3"] | None = None
    """degree-0 SH coefficients (nerfstudio `features_dc`); None = grey"""
    sh_rest: Float[Tensor, "n r 3"] | None = None
    """higher-order SH coefficients (nerfstudio `features_rest`, [N, (deg+1)^2 - 1, 3])"""
    property_keys: tuple[str, ...] = field(default_factory=_property_keys)
    simulated: bool = False
    """material posteriors come from the simulated VLM (always say so in outputs)"""
    labelled: Float[Tensor, " n"] | None = None
    """per Gaussian, the share of its (per-view normalised) blending weight that fell on pixels the material
    maps label (PhysGSModel.labelled_fraction, in [0, 1]); None = unknown. Object selection uses it."""
    evidence: Float[Tensor, " n"] | None = None
    """per Gaussian total lifted Dirichlet evidence (sum over materials, >= 0); None = unknown"""
    material_weights: MaterialWeights = "dominant"
    """how ``alpha`` becomes the per-Gaussian material weights that every writer uses (PLY columns, voxels,
    maps, mass): "dominant" (dominance probability) or "predictive" (alpha / sum(alpha)); a trained model's
    own ``material_weights`` (PhysGSModelConfig) when built by :meth:`from_model`."""
    dirichlet_prior: tuple[float, float] | None = None
    """(alpha0, lambda) of the model's Dirichlet posterior ``alpha = alpha0 + lambda x evidence``; None = unknown.
    The mass geometry fuses each 3-D part's material from the observations with the same prior"""
    _pi: Tensor | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        n = self.means.shape[0]
        k = len(self.material_names)
        p = len(self.property_keys)
        checks = [
            (self.means.shape == (n, 3), f"means must be [N, 3], got {tuple(self.means.shape)}"),
            (self.quats.shape == (n, 4), f"quats must be [N, 4] = [{n}, 4], got {tuple(self.quats.shape)}"),
            (self.scales.shape == (n, 3), f"scales must be [N, 3] = [{n}, 3], got {tuple(self.scales.shape)}"),
            (self.opacities.shape == (n,), f"opacities must be [N] = [{n}], got {tuple(self.opacities.shape)}"),
            (self.alpha.shape == (n, k), f"alpha must be [N, K] = [{n}, {k}], got {tuple(self.alpha.shape)}"),
            (tuple(self.nig.shape) == (k, p), f"nig must be [K, P] = [{k}, {p}], got {tuple(self.nig.shape)}"),
            (len(self.material_colors) == k, f"material_colors needs {k} entries, got {len(self.material_colors)}"),
            (len(self.thickness_m) == k, f"thickness_m needs {k} entries, got {len(self.thickness_m)}"),
            (len(self.log_space) == p, f"log_space needs {p} entries, got {len(self.log_space)}"),
            (k >= 1, "at least one material is needed"),
        ]
        for ok, msg in checks:
            if not ok:
                raise ValueError(f"PropertyField: {msg}.")
        if self.sh_dc is not None and self.sh_dc.shape != (n, 3):
            raise ValueError(f"PropertyField: sh_dc must be [N, 3], got {tuple(self.sh_dc.shape)}.")
        if self.sh_rest is not None and (self.sh_rest.dim() != 3 or self.sh_rest.shape[0] != n
                                         or self.sh_rest.shape[2] != 3):
            raise ValueError(f"PropertyField: sh_rest must be [N, R, 3], got {tuple(self.sh_rest.shape)}.")
        for name in ("labelled", "evidence"):
            t = getattr(self, name)
            if t is not None and t.shape != (n,):
                raise ValueError(f"PropertyField: {name} must be [N] = [{n}] or None, got {tuple(t.shape)}.")
        if not (math.isfinite(self.metres_per_unit) and self.metres_per_unit > 0):
            raise ValueError(f"PropertyField: metres_per_unit must be > 0, got {self.metres_per_unit}.")
        for t in self.thickness_m:
            if t is not None and not (math.isfinite(t) and t > 0):
                raise ValueError(f"PropertyField: thickness_m entries must be > 0 metres or None, got {t}.")
        if n and not bool(torch.isfinite(self.means).all()):
            raise ValueError("PropertyField: means contain NaN/inf.")
        if n and not bool((self.alpha > 0).all()):
            raise ValueError("PropertyField: alpha (Dirichlet concentrations) must be > 0 everywhere.")

    # ------------------------------------------------------------------ basic views
    @property
    def num_gaussians(self) -> int:
        return int(self.means.shape[0])

    @property
    def num_materials(self) -> int:
        return len(self.material_names)

    @property
    def device(self) -> torch.device:
        return self.means.device

    def pi(self) -> Float[Tensor, "n k"]:
        """Per-Gaussian material mixture weights chosen by ``material_weights`` (default: the posterior that
        each material is the Gaussian's dominant label, ``bayes.dominance_probability``). Computed once; every
        writer and ``fields()`` use these weights, so one file never mixes two weightings."""
        if self._pi is None or self._pi.shape != self.alpha.shape:
            self._pi = material_mixture_weights(self.alpha, self.material_weights)
        return self._pi

    def pi_rows(self, rows: Tensor) -> Float[Tensor, "m k"]:
        """:meth:`pi` of the Gaussians ``rows`` (a bool mask or indices) only: the same weights, without computing
        them for every Gaussian when only a few are needed (the object's, for its mass) and none were yet."""
        if self._pi is not None and self._pi.shape == self.alpha.shape:
            return self._pi[rows]
        return material_mixture_weights(self.alpha[rows], self.material_weights)

    def fields(self, rows: slice | Tensor | None = None) -> dict[str, Float[Tensor, "n p"]]:
        """Per-Gaussian mixture predictive (mean, aleatoric, epistemic, total variance), linear units, with the
        weights of :meth:`pi` (``rows``: only those Gaussians)."""
        pi = self.pi() if rows is None else self.pi()[rows]
        return mixture_fields(pi, self.nig.to(self.alpha.device), self.log_space)

    def material_means(self) -> Float[Tensor, "k p"]:
        """Per-material predictive mean in linear units (log-space: lognormal mean exp(tau + v/2)), float64."""
        nig = self.nig.to(torch.float64)
        v = nig.variance()
        log_mask = torch.as_tensor(self.log_space, dtype=torch.bool, device=nig.tau.device).expand_as(nig.tau)
        return torch.where(log_mask, torch.exp(nig.tau + v / 2), nig.tau)

    def property_index(self, key: str) -> int:
        if key not in self.property_keys:
            raise KeyError(f"property {key!r} is not one of {self.property_keys}.")
        return self.property_keys.index(key)

    def subset(self, mask: Tensor) -> PropertyField:
        """The Gaussians selected by a boolean mask or index tensor (materials unchanged)."""
        pick = lambda t: None if t is None else t[mask]
        return replace(self, means=self.means[mask], quats=self.quats[mask], scales=self.scales[mask],
                       opacities=self.opacities[mask], alpha=self.alpha[mask], sh_dc=pick(self.sh_dc),
                       sh_rest=pick(self.sh_rest), labelled=pick(self.labelled),
                       evidence=pick(self.evidence))  # fmt: skip

    def to(self, device: torch.device | str) -> PropertyField:
        mv = lambda t: None if t is None else t.to(device)
        return replace(self, means=self.means.to(device), quats=self.quats.to(device),
                       scales=self.scales.to(device), opacities=self.opacities.to(device),
                       alpha=self.alpha.to(device), nig=self.nig.to(device), sh_dc=mv(self.sh_dc),
                       sh_rest=mv(self.sh_rest), labelled=mv(self.labelled), evidence=mv(self.evidence))  # fmt: skip

    def with_scale(self, scale: SceneScale) -> PropertyField:
        return replace(self, metres_per_unit=scale.metres_per_unit, scale_source=scale.source)

    def legend(self) -> list[dict[str, Any]]:
        """JSON-ready legend: id (1..K, as materials.json), index (0..K-1), name, colour, thickness."""
        return [
            {"id": i + 1, "index": i, "name": n, "color": list(map(int, c)), "thickness_m": t}
            for i, (n, c, t) in enumerate(zip(self.material_names, self.material_colors, self.thickness_m))
        ]

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_model(
        cls,
        model: Any,
        dataparser_scale: float = 1.0,
        *,
        scale: float | None = None,
        known_length: Sequence[float] | None = None,
        materials_json: Path | None = None,
        env: str | None = None,
    ) -> PropertyField:
        """Snapshot of a PhysGSModel (splatfacto parameters + Dirichlet alpha + material legend).

        ``dataparser_scale``: nerfstudio's pose scale (``dataparser_transforms.json``); ``scale`` /
        ``known_length`` as in :func:`.scale.resolve_scale`. Thickness per material: ``thickness_m`` of
        materials.json (the VLM's answer fused by perception) or, when null there, the material library's
        typical value (``env`` or materials.json's ``env``); None = solid. ``labelled`` and ``evidence``:
        the model's ``labelled_fraction()`` and total lifted evidence once it has lifted the material maps
        (None before, or when the checkpoint predates ``labelled_weight``: object selection then falls back
        to geometry).
        """
        for attr in ("means", "quats", "scales", "opacities", "dirichlet_alpha", "legend"):
            if not hasattr(model, attr):
                raise TypeError(
                    f"PropertyField.from_model needs a PhysGSModel (missing `{attr}`); got {type(model).__name__}. "
                    "Train with `ns-train physgs` or `physgs-lite`."
                )
        with torch.no_grad():
            state = {k: v.detach() for k, v in model.state_dict().items()}
        return cls.from_state(state, model.legend, dataparser_scale, alpha0=model.alpha0, lam=model.lam,
                              material_weights=getattr(getattr(model, "config", None), "material_weights", "dominant"),
                              labelled_legacy=bool(getattr(model, "labelled_fraction_legacy", False)), scale=scale,
                              known_length=known_length, materials_json=materials_json, env=env)  # fmt: skip

    @classmethod
    def from_state(
        cls,
        state: dict[str, Tensor],
        legend: Any,
        dataparser_scale: float = 1.0,
        *,
        alpha0: float,
        lam: float,
        material_weights: MaterialWeights = "dominant",
        labelled_legacy: bool | None = None,
        scale: float | None = None,
        known_length: Sequence[float] | None = None,
        materials_json: Path | None = None,
        env: str | None = None,
    ) -> PropertyField:
        """The field of a PhysGSModel's state dict (``gauss_params.*``, ``nig_*``, ``lifted_views``: a checkpoint's
        model entries or ``model.state_dict()``) and its material ``legend``, without the model. ``alpha0``,
        ``lam``: the model's Dirichlet prior and evidence strength. ``labelled_legacy`` (None: the state has no
        ``labelled_weight``): a checkpoint from before it, whose labelled fraction is unknown. Other arguments as
        :meth:`from_model`."""
        from ..bayes import dirichlet_posterior
        from ..runfiles.keys import EVIDENCE_KEY, LABELLED_KEY, WEIGHT_KEY

        g = lambda name: state[f"gauss_params.{name}"].detach().float()
        evidence = g(EVIDENCE_KEY)
        sh_rest = g("features_rest") if "gauss_params.features_rest" in state else None
        if sh_rest is not None and sh_rest.dim() == 3 and sh_rest.shape[1] == 0:
            sh_rest = None
        labelled = total = None
        if int(state.get("lifted_views", torch.zeros((), dtype=torch.long))) > 0:
            if labelled_legacy or (labelled_legacy is None and f"gauss_params.{LABELLED_KEY}" not in state):
                logger.warning("the checkpoint predates labelled_weight: no labelled fraction for object "
                               "selection (retrain or re-lift the run)")  # fmt: skip
            else:
                w = g(WEIGHT_KEY)
                frac = torch.where(w > 0, g(LABELLED_KEY) / w.clamp_min(1e-12), torch.zeros_like(w))
                labelled = frac.clamp(0.0, 1.0).reshape(-1)
                total = evidence.sum(-1)
        nig = NIG(*(state[f"nig_{f}"].detach() for f in ("tau", "kappa", "a", "b")))
        colors = [tuple(round(float(c) * 255) for c in row) for row in legend.colors.reshape(-1, 3).tolist()]
        path = materials_json if materials_json is not None else getattr(legend, "path", None)
        thickness = load_thickness(path, list(legend.names), env=env)
        sc = resolve_scale(dataparser_scale, scale=scale, known_length=known_length)
        return cls(
            means=g("means"), quats=g("quats"), scales=torch.exp(g("scales")),
            opacities=torch.sigmoid(g("opacities")).reshape(-1),
            alpha=dirichlet_posterior(evidence, alpha0, lam).float(), nig=nig,
            material_names=list(legend.names), material_colors=colors, log_space=tuple(legend.log_space),
            thickness_m=thickness, metres_per_unit=sc.metres_per_unit, scale_source=sc.source,
            sh_dc=g("features_dc") if "gauss_params.features_dc" in state else None, sh_rest=sh_rest,
            property_keys=tuple(legend.property_keys), simulated=bool(legend.simulated), labelled=labelled,
            evidence=total, material_weights=material_weights, dirichlet_prior=(float(alpha0), float(lam)),
        )  # fmt: skip

    @classmethod
    def from_checkpoint(
        cls,
        config_path: Path,
        *,
        scale: float | None = None,
        known_length: Sequence[float] | None = None,
        env: str | None = None,
    ) -> PropertyField:
        """Load a trained run (its ``config.yml``) the way ``physgs export`` does: :func:`physgs_nerfstudio.runfiles.check.check_run`, then
        :func:`physgs_nerfstudio.runfiles.loader.load_run_state` (no model built) and :meth:`from_run_state`."""
        from ..runfiles.check import check_run
        from ..runfiles.loader import load_run_state

        run_files = check_run(Path(config_path))  # safe YAML, PhysGS method, checkpoint (beside the config if moved)
        rs = load_run_state(run_files.config, run_files.checkpoint, run_files.run_dir)
        return cls.from_run_state(rs, run_files.run_dir, scale=scale, known_length=known_length, env=env)

    @classmethod
    def from_run_state(
        cls,
        rs: Any,
        run_dir: Path,
        *,
        scale: float | None = None,
        known_length: Sequence[float] | None = None,
        env: str | None = None,
    ) -> PropertyField:
        """:meth:`from_state` of a :class:`physgs_nerfstudio.runfiles.loader.RunState` (checkpoint tensors, legend, the model config's prior
        and weights; ``run_dir``: the folder of its dataparser_transforms.json)."""
        alpha0, lam = rs.prior()
        return cls.from_state(rs.state, rs.dataparser_outputs.metadata["material_legend"],
                              read_dataparser_scale(Path(run_dir)), alpha0=alpha0, lam=lam,
                              material_weights=rs.material_weights(), scale=scale, known_length=known_length,
                              env=env)  # fmt: skip


def load_thickness(
    materials_json: Path | None, names: Sequence[str], env: str | None = None
) -> list[float | None]:
    """Per material thickness_m (metres, None = solid): materials.json's value where the material lists one
    (null there means solid), else the library's typical value, else None."""
    from_file: dict[str, float | None] = {}
    file_env = env
    if materials_json is not None and Path(materials_json).exists():
        meta = json.loads(Path(materials_json).read_text())
        file_env = env or meta.get("env")
        for m in meta.get("materials", []):
            if "thickness_m" in m:  # null = solid (perception's answer); absent = ask the library
                t = m["thickness_m"]
                from_file[m.get("name")] = float(t) if t is not None else None
    out: list[float | None] = []
    library = None
    for name in names:
        if name in from_file:
            out.append(from_file[name])
            continue
        t = None
        if library is None:
            try:
                from ..materials import load_library

                library = load_library(file_env or "indoor")
            except Exception as err:  # noqa: BLE001 - a broken library must not block an export
                logger.warning("material library unavailable (%s); materials without thickness are solid", err)
                library = False
        if library:
            canonical = library.resolve(name)
            t = library[canonical].thickness_m if canonical is not None else None
        out.append(t)
    return out
