"""Mesh loader: round trips, refusals by the named check, and the reference cabins.

Every format round-trips, every bad input is refused by the named check, and the reference cabins load
with the dimensions their manifest documents. Bad files are built in ``tmp_path`` by each test;
nothing malformed is committed.
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
import math
import os
import struct
from pathlib import Path

import fcl
import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from planner.core.exceptions import InvalidInput, InvalidMesh, PlannerError
from planner.meshes import REFERENCE_DIR, generate
from planner.meshio import LoadedMesh, MeshLimits, load_mesh
from planner.meshio import build as mesh_build

MESH_DIR = REFERENCE_DIR
MANIFEST = json.loads((MESH_DIR / "cabins.json").read_text(encoding="utf-8"))

# A box 0.4 x 0.3 x 0.5 m centred at (0.1, 0.2, 0.3): corners known exactly (and exact in float32).
BOX_SIZE = np.array([0.4, 0.3, 0.5])
BOX_CENTER = np.array([0.1, 0.2, 0.3])
BOX_AREA = 2 * (0.4 * 0.3 + 0.3 * 0.5 + 0.4 * 0.5)


def box_mesh(size=BOX_SIZE, center=BOX_CENTER) -> trimesh.Trimesh:
    transform = np.eye(4)
    transform[:3, 3] = center
    return trimesh.creation.box(extents=size, transform=transform)


def box_corners(size=BOX_SIZE, center=BOX_CENTER) -> np.ndarray:
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    return center + signs * np.asarray(size) / 2


def sorted_rows(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a)
    return a[np.lexsort(a.T[::-1])]


# ----------------------------------------------------------------------------- independent file writers


def stl_binary(triangles: np.ndarray, declared: int | None = None) -> bytes:
    """Binary STL written by hand: 80-byte header, uint32 count, 50-byte records."""
    triangles = np.asarray(triangles, dtype="<f4").reshape(-1, 3, 3)
    n = len(triangles) if declared is None else declared
    out = bytearray(b"test".ljust(80, b" ") + struct.pack("<I", n))
    for tri in triangles:
        out += struct.pack("<3f", 0.0, 0.0, 0.0) + tri.tobytes() + b"\x00\x00"
    return bytes(out)


def stl_ascii(triangles: np.ndarray, tokens: dict[tuple[int, int, int], str] | None = None) -> bytes:
    """ASCII STL; ``tokens`` replaces coordinate (face, corner, axis) by a raw token such as 'nan'."""
    tokens = tokens or {}
    lines = ["solid test"]
    for f, tri in enumerate(np.asarray(triangles, dtype=float).reshape(-1, 3, 3)):
        lines += ["facet normal 0 0 0", "outer loop"]
        for c, corner in enumerate(tri):
            coords = [tokens.get((f, c, a), repr(float(corner[a]))) for a in range(3)]
            lines.append("vertex " + " ".join(coords))
        lines += ["endloop", "endfacet"]
    lines.append("endsolid test")
    return ("\n".join(lines) + "\n").encode()


def obj_text(vertices: np.ndarray, faces: list[list[int]]) -> bytes:
    """OBJ with 1-based indices as given (so tests can write invalid ones)."""
    lines = ["# test", "o part"]
    lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in np.asarray(vertices, dtype=float).tolist()]
    lines += ["f " + " ".join(str(i) for i in face) for face in faces]
    return ("\n".join(lines) + "\n").encode()


def ply_ascii(vertices: np.ndarray, faces: list[list[int]], declared_vertices: int | None = None) -> bytes:
    nv = len(vertices) if declared_vertices is None else declared_vertices
    head = [
        "ply",
        "format ascii 1.0",
        f"element vertex {nv}",
        "property float x",
        "property float y",
        "property float z",
        f"element face {len(faces)}",
        "property list uchar int vertex_indices",
        "end_header",
    ]
    body = [" ".join(repr(float(c)) for c in v) for v in vertices]
    body += [" ".join(str(i) for i in [len(f), *f]) for f in faces]
    return ("\n".join(head + body) + "\n").encode()


def export(mesh: trimesh.Trimesh | trimesh.Scene, file_type: str) -> bytes:
    if file_type == "gltf":
        return mesh.export(file_type="gltf", embed_buffers=True)["model.gltf"]
    data = mesh.export(file_type=file_type)
    return data.encode() if isinstance(data, str) else bytes(data)


def write(tmp_path: Path, name: str, data: bytes) -> Path:
    path = tmp_path / name
    path.write_bytes(data)
    return path


def refused(check: str, source, **kwargs) -> InvalidMesh:
    """Load and assert the refusal names ``check`` (in details and message) and the file."""
    kwargs.setdefault("units", "m")
    with pytest.raises(InvalidMesh) as info:
        load_mesh(source, **kwargs)
    err = info.value
    assert err.reason == "invalid_mesh"
    assert err.details["check"] == check, err.message
    assert f"'{check}'" in err.message
    assert err.details["file"] in err.message
    return err


def assert_is_box(mesh: LoadedMesh, size=BOX_SIZE, center=BOX_CENTER, atol=1e-6) -> None:
    assert mesh.report.n_faces == 12 and mesh.report.n_faces_read == 12
    assert mesh.report.n_vertices == 8
    np.testing.assert_allclose(sorted_rows(mesh.vertices), sorted_rows(box_corners(size, center)), atol=atol)
    np.testing.assert_allclose(
        mesh.bounds_m, [center - np.asarray(size) / 2, center + np.asarray(size) / 2], atol=atol
    )
    assert mesh.report.surface_area_m2 == pytest.approx(
        2 * (size[0] * size[1] + size[1] * size[2] + size[0] * size[2]), rel=1e-5
    )
    assert mesh.report.is_closed
    assert mesh.report.n_dropped_degenerate == 0


# ------------------------------------------------------------------------------------------ round trips

FORMATS = [
    ("stl", "stl", "stl-binary"),
    ("stl_ascii", "stl", "stl-ascii"),
    ("obj", "obj", "obj"),
    ("ply", "ply", "ply"),
    ("glb", "glb", "glb"),
    ("gltf", "gltf", "gltf"),
]


@pytest.mark.parametrize(("file_type", "ext", "kind"), FORMATS)
def test_each_format_round_trips_from_path_and_bytes(tmp_path, file_type, ext, kind):
    data = export(box_mesh(), file_type)
    path = write(tmp_path, f"box.{ext}", data)
    from_path = load_mesh(path, units="m")
    from_bytes = load_mesh(data, units="m", name=f"upload.{ext}")
    for mesh in (from_path, from_bytes):
        assert_is_box(mesh)
        assert mesh.report.format == kind
        assert mesh.sha256 == hashlib.sha256(data).hexdigest()
        assert mesh.report.byte_size == len(data)
        assert mesh.vertices.dtype == np.float64 and mesh.faces.dtype == np.int64
        assert not mesh.vertices.flags.writeable and not mesh.faces.flags.writeable
    assert from_path.name == f"box.{ext}" and from_bytes.name == f"upload.{ext}"
    np.testing.assert_array_equal(from_path.vertices, from_bytes.vertices)


def test_hand_written_stl_and_ply_ascii_round_trip(tmp_path):
    tri = box_mesh().triangles
    assert_is_box(load_mesh(write(tmp_path, "b.stl", stl_binary(tri)), units="m"))
    assert_is_box(load_mesh(write(tmp_path, "a.stl", stl_ascii(tri)), units="m"))
    box = box_mesh()
    assert_is_box(load_mesh(ply_ascii(box.vertices, box.faces.tolist()), units="m", name="a.ply"))


def test_file_type_overrides_the_name(tmp_path):
    data = export(box_mesh(), "stl")
    assert_is_box(load_mesh(data, units="m", name="upload", file_type=".STL"))


def test_obj_polygons_negative_and_slash_indices():
    # a unit square as one quad (1-based), then the same square with relative and v/vt/vn indices
    text = b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\nf -4/1/1 -3/2/1 -1/4/1\n"
    mesh = load_mesh(text, units="m", name="quad.obj")
    assert mesh.report.n_faces_read == 3 and mesh.report.n_faces == 3
    assert mesh.report.surface_area_m2 == pytest.approx(1.5)
    np.testing.assert_allclose(mesh.bounds_m, [[0, 0, 0], [1, 1, 0]])


def test_millimetres_are_converted_once_to_metres(tmp_path):
    data = export(box_mesh(BOX_SIZE * 1000, BOX_CENTER * 1000), "stl")
    mesh = load_mesh(write(tmp_path, "mm.stl", data), units="mm")
    assert_is_box(mesh)
    assert mesh.report.units == "mm" and mesh.units == "mm"
    np.testing.assert_allclose(mesh.report.extent_m, BOX_SIZE, atol=1e-6)


def test_pose_places_the_mesh_in_the_base_frame():
    angle = math.radians(90)
    T = np.eye(4)
    T[:3, :3] = [[math.cos(angle), 0, math.sin(angle)], [0, 1, 0], [-math.sin(angle), 0, math.cos(angle)]]
    T[:3, 3] = [1.0, -2.0, 3.0]
    mesh = load_mesh(export(box_mesh(), "ply"), units="m", name="p.ply", pose=T)
    expected = box_corners() @ T[:3, :3].T + T[:3, 3]
    np.testing.assert_allclose(sorted_rows(mesh.vertices), sorted_rows(expected), atol=1e-9)
    np.testing.assert_allclose(mesh.T_base_mesh, T)
    # The extent is measured in the mesh frame (before the pose); the bounds are in the base frame.
    np.testing.assert_allclose(mesh.report.extent_m, BOX_SIZE, atol=1e-9)
    np.testing.assert_allclose(mesh.bounds_m, [expected.min(axis=0), expected.max(axis=0)], atol=1e-9)
    # an independent route: the same pose applied to the trimesh copy of the unposed load
    plain = load_mesh(export(box_mesh(), "ply"), units="m", name="p.ply").to_trimesh().apply_transform(T)
    np.testing.assert_allclose(sorted_rows(plain.vertices), sorted_rows(mesh.vertices), atol=1e-9)


def test_vertex_merge_is_exact_even_when_every_hash_collides(monkeypatch):
    data = stl_binary(box_mesh().triangles)  # 36 corners, 8 distinct
    fast = load_mesh(data, units="m", name="box.stl")
    monkeypatch.setattr(mesh_build, "_mix64", lambda x: x & np.uint64(0))  # every key equal
    slow = load_mesh(data, units="m", name="box.stl")
    assert_is_box(fast)
    np.testing.assert_array_equal(fast.vertices, slow.vertices)
    np.testing.assert_array_equal(fast.faces, slow.faces)


def test_scene_parts_are_flattened_with_their_transforms():
    scene = trimesh.Scene()
    a = np.eye(4)
    a[:3, 3] = [2.0, 0.0, 0.0]
    b = trimesh.transformations.rotation_matrix(math.pi / 2, [0, 0, 1])
    b[:3, 3] = [-2.0, 1.0, 0.0]
    box = box_mesh(center=np.zeros(3))
    scene.add_geometry(box, node_name="a", geom_name="box", transform=a)
    scene.add_geometry(box, node_name="b", geom_name="box", transform=b)  # same geometry, instanced twice
    scene.add_geometry(trimesh.creation.icosphere(1, radius=0.1), node_name="c", geom_name="ball")
    mesh = load_mesh(export(scene, "glb"), units="m", name="scene.glb")
    assert mesh.report.n_parts == 3
    assert mesh.report.n_faces == 12 + 12 + 80
    expected = np.vstack(
        [box_corners(center=np.zeros(3)) + a[:3, 3], box_corners(center=np.zeros(3)) @ b[:3, :3].T + b[:3, 3]]
    )
    ours = np.asarray(mesh.vertices)
    for corner in expected:  # every transformed corner is a vertex of the flattened mesh
        assert np.min(np.linalg.norm(ours - corner, axis=1)) < 1e-6
    np.testing.assert_allclose(mesh.bounds_m[1], [2.2, 1.2, 0.25], atol=1e-6)
    np.testing.assert_allclose(mesh.bounds_m[0], [-2.15, -0.15, -0.25], atol=1e-6)


# ------------------------------------------------------------------------------------------ bad inputs


def test_empty_file_is_refused(tmp_path):
    refused("empty", write(tmp_path, "empty.stl", b""))
    refused("empty", b"", name="empty.obj")


@pytest.mark.parametrize(
    ("name", "data"),
    [
        ("v.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\n"),
        ("e.stl", b"solid nothing\nendsolid nothing\n"),
        (
            "e.ply",
            b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
            b"property float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n",
        ),
        ("b.stl", stl_binary(np.zeros((0, 3, 3)))),
    ],
)
def test_files_without_triangles_are_refused(name, data):
    refused("no_faces", data, name=name)


def test_glb_with_only_lines_has_no_faces():
    path = trimesh.load_path(np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0]]))
    scene = trimesh.Scene()
    scene.add_geometry(path, node_name="lines")
    err = refused("no_faces", export(scene, "glb"), name="lines.glb")
    assert err.details["n_ignored_parts"] == 1


@pytest.mark.parametrize(
    ("check", "name", "data"),
    [
        ("content", "garbage.stl", b"this is not a mesh at all\n" * 10),
        ("content", "garbage.glb", bytes(range(256))),
        ("content", "short.glb", b"glTF\x02\x00"),
        ("content", "version.glb", b"glTF" + struct.pack("<III", 1, 20, 0)),
        ("content", "length.glb", b"glTF" + struct.pack("<III", 2, 999, 0) + b"JSON"),
        ("parse", "json.glb", b"glTF" + struct.pack("<III", 2, 28, 8) + b"JSON" + b"{broken "),
        ("content", "broken.gltf", b"{ not json"),
        ("content", "notgltf.gltf", b'{"hello": 1}'),
        ("parse", "vertex.obj", b"v 1 2 x\nf 1 2 3\n"),
        ("parse", "index.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 three\n"),
        ("parse", "short.obj", b"v 0 0 0\nv 1 0 0\nf 1 2\n"),
        ("parse", "header.ply", b"ply\nformat ascii 1.0\nelement vertex 3\n"),
        ("parse", "format.ply", b"ply\nformat weird 1.0\nelement vertex 3\nend_header\n"),
        ("parse", "element.ply", b"ply\nformat ascii 1.0\nelement vertex lots\nend_header\n"),
        ("parse", "truncated.ply", export(box_mesh(), "ply")[:-40]),
        ("parse", "garbled.glb", export(box_mesh(), "glb").replace(b'"bufferView":1', b'"bufferView":7')),
    ],
)
def test_unreadable_or_garbled_content_is_refused(check, name, data):
    refused(check, data, name=name)


@pytest.mark.parametrize("fmt", ["ascii_stl", "binary_stl", "obj", "ply"])
@pytest.mark.parametrize("token", ["nan", "inf", "-inf"])
def test_non_finite_vertices_are_refused(fmt, token):
    tri = box_mesh().triangles
    value = float(token)
    if fmt == "ascii_stl":
        data, name = stl_ascii(tri, tokens={(3, 1, 2): token}), "n.stl"
    elif fmt == "binary_stl":
        bad = tri.copy()
        bad[3, 1, 2] = value
        data, name = stl_binary(bad), "n.stl"
    else:
        box = box_mesh()
        vertices = box.vertices.copy()
        vertices[5, 0] = value
        data, name = (
            (obj_text(vertices, (box.faces + 1).tolist()), "n.obj")
            if fmt == "obj"
            else (ply_ascii(vertices, box.faces.tolist()), "n.ply")
        )
    err = refused("non_finite", data, name=name)
    assert err.details["n_vertices_non_finite"] >= 1


def _sphere_with_degenerate_faces() -> tuple[np.ndarray, list[list[int]]]:
    """320-triangle icosphere plus one face of each degenerate kind (1-based OBJ indices)."""
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.5)
    vertices = np.vstack([sphere.vertices, [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 0.0, 0.0]]])
    n = len(sphere.vertices)
    faces = (sphere.faces + 1).tolist()
    faces += [[n + 1, n + 2, n + 3]]  # collinear: zero area
    faces += [[1, 1, 2]]  # repeated index
    faces += [[1, 2, n + 99]]  # out of range
    faces += [[0, 1, 2]]  # OBJ index 0 is invalid (1-based): out of range
    return vertices, faces


def test_degenerate_faces_are_dropped_and_counted(caplog):
    vertices, faces = _sphere_with_degenerate_faces()
    with caplog.at_level(logging.WARNING, logger="planner.meshio"):
        mesh = load_mesh(obj_text(vertices, faces), units="m", name="sphere.obj")
    r = mesh.report
    assert (r.n_faces_read, r.n_faces) == (324, 320)
    assert (r.n_dropped_zero_area, r.n_dropped_repeated_index, r.n_dropped_out_of_range) == (1, 1, 2)
    assert r.degenerate_fraction == pytest.approx(4 / 324)
    assert r.is_closed  # the sphere survives intact; the stray collinear vertices are gone
    assert r.n_vertices == 162
    assert np.all(np.abs(np.linalg.norm(mesh.vertices, axis=1) - 0.5) < 1e-9)
    assert "dropped 4 degenerate faces" in caplog.text


def test_out_of_range_indices_from_the_trimesh_path_are_dropped():
    vertices, faces = _sphere_with_degenerate_faces()
    zero_based = [[i - 1 for i in f] for f in faces[:-1]]  # PLY is 0-based; -1 stays invalid
    zero_based.append([0, 1, -1])
    mesh = load_mesh(ply_ascii(vertices, zero_based), units="m", name="sphere.ply")
    r = mesh.report
    assert (r.n_faces, r.n_dropped_zero_area, r.n_dropped_repeated_index, r.n_dropped_out_of_range) == (
        320,
        1,
        1,
        2,
    )


def test_too_many_degenerate_faces_are_refused():
    box = box_mesh()
    faces = (box.faces + 1).tolist() + [[1, 1, 2], [1, 2, 99]]  # 2 of 14 = 14 % > 10 %
    data = obj_text(box.vertices, faces)
    err = refused("degenerate_faces", data, name="box.obj")
    assert err.details["degenerate_fraction"] == pytest.approx(2 / 14)
    assert err.details["n_dropped_repeated_index"] == 1 and err.details["n_dropped_out_of_range"] == 1
    # the fraction is configurable
    mesh = load_mesh(data, units="m", name="box.obj", limits=MeshLimits(max_degenerate_fraction=0.2))
    assert (mesh.report.n_faces_read, mesh.report.n_faces, mesh.report.n_dropped_degenerate) == (14, 12, 2)
    np.testing.assert_allclose(sorted_rows(mesh.vertices), sorted_rows(box_corners()), atol=1e-12)
    assert mesh.report.is_closed


def test_all_faces_degenerate_is_refused_even_with_a_permissive_fraction():
    data = stl_ascii(np.array([[[0, 0, 0], [1, 0, 0], [2, 0, 0]]]))
    refused("degenerate_faces", data, name="line.stl", limits=MeshLimits(max_degenerate_fraction=1.0))


@pytest.mark.parametrize(("file_type", "ext", "kind"), FORMATS)
def test_face_cap_is_enforced_for_every_format(file_type, ext, kind):
    err = refused(
        "face_count", export(box_mesh(), file_type), name=f"box.{ext}", limits=MeshLimits(max_faces=11)
    )
    assert err.details["max_faces"] == 11


def _forbid_parsing(monkeypatch):
    def boom(*args, **kwargs):
        raise AssertionError("the parser must not run")

    monkeypatch.setattr(trimesh, "load_scene", boom)


def test_binary_stl_header_count_is_capped_before_parsing(monkeypatch):
    _forbid_parsing(monkeypatch)
    # 3 million faces declared, body for one: refused on the cap, nothing allocated
    data = stl_binary(box_mesh().triangles[:1], declared=3_000_000)
    err = refused("face_count", data, name="huge.stl")
    assert err.details["n_faces"] == 3_000_000
    # a consistent file over a small cap is also refused before parsing
    refused("face_count", stl_binary(box_mesh().triangles), name="box.stl", limits=MeshLimits(max_faces=5))


@pytest.mark.parametrize("delta", [-10, -50, +1, +49])
def test_binary_stl_length_must_equal_84_plus_50n(monkeypatch, delta):
    _forbid_parsing(monkeypatch)
    data = stl_binary(box_mesh().triangles)
    bad = data[:delta] if delta < 0 else data + b"\x00" * delta
    err = refused("stl_length", bad, name="cut.stl")
    assert err.details["expected_bytes"] == 84 + 50 * 12
    assert err.details["byte_size"] == len(bad)


def test_byte_cap_is_checked_before_reading_or_parsing(tmp_path, monkeypatch):
    _forbid_parsing(monkeypatch)
    limits = MeshLimits(max_bytes=100)
    junk = b"\xff" * 101  # would fail the content check if it were looked at
    err = refused("byte_size", junk, name="big.stl", limits=limits)
    assert err.details["max_bytes"] == 100
    path = write(tmp_path, "big.stl", junk)
    monkeypatch.setattr(Path, "open", lambda *a, **k: pytest.fail("the file must not be opened"))
    refused("byte_size", path, limits=limits)


def test_a_file_that_grows_after_its_size_was_read_is_read_whole_and_capped(tmp_path, monkeypatch):
    """A file read asks for the size its stat gave, plus one byte to see growth.

    A grown file is read on (never cut at its old size), and refused once it passes the cap.
    """
    from planner.meshio.sniff import read_bytes

    data = export(box_mesh(), "stl")
    path = write(tmp_path, "box.stl", data)
    real_stat = Path.stat

    def stale(self, *a, **k):  # the stat of the file before it grew by 100 bytes
        st = real_stat(self, *a, **k)
        return os.stat_result((*st[:6], st.st_size - 100, *st[7:]))

    assert read_bytes("box.stl", path, MeshLimits()) == data
    monkeypatch.setattr(Path, "stat", stale)
    assert read_bytes("box.stl", path, MeshLimits()) == data
    err = refused("byte_size", path, limits=MeshLimits(max_bytes=len(data) - 1))
    assert err.details["max_bytes"] == len(data) - 1


def test_header_vertex_counts_are_capped_before_parsing(monkeypatch):
    _forbid_parsing(monkeypatch)
    box = box_mesh()
    refused(
        "vertex_count", ply_ascii(box.vertices, box.faces.tolist(), declared_vertices=10**9), name="v.ply"
    )
    # a glTF accessor with no buffer view and a huge count would make trimesh allocate gigabytes
    doc = json.loads(export(box, "gltf"))
    doc["accessors"][1] = {"componentType": 5126, "type": "VEC3", "count": 300_000_000}
    refused("vertex_count", json.dumps(doc).encode(), name="alloc.gltf")


def test_gltf_must_not_reference_outside_files(monkeypatch):
    _forbid_parsing(monkeypatch)
    doc = json.loads(export(box_mesh(), "gltf"))
    doc["buffers"][0]["uri"] = "../../secret.bin"
    err = refused("external_resource", json.dumps(doc).encode(), name="ext.gltf")
    assert err.details["buffer"] == 0


@pytest.mark.parametrize("name", ["mesh.txt", "model.3mf", "noextension", "box.stl.zip"])
def test_unsupported_extensions_are_refused(tmp_path, name):
    data = export(box_mesh(), "stl")
    err = refused("format", write(tmp_path, name, data))
    assert "stl" in err.details["supported"]
    refused("format", data, name=name)


def test_bytes_need_a_name_or_file_type():
    refused("name", export(box_mesh(), "stl"))


@pytest.mark.parametrize(
    ("source_type", "name", "looks_like"),
    [
        ("ply", "box.stl", "PLY"),
        ("glb", "box.stl", "GLB"),
        ("stl", "box.obj", "binary STL"),
        ("obj", "box.glb", "text"),
        ("stl_ascii", "box.ply", "ASCII STL"),
        ("glb", "box.ply", "GLB"),
        ("stl_ascii", "box.gltf", "ASCII STL"),
        ("gltf", "box.stl", "glTF JSON"),
        ("stl_ascii", "box.obj", "ASCII STL"),
    ],
)
def test_content_must_match_the_extension(source_type, name, looks_like):
    err = refused("content", export(box_mesh(), source_type), name=name)
    assert err.details["looks_like"] == looks_like
    assert looks_like in err.message


def test_metre_file_declared_as_mm_or_the_reverse_is_refused_with_a_hint():
    cabin_in_mm = export(box_mesh([2400.0, 1800.0, 6000.0], [0.0, 600.0, 3000.0]), "stl")
    err = refused("scale", cabin_in_mm, name="cabin.stl", units="m")
    assert "did you mean mm?" in err.message
    assert err.details["extent_m"] == pytest.approx(6000.0)
    payload_in_m = export(box_mesh([0.45, 0.35, 0.5], [0.0, 0.0, 0.0]), "stl")
    err = refused("scale", payload_in_m, name="payload.stl", units="mm")
    assert "did you mean m?" in err.message
    # the right units load, and the bounds are part of MeshLimits
    assert load_mesh(cabin_in_mm, units="mm", name="cabin.stl").report.extent_m[2] == pytest.approx(6.0)
    refused("scale", cabin_in_mm, name="cabin.stl", units="mm", limits=MeshLimits(max_extent_m=5.0))
    refused("scale", payload_in_m, name="payload.stl", limits=MeshLimits(min_extent_m=0.6))


def test_far_out_of_range_sizes_get_no_misleading_hint():
    huge = export(box_mesh([1e7, 1.0, 1.0], [0.0, 0.0, 0.0]), "ply")
    err = refused("scale", huge, name="huge.ply", units="mm")
    assert "did you mean" not in err.message


@pytest.mark.parametrize(
    "pose",
    [
        np.eye(3),
        np.diag([2.0, 1.0, 1.0, 1.0]),  # scaling is not rigid
        np.diag([-1.0, 1.0, 1.0, 1.0]),  # a reflection is not a rotation
        np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1.0]]),
        np.full((4, 4), np.nan),
        "not a matrix",
    ],
)
def test_bad_pose_is_refused(pose):
    refused("pose", export(box_mesh(), "stl"), name="box.stl", pose=pose)


def test_bad_units_are_refused():
    refused("units", export(box_mesh(), "stl"), name="box.stl", units="cm")


def test_missing_file_and_directory_are_refused(tmp_path):
    refused("read", tmp_path / "missing.stl")
    (tmp_path / "dir.stl").mkdir()
    refused("read", tmp_path / "dir.stl")


def test_mesh_limits_are_validated():
    for bad in (
        {"max_faces": 0},
        {"max_bytes": -1},
        {"max_vertices": 1.5},
        {"max_degenerate_fraction": 1.5},
        {"min_face_area_m2": -1.0},
        {"min_extent_m": 10.0, "max_extent_m": 1.0},
    ):
        with pytest.raises(InvalidInput):
            MeshLimits(**bad)


_SEEDS = {
    "stl": export(box_mesh(), "stl"),
    "stl_ascii": stl_ascii(box_mesh().triangles),
    "obj": export(box_mesh(), "obj"),
    "ply": export(box_mesh(), "ply"),
    "glb": export(box_mesh(), "glb"),
}
_EXT = {"stl": "stl", "stl_ascii": "stl", "obj": "obj", "ply": "ply", "glb": "glb"}


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.sampled_from(sorted(_SEEDS)),
    edits=st.lists(
        st.tuples(st.floats(0, 1, exclude_max=True), st.binary(max_size=8)), min_size=1, max_size=4
    ),
    cut=st.floats(0.0, 1.0),
)
def test_mutated_files_load_validly_or_raise_invalid_mesh_only(seed, edits, cut):
    data = bytearray(_SEEDS[seed])
    for where, chunk in edits:
        i = int(where * len(data))
        data[i : i + len(chunk)] = chunk
    data = data[: max(1, int(cut * len(data)))] if cut < 0.2 else data
    try:
        mesh = load_mesh(bytes(data), units="m", name=f"fuzz.{_EXT[seed]}")
    except InvalidMesh as err:
        assert err.details["check"]
        return
    assert np.isfinite(mesh.vertices).all()
    assert mesh.faces.min() >= 0 and mesh.faces.max() < len(mesh.vertices)
    assert mesh.report.n_faces >= 1 and mesh.report.n_faces + mesh.report.n_dropped_degenerate == (
        mesh.report.n_faces_read
    )


def test_invalid_mesh_belongs_to_the_planner_exception_tree():
    err = refused("empty", b"", name="e.stl")
    assert isinstance(err, PlannerError)
    assert err.to_dict()["reason"] == "invalid_mesh"
    json.dumps(err.to_dict())  # details are JSON-serialisable for the HTTP problem body


# ------------------------------------------------------------------------------------- reference cabins

CABINS = {c["name"]: c for c in MANIFEST["cabins"]}


def _bvh(mesh: LoadedMesh) -> fcl.CollisionObject:
    model = fcl.BVHModel()
    model.beginModel(len(mesh.vertices), len(mesh.faces))
    model.addSubModel(np.asarray(mesh.vertices), np.asarray(mesh.faces, dtype=np.int32))
    model.endModel()
    return fcl.CollisionObject(model, fcl.Transform())


def _distance_to_box(cabin: fcl.CollisionObject, size, center) -> float:
    other = fcl.CollisionObject(fcl.Box(*size), fcl.Transform(np.asarray(center, dtype=float)))
    return fcl.distance(cabin, other, fcl.DistanceRequest(), fcl.DistanceResult())


@pytest.fixture(scope="module")
def cabins() -> dict[str, LoadedMesh]:
    return {name: load_mesh(MESH_DIR / c["files"]["stl"], units="m") for name, c in CABINS.items()}


def test_manifest_lists_the_four_reference_cabins():
    assert {"cabin-aisle", "cabin-hatch", "cabin-cluttered", "cabin-tightbay"} <= set(CABINS)
    assert any("glb" in c["files"] for c in CABINS.values())


@pytest.mark.parametrize("name", sorted(CABINS))
def test_reference_cabin_loads_with_its_documented_bounds(cabins, name):
    entry, mesh = CABINS[name], cabins[name]
    path = MESH_DIR / entry["files"]["stl"]
    assert mesh.sha256 == entry["sha256"]["stl"], "the STL differs from the manifest: regenerate"
    assert path.stat().st_size < 5_000_000
    assert mesh.report.format == "stl-binary"
    assert mesh.report.n_faces == entry["n_faces"] <= 100_000
    assert mesh.report.n_dropped_degenerate == 0
    np.testing.assert_allclose(mesh.bounds_m, [entry["bounds_m"]["min"], entry["bounds_m"]["max"]], atol=1e-5)
    shell = entry["shell"]
    r_out = shell["inner_radius_m"] + shell["wall_m"]
    np.testing.assert_allclose(mesh.bounds_m[:, 0], [-r_out, r_out], atol=1e-5)
    np.testing.assert_allclose(
        mesh.bounds_m[:, 1], [shell["axis_m"][1] - r_out, shell["axis_m"][1] + r_out], atol=1e-5
    )
    np.testing.assert_allclose(mesh.bounds_m[:, 2], shell["z_range_m"], atol=1e-5)
    # the cabin section covers the whole rail
    rail = MANIFEST["carriage"]["rail_z_range_m"]
    assert shell["z_range_m"][0] < rail[0] and shell["z_range_m"][1] > rail[1]


def test_glb_cabin_matches_its_stl_twin(cabins):
    ((name, entry),) = [(n, c) for n, c in CABINS.items() if "glb" in c["files"]]
    glb = load_mesh(MESH_DIR / entry["files"]["glb"], units="m")
    stl = cabins[name]
    assert glb.sha256 == entry["sha256"]["glb"]
    assert glb.report.format == "glb" and glb.report.n_parts > 1  # exercised the scene-graph transforms
    assert glb.report.n_faces == stl.report.n_faces
    np.testing.assert_allclose(glb.bounds_m, stl.bounds_m, atol=1e-5)
    assert glb.report.surface_area_m2 == pytest.approx(stl.report.surface_area_m2, rel=1e-6)


def test_generator_is_deterministic_and_the_committed_files_are_current(tmp_path):
    manifest = generate.generate(tmp_path)
    assert manifest == MANIFEST
    for entry in manifest["cabins"]:
        for file_name in entry["files"].values():
            assert (tmp_path / file_name).read_bytes() == (MESH_DIR / file_name).read_bytes(), file_name


@pytest.mark.parametrize("name", sorted(CABINS))
def test_carriage_clears_every_cabin_along_the_whole_rail(cabins, name):
    cabin = _bvh(cabins[name])
    size = MANIFEST["carriage"]["size_m"]
    center_y = MANIFEST["carriage"]["center_m"][1]
    clearances = [_distance_to_box(cabin, size, (0.0, center_y, d1)) for d1 in np.linspace(0.0, 6.0, 25)]
    assert min(clearances) >= 0.03
    # and the free cross-section at the carriage's underside is wider than the carriage with margin
    assert CABINS[name]["shell"]["free_width_at_carriage_bottom_m"] >= size[0] + 0.2


@pytest.mark.parametrize("name", sorted(CABINS))
def test_payload_fits_every_bay_with_the_documented_clearance(cabins, name):
    cabin = _bvh(cabins[name])
    sx, sy, sz = MANIFEST["payload_reference_size_m"]
    for bay in CABINS[name]["bays"]:
        center = np.array(bay["center_m"])
        clearance = bay["payload_clearance_per_side_m"]
        expected = min(clearance["z"], clearance["y"], clearance["x_back"] / 2)
        # payload 0.50 along the insertion axis x, 0.35 vertical, 0.45 along the cabin axis
        assert _distance_to_box(cabin, (sz, sy, sx), center) == pytest.approx(expected, abs=2e-4)
        # bays sit where the robot reaches: x in [0.6, 1.2], y in [0.4, 1.1], inside the shell
        assert 0.6 <= center[0] <= 1.2 and 0.4 <= center[1] <= 1.1
        axis = CABINS[name]["shell"]["axis_m"]
        assert math.hypot(center[0] + bay["depth_m"] / 2, center[1] - axis[1]) < 1.25


def test_tight_bay_leaves_10_to_15_mm_per_side(cabins):
    bays = CABINS["cabin-tightbay"]["bays"]
    tight = [b for b in bays if b["payload_clearance_per_side_m"]["z"] < 0.02]
    assert len(tight) == 1
    c = tight[0]["payload_clearance_per_side_m"]
    assert 0.010 <= c["z"] <= 0.015 and 0.010 <= c["y"] <= 0.015
    cabin = _bvh(cabins["cabin-tightbay"])
    sx, sy, sz = MANIFEST["payload_reference_size_m"]
    center = np.array(tight[0]["center_m"])
    # 10 mm off-centre sideways still fits; 20 mm does not
    assert _distance_to_box(cabin, (sz, sy, sx), center + [0, 0, 0.010]) > 0.002
    assert _distance_to_box(cabin, (sz, sy, sx), center + [0, 0, 0.020]) <= 0.0


def test_hatch_opening_passes_the_carriage_and_not_much_more(cabins):
    entry = CABINS["cabin-hatch"]
    cabin = _bvh(cabins["cabin-hatch"])
    z0, z1 = entry["bulkhead"]["z_range_m"]
    size = MANIFEST["carriage"]["size_m"]
    center_y = MANIFEST["carriage"]["center_m"][1]
    # the carriage crosses the bulkhead with >= 30 mm (sides: 50 mm)
    for d1 in np.linspace(z0 - 0.3, z1 + 0.3, 7):
        assert _distance_to_box(cabin, size, (0.0, center_y, d1)) >= 0.03
    steps = entry["bulkhead"]["opening_steps"]
    assert [s["name"] for s in steps] == ["carriage", "stage", "arm"]
    assert steps[0]["width_m"] >= size[0] + 0.05
    for lower, upper in zip(steps, steps[1:], strict=False):
        assert lower["y_range_m"][1] == pytest.approx(upper["y_range_m"][0])
        assert upper["width_m"] < lower["width_m"]
    zc = (z0 + z1) / 2
    for step in steps:
        (x0, x1), (y0, y1) = step["x_range_m"], step["y_range_m"]
        centre = ((x0 + x1) / 2, (y0 + y1) / 2, zc)
        # each step is exactly as documented: 2 mm narrower fits, 2 cm wider hits the bulkhead
        assert _distance_to_box(cabin, (x1 - x0 - 0.002, y1 - y0 - 0.002, 0.3), centre) > 0.0
        assert _distance_to_box(cabin, (x1 - x0 + 0.02, y1 - y0 - 0.002, 0.3), centre) <= 0.0
    # the bulkhead closes the cabin everywhere else: a box above the opening collides
    assert _distance_to_box(cabin, (0.2, 0.2, 0.3), (0.0, steps[-1]["y_range_m"][1] + 0.15, zc)) <= 0.0


def test_cluttered_cabin_obstacles_sit_inside_the_shell(cabins):
    entry = CABINS["cabin-cluttered"]
    axis_y = entry["shell"]["axis_m"][1]
    radius = entry["shell"]["inner_radius_m"]
    assert len(entry["ducts"]) >= 3 and len(entry["brackets"]) >= 6
    cabin = _bvh(cabins["cabin-cluttered"])
    for duct in entry["ducts"]:
        x, y = duct["center_xy_m"]
        assert math.hypot(x, y - axis_y) + duct["radius_m"] < radius  # free-hanging, not in the wall
        # the duct is solid geometry: a probe at its centre line touches the mesh surface around it
        probe = _distance_to_box(cabin, (0.01, 0.01, 0.01), (x, y, 3.0))
        assert probe == pytest.approx(duct["radius_m"] - 0.005, abs=0.01)
    for bracket in entry["brackets"]:
        lo, hi = np.array(bracket["min_m"]), np.array(bracket["max_m"])
        size, center = hi - lo, 0.5 * (hi + lo)
        inward = -np.sign(center[0])  # towards the cabin axis
        face_x = lo[0] if inward < 0 else hi[0]  # the bracket's exposed face
        # a thin probe straddling the exposed face touches the bracket (FCL sees surfaces, not volumes)
        probe = (0.02, size[1] / 2, size[2] / 2)
        assert _distance_to_box(cabin, probe, (face_x, center[1], center[2])) <= 0.0
        # 30 mm further in, the probe is 20 mm clear of it
        clear = _distance_to_box(cabin, probe, (face_x + inward * 0.03, center[1], center[2]))
        assert clear == pytest.approx(0.02, abs=1e-3)


def test_reference_cabin_loads_from_bytes_like_an_upload(cabins):
    entry = CABINS["cabin-aisle"]
    data = (MESH_DIR / entry["files"]["stl"]).read_bytes()
    mesh = load_mesh(io.BytesIO(data).getvalue(), units="m", name=entry["files"]["stl"])
    np.testing.assert_array_equal(mesh.vertices, cabins["cabin-aisle"].vertices)
