"""Parsing mesh bytes into (vertices, faces) parts: trimesh for STL/PLY/GLB/glTF, our own strict OBJ parser.

trimesh loads with ``process=False`` so it neither merges nor drops anything; OBJ has a small strict
parser of its own (trimesh silently remaps the invalid OBJ index ``0`` to the last vertex and crashes on
out-of-range indices, which would make the counts dishonest). A multi-part scene is flattened with its
scene-graph transforms; faces with an index outside their part are kept as rows of -1, to be counted and
dropped by :mod:`planner.meshio.build`.
"""

from __future__ import annotations

import io
import warnings
from array import array

import numpy as np

from planner.core.exceptions import InvalidMesh
from planner.core.types import Array, IntArray
from planner.meshio.types import MeshLimits, error, fail


def parse_obj(label: str, data: bytes, limits: MeshLimits) -> tuple[Array, IntArray]:
    """Strict Wavefront OBJ geometry parser: ``v`` and ``f`` statements, everything else ignored.

    Polygons are split into a triangle fan (exact for the convex planar polygons exporters write).
    Positive indices are 1-based; negative ones count back from the latest vertex. Invalid indices
    (0, or outside the vertex list) are kept as -1 so the face is counted and dropped as out-of-range.
    """
    text = data.decode("utf-8", errors="replace")
    coords = array("d")
    tris = array("q")
    n_v = 0
    for lineno, line in enumerate(text.splitlines(), start=1):
        words = line.split()
        if not words:
            continue
        key = words[0]
        if key == "v":
            try:
                x, y, z = float(words[1]), float(words[2]), float(words[3])
            except (IndexError, ValueError):
                raise error(
                    label, "parse", f"line {lineno}: malformed vertex {line.strip()[:80]!r}", line=lineno
                ) from None
            coords.extend((x, y, z))
            n_v += 1
            if n_v > limits.max_vertices:
                raise error(
                    label,
                    "vertex_count",
                    f"more than {limits.max_vertices} vertices",
                    max_vertices=limits.max_vertices,
                )
        elif key == "f":
            idx: list[int] = []
            for token in words[1:]:
                try:
                    k = int(token.split("/", 1)[0])
                except ValueError:
                    raise error(
                        label, "parse", f"line {lineno}: malformed face index {token[:40]!r}", line=lineno
                    ) from None
                idx.append(k - 1 if k > 0 else (n_v + k if k < 0 else -1))
            if len(idx) < 3:
                raise error(label, "parse", f"line {lineno}: a face needs at least 3 vertices", line=lineno)
            for i in range(1, len(idx) - 1):
                tris.extend((idx[0], idx[i], idx[i + 1]))
            if len(tris) > 3 * limits.max_faces:
                fail(
                    label, "face_count", f"more than {limits.max_faces} triangles", max_faces=limits.max_faces
                )
    vertices = np.frombuffer(coords, dtype=np.float64).reshape(-1, 3).copy()
    faces = np.frombuffer(tris, dtype=np.int64).reshape(-1, 3).copy()
    return vertices, faces


def parse_with_trimesh(
    label: str, fmt: str, data: bytes, limits: MeshLimits
) -> tuple[list[tuple[Array, IntArray]], int]:
    """Parse with trimesh and flatten the scene graph: one (vertices, faces) per geometry instance."""
    import trimesh  # imported on first parse only (0.2-1 s); a cached parse needs none (planner.meshio.load)

    try:
        # Bad numbers (inf, nan) are found and refused below with the file's name; trimesh's own numpy
        # warnings about them would only add lines to a one-line error.
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            scene = trimesh.load_scene(io.BytesIO(data), file_type=fmt, process=False)
        instances = []
        n_ignored = 0
        n_faces = 0
        for node in scene.graph.nodes_geometry:
            transform, geometry_name = scene.graph[node]
            geometry = scene.geometry[geometry_name]
            if not isinstance(geometry, trimesh.Trimesh):
                n_ignored += 1
                continue
            n_faces += len(geometry.faces)
            if n_faces > limits.max_faces:  # checked before any instance is copied
                fail(
                    label,
                    "face_count",
                    f"the scene instantiates more than {limits.max_faces} triangles",
                    max_faces=limits.max_faces,
                )
            instances.append((np.asarray(transform, dtype=np.float64), geometry))
        parts: list[tuple[Array, IntArray]] = []
        n_vertices = 0
        for transform, geometry in instances:
            vertices = np.asarray(geometry.vertices, dtype=np.float64)
            faces = np.asarray(geometry.faces, dtype=np.int64).reshape(-1, 3)
            if vertices.ndim != 2 or vertices.shape[1] != 3:
                fail(label, "parse", f"vertex array of shape {vertices.shape}")
            n_vertices += len(vertices)
            if n_vertices > limits.max_vertices:
                fail(
                    label,
                    "vertex_count",
                    f"the scene holds more than {limits.max_vertices} vertices",
                    max_vertices=limits.max_vertices,
                )
            with np.errstate(all="ignore"):
                vertices = vertices @ transform[:3, :3].T + transform[:3, 3]
            parts.append((vertices, faces))
    except InvalidMesh:
        raise
    except Exception as exc:  # trimesh raises anything (ValueError, IndexError, KeyError, struct.error...)
        raise error(
            label,
            "parse",
            f"{fmt.upper()} parser failed: {type(exc).__name__}: {str(exc)[:200]}",
            error=type(exc).__name__,
        ) from exc
    return parts, n_ignored


def concatenate(parts: list[tuple[Array, IntArray]]) -> tuple[Array, IntArray, int]:
    """Stack parts; faces with an index outside their own part become rows of -1."""
    all_v: list[Array] = []
    all_f: list[IntArray] = []
    offset = 0
    for vertices, faces in parts:
        bad = ((faces < 0) | (faces >= len(vertices))).any(axis=1)
        shifted = faces + offset
        shifted[bad] = -1
        all_v.append(vertices)
        all_f.append(shifted)
        offset += len(vertices)
    vertices = np.concatenate(all_v) if all_v else np.zeros((0, 3))
    faces = np.concatenate(all_f) if all_f else np.zeros((0, 3), dtype=np.int64)
    return vertices, faces, len(faces)
