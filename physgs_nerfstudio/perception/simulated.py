"""The ``simulated`` VLM: answers from a generated scene's ground truth through a noise/confusion model.

For generated scenes only (needs ``ground_truth.json`` and its ``gt/material`` maps). Every answer is
flagged: ``VLMResponse.simulated = True``, ``"simulated": true`` inside the answer JSON, and downstream in
observations.jsonl and materials.json.

Model, for one request (view, mask), with a random generator seeded from (seed, view, mask id, image hash),
so the same request always gets the same answer:

1. truth: the majority ground-truth material under the mask. If more than ``background_max_fraction`` of
   the mask is background (material 0), the answer has no candidates (as a real VLM told to return an
   empty list for background would).
2. top candidate: the truth with probability ``p_correct``; otherwise, with probability ``p_random`` a
   uniformly drawn other library material, else one of the truth's ``confusable`` neighbours (uniform; a
   random material if it lists none).
3. 1..``max_candidates`` candidates (uniform count); the extra ones are drawn (without repetition) from the
   truth and its confusable neighbours first, then the library. Confidences: a symmetric Dirichlet draw
   (``concentration``) sorted in decreasing order, so the top candidate has the largest.
4. property values: centre x exp(sigma_k * N(0, 1)) (log-normal noise, ``sigma`` per property), where the
   centre is the TRUE value used to generate the scene for the truth's candidate (from the ground-truth
   part that holds most of the mask's truth-material pixels) and the library's typical value for the
   others. Hardness is answered on the material's quoted Shore scale (noise applied to that reading,
   clipped to [0, 100]).
5. structure: one judgment per mask, shared by its candidates: the part is called hollow when the ground-truth
   part is a shell, flipped with probability ``p_structure_error``. A hollow answer gives ``thickness_m`` =
   the part's true wall thickness (truth candidate) or the candidate material's library thickness
   (``default_thickness_m`` without one), times exp(``thickness_sigma`` * N(0, 1)); a solid answer gives null.
6. object: the whole object of that ground-truth part (``object`` in ground_truth.json: "table" for its leg, "mug"
   for the mug standing on it, "stand" for the stand under it, "floor" for the floor), as the prompt asks of every
   physical part; null only where the answer has no candidates (background). With probability ``p_object_error``
   another object's name instead, one of the scene's other objects (uniform; "unknown object" in a scene of one
   object). Drawn after everything above, so the materials, values and structure are those an answer without the
   field had.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..advanced import Advanced
from ..materials import PROPERTY_KEYS, MaterialLibrary, from_canonical
from .prompts import VLMRequest
from .vlm import Usage, VLMError, VLMResponse

SIMULATED_MODEL = "simulated"


@dataclass
class SimulatedConfig:
    """A simulated VLM for generated scenes: it answers from the scene's ground truth, with errors."""

    p_correct: float = 0.75
    """Probability that the top candidate is the true material."""
    p_random: Advanced[float] = 0.1
    """When wrong: probability of a random library material instead of a confusable neighbour."""
    max_candidates: Advanced[int] = 3
    concentration: Advanced[float] = 1.5
    """Symmetric Dirichlet concentration of the candidate confidences (lower = more peaked)."""
    sigma: Advanced[dict[str, float]] = field(
        default_factory=lambda: {
            "density": 0.15,
            "kinetic_friction": 0.2,
            "shore_hardness": 0.1,
            "youngs_modulus": 0.4,
        }
    )
    """Log-normal noise sigma per property."""
    background_max_fraction: Advanced[float] = 0.5
    """Masks with more background than this get an empty answer."""
    p_structure_error: Advanced[float] = 0.1
    """Probability that the answer calls a solid part hollow or a hollow part solid (one judgment per mask,
    shared by its candidates)."""
    thickness_sigma: Advanced[float] = 0.25
    """Log-normal noise sigma of the answered wall thickness."""
    p_object_error: Advanced[float] = 0.1
    """Probability that the answer names another object than the one the part belongs to."""
    default_thickness_m: Advanced[float] = 0.003
    """Thickness answered for a part called hollow whose candidate material has none in the library."""
    seed: int = 0
    """Seed of the simulated answers."""

    def setup(self, data: Path, library: MaterialLibrary) -> SimulatedBackend:
        """The simulated VLM answering from the generated scene at ``data`` (its ground truth)."""
        return SimulatedBackend(data, library, self)

    def fingerprint(self) -> str:
        return json.dumps(
            {
                "p_correct": self.p_correct,
                "p_random": self.p_random,
                "max_candidates": self.max_candidates,
                "concentration": self.concentration,
                "sigma": dict(sorted(self.sigma.items())),
                "background_max_fraction": self.background_max_fraction,
                "p_structure_error": self.p_structure_error,
                "thickness_sigma": self.thickness_sigma,
                "default_thickness_m": self.default_thickness_m,
                "p_object_error": self.p_object_error,
                "seed": self.seed,
                "model": 3,
            },
            sort_keys=True,
        )


