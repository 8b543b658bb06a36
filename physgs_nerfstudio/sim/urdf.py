"""URDF: ``object.urdf``, one link with the body's inertial (mass, centre of mass, full inertia tensor), a visual
mesh per part and a collision mesh per convex piece. URDF has no standard friction: the link carries PyBullet's
``<contact><lateral_friction>`` and Gazebo's ``mu1``/``mu2`` with the parts' kinetic friction weighted by their
surface area. Metres, kilograms, z up."""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from .simobject import SimObject

__all__ = ["mean_friction", "urdf_text", "write_urdf"]


def mean_friction(obj: SimObject) -> float:
    """The parts' kinetic friction weighted by their visual mesh's surface area."""
    areas = np.array([m.trimesh().area for m in obj.meshes])
    mus = np.array([obj.materials[m.part].friction for m in obj.meshes])
    return float((areas * mus).sum() / areas.sum())


def _n(x: float) -> str:
    return repr(float(x))


def _v(xs) -> str:
    return " ".join(_n(x) for x in xs)


def urdf_text(obj: SimObject) -> str:
    b, name, I = obj.body, obj.name, obj.body.inertia
    d = obj.mesh_dir
    els = []
    for m in obj.meshes:
        els.append(f'    <visual name="part{m.part}_visual"><geometry><mesh filename={quoteattr(f"{d}/{obj.mesh_file(m.part)}")}/>'
                   '</geometry></visual>')  # fmt: skip
        for i in range(len(m.collision)):
            f = quoteattr(f"{d}/{obj.mesh_file(m.part, i)}")
            els.append(f'    <collision name="part{m.part}_collision{i}"><geometry><mesh filename={f}/></geometry>'
                       '</collision>')  # fmt: skip
    mu = repr(mean_friction(obj))
    return (f'<?xml version="1.0"?>\n<robot name={quoteattr(name)}>\n  <link name={quoteattr(name)}>\n'
            f'    <inertial>\n      <origin xyz="{_v(b.com_m)}" rpy="0 0 0"/>\n'
            f'      <mass value="{_n(b.mass_kg)}"/>\n'
            f'      <inertia ixx="{_n(I[0, 0])}" ixy="{_n(I[0, 1])}" ixz="{_n(I[0, 2])}" iyy="{_n(I[1, 1])}" '
            f'iyz="{_n(I[1, 2])}" izz="{_n(I[2, 2])}"/>\n    </inertial>\n'
            + "\n".join(els) + f'\n    <contact><lateral_friction value="{mu}"/></contact>\n  </link>\n'
            f'  <gazebo reference={quoteattr(name)}><mu1>{mu}</mu1><mu2>{mu}</mu2></gazebo>\n</robot>\n')  # fmt: skip


def write_urdf(obj: SimObject, folder: Path) -> list[Path]:
    path = Path(folder) / "object.urdf"
    path.write_text(urdf_text(obj))
    return [path]
