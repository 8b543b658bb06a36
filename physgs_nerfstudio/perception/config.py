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

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Annotated, Literal, Union

import tyro

from ..advanced import Advanced
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
    """The nerfstudio dataset folder (with transforms.json)."""
    vlm: VLMConfig = field(default_factory=OpenAIConfig)
    """The VLM backend, chosen by its config (vlm:openai | vlm:replay | vlm:simulated)."""
    segmenter: SegmenterConfig = field(default_factory=BuiltinSegmenterConfig)
    """The part segmenter, chosen by its config (segmenter:builtin | segmenter:sam, pip install -e ".[sam]")."""
    env: str = "indoor"
    """Material library: indoor, outdoor or the path of a library YAML file."""
    library_files: tuple[Path, ...] = ()
    """Extra library YAML files merged into the --env library."""
    max_views: int | None = None
    """Use at most this many frames, evenly spaced (None: all)."""
    max_concurrency: int = 4
    """The most VLM requests in flight at once."""
    budget: float | None = None
    """Stop sending new requests once their estimated cost reaches this many USD (set the --vlm.usd-per-1k-* prices)."""
    max_calls: int | None = None
    """Send at most this many new requests in this run (None: no limit)."""
    prompt: Literal["triplet", "baseline"] = "triplet"
    """The prompt kind: triplet asks about each mask with three images, baseline about each whole frame."""
    cache_dir: Path | None = None
    """Folder of cached VLM answers (None: <data>/perception/cache)."""
    overwrite: bool = False
    """Start over even if an earlier run's observations exist (they are kept as .bak files)."""
    strict: bool = False
    """Fail on the first unreadable frame, and at the end if a request failed, instead of warning and going on."""
    wait_for_lock: bool = False
    """When another run is perceiving this dataset, wait for it to finish instead of refusing to start."""
    allow_outside_paths: bool = False
    """Accept frames whose file_path points outside the dataset folder (refused by default, for safety)."""
    legend: Literal["observed", "library"] = "observed"
    """Which materials materials.json lists: the observed ones or the whole library."""
    write_outputs: bool = True
    """Write materials.json, the per-frame material maps and their transforms.json entries."""
    progress: bool = True
    """Show progress bars."""
    prompt_options: Advanced[PromptConfig] = field(default_factory=PromptConfig)
    """How the prompt images are drawn and encoded."""
    validation: Advanced[ValidationConfig] = field(default_factory=ValidationConfig)
    """How the VLM's answers are checked."""
    fusion: Advanced[MapFusionConfig] = field(default_factory=MapFusionConfig)
    """How the answers are fused into per-pixel material beliefs."""
    prior: Advanced[PriorConfig] = field(default_factory=PriorConfig)
    """How the library's property ranges become priors."""

    def __post_init__(self) -> None:
        if self.max_concurrency < 1:
            raise ValueError(f"--max-concurrency must be >= 1, got {self.max_concurrency}")
        if self.prompt_options.kind != self.prompt:  # one setting: the prompt kind is ``prompt``'s
            self.prompt_options = replace(self.prompt_options, kind=self.prompt)
