"""Inputs of single-image mode: find the images, stage them in a perception workspace, and (for the
simulated VLM) tie each one to a frame of a generated scene's ground truth.

The workspace is the output directory itself, laid out like the small nerfstudio-style dataset that
``perception.run_perception`` works on, so masks, the response cache, ``observations.jsonl`` and its
commit log are exactly the ones ``physgs perceive`` writes::

    <output_dir>/transforms.json          frames only (no cameras): file_path = images/<name>.png, source
    <output_dir>/images/<name>.png        the working copy: EXIF-rotated RGB, long side <= max_side
    <output_dir>/observations.jsonl       appended as VLM answers arrive (resumable)
    <output_dir>/perception/...           masks, response cache, commit log, run.json
    <output_dir>/perception/single_image.json   pixel hash per view (guards against a changed image)
"""

from __future__ import annotations

import hashlib
import json
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
MANIFEST = "perception/single_image.json"


class InputError(ValueError):
    """Bad input path, unreadable image or a workspace that does not match the inputs."""


@dataclass
class StagedImage:
    source: Path
    """The user's file."""
    name: str
    """Output stem (unique in the run)."""
    view: str
    """Workspace file_path (``images/<name>.png``): the ``view`` of its observations."""
    image: np.ndarray
    """uint8 [H, W, 3] working copy."""
    original_size: tuple[int, int]
    """(H, W) of the source image (after EXIF rotation)."""
    sha256: str
    """Hash of the working copy's pixels and shape."""


def find_images(path: Path) -> list[Path]:
    """An image file, or the image files directly inside a folder (sorted by name)."""
    path = Path(path)
    if path.is_file():
        if path.suffix.lower() not in IMAGE_SUFFIXES:
            raise InputError(f"{path} does not look like an image (suffix {path.suffix!r}; expected one of {', '.join(IMAGE_SUFFIXES)})")
        return [path]
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise InputError(f"{path} holds no image files ({', '.join(IMAGE_SUFFIXES)}); pass an image or a folder of images")
        return files
    raise InputError(f"{path} does not exist; pass an image file or a folder of images")


def unique_names(files: Sequence[Path]) -> list[str]:
    """Output stems: the file stem, plus the suffix where two files share a stem (a.jpg, a.png)."""
    stems = [f.stem for f in files]
    return [f"{f.stem}_{f.suffix.lower().lstrip('.')}" if stems.count(f.stem) > 1 else f.stem for f in files]


