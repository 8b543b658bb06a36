"""Render an exported object (`physgs export --outputs sim`) at rest in MuJoCo, off-screen, to a PNG.

    MUJOCO_GL=egl python benchmarks/sim_render.py EXPORT/sim --out docs/sim_mujoco.png [--drop 0.05] [--seconds 1.5]

Loads ``scene.xml`` (the object on a floor), drops the object from ``--drop`` metres, simulates ``--seconds`` and
renders its resting state (visual meshes, in their materials' legend colours) from a camera framing its bounds.
Prints the lowest collision point's height (0 = on the floor), the tilt of the object's z axis and its largest
speed at the end. Needs an OpenGL that MuJoCo can
open without a display: ``MUJOCO_GL=egl`` (Mesa's EGL works on CPU machines) or ``osmesa``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sim_dir", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--drop", type=float, default=0.05)
    ap.add_argument("--seconds", type=float, default=1.5)
    ap.add_argument("--size", type=int, nargs=2, default=(480, 640), metavar=("H", "W"))
    args = ap.parse_args()

    import mujoco
    import numpy as np
    from PIL import Image

    model = mujoco.MjModel.from_xml_path(str(args.sim_dir / "scene.xml"))
    data = mujoco.MjData(model)
    data.qpos[2] = args.drop
    for _ in range(int(args.seconds / model.opt.timestep)):
        mujoco.mj_step(model, data)
    man = json.loads((args.sim_dir / "manifest.json").read_text())
    extent = 2.0 * float(np.max(np.abs(model.geom_rbound[1:])))
    cam = mujoco.MjvCamera()
    cam.lookat[:] = data.xipos[1]
    cam.distance, cam.azimuth, cam.elevation = 2.2 * extent, 135.0, -25.0
    renderer = mujoco.Renderer(model, *args.size)
    renderer.update_scene(data, camera=cam)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(renderer.render()).save(args.out)
    geoms = [i for i in range(model.ngeom) if "collision" in model.geom(i).name]
    low = min(float((data.geom_xpos[i] + model.mesh_vert[model.mesh_vertadr[j]:model.mesh_vertadr[j]
                                                         + model.mesh_vertnum[j]] @ data.geom_xmat[i].reshape(3, 3).T
                     )[:, 2].min()) for i, j in ((i, model.geom_dataid[i]) for i in geoms))  # fmt: skip
    tilt = np.degrees(np.arccos(np.clip(data.xmat[1].reshape(3, 3)[2, 2], -1, 1)))
    print(f"{args.out}: {man['object']} ({man['body']['mass_kg']:.4g} kg) at rest after {args.seconds} s: lowest "
          f"collision point {low * 1000:.3f} mm, tilted {tilt:.2f} deg, largest speed {np.abs(data.qvel).max():.2e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