class GroundTruth:
    """Reader for ``ground_truth.json`` of a generated scene (docs/architecture.md, "Generated scenes").

    Tolerant about the exact frame record layout: a frame's ground-truth material map is the value of its
    ``material``/``material_path`` key (or any string value containing ``gt/material``), and frames are
    matched to views by ``file_path`` (or by position in transforms.json when they have none).
    """

    def __init__(self, root: Path, library: MaterialLibrary):
        self.root = Path(root)
        path = self.root / "ground_truth.json"
        if not path.is_file():
            raise VLMError(
                f"the simulated VLM needs a generated scene with ground truth, but {path} does not exist. "
                "Generate one with `physgs synth`, or use --vlm openai / replay for real data."
            )
        self.data = data = json.loads(path.read_text(encoding="utf-8"))
        self.library = library
        self.material_names: list[str] = []
        for m in data.get("materials", []):
            raw = m.get("name") if isinstance(m, dict) else m
            name = library.resolve(str(raw)) if raw is not None else None
            if name is None:
                raise VLMError(f"ground-truth material {raw!r} is not in the {library.env} library")
            self.material_names.append(name)
        self.parts: list[dict] = [p for p in data.get("parts", []) if isinstance(p, dict)]
        self._part_by_id = {int(p["id"]): p for p in self.parts if "id" in p}
        self._maps: dict[str, dict[str, str]] = {}
        frames = data.get("frames", [])
        tf_frames = []
        tf = self.root / "transforms.json"
        if tf.is_file():
            tf_frames = json.loads(tf.read_text(encoding="utf-8")).get("frames", [])
        for i, fr in enumerate(frames):
            if not isinstance(fr, dict):
                continue
            view = fr.get("file_path") or (tf_frames[i].get("file_path") if i < len(tf_frames) else None)
            if view is None:
                continue
            entry = {}
            for key, val in fr.items():
                if not isinstance(val, str):
                    continue
                if key in ("material", "material_path", "gt_material") or "gt/material" in val:
                    entry.setdefault("material", val)
                elif key in ("part", "part_path", "gt_part") or "gt/part" in val:
                    entry.setdefault("part", val)
            self._maps[str(view)] = entry
        self._cache: dict[str, np.ndarray] = {}

    def _load_map(self, rel: str) -> np.ndarray:
        if rel not in self._cache:
            from ..image_files import read_array

            self._cache[rel] = read_array(self.root / rel)
        return self._cache[rel]

    def maps(self, view: str) -> tuple[np.ndarray, np.ndarray | None]:
        entry = self._maps.get(view)
        if not entry or "material" not in entry:
            raise VLMError(f"ground_truth.json has no material map for view {view!r}")
        mat = self._load_map(entry["material"])
        part = self._load_map(entry["part"]) if "part" in entry else None
        return mat, part

    def material_map(self, view: str) -> np.ndarray:
        """int [H, W]: 0 background, i + 1 = self.material_names[i]."""
        return self.maps(view)[0]

    def part(self, part_id: int) -> dict | None:
        return self._part_by_id.get(int(part_id))

    def true_values(self, material: str, part: dict | None) -> tuple[dict[str, float], float | None, bool]:
        """(canonical property values, thickness or None, is_shell) of the scene part (fallback: library)."""
        mat = self.library[material]
        values = {k: mat.properties[k].typical for k in PROPERTY_KEYS}
        thickness, shell = mat.thickness_m, mat.thickness_m is not None
        if part is not None:
            props = part.get("properties") or {}
            for k in PROPERTY_KEYS:
                v = props.get(k)
                if isinstance(v, dict):
                    v = v.get("value", v.get("typical"))
                if isinstance(v, (int, float)) and math.isfinite(v):
                    values[k] = float(v)
            shell = part.get("volume_model") == "shell"
            t = part.get("thickness_m")
            thickness = float(t) if shell and isinstance(t, (int, float)) else None
        return values, thickness, shell


def _rng_for(seed: int, request: VLMRequest) -> np.random.Generator:
    h = hashlib.sha256()
    h.update(f"{seed}|{request.view}|{request.mask_id}|".encode())
    for d in request.image_hashes():
        h.update(d.encode())
    return np.random.default_rng(int.from_bytes(h.digest()[:8], "little"))


