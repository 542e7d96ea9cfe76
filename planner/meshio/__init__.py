"""Mesh file I/O: STL/OBJ/PLY/GLB/glTF files into validated triangle meshes in metres, in the base frame.

:func:`load_mesh` (:mod:`.load`) reads (:mod:`.sniff`), parses (:mod:`.parse`) and validates
(:mod:`.build`) one file into a :class:`LoadedMesh`; the values are in :mod:`.types`.
"""

from planner.meshio.load import load_mesh
from planner.meshio.types import SUPPORTED_EXTENSIONS, LoadedMesh, MeshLimits, MeshReport, Units

__all__ = ["SUPPORTED_EXTENSIONS", "LoadedMesh", "MeshLimits", "MeshReport", "Units", "load_mesh"]
