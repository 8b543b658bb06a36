"""USD (``usd-core``): ``object.usda``, the object as a rigid body with physics materials.

``/Object`` (the default prim, an Xform) has ``UsdPhysics.RigidBodyAPI`` and ``MassAPI``: ``mass``,
``centerOfMass``, ``diagonalInertia`` and ``principalAxes`` (the inertia tensor's eigenvectors as a quaternion: the
tensor is ``R diag(d) R^T`` with ``R`` that rotation). ``/Object/part_<p>/visual`` is the part's mesh;
``/Object/part_<p>/collision_<i>`` its convex pieces (``CollisionAPI``, ``MeshCollisionAPI`` approximation
``convexHull``, purpose guide), bound (purpose physics) to ``/Object/Materials/part_<p>``, a ``UsdPhysics.MaterialAPI``
with the part's density and its kinetic friction as ``dynamicFriction`` (and ``staticFriction``: static friction is
not estimated). Stage: ``metersPerUnit`` 1, ``kilogramsPerUnit`` 1, ``upAxis`` Z. A posterior sample
(:mod:`.samples`) is a small layer that references ``object.usda`` and overrides the mass and the materials.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .simobject import SimObject

__all__ = ["usd_available", "write_usd", "write_usd_sample"]


def usd_available() -> bool:
    """Whether ``pxr`` (usd-core) imports here."""
    try:
        import pxr  # noqa: F401
    except ImportError:
        return False
    return True


def _pxr():
    try:
        from pxr import Gf, Sdf, Usd, UsdGeom, UsdPhysics, UsdShade
    except ImportError:
        raise ImportError("the USD file needs usd-core: pip install usd-core (or physgs-nerfstudio[sim]).") from None
    return Gf, Sdf, Usd, UsdGeom, UsdPhysics, UsdShade


def _quat(axes: np.ndarray):
    """The quaternion (USD's Quatf: real, imaginary) of the rotation whose columns are ``axes``."""
    from scipy.spatial.transform import Rotation

    Gf = _pxr()[0]
    x, y, z, w = Rotation.from_matrix(axes).as_quat()
    return Gf.Quatf(float(w), Gf.Vec3f(float(x), float(y), float(z)))


def _set_mass(prim, obj: SimObject) -> None:
    Gf, _, _, _, UsdPhysics, _ = _pxr()
    b = obj.body
    w, v = b.principal
    mass = UsdPhysics.MassAPI.Apply(prim)
    mass.CreateMassAttr().Set(float(b.mass_kg))
    mass.CreateCenterOfMassAttr().Set(Gf.Vec3f(*[float(x) for x in b.com_m]))
    mass.CreateDiagonalInertiaAttr().Set(Gf.Vec3f(*[float(x) for x in w]))
    mass.CreatePrincipalAxesAttr().Set(_quat(v))


def _set_materials(stage, obj: SimObject) -> None:
    UsdPhysics, UsdShade = _pxr()[4], _pxr()[5]
    for p, mat in obj.materials.items():
        m = UsdShade.Material.Define(stage, f"/Object/Materials/part_{p}")
        api = UsdPhysics.MaterialAPI.Apply(m.GetPrim())
        api.CreateDensityAttr().Set(float(mat.density))
        api.CreateDynamicFrictionAttr().Set(float(mat.friction))
        api.CreateStaticFrictionAttr().Set(float(mat.friction))
        api.CreateRestitutionAttr().Set(0.0)


def _mesh(stage, path: str, verts: np.ndarray, faces: np.ndarray):
    Gf, _, _, UsdGeom, _, _ = _pxr()
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr([Gf.Vec3f(*map(float, x)) for x in verts])
    mesh.CreateFaceVertexCountsAttr([3] * len(faces))
    mesh.CreateFaceVertexIndicesAttr([int(i) for i in np.asarray(faces).reshape(-1)])
    mesh.CreateSubdivisionSchemeAttr().Set("none")
    return mesh


def write_usd(obj: SimObject, folder: Path) -> list[Path]:
    """``object.usda`` in ``folder`` (module doc)."""
    _, _, Usd, UsdGeom, UsdPhysics, UsdShade = _pxr()
    path = Path(folder) / "object.usda"
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdPhysics.SetStageKilogramsPerUnit(stage, 1.0)
    root = UsdGeom.Xform.Define(stage, "/Object").GetPrim()
    stage.SetDefaultPrim(root)
    UsdPhysics.RigidBodyAPI.Apply(root)
    _set_mass(root, obj)
    _set_materials(stage, obj)
    for m in obj.meshes:
        UsdGeom.Xform.Define(stage, f"/Object/part_{m.part}")
        _mesh(stage, f"/Object/part_{m.part}/visual", m.vertices, m.faces)
        material = UsdShade.Material.Get(stage, f"/Object/Materials/part_{m.part}")
        for i, (v, f) in enumerate(m.collision):
            c = _mesh(stage, f"/Object/part_{m.part}/collision_{i}", v, f)
            c.CreatePurposeAttr().Set(UsdGeom.Tokens.guide)
            UsdPhysics.CollisionAPI.Apply(c.GetPrim())
            UsdPhysics.MeshCollisionAPI.Apply(c.GetPrim()).CreateApproximationAttr().Set("convexHull")
            UsdShade.MaterialBindingAPI.Apply(c.GetPrim()).Bind(
                material, UsdShade.Tokens.weakerThanDescendants, "physics")
    stage.GetRootLayer().Save()
    return [path]


def write_usd_sample(obj: SimObject, folder: Path, base: str) -> list[Path]:
    """A layer in ``folder`` referencing ``base`` (the object's ``object.usda``, relative to ``folder``) with this
    sample's mass and materials."""
    _, _, Usd, UsdGeom, UsdPhysics, _ = _pxr()
    path = Path(folder) / "object.usda"
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdPhysics.SetStageKilogramsPerUnit(stage, 1.0)
    root = stage.DefinePrim("/Object")
    root.GetReferences().AddReference(base)
    stage.SetDefaultPrim(root)
    _set_mass(root, obj)
    _set_materials(stage, obj)
    stage.GetRootLayer().Save()
    return [path]
