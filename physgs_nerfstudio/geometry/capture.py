"""The views an object's geometry is recovered from: cameras, object masks and what perception said per mask.

A :class:`CaptureView` is one training camera (world-to-camera in OpenCV axes, intrinsics, size) with its
*foreground mask*: the pixels perception put on objects. Source, in order of preference:

the pixels the material maps label (label > 0: perception found a material there) AND the union of the
perception run's ``whole``-level masks (``perception/masks/*.npz``: the segmenter's object-level regions,
which exclude the floor, walls and background by construction, since those touch the image border). Either
alone when the other is missing. A view's segmentation error (a blob of background merged into a whole mask,
a part left unlabelled) then needs both sources to agree before it carves or keeps space wrongly.

:func:`load_observations` reads what perception said per mask (``observations.jsonl``) together with the
mask's pixels, for the per-part structure (:mod:`.structure`). Everything here is read-only on the dataset.
Formats: docs/architecture.md.
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from jaxtyping import Bool, Float
from torch import Tensor

logger = logging.getLogger(__name__)

__all__ = ["CaptureView", "MaskObservation", "clear_mask_cache", "load_capture", "load_observations",
           "viewmat_from_c2w"]

MASK_DIR = "perception/masks"
_LEVELS = ("whole", "part", "subpart")


def viewmat_from_c2w(c2w: Float[Tensor, "*batch 3 4"]) -> Float[Tensor, "*batch 4 4"]:
    """World-to-camera (OpenCV axes, as gsplat) from a nerfstudio camera-to-world (OpenGL axes: y up, z backward),
    float32 on the input's device; one matrix or a batch. The package's one copy: nerfstudio's own
    (`splatfacto.get_viewmat`) is wrapped in torch.compile, which costs about 20 s on the first CPU call."""
    c2w = torch.as_tensor(c2w, dtype=torch.float32)
    R = c2w[..., :3, :3] * torch.tensor([1.0, -1.0, -1.0], device=c2w.device)  # flip camera y and z
    R_t = R.transpose(-1, -2)
    out = torch.zeros((*c2w.shape[:-2], 4, 4), device=c2w.device)
    out[..., 3, 3] = 1.0
    out[..., :3, :3] = R_t
    out[..., :3, 3:4] = -R_t @ c2w[..., :3, 3:4]
    return out


@dataclass
class CaptureView:
    """One camera and its foreground mask (scene units, OpenCV camera axes)."""

    viewmat: Float[Tensor, "4 4"]
    K: Float[Tensor, "3 3"]
    width: int
    height: int
    mask: Bool[Tensor, "H W"]
    """foreground: pixels perception put on objects (module doc)"""
    name: str = "view"
    """the frame's ``file_path`` in transforms.json (the key of observations.jsonl)"""
    mask_source: str = "given"

    def __post_init__(self) -> None:
        if tuple(self.mask.shape) != (self.height, self.width):
            raise ValueError(f"view {self.name}: mask is {tuple(self.mask.shape)}, expected "
                             f"({self.height}, {self.width}).")  # fmt: skip

    @property
    def centre(self) -> Tensor:
        """Camera centre in world coordinates."""
        R, t = self.viewmat[:3, :3], self.viewmat[:3, 3]
        return -R.T @ t

    @property
    def axis(self) -> Tensor:
        """Viewing direction (camera +z) in world coordinates."""
        return self.viewmat[2, :3]


@dataclass
class MaskObservation:
    """One VLM candidate for one mask: what it said about the part's structure, and where the mask is."""

    view: str
    mask: np.ndarray
    """bool [h, w] at the perception image's resolution"""
    material: str
    confidence: float
    thickness_m: float | None
    """None: the answer called the part solid (or gave no wall)"""
    level: str = "part"
    weight: float = 1.0
    """the fusion's weight of the mask's level (materials.json ``level_weights``: whole 0.5, part 1, subpart 1.5)"""
    mask_id: int | None = None
    """the mask's index in its view (observations.jsonl ``mask_id``): the candidates of one answer share it (None:
    candidates share a mask when they share its array object)"""
    object: str | None = None
    """the whole object the answer says the part belongs to (observations.jsonl ``object``; None: not said)"""


def _mask_file(data_dir: Path, view: str) -> Path:
    return data_dir / MASK_DIR / f"{Path(view).stem}__{hashlib.sha256(view.encode()).hexdigest()[:8]}.npz"


def _read_masks(path: Path) -> tuple[np.ndarray, np.ndarray] | None:
    """(masks bool [n, h, w], level index [n]) of a perception mask file; None when absent or unreadable. Read once
    per file version until :func:`clear_mask_cache` (the views' foregrounds and the observations both need a view's
    masks); the arrays are shared and read-only."""
    try:
        st = path.stat()
    except OSError:
        return None
    return _read_masks_cached(str(path), st.st_mtime_ns, st.st_size)


@functools.lru_cache(maxsize=512)
def _read_masks_cached(name: str, _mtime_ns: int, _size: int) -> tuple[np.ndarray, np.ndarray] | None:
    path = Path(name)
    if not path.is_file():
        return None
    try:
        with np.load(path) as z:
            n, h, w = (int(v) for v in z["shape"])
            bits = np.unpackbits(z["bits"], axis=1, count=h * w) if n else np.zeros((0, h * w), np.uint8)
            masks, level = bits.reshape(n, h, w).astype(bool), np.asarray(z["level"], dtype=np.int64)
            masks.flags.writeable = False
            level.flags.writeable = False
            return masks, level
    except Exception as err:  # noqa: BLE001 - an unreadable mask file falls back to the label map
        logger.warning("ignoring unreadable mask file %s (%s)", path, err)
        return None


