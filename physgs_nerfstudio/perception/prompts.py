"""VLM prompts: the side-by-side triplet image and the structured text query (paper sec. 3.4, supp. C.1).

* triplet: ``full image | mask overlay | isolated part on neutral grey`` in one image, plus a text query
  that names the environment's material library and the JSON schema of the answer;
* baseline: the raw image only, with a query about the dominant visible region (paper supp. C.2).

Image bytes are encoded deterministically (PNG without metadata, or baseline JPEG with fixed quality and
no optimisation) so that equal inputs give equal bytes and therefore stable cache keys.
"""

from __future__ import annotations

import hashlib
import io
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import tyro

SCHEMA_VERSION = "physgs-vlm-v2"  # v2: the answer names the whole object ("object")

SYSTEM_PROMPT = (
    "You are an expert in materials science and physical properties of everyday objects and outdoor "
    "terrain. You answer with a single JSON object and nothing else."
)

#: JSON schema of one answer, shown to the model (and used by validate.py's field names).
RESPONSE_SCHEMA: dict = {
    "type": "object",
    "properties": {
        "caption": {"type": "string", "description": "short description of the highlighted part"},
        "object": {
            "type": ["string", "null"],
            "description": "the whole object the highlighted part belongs to, in one or two words (a table's leg: "
            "'table'; a mug standing on the table: 'mug'); null for background",
        },
        "candidates": {
            "type": "array",
            "minItems": 1,
            "maxItems": 3,
            "items": {
                "type": "object",
                "properties": {
                    "material": {"type": "string", "description": "one name from the material list"},
                    "confidence": {"type": "number", "minimum": 0, "maximum": 1},
                    "density": {"type": "number", "description": "kg/m^3"},
                    "kinetic_friction": {"type": "number", "description": "kinetic friction coefficient"},
                    "shore_hardness": {"type": "number", "description": "Shore hardness value"},
                    "shore_scale": {"type": "string", "enum": ["A", "D", "00"]},
                    "youngs_modulus": {"type": "number", "description": "Pa"},
                    "thickness_m": {
                        "type": ["number", "null"],
                        "description": "wall thickness in metres if the part is a hollow shell, else null",
                    },
                },
                "required": ["material", "confidence"],
            },
        },
    },
    "required": ["caption", "candidates"],
}


@dataclass
class PromptConfig:
    """How the prompt images are drawn and encoded."""

    kind: tyro.conf.Suppress[Literal["triplet", "baseline"]] = "triplet"
    """Triplet or baseline prompt; a perception run sets it from its ``prompt`` (``--prompt``)."""
    panel_size: int = 512
    """Long side of each panel in pixels (images are downscaled, never upscaled)."""
    image_format: Literal["png", "jpeg"] = "png"
    jpeg_quality: int = 90
    overlay_color: tuple[int, int, int] = (255, 0, 0)
    overlay_alpha: float = 0.5
    background_grey: int = 128
    """Neutral grey of the isolated-part panel."""
    crop_margin: float = 0.15
    """Margin around the part's bounding box in the isolated panel (fraction of the box size)."""
    gap: int = 8
    """Grey gap between panels, pixels."""
    max_candidates: int = 3


@dataclass(frozen=True)
class VLMRequest:
    """One question to a VLM. ``mask`` and ``view``/``mask_id`` are context, not part of the cache key."""

    view: str
    mask_id: int
    level: str
    system: str
    text: str
    images: tuple[bytes, ...]
    mime: str
    schema_version: str = SCHEMA_VERSION
    mask: np.ndarray | None = field(default=None, compare=False, repr=False)

    def image_hashes(self) -> list[str]:
        return [hashlib.sha256(b).hexdigest() for b in self.images]

    def describe(self) -> str:
        return f"view {self.view!r}, mask {self.mask_id} ({self.level})"


