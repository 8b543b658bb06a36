"""What the simulator files are written from: one rigid object, its parts' meshes and materials."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from .body import MassProperties
from .mesh import PartMesh

__all__ = ["PartMaterial", "SimObject"]


@dataclass(frozen=True)
class PartMaterial:
    """A part's physical material as a simulator reads it."""

    name: str
    """the part's dominant material (the library's name)"""
    friction: float
    """kinetic (dynamic) friction coefficient, the fused posterior's (dimensionless)"""
    density: float
    """the part's mass over the volume that weighs (the wall's where it is hollow), kg/m^3"""
    color: tuple[int, int, int] = (180, 180, 180)
    """the material's legend colour (RGB 0-255), for the visual meshes"""


@dataclass
class SimObject:
    name: str
    body: MassProperties
    meshes: list[PartMesh]
    materials: dict[int, PartMaterial]
    """part id -> its material"""
    mesh_dir: str = "meshes"
    """the meshes' folder relative to the file being written"""
    collision_method: str = "hull"
    extra: dict = field(default_factory=dict)

    def mesh_file(self, part: int, piece: int | None = None) -> str:
        """A part's visual mesh (``piece`` None) or collision piece file, relative to ``mesh_dir``."""
        return f"part_{part}.obj" if piece is None else f"part_{part}_collision_{piece}.obj"

    def variant(self, body: MassProperties, materials: dict[int, PartMaterial], mesh_dir: str) -> SimObject:
        """The same meshes with another body and materials (a posterior sample)."""
        return replace(self, body=body, materials=materials, mesh_dir=mesh_dir)
