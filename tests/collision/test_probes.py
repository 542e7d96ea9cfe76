"""The exact-distance probes' own geometry."""

from __future__ import annotations

import numpy as np
import trimesh

from planner.collision.probes import box_mesh


def test_box_mesh_is_trimesh_s_box_vertex_for_vertex_and_closed_outward() -> None:
    rng = np.random.default_rng(4)
    for size in [(1.0, 2.0, 3.0), (0.05, 0.6, 0.2), *(tuple(rng.uniform(0.01, 2.0, 3)) for _ in range(20))]:
        vertices, faces = box_mesh(size)  # type: ignore[arg-type]
        ref = trimesh.creation.box(extents=size)
        assert np.array_equal(vertices, np.asarray(ref.vertices))
        assert np.array_equal(faces, np.asarray(ref.faces))
        mesh = trimesh.Trimesh(vertices, faces, process=False)
        assert mesh.is_watertight and mesh.is_winding_consistent
        assert np.isclose(mesh.volume, np.prod(size), rtol=1e-12)  # positive: the normals point outward
