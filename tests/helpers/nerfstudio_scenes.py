"""A tiny nerfstudio dataset with material maps, for the nerfstudio, export and viewer tests.

Stand-in for `physgs perceive` output (materials.json + per-frame `material_path` /
`material_confidence_path`, docs/architecture.md) written directly from ground truth:

- `write_blob_scene`: a self-contained scene of coloured Gaussian blobs (two objects, two materials) rendered
  with the reference rasterizer; ground-truth label maps come from the same render. No dependency on
  `physgs_nerfstudio.synth`.
- `write_material_files`: adds the perception outputs to any nerfstudio dataset from per-frame label maps
  (used with `physgs_nerfstudio.synth` scenes, whose `gt/material` maps are ground truth).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from PIL import Image

PROPERTY_KEYS = ("density", "kinetic_friction", "shore_hardness", "youngs_modulus")
LOG_SPACE = {"density": True, "kinetic_friction": False, "shore_hardness": False, "youngs_modulus": True}
# (density kg/m^3, friction, hardness, Young's modulus Pa) per test material
TEST_MATERIALS = {
    "ceramic": ((2400.0, 0.5, 85.0, 7.0e10), (220, 120, 60)),
    "rubber": ((1100.0, 0.9, 40.0, 5.0e6), (40, 160, 80)),
    "wood": ((650.0, 0.4, 70.0, 1.0e10), (150, 100, 40)),
}


def _nig(value: float, log: bool, kappa: float = 8.0) -> dict[str, float]:
    tau = math.log(value) if log else value
    spread = 0.25 if log else 0.1 * abs(value) + 1e-3
    a = 3.0
    return {"tau": tau, "kappa": kappa, "a": a, "b": spread**2 * (a - 1)}


def materials_json(
    entries: Sequence[tuple[str, Sequence[int], dict[str, float]]], simulated: bool = True
) -> dict:
    """materials.json (contract layout) for (name, colour, true properties) entries, ids 1..K in order;
    posteriors centred on the given values."""
    mats = []
    for i, (name, color, values) in enumerate(entries):
        post = {k: _nig(float(values[k]), LOG_SPACE[k]) for k in PROPERTY_KEYS}
        prior = {k: _nig(float(values[k]), LOG_SPACE[k], kappa=1.0) for k in PROPERTY_KEYS}
        mats.append(
            {"id": i + 1, "name": name, "color": list(color), "posterior": post, "prior": prior,
             "thickness_m": None, "num_observations": 10}
        )  # fmt: skip
    return {
        "version": 1, "env": "indoor", "simulated": simulated, "property_keys": list(PROPERTY_KEYS),
        "log_space": LOG_SPACE, "alpha0": 1.0, "lambda": 1.0, "materials": mats,
    }  # fmt: skip


def fixture_materials_json(names: Sequence[str]) -> dict:
    return materials_json(
        [(n, TEST_MATERIALS[n][1], dict(zip(PROPERTY_KEYS, TEST_MATERIALS[n][0]))) for n in names]
    )


def write_synth_scene(
    root: Path, resolution: int = 64, views: int = 24, object: str = "mug", seed: int = 0
) -> dict:
    """A `physgs_nerfstudio.synth` scene plus perception outputs written from its ground-truth material
    maps (a fixture standing in for `physgs perceive`). Returns ground_truth.json."""
    from physgs_nerfstudio.synth import SynthConfig, generate_scene, load_ground_truth

    generate_scene(
        SynthConfig(out=Path(root), object=object, views=views, resolution=resolution, seed=seed,
                    num_points=3000, background_points=300, overwrite=True)
    )  # fmt: skip
    gt = load_ground_truth(root)
    labels = {f["file_path"]: np.asarray(Image.open(Path(root) / f["material_path"])) for f in gt["frames"]}
    doc = materials_json([(m["name"], m["color"], m["properties"]) for m in gt["materials"]])
    write_material_files(root, labels, doc)
    return gt


def write_material_files(
    root: Path,
    labels: dict[str, np.ndarray],
    doc: dict,
    confidence: float = 0.9,
    skip: Sequence[str] = (),
) -> None:
    """Writes materials.json and per-frame label/confidence PNGs; `labels` maps a frame's file_path to its
    [H, W] uint8 label map (0 = unknown). Frames in `skip` get no map."""
    root = Path(root)
    (root / "materials").mkdir(exist_ok=True)
    (root / "materials.json").write_text(json.dumps(doc, indent=1))
    meta = json.loads((root / "transforms.json").read_text())
    for frame in meta["frames"]:
        fp = frame["file_path"]
        if fp in skip:
            continue
        stem = Path(fp).stem
        lab = labels[fp].astype(np.uint8)
        conf = np.where(lab > 0, round(confidence * 255), 0).astype(np.uint8)
        Image.fromarray(lab, mode="L").save(root / "materials" / f"{stem}.png")
        Image.fromarray(conf, mode="L").save(root / "materials" / f"{stem}_conf.png")
        frame["material_path"] = f"materials/{stem}.png"
        frame["material_confidence_path"] = f"materials/{stem}_conf.png"
    (root / "transforms.json").write_text(json.dumps(meta, indent=1))


def look_at_c2w(eye: np.ndarray, target: np.ndarray | None = None) -> np.ndarray:
    """OpenGL camera-to-world (camera looks down -z, y up) from eye to target, world up = +z."""
    fwd = (np.zeros(3) if target is None else target) - eye
    fwd = fwd / np.linalg.norm(fwd)
    right = np.cross(fwd, np.array([0.0, 0.0, 1.0]))
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, up, -fwd, eye
    return c2w


def blob_gaussians(seed: int = 0, per_object: int = 600):
    """Two textured objects: a sphere (material 1) and a box (material 2), as opaque Gaussian blobs."""
    g = torch.Generator().manual_seed(seed)
    d = torch.randn(per_object, 3, generator=g)
    sphere = d / d.norm(dim=-1, keepdim=True) * 0.3 + torch.tensor([-0.3, 0.0, 0.0])
    u = torch.rand(per_object, 3, generator=g) * 2 - 1
    face = torch.randint(0, 3, (per_object,), generator=g)
    u[torch.arange(per_object), face] = torch.sign(u[torch.arange(per_object), face])
    box = u * torch.tensor([0.2, 0.2, 0.3]) + torch.tensor([0.35, 0.0, 0.0])
    means = torch.cat([sphere, box])
    # textured colours: stripes so that RGB alone is not the label
    stripes = (torch.sin(means[:, 2] * 25) > 0).float()[:, None]
    base = torch.tensor([[0.85, 0.45, 0.25]] * per_object + [[0.25, 0.6, 0.35]] * per_object)
    colors = (base * (0.6 + 0.4 * stripes)).clamp(0, 1)
    labels = torch.cat([torch.ones(per_object), 2 * torch.ones(per_object)]).long()
    n = means.shape[0]
    return {
        "means": means,
        "quats": torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1),
        "scales": torch.full((n, 3), 0.035),
        "opacities": torch.full((n,), 0.95),
        "colors": colors,
        "labels": labels,
    }


def write_blob_scene(
    root: Path,
    num_views: int = 12,
    size: int = 64,
    seed: int = 0,
    with_ply: bool = True,
    skip_material_for: Sequence[int] = (),
) -> dict:
    """Renders the blob scene into a nerfstudio dataset at `root` with material maps; returns ground truth
    label maps by frame file_path."""
    from physgs_nerfstudio.geometry.capture import viewmat_from_c2w
    from physgs_nerfstudio.render import rasterize

    root = Path(root)
    (root / "images").mkdir(parents=True, exist_ok=True)
    scene = blob_gaussians(seed)
    fl = size * 1.1
    frames, gt = [], {}
    for i in range(num_views):
        ang = 2 * math.pi * i / num_views
        eye = np.array([1.6 * math.cos(ang), 1.6 * math.sin(ang), 0.5 + 0.3 * math.sin(3 * ang)])
        c2w = look_at_c2w(eye)
        viewmat = viewmat_from_c2w(torch.tensor(c2w[None, :3, :4], dtype=torch.float32))
        Ks = torch.tensor([[[fl, 0, size / 2], [0, fl, size / 2], [0, 0, 1]]], dtype=torch.float32)
        onehot = torch.nn.functional.one_hot(scene["labels"] - 1, 2).float()
        colors = torch.cat([scene["colors"], onehot], dim=-1)
        with torch.no_grad():
            img, alpha, _ = rasterize(
                scene["means"],
                scene["quats"],
                scene["scales"],
                scene["opacities"],
                colors,
                viewmat,
                Ks,
                size,
                size,
            )
        rgb = img[0, ..., :3] + (1 - alpha[0]) * 1.0  # white background
        lab = torch.where(alpha[0, ..., 0] > 0.5, img[0, ..., 3:].argmax(-1) + 1, 0).numpy().astype(np.uint8)
        fp = f"images/frame_{i:03d}.png"
        Image.fromarray((rgb.clamp(0, 1).numpy() * 255).round().astype(np.uint8)).save(root / fp)
        frames.append({"file_path": fp, "transform_matrix": c2w.tolist()})
        gt[fp] = lab
    meta = {
        "fl_x": fl, "fl_y": fl, "cx": size / 2, "cy": size / 2, "w": size, "h": size,
        "camera_model": "OPENCV", "frames": frames,
    }  # fmt: skip
    if with_ply:
        write_ply(root / "points.ply", scene["means"], scene["colors"], seed)
        meta["ply_file_path"] = "points.ply"
    (root / "transforms.json").write_text(json.dumps(meta, indent=1))
    skip = [frames[i]["file_path"] for i in skip_material_for]
    write_material_files(root, gt, fixture_materials_json(["ceramic", "rubber"]), skip=skip)
    return gt


def blob_datamanager(root: Path):
    """A CPU datamanager over a 6-view, 32 px blob scene written into ``root`` (view 5 without material maps,
    every third view held out)."""
    from physgs_nerfstudio.nerfstudio import PhysGSDatamanagerConfig, PhysGSDataParserConfig

    write_blob_scene(root, num_views=6, size=32, skip_material_for=[5])
    cfg = PhysGSDatamanagerConfig(dataparser=PhysGSDataParserConfig(data=root, eval_mode="interval", eval_interval=3))
    return cfg.setup(device="cpu")


def blob_model(dm, **config):
    """A small PhysGS model (SH degree 1, no downscales) seeded from the datamanager's points."""
    from nerfstudio.data.scene_box import SceneBox

    from physgs_nerfstudio.nerfstudio import PhysGSModelConfig

    meta = dm.train_dataparser_outputs.metadata
    config = {"sh_degree": 1, "num_downscales": 0, **config}
    return PhysGSModelConfig(**config).setup(
        scene_box=SceneBox(torch.tensor([[-1.0, -1, -1], [1, 1, 1]])),
        num_train_data=len(dm.train_dataset),
        metadata=dm.train_dataset.metadata,
        seed_points=(meta["points3D_xyz"], meta["points3D_rgb"]),
    )


def write_ply(
    path: Path, means: torch.Tensor, colors: torch.Tensor, seed: int = 0, noise: float = 0.02
) -> None:
    """Noisy subsample of the scene points as an ASCII PLY (a stand-in for SfM points)."""
    g = torch.Generator().manual_seed(seed + 1)
    pts = means + noise * torch.randn(means.shape, generator=g)
    rgb = (colors.clamp(0, 1) * 255).round().to(torch.uint8)
    lines = [
        "ply", "format ascii 1.0", f"element vertex {len(pts)}", "property float x", "property float y",
        "property float z", "property uchar red", "property uchar green", "property uchar blue", "end_header",
    ]  # fmt: skip
    lines += [
        f"{p[0]:.5f} {p[1]:.5f} {p[2]:.5f} {c[0]} {c[1]} {c[2]}" for p, c in zip(pts.tolist(), rgb.tolist())
    ]
    Path(path).write_text("\n".join(lines) + "\n")