def encode_image(image: np.ndarray, fmt: str = "png", quality: int = 90) -> tuple[bytes, str]:
    """uint8 RGB -> (bytes, mime). Deterministic: no timestamps or metadata."""
    from PIL import Image

    pil = Image.fromarray(np.ascontiguousarray(image.astype(np.uint8)), mode="RGB")
    buf = io.BytesIO()
    if fmt == "png":
        pil.save(buf, format="PNG", optimize=False, compress_level=6)
        return buf.getvalue(), "image/png"
    if fmt == "jpeg":
        pil.save(buf, format="JPEG", quality=int(quality), optimize=False, progressive=False, subsampling=0)
        return buf.getvalue(), "image/jpeg"
    raise ValueError(f"unknown image format {fmt!r}; choose 'png' or 'jpeg'")


def _resize_to(image: np.ndarray, long_side: int) -> np.ndarray:
    import cv2

    h, w = image.shape[:2]
    s = long_side / max(h, w)
    if s >= 1:
        return image
    size = (max(1, round(w * s)), max(1, round(h * s)))
    interp = cv2.INTER_AREA if image.dtype == np.uint8 else cv2.INTER_NEAREST
    return cv2.resize(image, size, interpolation=interp)


def overlay_panel(image: np.ndarray, mask: np.ndarray, cfg: PromptConfig) -> np.ndarray:
    import cv2

    out = image.astype(np.float32)
    color = np.array(cfg.overlay_color, np.float32)
    out[mask] = (1 - cfg.overlay_alpha) * out[mask] + cfg.overlay_alpha * color
    out = out.round().astype(np.uint8)
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    thickness = max(1, round(max(image.shape[:2]) / 256))
    cv2.drawContours(out, contours, -1, tuple(int(c) for c in cfg.overlay_color), thickness)
    return out


