"""Mesh file I/O: STL/OBJ/PLY/GLB/glTF files into validated triangle meshes in metres, in the base frame."""