def load_rgb(path: Path, max_side: int | None) -> tuple[np.ndarray, tuple[int, int]]:
    """uint8 [H, W, 3] with EXIF orientation applied, downscaled (area filter) to ``max_side``."""
    from PIL import ImageOps

    from ..image_files import BadImage, open_image
    from ..perception.images import to_rgb8

    try:
        with open_image(path) as im:  # the pixel limit (image_files.MAX_PIXELS) before decoding
            im = ImageOps.exif_transpose(im)
            rgb = to_rgb8(im)  # 16-bit and float images scaled, not clipped
    except BadImage as err:
        raise InputError(f"cannot read image: {err}") from None
    h, w = rgb.shape[:2]
    if max_side is not None and max(h, w) > max_side:
        import cv2

        s = max_side / max(h, w)
        rgb = cv2.resize(rgb, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(rgb), (h, w)


def pixel_hash(image: np.ndarray) -> str:
    h = hashlib.sha256()
    h.update(str(image.shape).encode())
    h.update(np.ascontiguousarray(image).tobytes())
    return h.hexdigest()


def stage_images(files: Sequence[Path], workspace: Path, max_side: int | None, overwrite: bool) -> list[StagedImage]:
    """Write the working copies and the workspace transforms.json; check the manifest of earlier runs.

    A view whose pixels differ from what an earlier run in this workspace saw would silently reuse that
    run's masks and answers, so it is an error unless ``overwrite`` (which then also drops the old masks).
    """
    from PIL import Image

    workspace = Path(workspace)
    manifest_path = workspace / MANIFEST
    old = json.loads(manifest_path.read_text(encoding="utf-8")) if manifest_path.is_file() else {}
    staged = []
    for src, name in zip(files, unique_names(files)):
        rgb, size = load_rgb(src, max_side)
        view = f"images/{name}.png"
        staged.append(StagedImage(Path(src), name, view, rgb, size, pixel_hash(rgb)))
    changed = [s for s in staged if s.view in old and old[s.view].get("sha256") != s.sha256]
    if changed and not overwrite:
        names = ", ".join(str(s.source) for s in changed[:3])
        raise InputError(
            f"{workspace} holds results for different pixels of {names} (another image of the same name, or "
            "another --max-side). Use another --output-dir, or pass --overwrite to start over "
            "(old observations are kept as .bak; cached VLM answers are reused where the prompts match)."
        )
    if overwrite:
        shutil.rmtree(workspace / "perception" / "masks", ignore_errors=True)
        old = {}
    (workspace / "images").mkdir(parents=True, exist_ok=True)
    for s in staged:
        target = workspace / s.view
        if not target.is_file() or old.get(s.view, {}).get("sha256") != s.sha256:
            tmp = target.with_name(f".{target.name}.tmp.png")
            Image.fromarray(s.image).save(tmp, format="PNG")
            tmp.replace(target)
    for s in staged:
        old[s.view] = {"source": str(s.source), "sha256": s.sha256, "size": list(s.image.shape[:2]), "original_size": list(s.original_size)}
    from ..fusion.writer import atomic_write_text

    atomic_write_text(manifest_path, json.dumps(old, indent=2))
    transforms = {
        "physgs_single_image": True,
        "comment": "workspace of `physgs image`: frames only, no cameras; not a dataset for ns-train",
        "frames": [{"file_path": s.view, "source": str(s.source)} for s in staged],
    }
    atomic_write_text(workspace / "transforms.json", json.dumps(transforms, indent=2))
    return staged


# --------------------------------------------------------------------------------------------------------
# ground truth of generated scenes
# --------------------------------------------------------------------------------------------------------


def ground_truth_root(path: Path) -> Path:
    """A generated scene's directory, from the directory or its ground_truth.json."""
    path = Path(path)
    root = path.parent if path.is_file() else path
    if not (root / "ground_truth.json").is_file():
        raise InputError(
            f"no ground_truth.json at {path}: --ground-truth must name a generated scene (`physgs synth`) or its "
            "ground_truth.json"
        )
    return root


def ground_truth_views(root: Path) -> list[str]:
    """file_path of every ground-truth frame (falling back to transforms.json by position)."""
    data = json.loads((Path(root) / "ground_truth.json").read_text(encoding="utf-8"))
    frames = data.get("frames", [])
    tf = Path(root) / "transforms.json"
    tf_frames = json.loads(tf.read_text(encoding="utf-8")).get("frames", []) if tf.is_file() else []
    out = []
    for i, fr in enumerate(frames):
        view = fr.get("file_path") if isinstance(fr, dict) else None
        if view is None and i < len(tf_frames):
            view = tf_frames[i].get("file_path")
        if view is not None:
            out.append(str(view))
    return out


def match_ground_truth(staged: Sequence[StagedImage], root: Path) -> dict[str, str]:
    """Workspace view -> ground-truth view, by the image's path inside the scene, else by unique file name."""
    root = Path(root).resolve()
    views = ground_truth_views(root)
    by_name: dict[str, list[str]] = {}
    for v in views:
        by_name.setdefault(Path(v).name, []).append(v)
    out = {}
    for s in staged:
        src = s.source.resolve()
        rel = None
        try:
            rel = src.relative_to(root).as_posix()
        except ValueError:
            pass
        if rel in views:
            out[s.view] = rel
        elif len(by_name.get(src.name, [])) == 1:
            out[s.view] = by_name[src.name][0]
        else:
            raise InputError(
                f"{s.source} is not a frame of the generated scene {root} (frames: {', '.join(views[:4])}"
                f"{', ...' if len(views) > 4 else ''}); the simulated VLM answers only for its own frames"
            )
    return out


def ground_truth_material(root: Path, gt_view: str, shape: tuple[int, int]) -> tuple[np.ndarray, list[str]]:
    """(material map int [H, W] resized to ``shape`` with nearest neighbours, 0 = background, i + 1 =
    names[i]; names) of a ground-truth frame."""
    import cv2

    from ..materials import load_library
    from ..perception.simulated import GroundTruth

    data = json.loads((Path(root) / "ground_truth.json").read_text(encoding="utf-8"))
    library = load_library(data.get("env", "indoor"))
    truth = GroundTruth(root, library)
    gt = np.asarray(truth.material_map(gt_view))
    if gt.shape[:2] != tuple(shape):
        gt = cv2.resize(gt.astype(np.uint8), (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)
    return gt.astype(np.int64), list(truth.material_names)
