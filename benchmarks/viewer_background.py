"""Why the property outputs painted the background (README "Viewer"): for training views of a trained run, the
share of the background's blending weight (pixels outside the generated scene's ground-truth part maps) that
comes from Gaussians with no lifted evidence (the Dirichlet prior), from Gaussians with some evidence but less
than 0.3 of their weight on labelled pixels, and the accumulated opacity there.

    python benchmarks/viewer_background.py --load-config runs/.../config.yml --data scene/ [--every 5]

Needs a `physgs synth` scene (its `gt/part` maps tell object from background).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from PIL import Image


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--load-config", type=Path, required=True)
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--every", type=int, default=5)
    args = ap.parse_args()
    from nerfstudio.utils.eval_utils import eval_setup

    from physgs_nerfstudio.geometry.capture import viewmat_from_c2w
    from physgs_nerfstudio.render import rasterize

    _, pipe, _, _ = eval_setup(args.load_config, test_mode="inference")
    m = pipe.model.eval()
    ds = pipe.datamanager.train_dataset
    gt = {Path(f["file_path"]).name: f for f in json.loads((args.data / "ground_truth.json").read_text())["frames"]}
    tf = {Path(f["file_path"]).name: f for f in json.loads((args.data / "transforms.json").read_text())["frames"]}
    ev, lab = m.dirichlet_evidence.sum(-1), m.labelled_fraction()[:, 0]
    prior_only, stray = (ev == 0).float(), ((ev > 0) & (lab < 0.3)).float()
    dens = m.gaussian_properties()["mean"][:, 0]
    print(f"prior-only Gaussians' density: {float(dens[ev == 0].min()):.1f} kg/m^3 "
          f"({int((ev == 0).sum())} of {m.num_points} Gaussians)")  # fmt: skip
    for i in range(0, len(ds), args.every):
        name = Path(ds.image_filenames[i]).name
        bg = torch.from_numpy(np.asarray(Image.open(args.data / gt[name]["part_path"])) == 0)
        labels = np.asarray(Image.open(args.data / tf[name]["material_path"]))
        cam = ds.cameras[i : i + 1]
        colors = torch.stack([prior_only, stray, dens], -1)
        with torch.no_grad():
            img, alpha, _ = rasterize(m.means, m.quats, torch.exp(m.scales), torch.sigmoid(m.opacities)[:, 0],
                                      colors, viewmat_from_c2w(cam.camera_to_worlds), cam.get_intrinsics_matrices(),
                                      int(cam.width), int(cam.height))  # fmt: skip
        img, a = img[0], alpha[0, ..., 0]
        sel = bg & (a > 0.5)
        prior_share, stray_share = (float((img[..., c][sel] / a[sel]).mean()) for c in (0, 1))
        d = img[..., 2][sel] / a[sel]
        print(f"{name}: background pixels {int(bg.sum())}, opacity median {float(a[bg].median()):.2f}, labelled by "
              f"perception {float((labels[bg.numpy()] > 0).mean()):.1%}; weight from prior-only Gaussians "
              f"{prior_share:.0%}, from stray-evidence Gaussians {stray_share:.0%}; old density output there "
              f"{float(d.min()):.0f} - {float(d.max()):.0f} kg/m^3")  # fmt: skip


if __name__ == "__main__":
    main()
