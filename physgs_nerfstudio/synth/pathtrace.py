"""Path-traced views of a generated layout with Mitsuba 3 (the ``pathtrace`` extra: ``pip install mitsuba``).

The same layouts, cameras and procedural textures as the project's renderer (:mod:`.render`), through a
physically based renderer: every part is a triangle mesh (:mod:`.meshing`) whose vertex colours carry the part's
albedo texture (:func:`.appearance.albedo`); its BSDF follows its texture kind and a per-part draw of gloss:

* metal: a rough conductor tinted by its albedo, glossy (GGX alpha 0.04-0.12) or rough (0.2-0.4);
* glass: a thin dielectric for a hollow part (a bottle, a bulb), a dielectric for a solid one;
* ceramic, marble, plastic: a principled BSDF (a dielectric coat over the albedo), glossy (roughness 0.05-0.15) or
  satin (0.25-0.45); wood: a rough varnish (0.45-0.7);
* everything else (fabric, paper, cardboard, leather, rubber, foam, stone): diffuse.

Light: the project's environment (:func:`.appearance.background`) as an environment map, plus a sun along the
project's key light direction, so parts cast shadows onto the support. Label maps (part index, z-depth) come from the
same renderer and meshes (Mitsuba's ``aov`` integrator, one sample at each pixel centre), so the simulated VLM reads
the part under each pixel of the path-traced image.

The variant is ``scalar_rgb`` (`VARIANTS`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import lru_cache

import numpy as np

from .appearance import LIGHT_DIR, Look, albedo, background
from .meshing import orient_faces, part_mesh
from .objects import Part
from .render import Intrinsics, View, camera_rays

# scalar_rgb: Mitsuba's CPU variant without the LLVM JIT (its image blocks run on all cores). The llvm_ad_rgb variant
# loads here but its JIT aborts the process on the principled BSDF (an LLVM instruction-selection error), so it is
# not tried.
VARIANTS: tuple[str, ...] = ("scalar_rgb",)
# light levels: a white diffuse floor in the sun comes out near the project's shading (ambient 0.28-0.42 plus 0.72
# of the key light: about 0.3 from the environment plus 0.64 x cos from the sun), and in the object's shadow at about
# a third of that, as under a window
ENV_SCALE = 0.4
SUN_IRRADIANCE = 2.0
EXPOSURE = 1.0
NEAR_CLIP_M = 1e-3  # the sensor's near plane: Mitsuba's rays start on it, so a depth AOV counts from it


def available() -> str | None:
    """Why the path tracer cannot run here (one line), or None when it can."""
    try:
        _mitsuba()
    except ImportError as err:
        return f"mitsuba is not installed ({err}); pip install 'physgs-nerfstudio[pathtrace]'"
    except RuntimeError as err:
        return str(err)
    return None


@lru_cache(maxsize=1)
def _mitsuba():
    import mitsuba as mi

    errors = []
    for variant in VARIANTS:
        try:
            mi.set_variant(variant)
            mi.load_dict({"type": "scene", "s": {"type": "sphere"}})
            return mi
        except Exception as err:  # noqa: BLE001 - a variant whose backend does not load here (any error)
            errors.append(f"{variant}: {err}")
    raise RuntimeError("no Mitsuba variant works here: " + "; ".join(errors))


def _bsdf(look: Look, solid: bool, rng: np.random.Generator) -> dict:
    colour = {"type": "mesh_attribute", "name": "vertex_color"}
    k = look.texture
    if k == "metal":
        alpha = float(rng.uniform(0.04, 0.12) if rng.random() < 0.5 else rng.uniform(0.2, 0.4))
        return {"type": "roughconductor", "material": "none", "alpha": alpha, "specular_reflectance": colour}
    if k == "glass":
        inner = {"type": "dielectric" if solid else "thindielectric", "int_ior": 1.5}
        return inner
    if k in ("ceramic", "marble", "plastic"):  # a dielectric coat over the albedo, glossy or satin
        rough = float(rng.uniform(0.05, 0.15) if rng.random() < 0.5 else rng.uniform(0.25, 0.45))
        return {"type": "principled", "base_color": colour, "roughness": rough, "specular": 0.5}
    if k == "wood":  # a rough varnish
        return {"type": "principled", "base_color": colour, "roughness": float(rng.uniform(0.45, 0.7)), "specular": 0.4}
    return {"type": "diffuse", "reflectance": colour}


def _envmap(env: str, seed: int, width: int = 256) -> np.ndarray:
    """Equirectangular environment [H, W, 3] in Mitsuba's envmap convention (its +y is our +z, see `_env_to_world`)."""
    h = width // 2
    v, u = np.meshgrid((np.arange(h) + 0.5) / h, (np.arange(width) + 0.5) / width, indexing="ij")
    theta, phi = v * math.pi, u * 2 * math.pi
    local = np.stack([np.sin(theta) * np.sin(phi), np.cos(theta), -np.sin(theta) * np.cos(phi)], -1).reshape(-1, 3)
    world = np.stack([local[:, 0], -local[:, 2], local[:, 1]], 1)  # rotate +90 degrees about x: y -> z, z -> -y
    return background(world, env, seed).reshape(h, width, 3).astype(np.float32)


