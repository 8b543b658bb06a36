"""`PerceptionConfig`: the one configuration of a perception run (``physgs perceive``, single-image mode,
``physgs demo``). Components are chosen by config type, each with a ``setup()``:

* ``vlm``: :class:`~.vlm.OpenAIConfig` (any OpenAI-compatible endpoint), :class:`~.replay.ReplayConfig`
  (cached answers only) or :class:`~.simulated.SimulatedConfig` (generated scenes only);
* ``segmenter``: :class:`~.segment_builtin.BuiltinSegmenterConfig` (weight-free) or
  :class:`~.segment_sam.SamSegmenterConfig` (segment-anything).

On the command line they are subcommands: ``physgs perceive --data D vlm:simulated``,
``... vlm:openai --vlm.model gpt-5 segmenter:sam --segmenter.checkpoint sam.pth``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal, Union

import tyro

from ..fusion.maps import MapFusionConfig
from ..materials import PriorConfig
from .prompts import PromptConfig
from .replay import ReplayConfig
from .segment_builtin import BuiltinSegmenterConfig
from .segment_sam import SamSegmenterConfig
from .simulated import SimulatedConfig
from .validate import ValidationConfig
from .vlm import OpenAIConfig

VLMConfig = Union[
    Annotated[OpenAIConfig, tyro.conf.subcommand("openai")],
    Annotated[ReplayConfig, tyro.conf.subcommand("replay")],
    Annotated[SimulatedConfig, tyro.conf.subcommand("simulated")],
]
"""openai: any OpenAI-compatible endpoint; replay: cached answers only; simulated: generated scenes only."""

SegmenterConfig = Union[
    Annotated[BuiltinSegmenterConfig, tyro.conf.subcommand("builtin")],
    Annotated[SamSegmenterConfig, tyro.conf.subcommand("sam")],
]
"""builtin: weight-free SLIC superpixel masks merged by colour (weaker than SAM); sam: segment-anything."""


@dataclass
class PerceptionConfig:
    """Masks -> VLM -> validated observations -> Bayesian fusion -> material maps, for a nerfstudio dataset."""

    data: Path
    """Nerfstudio dataset directory (with transforms.json)."""
    vlm: VLMConfig = field(default_factory=OpenAIConfig)
    """The VLM backend, chosen by its config (vlm:openai | vlm:replay | vlm:simulated)."""
    segmenter: SegmenterConfig = field(default_factory=BuiltinSegmenterConfig)
    """The part segmenter, chosen by its config (segmenter:builtin | segmenter:sam, pip install -e ".[sam]")."""
    env: str = "indoor"
    """Material library: indoor | outdoor | path to a library YAML."""
    library_files: tuple[Path, ...] = ()
    """Extra library YAML files merged into --env."""
    max_views: int | None = None
    """Use at most this many frames (evenly spaced); None: all."""
    max_concurrency: int = 4
    """VLM requests this run keeps in flight at once (its thread pool)."""
    budget: float | None = None
    """Stop issuing new (uncached) requests once the estimated cost reaches this many USD (needs the
    --vlm.usd-per-1k-* rates); None: no limit. Unqueried masks are done by a later run."""
    max_calls: int | None = None
    """At most this many uncached requests in this run; None: no limit."""
    prompt: Literal["triplet", "baseline"] = "triplet"
    """triplet: per-mask full | overlay | isolated prompt (PhysGS); baseline: raw image only, one per frame."""
    cache_dir: Path | None = None
    """Response cache directory; default <data>/perception/cache."""
    overwrite: bool = False
    """Start over even if observations.jsonl exists (old files kept as .bak)."""
    strict: bool = False
    """Fail on the first unreadable frame image and at the end if any request failed (default: skip such
    frames with a warning, report them and the failures at the end, and fuse what arrived)."""
    wait_for_lock: bool = False
    """When another run is perceiving this dataset, wait for it to finish instead of refusing to start."""
    allow_outside_paths: bool = False
    """Read frames whose file_path leaves the dataset (../x.png, absolute paths, symlinks out of it); by default
    such a dataset is refused, so a downloaded one cannot make the run upload images from elsewhere."""
    legend: Literal["observed", "library"] = "observed"
    """Materials in materials.json: the observed ones, or the whole library."""
    write_outputs: bool = True
    """Write materials.json, the per-frame maps and transforms.json entries."""
    progress: bool = True
    """Show progress bars."""
    prompt_options: PromptConfig = field(default_factory=PromptConfig)
    validation: ValidationConfig = field(default_factory=ValidationConfig)
    fusion: MapFusionConfig = field(default_factory=MapFusionConfig)
    prior: PriorConfig = field(default_factory=PriorConfig)

    def __post_init__(self) -> None:
        if self.max_concurrency < 1:
            raise ValueError(f"--max-concurrency must be >= 1, got {self.max_concurrency}")
