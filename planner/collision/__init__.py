"""Collision world: cabin, payload and robot geometry.

The mesh layer (:mod:`planner.meshio.load`) turns STL/OBJ/PLY/GLB/glTF files into validated
triangle meshes in metres, in the robot base frame.
"""

from planner.meshio import (
    SUPPORTED_EXTENSIONS,
    LoadedMesh,
    MeshLimits,
    MeshReport,
    Units,
    load_mesh,
)

__all__ = ["SUPPORTED_EXTENSIONS", "LoadedMesh", "MeshLimits", "MeshReport", "Units", "load_mesh"]