def scene_dict(parts: Sequence[Part], looks: Sequence[Look], look_seeds: Sequence[int], env: str, seed: int,
               spacing: float) -> dict:  # fmt: skip
    """The Mitsuba scene of the parts (shape ``p###`` = part index ###), without sensors."""
    mi = _mitsuba()
    scene: dict = {"type": "scene"}
    for k, (part, look) in enumerate(zip(parts, looks)):
        v, n, f = part_mesh(part.primitive, max(spacing, 2 * float(part.primitive.half_extents().max()) / 200))
        f = orient_faces(v, n, f)
        col = np.clip(albedo(look, v, look_seeds[k]), 0.0, 1.0)
        wv, wn = part.to_world(v), part.dir_to_world(n)
        mesh = mi.Mesh(f"p{k:03d}", len(wv), len(f), has_vertex_normals=True)
        params = mi.traverse(mesh)
        floats, ints = type(params["vertex_positions"]), type(params["faces"])  # the variant's dynamic arrays
        params["vertex_positions"] = floats(wv.astype(np.float32).ravel())
        params["vertex_normals"] = floats(wn.astype(np.float32).ravel())
        params["faces"] = ints(f.astype(np.uint32).ravel())
        mesh.add_attribute("vertex_color", 3, floats(col.astype(np.float32).ravel()))
        params.update()
        solid = part.volume_model == "solid"
        bsdf = _bsdf(look, solid, np.random.default_rng([look_seeds[k], 3]))
        if bsdf["type"] not in ("dielectric", "thindielectric"):
            bsdf = {"type": "twosided", "bsdf": bsdf}
        mesh.set_bsdf(mi.load_dict(bsdf))
        scene[f"p{k:03d}"] = mesh
    scene["env"] = {"type": "envmap", "bitmap": mi.Bitmap(_envmap(env, seed)), "scale": ENV_SCALE,
                    "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], 90)}  # fmt: skip
    scene["sun"] = {"type": "directional", "direction": (-LIGHT_DIR).tolist(),
                    "irradiance": {"type": "rgb", "value": [SUN_IRRADIANCE] * 3}}  # fmt: skip
    return scene


def _sensor(K: Intrinsics, c2w: np.ndarray, labels: bool, spp: int) -> dict:
    mi = _mitsuba()
    eye, forward, up = c2w[:3, 3], -c2w[:3, 2], c2w[:3, 1]
    sampler = {"type": "stratified", "sample_count": 1, "jitter": False} if labels else {
        "type": "independent", "sample_count": spp}  # fmt: skip
    return {
        "type": "perspective", "fov": math.degrees(2 * math.atan(0.5 * K.width / K.fx)), "fov_axis": "x",
        "near_clip": NEAR_CLIP_M,
        "to_world": mi.ScalarTransform4f().look_at(origin=eye.tolist(), target=(eye + forward).tolist(), up=up.tolist()),
        "sampler": sampler,
        "film": {"type": "hdrfilm", "width": K.width, "height": K.height, "pixel_format": "rgb",
                 "rfilter": {"type": "box"}},
    }  # fmt: skip


def _srgb(linear: np.ndarray) -> np.ndarray:
    x = np.clip(linear * EXPOSURE, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


class PathTracer:
    """One layout's Mitsuba scene, rendered from any camera: `view(K, c2w, spp, seed)` -> :class:`.render.View`."""

    def __init__(self, parts: Sequence[Part], looks: Sequence[Look], look_seeds: Sequence[int], env: str, seed: int,
                 spacing: float) -> None:  # fmt: skip
        mi = _mitsuba()
        self.mi = mi
        self.scene = mi.load_dict(scene_dict(parts, looks, look_seeds, env, seed, spacing))
        ids = [s.id() for s in self.scene.shapes()]
        self.part_of_shape = np.array([int(i[1:]) if i.startswith("p") else -1 for i in ids])
        self.rgb_integrator = mi.load_dict({"type": "path", "max_depth": 8})
        self.aov_integrator = mi.load_dict({"type": "aov", "aovs": "dd:depth,si:shape_index"})

    def view(self, K: Intrinsics, c2w: np.ndarray, spp: int, seed: int) -> View:
        mi = self.mi
        rgb_sensor = mi.load_dict(_sensor(K, c2w, False, spp))
        lin = np.asarray(mi.render(self.scene, sensor=rgb_sensor, integrator=self.rgb_integrator, spp=spp, seed=seed))
        lab_sensor = mi.load_dict(_sensor(K, c2w, True, 1))
        aov = np.asarray(mi.render(self.scene, sensor=lab_sensor, integrator=self.aov_integrator, spp=1))
        dist, index = aov[..., 0], np.rint(aov[..., 1]).astype(np.int64)
        hit = dist > 0
        part = np.where(hit, self.part_of_shape[np.clip(index - 1, 0, len(self.part_of_shape) - 1)] + 1, 0)
        _, _, zfac = camera_rays(K, c2w)
        depth = np.where(hit, dist * zfac.reshape(K.height, K.width) + NEAR_CLIP_M, 0.0).astype(np.float32)
        rgb8 = np.clip(np.round(_srgb(lin[..., :3]) * 255.0), 0, 255).astype(np.uint8)
        return View(rgb8, part.astype(np.int64), depth)
