"""The mass export's object selection re-run offline, from `selection_diag.py`'s candidates and the scene's files
(issue 12: why a GPU `indoor_room` selected its neighbours, without the device).

    python benchmarks/selection_offline.py DIAG/selection.npz SCENE [--out result.json]

``selection.npz`` holds the foreground candidates (their means, opacities, mask evidence and generated part) and the
run's dataparser transform; SCENE is the `physgs synth` + `physgs perceive` folder the run trained on (its
``transforms.json``, its masks under ``perception/``, its ``ground_truth.json``). The views are rebuilt from those files
in the run's scene coordinates, only the views whose cameras the run trained on (the candidates' file lists them), and
the selection's steps after the mask lifting run as the export runs them (:func:`.select.select_object`): the support
plane with the views, the banded coarse clusters, the cluster nearest the capture centre, then the split over the
plane with each rule of ``--rules``. Prints, for each rule, how many selected candidates lie on each generated
object (a part's solid within ``--near-m``; "off": on none). The export's own result on the device is the ``new``
rule's or the ``in_band`` rule's, whichever the run's code had.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from physgs_nerfstudio.geometry.capture import load_capture  # noqa: E402
from physgs_nerfstudio.geometry.clusters import band_labels, split_close  # noqa: E402
from physgs_nerfstudio.geometry.select import SelectConfig, capture_centre, nearest_cluster  # noqa: E402
from physgs_nerfstudio.geometry.support import support_plane_or_reason  # noqa: E402
from physgs_nerfstudio.synth.objects import build_layout  # noqa: E402

RULES = {"new": {}, "in_band": {"split_in_band": True}, "no_split": {"split_on_plane": False}}


def scene_views(scene: Path, transform: np.ndarray, scale: float, cameras: np.ndarray) -> list:
    """The capture's views in the run's scene coordinates (``p_scene = scale * (T @ p_data)``), those whose camera
    centres are among ``cameras`` [V, 3] (the run's training views)."""
    meta = json.loads((scene / "transforms.json").read_text())
    frames = meta["frames"]
    c2w = []
    for f in frames:
        m = transform @ np.asarray(f["transform_matrix"], dtype=np.float64)
        m[:3, 3] *= scale
        c2w.append(m)
    n = len(frames)

    def full(key: str) -> torch.Tensor:
        return torch.full((n,), float(meta[key]))

    cams = SimpleNamespace(camera_to_worlds=torch.tensor(np.stack(c2w), dtype=torch.float32), width=full("w"),
                           height=full("h"), fx=full("fl_x"), fy=full("fl_y"), cx=full("cx"), cy=full("cy"))  # fmt: skip
    views = load_capture(cams, [scene / f["file_path"] for f in frames], scene)
    centres = np.stack([v.centre.double().numpy() for v in views])
    nearest = np.sqrt(((centres[:, None] - cameras[None]) ** 2).sum(-1)).argmin(0)
    return [views[i] for i in sorted(set(nearest.tolist()))]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("npz", type=Path)
    ap.add_argument("scene", type=Path)
    ap.add_argument("--rules", nargs="+", default=list(RULES), choices=list(RULES))
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    z = np.load(a.npz)
    truth = json.loads((a.scene / "ground_truth.json").read_text())
    parts = list(build_layout(truth["layout"], int(truth.get("seed", 0))).parts)
    owner = np.array(["off" if i < 0 else "ground" if parts[i].role == "ground" else parts[i].object
                      for i in z["part"]])  # fmt: skip
    views = scene_views(a.scene, z["transform"], float(z["scale"]), z["cameras"])
    means = z["means"].astype(np.float64)
    res: dict = {"candidates": int(len(means)), "views": len(views), "rules": {}}
    for rule in a.rules:
        cfg = SelectConfig(**RULES[rule])
        plane, why = support_plane_or_reason(means, z["cameras"], z["up"], cfg.support, views)
        if plane is None:
            res["rules"][rule] = {"plane": why}
            continue
        h = plane.height(means)
        keep = h > plane.tol
        m = torch.from_numpy(means[keep])
        lab, _ = band_labels(m, cfg, plane.size, h[keep], plane.tol)
        chosen = nearest_cluster(m, lab, capture_centre(views))
        if cfg.split_on_plane:
            chosen = split_close(m, chosen, capture_centre(views), cfg, height=None if cfg.split_in_band else h[keep],
                                 tol=plane.tol)  # fmt: skip
        ch = chosen.numpy()
        kept_owner = owner[keep]
        res["rules"][rule] = {"selected": int(ch.sum()),
                              "on": {o: int(((kept_owner == o) & ch).sum()) for o in sorted(set(owner))},
                              "plane_tol": float(plane.tol)}  # fmt: skip
        print(rule, json.dumps(res["rules"][rule]))
    if a.out is not None:
        a.out.write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
