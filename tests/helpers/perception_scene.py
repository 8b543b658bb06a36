"""A tiny hand-made nerfstudio dataset with ground truth for the perception tests (no renderer needed).

Views are 96x128 images: a noisy grey background and an "object" of flat-coloured parts (a box, a disc and
a bar), each of one indoor library material, moved a little between views. Files follow the generated-scene
contract of docs/architecture.md (transforms.json, ground_truth.json, gt/material/*.png, gt/part/*.png).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PIL import Image

PARTS = [
    # id, name, material, colour
    (1, "body", "ceramic", (200, 60, 50)),
    (2, "lid", "steel", (60, 90, 200)),
    (3, "handle", "oak", (230, 200, 40)),
]
TRUE_PROPS = {
    "ceramic": {
        "density": 2300.0,
        "kinetic_friction": 0.5,
        "shore_hardness": 140.0,
        "youngs_modulus": 7.0e10,
    },
    "steel": {"density": 7850.0, "kinetic_friction": 0.45, "shore_hardness": 140.0, "youngs_modulus": 2.0e11},
    "oak": {"density": 720.0, "kinetic_friction": 0.4, "shore_hardness": 112.0, "youngs_modulus": 1.1e10},
}


def make_scene(root: Path, num_views: int = 3, h: int = 96, w: int = 128, seed: int = 0) -> Path:
    root = Path(root)
    (root / "images").mkdir(parents=True, exist_ok=True)
    (root / "gt" / "material").mkdir(parents=True, exist_ok=True)
    (root / "gt" / "part").mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    materials = [p[2] for p in PARTS]
    frames, gt_frames = [], []
    yy, xx = np.mgrid[0:h, 0:w]
    for v in range(num_views):
        dx = 6 * v - 6
        part = np.zeros((h, w), np.uint8)
        part[(yy >= 30) & (yy < 80) & (xx >= 30 + dx) & (xx < 80 + dx)] = 1  # body box
        part[((yy - 24) ** 2 + (xx - 55 - dx) ** 2) < 12**2] = 2  # lid disc
        part[(yy >= 45) & (yy < 62) & (xx >= 80 + dx) & (xx < 98 + dx)] = 3  # handle bar
        img = np.full((h, w, 3), 150, np.float32) + rng.normal(0, 3, (h, w, 3))
        for pid, _, _, color in PARTS:
            img[part == pid] = np.asarray(color, np.float32) + rng.normal(0, 3, ((part == pid).sum(), 3))
        img = np.clip(img, 0, 255).astype(np.uint8)
        name = f"frame_{v:05d}.png"
        Image.fromarray(img).save(root / "images" / name)
        Image.fromarray(part).save(root / "gt" / "part" / name)
        mat = np.zeros_like(part)
        for pid, _, material, _ in PARTS:
            mat[part == pid] = materials.index(material) + 1
        Image.fromarray(mat).save(root / "gt" / "material" / name)
        c2w = np.eye(4)
        c2w[0, 3] = 0.1 * v
        frames.append({"file_path": f"images/{name}", "transform_matrix": c2w.tolist(), "colmap_im_id": v})
        gt_frames.append(
            {
                "file_path": f"images/{name}",
                "part_path": f"gt/part/{name}",
                "material_path": f"gt/material/{name}",
                "depth_path": f"gt/depth/{v}.npy",
            }
        )
    transforms = {
        "camera_model": "OPENCV",
        "fl_x": 100.0,
        "fl_y": 100.0,
        "cx": w / 2,
        "cy": h / 2,
        "w": w,
        "h": h,
        "k1": 0.0,
        "k2": 0.0,
        "p1": 0.0,
        "p2": 0.0,
        "aabb_scale": 4,
        "custom_top_level_key": {"keep": [1, 2, 3]},
        "frames": frames,
    }
    (root / "transforms.json").write_text(json.dumps(transforms, indent=4))
    parts = [
        {
            "id": pid,
            "name": pname,
            "material": material,
            "volume_m3": 1e-4,
            "volume_model": "solid",
            "thickness_m": None,
            "mass_kg": 1e-4 * TRUE_PROPS[material]["density"],
            "properties": TRUE_PROPS[material],
        }
        for pid, pname, material, _ in PARTS
    ]
    gt = {
        "object": "test_object",
        "seed": seed,
        "env": "indoor",
        "materials": materials,
        "parts": parts,
        "frames": gt_frames,
    }
    (root / "ground_truth.json").write_text(json.dumps(gt, indent=2))
    return root