class SimulatedBackend:
    """See the module docstring. Thread-safe (no shared mutable state besides a read-only map cache)."""

    name = "simulated"
    simulated = True

    def __init__(self, root: Path, library: MaterialLibrary, config: SimulatedConfig | None = None):
        self.config = config or SimulatedConfig()
        if not all(0 <= q <= 1 for q in (self.config.p_correct, self.config.p_random, self.config.p_object_error)):
            raise ValueError("p_correct, p_random and p_object_error must lie in [0, 1]")
        self.library = library
        self.truth = GroundTruth(root, library)
        self.model = SIMULATED_MODEL
        self.variant = self.config.fingerprint()
        self.calls = 0

    def cost_usd(self, usage: Usage) -> float:
        return 0.0

    def _truth_of(self, request: VLMRequest) -> tuple[str | None, dict | None]:
        if request.mask is None:
            raise VLMError(f"simulated VLM: {request.describe()} carries no mask")
        mat_map, part_map = self.truth.maps(request.view)
        mask = request.mask
        if mask.shape != mat_map.shape[:2]:
            import cv2

            mask = cv2.resize(
                mask.astype(np.uint8), (mat_map.shape[1], mat_map.shape[0]), interpolation=cv2.INTER_NEAREST
            ).astype(bool)
        ids = mat_map[mask].astype(np.int64).reshape(-1)
        if ids.size == 0:
            return None, None
        counts = np.bincount(ids, minlength=len(self.truth.material_names) + 1)
        if counts[0] > self.config.background_max_fraction * ids.size:
            return None, None
        idx = int(np.argmax(counts[1:])) + 1
        material = self.truth.material_names[idx - 1]
        part = None
        if part_map is not None:
            pids = part_map[mask & (mat_map == idx)].astype(np.int64).reshape(-1)
            pids = pids[pids > 0]
            if pids.size:
                part = self.truth.part(int(np.bincount(pids).argmax()))
        if part is None:
            part = next(
                (p for p in self.truth.parts if self.library.resolve(str(p.get("material"))) == material),
                None,
            )
        return material, part

    def answer(self, request: VLMRequest) -> dict[str, Any]:
        cfg = self.config
        lib = self.library
        truth, part = self._truth_of(request)
        if truth is None:
            return {"caption": "simulated answer: background", "candidates": [], "simulated": True}
        rng = _rng_for(cfg.seed, request)
        names = lib.names
        confusable = [c for c in lib[truth].confusable if c in lib and c != truth]

        def random_other(exclude: set[str]) -> str | None:
            pool = [n for n in names if n not in exclude]
            return pool[int(rng.integers(len(pool)))] if pool else None

        if rng.random() < cfg.p_correct:
            top = truth
        elif confusable and rng.random() >= cfg.p_random:
            top = confusable[int(rng.integers(len(confusable)))]
        else:
            top = random_other({truth}) or truth
        n = int(rng.integers(1, max(1, cfg.max_candidates) + 1))
        chosen = [top]
        pool = [m for m in [truth, *confusable] if m != top]
        rng.shuffle(pool)
        while len(chosen) < n:
            nxt = pool.pop() if pool else random_other(set(chosen))
            if nxt is None:
                break
            chosen.append(nxt)
        conf = np.sort(rng.dirichlet(np.full(len(chosen), cfg.concentration)))[::-1]
        _, true_t, true_shell = self.truth.true_values(truth, part)
        says_hollow = bool(true_shell) != bool(rng.random() < cfg.p_structure_error)

        candidates = []
        for name, p in zip(chosen, conf):
            mat = lib[name]
            if name == truth:
                centre, _, _ = self.truth.true_values(name, part)
            else:
                centre = {k: mat.properties[k].typical for k in PROPERTY_KEYS}
            base_t = true_t if (name == truth and true_t) else (mat.thickness_m or cfg.default_thickness_m)
            t_noise = float(np.exp(cfg.thickness_sigma * rng.standard_normal()))
            thickness = base_t * t_noise if says_hollow else None
            noise = {k: float(np.exp(cfg.sigma.get(k, 0.0) * rng.standard_normal())) for k in PROPERTY_KEYS}
            reading = float(from_canonical(centre["shore_hardness"], mat.hardness_scale))
            candidates.append(
                {
                    "material": name,
                    "confidence": round(float(p), 4),
                    "density": centre["density"] * noise["density"],
                    "kinetic_friction": centre["kinetic_friction"] * noise["kinetic_friction"],
                    "shore_hardness": float(np.clip(reading * noise["shore_hardness"], 0.0, 100.0)),
                    "shore_scale": mat.hardness_scale,
                    "youngs_modulus": centre["youngs_modulus"] * noise["youngs_modulus"],
                    "thickness_m": thickness,
                }
            )
        return {
            "caption": f"simulated answer for mask {request.mask_id} ({request.level})",
            "object": self._object_of(part, rng),
            "candidates": candidates,
            "simulated": True,
        }

    def _object_of(self, part: dict | None, rng: np.random.Generator) -> str | None:
        """The answer's ``object`` (module doc, 6): the part's object, or another with ``p_object_error``."""
        true = part.get("object") if part is not None else None
        if not isinstance(true, str):
            return None
        if rng.random() >= self.config.p_object_error:
            return true
        others = sorted({str(p["object"]) for p in self.truth.parts
                         if isinstance(p.get("object"), str) and p.get("object") != true})  # fmt: skip
        return others[int(rng.integers(len(others)))] if others else "unknown object"

    def query(self, request: VLMRequest) -> VLMResponse:
        self.calls += 1
        text = json.dumps(self.answer(request))
        return VLMResponse(text=text, usage=Usage(), cached=False, simulated=True)
