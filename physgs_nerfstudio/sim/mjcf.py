"""MuJoCo MJCF: ``object.xml`` (one free rigid body) and ``scene.xml`` (the object on a floor, for a quick look).

The body's ``<inertial>`` carries the mass, centre of mass and full inertia tensor (``inertiafromgeom="false"``:
MuJoCo does not recompute them from the meshes). Each part has a visual geom (group 1, no contacts) and one
collision geom per convex piece (group 3) with the part's kinetic friction as its sliding friction (MuJoCo's
torsional and rolling coefficients keep their defaults). Lengths in metres, z up, gravity -9.81 m/s^2.
"""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import quoteattr

from .simobject import SimObject

__all__ = ["mjcf_text", "write_mjcf"]


def _f(x: float) -> str:
    return repr(float(x))


def _v(xs) -> str:
    return " ".join(_f(x) for x in xs)


def mjcf_text(obj: SimObject, free: bool = True) -> str:
    """The MJCF of ``obj`` (module doc); ``free``: the body gets a free joint."""
    b, name = obj.body, obj.name
    I = b.inertia
    assets, geoms = [], []
    for m in obj.meshes:
        p = m.part
        rgba = " ".join(f"{c / 255:.3f}" for c in obj.materials[p].color) + " 1"
        assets.append(f'    <mesh name="part{p}_visual" file={quoteattr(obj.mesh_file(p))}/>')
        geoms.append(f'      <geom name="part{p}_visual" type="mesh" mesh="part{p}_visual" contype="0" '
                     f'conaffinity="0" group="1" rgba="{rgba}"/>')  # fmt: skip
        mu = obj.materials[p].friction
        for i in range(len(m.collision)):
            assets.append(f'    <mesh name="part{p}_collision{i}" file={quoteattr(obj.mesh_file(p, i))}/>')
            geoms.append(f'      <geom name="part{p}_collision{i}" type="mesh" mesh="part{p}_collision{i}" '
                         f'group="3" friction="{_f(mu)} 0.005 0.0001" rgba="0.2 0.6 0.9 0.3"/>')  # fmt: skip
    joint = f'      <freejoint name="{name}_free"/>\n' if free else ""
    full = _v([I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]])
    return (f'<mujoco model={quoteattr(name)}>\n'
            f'  <compiler angle="radian" meshdir={quoteattr(obj.mesh_dir)} inertiafromgeom="false"/>\n'
            '  <option gravity="0 0 -9.81"/>\n'
            '  <asset>\n' + "\n".join(assets) + '\n  </asset>\n'
            '  <worldbody>\n'
            f'    <body name={quoteattr(name)} pos="0 0 0">\n{joint}'
            f'      <inertial pos="{_v(b.com_m)}" mass="{_f(b.mass_kg)}" fullinertia="{full}"/>\n'
            + "\n".join(geoms) + '\n    </body>\n  </worldbody>\n</mujoco>\n')  # fmt: skip


def scene_text(object_file: str, floor_friction: float = 1.0) -> str:
    """A scene that includes ``object_file`` above a floor plane at z = 0, with a light."""
    return ('<mujoco model="scene">\n'
            f'  <include file={quoteattr(object_file)}/>\n'
            '  <visual><headlight ambient="0.4 0.4 0.4" diffuse="0.6 0.6 0.6"/></visual>\n'
            '  <asset><texture name="grid" type="2d" builtin="checker" rgb1="0.85 0.85 0.85" rgb2="0.7 0.7 0.7" '
            'width="256" height="256"/><material name="grid" texture="grid" texrepeat="8 8"/></asset>\n'
            '  <worldbody>\n'
            f'    <geom name="floor" type="plane" size="2 2 0.05" material="grid" friction="{_f(floor_friction)} '
            '0.005 0.0001"/>\n'
            '    <light pos="0.5 -0.5 2" dir="-0.25 0.25 -1"/>\n'
            '  </worldbody>\n</mujoco>\n')  # fmt: skip


def write_mjcf(obj: SimObject, folder: Path) -> list[Path]:
    """``object.xml`` and ``scene.xml`` in ``folder``."""
    folder = Path(folder)
    (folder / "object.xml").write_text(mjcf_text(obj))
    (folder / "scene.xml").write_text(scene_text("object.xml"))
    return [folder / "object.xml", folder / "scene.xml"]