def clear_mask_cache() -> None:
    """Forget the mask files read (:func:`_read_masks`): a loader calls it once it has built its views and
    observations, so no process keeps every view's masks."""
    _read_masks_cached.cache_clear()


def _resize_mask(mask: np.ndarray, width: int, height: int) -> np.ndarray:
    if mask.shape == (height, width):
        return mask
    import cv2

    return cv2.resize(mask.astype(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST).astype(bool)


def _foreground(data_dir: Path, view: str, label_path: Path | None, width: int, height: int) -> tuple[np.ndarray, str]:
    labelled = None
    if label_path is not None and Path(label_path).is_file():
        from ..image_files import read_array

        labelled = _resize_mask(read_array(label_path, what=f"material map {label_path}") > 0, width, height)
    read = _read_masks(_mask_file(data_dir, view))
    whole = None
    if read is not None and (read[1] == 0).any():
        whole = _resize_mask(read[0][read[1] == 0].any(0), width, height)
    if whole is not None and labelled is not None:
        return whole & labelled, "labels_and_whole_masks"
    if labelled is not None:
        return labelled, "labels"
    if whole is not None:
        return whole, "whole_masks"
    return np.zeros((height, width), bool), "none"


def load_capture(
    cameras,
    image_filenames: Sequence[Path],
    data_dir: Path,
    *,
    label_paths: Sequence[Path | None] | None = None,
    max_width: int | None = None,
) -> list[CaptureView]:
    """One :class:`CaptureView` per nerfstudio camera (``cameras[i]`` shows ``image_filenames[i]``), with
    its foreground mask (module doc), optionally downscaled to at most ``max_width`` pixels."""
    data_dir = Path(data_dir)
    meta = json.loads((data_dir / "transforms.json").read_text())
    by_name: dict[str, str] = {}
    for f in meta.get("frames", []):
        p = str(f["file_path"])
        by_name[str((data_dir / p).resolve())] = p
        by_name.setdefault(Path(p).name, p)
    n = int(cameras.camera_to_worlds.shape[0])
    sizes, Ks, keys = [], [], []
    for i in range(n):
        img = Path(image_filenames[i])
        keys.append(by_name.get(str(img.resolve()), by_name.get(img.name, img.name)))
        w, h = int(cameras.width[i]), int(cameras.height[i])
        s = 1.0 if max_width is None else min(1.0, max_width / w)
        sizes.append((max(1, round(w * s)), max(1, round(h * s))))
        Ks.append(torch.tensor([[float(cameras.fx[i]) * s, 0.0, float(cameras.cx[i]) * s],
                                [0.0, float(cameras.fy[i]) * s, float(cameras.cy[i]) * s], [0.0, 0.0, 1.0]]))  # fmt: skip

    def foreground(i: int) -> tuple[np.ndarray, str]:
        return _foreground(data_dir, keys[i], label_paths[i] if label_paths is not None else None, *sizes[i])

    # the views' files on a thread pool: PNG decoding and the masks' decompression release the GIL (60 views of
    # 512 px: 0.55 s one at a time on the GPU machine's CPU)
    with ThreadPoolExecutor(max_workers=max(1, min(8, n, os.cpu_count() or 1))) as pool:
        masks = list(pool.map(foreground, range(n)))
    views: list[CaptureView] = []
    sources: dict[str, int] = {}
    for i, (mask, src) in enumerate(masks):
        sources[src] = sources.get(src, 0) + 1
        views.append(CaptureView(viewmat_from_c2w(cameras.camera_to_worlds[i].cpu()), Ks[i], *sizes[i],
                                 torch.from_numpy(mask), name=keys[i], mask_source=src))  # fmt: skip
    logger.info("object masks: %s", ", ".join(f"{v} views from {k}" for k, v in sorted(sources.items())))
    return views


def _level_weights(data_dir: Path) -> dict[str, float]:
    """materials.json's ``level_weights`` (the fusion's weight per mask level), else the fusion's defaults."""
    out = {"whole": 0.5, "part": 1.0, "subpart": 1.5}
    try:
        lw = json.loads((data_dir / "materials.json").read_text()).get("level_weights") or {}
        out.update({str(k): float(v) for k, v in lw.items() if isinstance(v, (int, float)) and v >= 0})
    except (OSError, ValueError, AttributeError):
        pass
    return out


def load_observations(data_dir: Path) -> list[MaskObservation]:
    """Every candidate of ``observations.jsonl`` joined with its mask's pixels (skipped, with a count in the
    log, where the mask file is missing)."""
    data_dir = Path(data_dir)
    path = data_dir / "observations.jsonl"
    if not path.is_file():
        return []
    out: list[MaskObservation] = []
    cache: dict[str, tuple[np.ndarray, np.ndarray] | None] = {}
    missing = 0
    level_w = _level_weights(data_dir)
    for line in path.read_text().splitlines():
        try:
            rec = json.loads(line)
            view, mid = str(rec["view"]), int(rec["mask_id"])
        except (ValueError, KeyError, TypeError):
            continue
        if view not in cache:
            cache[view] = _read_masks(_mask_file(data_dir, view))
        read = cache[view]
        if read is None or not 0 <= mid < len(read[0]):
            missing += 1
            continue
        t = (rec.get("properties") or {}).get("thickness_m")
        out.append(MaskObservation(view, read[0][mid], str(rec.get("material")), float(rec.get("confidence", 0.0)),
                                   float(t) if isinstance(t, (int, float)) and t > 0 else None,
                                   str(rec.get("level", "part")),
                                   level_w.get(str(rec.get("level", "part")), 1.0), mid,
                                   rec["object"] if isinstance(rec.get("object"), str) else None))  # fmt: skip
    if missing:
        logger.info("%d observations without a readable mask were not used for the part structure", missing)
    return out