def isolated_panel(image: np.ndarray, mask: np.ndarray, cfg: PromptConfig) -> np.ndarray:
    """The part alone on neutral grey, cropped around its box and letterboxed to the image size."""
    import cv2

    h, w = image.shape[:2]
    grey = np.full_like(image, cfg.background_grey)
    part = np.where(mask[..., None], image, grey)
    ys, xs = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
    if len(ys) == 0:
        return grey
    y0, y1, x0, x1 = ys[0], ys[-1] + 1, xs[0], xs[-1] + 1
    my, mx = int(cfg.crop_margin * (y1 - y0)) + 1, int(cfg.crop_margin * (x1 - x0)) + 1
    y0, y1, x0, x1 = max(0, y0 - my), min(h, y1 + my), max(0, x0 - mx), min(w, x1 + mx)
    crop = part[y0:y1, x0:x1]
    s = min(h / crop.shape[0], w / crop.shape[1])
    size = (max(1, int(crop.shape[1] * s)), max(1, int(crop.shape[0] * s)))
    crop = cv2.resize(crop, size, interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
    # resizing blends part pixels with grey only at the silhouette; keep the background exactly grey
    cmask = cv2.resize(mask[y0:y1, x0:x1].astype(np.uint8), size, interpolation=cv2.INTER_NEAREST).astype(
        bool
    )
    crop = np.where(cmask[..., None], crop, np.uint8(cfg.background_grey))
    canvas = grey.copy()
    oy, ox = (h - size[1]) // 2, (w - size[0]) // 2
    canvas[oy : oy + size[1], ox : ox + size[0]] = crop
    return canvas


def triplet_image(image: np.ndarray, mask: np.ndarray, cfg: PromptConfig | None = None) -> np.ndarray:
    """``full | overlay | isolated`` side by side, uint8 [h, 3w + 2 gap, 3] after downscaling."""
    cfg = cfg or PromptConfig()
    if mask.shape != image.shape[:2]:
        raise ValueError(f"mask shape {mask.shape} does not match image shape {image.shape[:2]}")
    img = _resize_to(image, cfg.panel_size)
    m = mask
    if img.shape[:2] != image.shape[:2]:
        import cv2

        m = cv2.resize(
            mask.astype(np.uint8), (img.shape[1], img.shape[0]), interpolation=cv2.INTER_NEAREST
        ).astype(bool)
    gap = np.full((img.shape[0], cfg.gap, 3), cfg.background_grey, np.uint8)
    return np.concatenate([img, gap, overlay_panel(img, m, cfg), gap, isolated_panel(img, m, cfg)], axis=1)


def material_list_text(names: Sequence[str]) -> str:
    return ", ".join(names)


def triplet_text(material_names: Sequence[str], env: str, max_candidates: int = 3) -> str:
    schema = json.dumps(RESPONSE_SCHEMA, indent=1, sort_keys=True)
    return (
        "The image shows three panels side by side: (left) the full image, (middle) the same image with "
        "one part highlighted by a red overlay and outline, (right) that part alone on a neutral grey "
        "background. Ignore the grey background and everything outside the highlighted part; describe "
        "only the highlighted part.\n"
        "Tasks: (1) give a short caption of the part; (2) name its predominant material, choosing only "
        f"from this {env} material list: [{material_list_text(material_names)}]; list up to "
        f"{max_candidates} plausible candidate materials, most likely first, each with a confidence in "
        "[0, 1] (the confidences of all candidates sum to 1); (3) for each candidate estimate its "
        "physical properties: density in kg/m^3, kinetic friction coefficient (dimensionless), Shore "
        'hardness with its scale ("A", "D" or "00"), Young\'s modulus in Pa, and thickness_m: the '
        "wall thickness in metres if the part is a hollow shell (e.g. a bottle, a mug wall, a cardboard "
        "box), else null; (4) name the whole object the part belongs to (object), in one or two words: "
        "for a table's leg 'table', for a mug standing on the table 'mug'.\n"
        "If the highlighted region is background, sky or not a physical object, return an empty "
        "candidate list.\n"
        "Answer with one JSON object matching this schema, with numbers as plain JSON numbers (no units "
        f"in the values) and no other text:\n{schema}"
    )


def baseline_text(material_names: Sequence[str], env: str) -> str:
    schema = json.dumps(RESPONSE_SCHEMA, indent=1, sort_keys=True)
    return (
        "Look at the image. (1) Describe the dominant visible region in a short caption. (2) Predict the "
        "most likely material of that region based solely on its visual appearance, choosing only from "
        f"this {env} material list: [{material_list_text(material_names)}], with a confidence in [0, 1]. "
        "(3) Estimate its density in kg/m^3, kinetic friction coefficient, Shore hardness with its scale "
        '("A", "D" or "00"), Young\'s modulus in Pa, and thickness_m (wall thickness in metres if it '
        "is a hollow shell, else null).\n"
        f"Answer with one JSON object matching this schema and no other text:\n{schema}"
    )


def build_request(
    view: str,
    mask_id: int,
    level: str,
    image: np.ndarray,
    mask: np.ndarray | None,
    material_names: Sequence[str],
    env: str,
    cfg: PromptConfig | None = None,
) -> VLMRequest:
    """Triplet request for one mask (``cfg.kind == "triplet"``) or baseline request for the raw image."""
    cfg = cfg or PromptConfig()
    if cfg.kind == "triplet":
        if mask is None:
            raise ValueError("the triplet prompt needs a mask")
        pixels = triplet_image(image, mask, cfg)
        text = triplet_text(material_names, env, cfg.max_candidates)
    elif cfg.kind == "baseline":
        pixels = _resize_to(image, cfg.panel_size)
        text = baseline_text(material_names, env)
    else:
        raise ValueError(f"unknown prompt kind {cfg.kind!r}; choose 'triplet' or 'baseline'")
    data, mime = encode_image(pixels, cfg.image_format, cfg.jpeg_quality)
    return VLMRequest(view, int(mask_id), level, SYSTEM_PROMPT, text, (data,), mime, SCHEMA_VERSION, mask)
