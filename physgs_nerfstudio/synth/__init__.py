"""Generated scenes with known materials: the embedded demo data and the ground truth of the benchmarks.

`generate_scene(SynthConfig(out=..., object="mug"))` writes a nerfstudio dataset (transforms.json, images,
points.ply) with per-pixel ground truth (part, material, depth) and ground_truth.json (parts, materials,
exact volumes and masses). `SynthCommand` is the `physgs synth` subcommand.
"""

from .command import SynthCommand
from .dataset import GENERATOR_VERSION, SynthConfig, generate_scene, load_ground_truth
from .objects import OBJECTS, SCENES, SUITE, Layout, Part, all_names, build_layout, build_object

__all__ = [
    "GENERATOR_VERSION",
    "OBJECTS",
    "SCENES",
    "SUITE",
    "Layout",
    "Part",
    "SynthCommand",
    "SynthConfig",
    "all_names",
    "build_layout",
    "build_object",
    "generate_scene",
    "load_ground_truth",
]
