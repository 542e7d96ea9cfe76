"""Load cabin and payload meshes (STL, OBJ, PLY, GLB/glTF) into validated triangle soups in metres.

This is the I/O edge of the collision world: everything behind it works on :class:`LoadedMesh` values
whose vertices are finite, in metres, expressed in the robot base frame, and whose faces all index
existing vertices and span a non-zero area.

The pipeline of :func:`load_mesh` is, in order:

1. validate the caller's ``units`` and ``pose`` (a rigid 4x4 transform ``T_base_mesh``);
2. read the bytes, refusing anything above ``MeshLimits.max_bytes`` *before* the file is read or parsed;
3. pick the format from the extension and check that the content really is that format (magic bytes,
   binary-STL length ``84 + 50 n``, PLY/GLB headers, glTF JSON); header face and vertex counts are
   checked against the caps here, still before parsing;
4. parse: STL, PLY and GLB/glTF with trimesh (``process=False`` so it neither merges nor drops
   anything), OBJ with a small strict parser of our own (trimesh silently remaps the invalid OBJ index
   ``0`` to the last vertex and crashes on out-of-range indices, which would make the counts dishonest);
   a multi-part scene is flattened with its scene-graph transforms;
5. convert to metres (once) and validate: finite vertices, plausible size for the declared units, and
   degenerate faces (out-of-range indices, repeated indices, zero area) dropped and counted -- refused
   when they are more than ``MeshLimits.max_degenerate_fraction`` of the faces read;
6. drop unreferenced vertices, merge bit-identical ones (faces are unchanged), apply the pose.

Any failure raises :class:`~planner.exceptions.InvalidMesh` whose message names the file and the check
and whose ``details`` carry ``file``, ``check`` and the measured values; no other exception type leaves
this module. Meshes are treated as triangle shells: they need not be closed (the report says whether
they are).
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
import math
import os
import stat
import struct
import threading
import warnings
from array import array
from collections import OrderedDict
from collections.abc import Hashable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal, NoReturn, get_args

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

from planner.exceptions import InvalidInput, InvalidMesh

_LOG = logging.getLogger(__name__)

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]

Units = Literal["m", "mm"]
#: Metres per declared unit.
UNIT_SCALE_M: Mapping[str, float] = {"m": 1.0, "mm": 1e-3}

#: File extensions (lower case, no dot) that :func:`load_mesh` accepts.
SUPPORTED_EXTENSIONS: tuple[str, ...] = ("stl", "obj", "ply", "glb", "gltf")

MeshSource = str | os.PathLike[str] | bytes | bytearray | memoryview

_STL_HEADER_BYTES = 84
_STL_RECORD_BYTES = 50
_PLY_MAX_HEADER_BYTES = 1 << 20
_GLB_MAGIC = b"glTF"
_POSE_TOL = 1e-6


@dataclass(frozen=True)
class MeshLimits:
    """Caps and plausibility bounds applied by :func:`load_mesh`.

    Attributes:
        max_bytes: Largest accepted file size [bytes] (checked before the file is read or parsed).
        max_faces: Largest accepted triangle count (header counts are checked before parsing; polygons
            count as the triangles they split into; instanced scene parts count once per instance).
        max_vertices: Largest accepted vertex count (header counts checked before parsing).
        max_degenerate_fraction: Largest accepted fraction of dropped degenerate faces, in [0, 1].
        min_face_area_m2: Faces whose area is at most this [m^2] count as zero-area (degenerate).
        max_extent_m: Largest accepted extent [m] of the mesh's axis-aligned box after unit conversion.
        min_extent_m: Smallest accepted extent [m] (the largest side of the box must reach it).
    """

    max_bytes: int = 200_000_000
    max_faces: int = 2_000_000
    max_vertices: int = 6_000_000
    max_degenerate_fraction: float = 0.10
    min_face_area_m2: float = 1e-12
    max_extent_m: float = 200.0
    min_extent_m: float = 1e-3

    def __post_init__(self) -> None:
        for name in ("max_bytes", "max_faces", "max_vertices"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
                raise InvalidInput(f"MeshLimits.{name} must be a positive integer, got {value!r}", field=name)
        if not 0.0 <= self.max_degenerate_fraction <= 1.0:
            raise InvalidInput(
                f"MeshLimits.max_degenerate_fraction must lie in [0, 1], got {self.max_degenerate_fraction}",
                field="max_degenerate_fraction",
            )
        if not (math.isfinite(self.min_face_area_m2) and self.min_face_area_m2 >= 0.0):
            raise InvalidInput(
                f"MeshLimits.min_face_area_m2 must be finite and >= 0, got {self.min_face_area_m2}",
                field="min_face_area_m2",
            )
        if not (0.0 < self.min_extent_m < self.max_extent_m < math.inf):
            raise InvalidInput(
                "MeshLimits needs 0 < min_extent_m < max_extent_m < inf, got "
                f"{self.min_extent_m} and {self.max_extent_m}",
                field="min_extent_m",
            )


@dataclass(frozen=True)
class MeshReport:
    """What :func:`load_mesh` found and did; every count is honest (nothing is dropped silently).

    Attributes:
        source: File name the mesh came from.
        format: Parsed format: ``stl-binary``, ``stl-ascii``, ``obj``, ``ply``, ``glb`` or ``gltf``.
        units: Units the caller declared for the file.
        byte_size: File size [bytes].
        n_parts: Triangle-mesh instances flattened from the file's scene graph.
        n_ignored_parts: Non-triangle geometry instances (lines, points) that were skipped.
        n_faces_read: Triangles in the file (after polygon splitting and scene instancing).
        n_faces: Triangles kept.
        n_vertices: Vertices kept (referenced by a kept face; bit-identical positions merged).
        n_dropped_out_of_range: Faces dropped for an index outside the vertex list.
        n_dropped_repeated_index: Faces dropped for naming one vertex twice.
        n_dropped_zero_area: Faces dropped for an area at most ``MeshLimits.min_face_area_m2``.
        n_boundary_edges: Edges used by exactly one kept face (0 for a closed shell).
        n_nonmanifold_edges: Edges used by three or more kept faces.
        extent_m: Sides of the axis-aligned box in the mesh frame after unit conversion [m], (3,).
        bounds_min_m: Lower corner of the axis-aligned box in the base frame (after the pose) [m], (3,).
        bounds_max_m: Upper corner of that box [m], (3,).
        surface_area_m2: Total area of the kept faces [m^2].
    """

    source: str
    format: str
    units: str
    byte_size: int
    n_parts: int
    n_ignored_parts: int
    n_faces_read: int
    n_faces: int
    n_vertices: int
    n_dropped_out_of_range: int
    n_dropped_repeated_index: int
    n_dropped_zero_area: int
    n_boundary_edges: int
    n_nonmanifold_edges: int
    extent_m: tuple[float, float, float]
    bounds_min_m: tuple[float, float, float]
    bounds_max_m: tuple[float, float, float]
    surface_area_m2: float

    @property
    def n_dropped_degenerate(self) -> int:
        """Faces dropped for any degeneracy."""
        return self.n_dropped_out_of_range + self.n_dropped_repeated_index + self.n_dropped_zero_area

    @property
    def degenerate_fraction(self) -> float:
        """Dropped faces over faces read, in [0, 1]."""
        return self.n_dropped_degenerate / self.n_faces_read if self.n_faces_read else 0.0

    @property
    def is_closed(self) -> bool:
        """Every edge is shared by exactly two faces (watertight, orientation not checked)."""
        return self.n_boundary_edges == 0 and self.n_nonmanifold_edges == 0

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable form, including the derived counts."""
        out = asdict(self)
        out["n_dropped_degenerate"] = self.n_dropped_degenerate
        out["degenerate_fraction"] = self.degenerate_fraction
        out["is_closed"] = self.is_closed
        return out


@dataclass(frozen=True, eq=False)
class LoadedMesh:
    """A validated triangle mesh in metres, expressed in the robot base frame.

    Attributes:
        name: Source file name.
        sha256: SHA-256 (hex) of the file's bytes, for provenance.
        units: Units the file was declared in (the arrays are always in metres).
        vertices: Vertex positions in the base frame [m], shape (V, 3), float64, read-only.
        faces: Vertex indices of each triangle, shape (F, 3), int64, read-only; F >= 1.
        T_base_mesh: The pose applied on load (mesh frame in the base frame), shape (4, 4), read-only.
        report: Counts and measurements of the load.
    """

    name: str
    sha256: str
    units: str
    vertices: Array
    faces: IntArray
    T_base_mesh: Array
    report: MeshReport = field(repr=False)

    def __post_init__(self) -> None:
        v, f = self.vertices, self.faces
        if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
            raise InvalidMesh(f"mesh {self.name!r}: arrays must be (V, 3) and (F>=1, 3)", file=self.name)
        for arr in (v, f, self.T_base_mesh):
            arr.flags.writeable = False

    @property
    def bounds_m(self) -> Array:
        """Axis-aligned box in the base frame, shape (2, 3): rows are the lower and upper corner [m]."""
        return np.array([self.report.bounds_min_m, self.report.bounds_max_m])

    def to_trimesh(self) -> trimesh.Trimesh:
        """A fresh :class:`trimesh.Trimesh` copy (no processing, so faces keep their order)."""
        return trimesh.Trimesh(vertices=self.vertices.copy(), faces=self.faces.copy(), process=False)


def load_mesh(
    source: MeshSource,
    *,
    units: Units,
    name: str | None = None,
    file_type: str | None = None,
    pose: ArrayLike | None = None,
    limits: MeshLimits | None = None,
) -> LoadedMesh:
    """Load, validate and convert one mesh file.

    Args:
        source: A path, or the file's raw bytes (e.g. an HTTP upload).
        units: Length unit of the file's coordinates: ``"m"`` or ``"mm"``. Converted once, to metres.
            This wins over any unit the format itself implies (glTF is metres by specification).
        name: File name used in messages and, with its extension, to choose the format. Defaults to the
            path's name; required for bytes unless ``file_type`` is given.
        file_type: Format override (``stl``, ``obj``, ``ply``, ``glb``, ``gltf``); by default the
            extension of ``name`` (or of the path).
        pose: ``T_base_mesh``, the mesh frame in the robot base frame, a rigid 4x4 transform whose
            translation is in metres; applied after unit conversion. ``None`` means identity.
        limits: Caps and plausibility bounds; defaults to :class:`MeshLimits` ().

    Returns:
        The validated mesh (vertices in metres, in the base frame) with its load report.

    Raises:
        InvalidMesh: the mesh cannot be used. ``details['check']`` names the failed check, one of
            ``units``, ``pose``, ``name``, ``read``, ``byte_size``, ``format``, ``empty``, ``content``,
            ``stl_length``, ``face_count``, ``vertex_count``, ``external_resource``, ``parse``,
            ``no_faces``, ``non_finite``, ``scale``, ``degenerate_faces``.
    """
    limits = MeshLimits() if limits is None else limits
    label = name if name is not None else _default_name(source)
    if units not in UNIT_SCALE_M:
        raise _error(
            label, "units", f"units must be one of {list(get_args(Units))}, got {units!r}", units=str(units)
        )
    T_base_mesh = _validate_pose(label, pose)
    fmt = _format_of(label, source, file_type)
    data = _read_bytes(label, source, limits)
    if not data:
        _fail(label, "empty", "the file is empty (0 bytes)", byte_size=0)
    sha256 = hashlib.sha256(data).hexdigest()
    key = (sha256, fmt, units, label, T_base_mesh.tobytes(), limits)
    cached = _cache_get(key)
    if cached is not None:  # the same bytes parsed and validated before: the result is immutable
        return cached

    kind = _sniff(label, fmt, data, limits)
    if kind == "obj":
        parts, n_ignored = [_parse_obj(label, data, limits)], 0
    else:
        parts, n_ignored = _parse_with_trimesh(label, fmt, data, limits)

    mesh_vertices, faces, n_faces_read = _concatenate(parts)
    if n_ignored:
        _LOG.warning("mesh %r: skipped %d non-triangle scene part(s)", label, n_ignored)
    if n_faces_read == 0:
        _fail(
            label, "no_faces", "the file contains no triangles", n_parts=len(parts), n_ignored_parts=n_ignored
        )

    mesh_vertices = mesh_vertices * UNIT_SCALE_M[units]
    loaded = _validate_and_build(
        label,
        sha256,
        units,
        kind,
        len(data),
        mesh_vertices,
        faces,
        T_base_mesh,
        limits,
        n_parts=len(parts),
        n_ignored=n_ignored,
    )
    _cache_put(key, loaded)
    return loaded


#: Parsed meshes by content hash (and format, units, name, pose, limits): a service resolving many
#: scenarios in the same cabin parses its file once. Meshes are immutable (read-only arrays), so one
#: object is shared. Bounded by entries and by the faces they hold.
MESH_CACHE_ENTRIES = 8
MESH_CACHE_MAX_FACES = 2_000_000
_MESH_CACHE: OrderedDict[Hashable, LoadedMesh] = OrderedDict()
_MESH_CACHE_LOCK = threading.Lock()


def _cache_get(key: Hashable) -> LoadedMesh | None:
    with _MESH_CACHE_LOCK:
        found = _MESH_CACHE.get(key)
        if found is not None:
            _MESH_CACHE.move_to_end(key)
        return found


def _cache_put(key: Hashable, mesh: LoadedMesh) -> None:
    with _MESH_CACHE_LOCK:
        _MESH_CACHE[key] = mesh
        _MESH_CACHE.move_to_end(key)
        while len(_MESH_CACHE) > MESH_CACHE_ENTRIES or (
            len(_MESH_CACHE) > 1 and sum(len(m.faces) for m in _MESH_CACHE.values()) > MESH_CACHE_MAX_FACES
        ):
            _MESH_CACHE.popitem(last=False)


def clear_mesh_cache() -> None:
    """Forget every parsed mesh (tests, benchmarks)."""
    with _MESH_CACHE_LOCK:
        _MESH_CACHE.clear()


# --------------------------------------------------------------------------------------------- helpers


def _error(label: str, check: str, why: str, **details: Any) -> InvalidMesh:
    """The one error type of this module, naming the file and the check."""
    return InvalidMesh(f"mesh {label!r}: check '{check}' failed: {why}", file=label, check=check, **details)


def _fail(label: str, check: str, why: str, **details: Any) -> NoReturn:
    """Raise :func:`_error`."""
    raise _error(label, check, why, **details)


def _default_name(source: MeshSource) -> str:
    if isinstance(source, bytes | bytearray | memoryview):
        return "<bytes>"
    try:
        return Path(source).name
    except TypeError:
        return repr(source)


def _validate_pose(label: str, pose: ArrayLike | None) -> Array:
    if pose is None:
        return np.eye(4)
    try:
        T = np.array(pose, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise _error(label, "pose", f"pose is not a numeric array: {exc}") from exc
    if T.shape != (4, 4):
        raise _error(label, "pose", f"pose must be a 4x4 matrix, got shape {T.shape}", shape=list(T.shape))
    if not np.all(np.isfinite(T)):
        _fail(label, "pose", "pose contains NaN or Inf")
    R = T[:3, :3]
    orthonormal_error = float(np.max(np.abs(R.T @ R - np.eye(3))))
    if (
        np.max(np.abs(T[3] - (0.0, 0.0, 0.0, 1.0))) > _POSE_TOL
        or orthonormal_error > _POSE_TOL
        or np.linalg.det(R) <= 0.0
    ):
        _fail(
            label,
            "pose",
            "pose must be a rigid transform (orthonormal rotation with det +1, last row 0 0 0 1)",
            orthonormal_error=orthonormal_error,
        )
    T[3] = (0.0, 0.0, 0.0, 1.0)
    return T


def _format_of(label: str, source: MeshSource, file_type: str | None) -> str:
    if file_type is not None:
        ext = file_type.lower().lstrip(".")
    else:
        if label == "<bytes>":
            _fail(label, "name", "raw bytes need a file name with an extension, or file_type")
        ext = Path(label).suffix.lower().lstrip(".")
        if not ext and not isinstance(source, bytes | bytearray | memoryview):
            ext = Path(os.fspath(source)).suffix.lower().lstrip(".")
    if ext not in SUPPORTED_EXTENSIONS:
        _fail(
            label,
            "format",
            f"unsupported file type {ext or '<none>'!r}; supported: {', '.join(SUPPORTED_EXTENSIONS)}",
            extension=ext,
            supported=list(SUPPORTED_EXTENSIONS),
        )
    return ext


def _read_bytes(label: str, source: MeshSource, limits: MeshLimits) -> bytes:
    """Return the file's bytes, refusing oversize input before reading it."""
    if isinstance(source, bytes | bytearray | memoryview):
        size = memoryview(source).nbytes
        if size > limits.max_bytes:
            _fail(
                label,
                "byte_size",
                f"{size} bytes exceeds the cap of {limits.max_bytes}",
                byte_size=size,
                max_bytes=limits.max_bytes,
            )
        return bytes(source)
    try:
        path = Path(os.fspath(source))
        info = path.stat()
        if not stat.S_ISREG(info.st_mode):
            _fail(label, "read", f"{path} is not a regular file", path=str(path))
        if info.st_size > limits.max_bytes:
            _fail(
                label,
                "byte_size",
                f"{info.st_size} bytes exceeds the cap of {limits.max_bytes}",
                byte_size=info.st_size,
                max_bytes=limits.max_bytes,
            )
        with path.open("rb") as fh:
            data = fh.read(limits.max_bytes + 1)
    except (OSError, TypeError, ValueError) as exc:
        raise _error(label, "read", f"cannot read the file: {exc}") from exc
    if len(data) > limits.max_bytes:  # the file grew between stat and read
        raise _error(label, "byte_size", f"more than {limits.max_bytes} bytes", max_bytes=limits.max_bytes)
    return data


def _looks_like(data: bytes) -> str:
    """Best guess of what a blob is, for 'content does not match the extension' messages."""
    head = data[:512].lstrip()
    if data[:4] == _GLB_MAGIC:
        return "GLB"
    if head[:3] == b"ply" and head[3:4] in (b"\n", b"\r"):
        return "PLY"
    if head[:1] == b"{":
        return "glTF JSON"
    if head[:5].lower() == b"solid" and b"\x00" not in data:
        return "ASCII STL"
    if len(data) >= _STL_HEADER_BYTES and _stl_binary_count(data) is not None:
        return "binary STL"
    if _is_text(data):
        return "text"
    return "binary data"


def _is_text(data: bytes) -> bool:
    return b"\x00" not in data and data.isascii()


def _stl_binary_count(data: bytes) -> int | None:
    """Face count of a well-formed binary STL (length 84 + 50 n), else None."""
    if len(data) < _STL_HEADER_BYTES:
        return None
    (n,) = struct.unpack_from("<I", data, 80)
    return n if len(data) == _STL_HEADER_BYTES + _STL_RECORD_BYTES * n else None


def _mismatch(label: str, fmt: str, data: bytes, why: str) -> NoReturn:
    found = _looks_like(data)
    _fail(
        label,
        "content",
        f"content does not match the .{fmt} extension: {why} (looks like {found})",
        extension=fmt,
        looks_like=found,
    )


def _sniff(label: str, fmt: str, data: bytes, limits: MeshLimits) -> str:
    """Check that the content is the format the extension claims; check header counts. Returns the kind."""
    if fmt == "stl":
        return _sniff_stl(label, data, limits)
    if fmt == "obj":
        if b"\x00" in data:
            _mismatch(label, fmt, data, "OBJ is a text format")
        if _looks_like(data) in ("GLB", "PLY", "glTF JSON", "ASCII STL"):
            _mismatch(label, fmt, data, "not OBJ text")
        n_face_lines = data.count(b"\nf ") + int(data.startswith(b"f "))
        if n_face_lines > limits.max_faces:
            _fail(
                label,
                "face_count",
                f"{n_face_lines} face lines exceed the cap of {limits.max_faces}",
                n_faces=n_face_lines,
                max_faces=limits.max_faces,
            )
        return "obj"
    if fmt == "ply":
        _check_ply_header(label, data, limits)
        return "ply"
    if fmt == "glb":
        _check_glb(label, data, limits)
        return "glb"
    # gltf
    if data.lstrip()[:1] != b"{":
        _mismatch(label, fmt, data, "a .gltf file is a JSON object")
    try:
        doc = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise _error(label, "content", f"not valid glTF JSON: {exc}") from exc
    _check_gltf_json(label, doc, limits, glb=False)
    return "gltf"


def _sniff_stl(label: str, data: bytes, limits: MeshLimits) -> str:
    n = _stl_binary_count(data)
    if n is not None:
        if n > limits.max_faces:
            raise _error(
                label,
                "face_count",
                f"binary STL header declares {n} faces, cap is {limits.max_faces}",
                n_faces=n,
                max_faces=limits.max_faces,
            )
        return "stl-binary"
    if data.lstrip()[:5].lower() == b"solid" and b"\x00" not in data:
        n_facets = data.count(b"endfacet") + data.count(b"ENDFACET")
        if n_facets > limits.max_faces:
            _fail(
                label,
                "face_count",
                f"{n_facets} facets exceed the cap of {limits.max_faces}",
                n_faces=n_facets,
                max_faces=limits.max_faces,
            )
        return "stl-ascii"
    found = _looks_like(data)
    if found in ("GLB", "PLY", "glTF JSON", "text") or len(data) < _STL_HEADER_BYTES:
        _mismatch(label, "stl", data, "neither an ASCII STL ('solid' text) nor a binary STL")
    (declared,) = struct.unpack_from("<I", data, 80)
    if declared > limits.max_faces:
        _fail(
            label,
            "face_count",
            f"binary STL header declares {declared} faces, cap is {limits.max_faces}",
            n_faces=declared,
            max_faces=limits.max_faces,
        )
    expected = _STL_HEADER_BYTES + _STL_RECORD_BYTES * declared
    _fail(
        label,
        "stl_length",
        f"binary STL header declares {declared} faces, so the file must be {expected} bytes "
        f"(84 + 50 n), but it is {len(data)} bytes (truncated or corrupt)",
        n_faces=declared,
        expected_bytes=expected,
        byte_size=len(data),
    )


def _check_ply_header(label: str, data: bytes, limits: MeshLimits) -> None:
    if not (data[:3] == b"ply" and data[3:4] in (b"\n", b"\r")):
        _mismatch(label, "ply", data, "a PLY file starts with the line 'ply'")
    end = data.find(b"end_header", 0, _PLY_MAX_HEADER_BYTES)
    if end < 0:
        _fail(label, "parse", "PLY header has no 'end_header' within the first 1 MiB")
    header = data[:end].decode("ascii", errors="replace").splitlines()
    counts: dict[str, int] = {}
    fmt_line = ""
    for line in header:
        words = line.split()
        if not words:
            continue
        if words[0] == "format":
            fmt_line = " ".join(words[1:2])
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                _fail(label, "parse", f"malformed PLY element line {line.strip()!r}")
            counts[words[1]] = int(words[2])
    if fmt_line not in ("ascii", "binary_little_endian", "binary_big_endian"):
        _fail(label, "parse", f"PLY format line missing or unknown ({fmt_line or 'none'!r})")
    n_vertices, n_faces = counts.get("vertex", 0), counts.get("face", 0)
    if n_vertices > limits.max_vertices:
        _fail(
            label,
            "vertex_count",
            f"PLY header declares {n_vertices} vertices, cap is {limits.max_vertices}",
            n_vertices=n_vertices,
            max_vertices=limits.max_vertices,
        )
    if n_faces > limits.max_faces:
        _fail(
            label,
            "face_count",
            f"PLY header declares {n_faces} faces, cap is {limits.max_faces}",
            n_faces=n_faces,
            max_faces=limits.max_faces,
        )


def _check_glb(label: str, data: bytes, limits: MeshLimits) -> None:
    if data[:4] != _GLB_MAGIC:
        _mismatch(label, "glb", data, "a GLB file starts with the magic 'glTF'")
    if len(data) < 20:
        _fail(
            label, "content", f"GLB shorter than its 20-byte header ({len(data)} bytes)", byte_size=len(data)
        )
    version, declared, json_len = struct.unpack_from("<III", data, 4)
    if version != 2:
        _fail(
            label,
            "content",
            f"only glTF 2 binaries are supported, header says version {version}",
            version=version,
        )
    if declared != len(data):
        _fail(
            label,
            "content",
            f"GLB header declares {declared} bytes, file has {len(data)}",
            declared_bytes=declared,
            byte_size=len(data),
        )
    if data[16:20] != b"JSON" or 20 + json_len > len(data):
        _fail(label, "content", "GLB first chunk is not a complete JSON chunk")
    try:
        doc = json.loads(data[20 : 20 + json_len].decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise _error(label, "parse", f"GLB JSON chunk is not valid JSON: {exc}") from exc
    _check_gltf_json(label, doc, limits, glb=True)


def _check_gltf_json(label: str, doc: Any, limits: MeshLimits, *, glb: bool) -> None:
    """Refuse glTF documents that reference outside files or declare oversized arrays."""
    if not isinstance(doc, dict) or not isinstance(doc.get("asset"), dict):
        raise _error(label, "content", "not a glTF document (no 'asset' object)")
    for i, buf in enumerate(_json_list(label, doc, "buffers")):
        uri = buf.get("uri") if isinstance(buf, dict) else None
        if uri is None and glb and i == 0:
            continue
        if not (isinstance(uri, str) and uri.startswith("data:")):
            _fail(
                label,
                "external_resource",
                f"buffer {i} refers to an outside file ({uri!r}); glTF buffers must be embedded",
                buffer=i,
            )
    cap = max(limits.max_vertices, 3 * limits.max_faces)
    for i, acc in enumerate(_json_list(label, doc, "accessors")):
        count = acc.get("count") if isinstance(acc, dict) else None
        if not isinstance(count, int) or count < 0:
            _fail(label, "parse", f"glTF accessor {i} has no valid count", accessor=i)
        elif count > cap:
            _fail(
                label,
                "vertex_count",
                f"glTF accessor {i} declares {count} elements, cap is {cap}",
                accessor=i,
                count=count,
                cap=cap,
            )


def _json_list(label: str, doc: dict[str, Any], key: str) -> list[Any]:
    value = doc.get(key, [])
    if not isinstance(value, list):
        _fail(label, "parse", f"glTF '{key}' is not a list")
    return value


def _parse_obj(label: str, data: bytes, limits: MeshLimits) -> tuple[Array, IntArray]:
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
                raise _error(
                    label, "parse", f"line {lineno}: malformed vertex {line.strip()[:80]!r}", line=lineno
                ) from None
            coords.extend((x, y, z))
            n_v += 1
            if n_v > limits.max_vertices:
                raise _error(
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
                    raise _error(
                        label, "parse", f"line {lineno}: malformed face index {token[:40]!r}", line=lineno
                    ) from None
                idx.append(k - 1 if k > 0 else (n_v + k if k < 0 else -1))
            if len(idx) < 3:
                raise _error(label, "parse", f"line {lineno}: a face needs at least 3 vertices", line=lineno)
            for i in range(1, len(idx) - 1):
                tris.extend((idx[0], idx[i], idx[i + 1]))
            if len(tris) > 3 * limits.max_faces:
                _fail(
                    label, "face_count", f"more than {limits.max_faces} triangles", max_faces=limits.max_faces
                )
    vertices = np.frombuffer(coords, dtype=np.float64).reshape(-1, 3).copy()
    faces = np.frombuffer(tris, dtype=np.int64).reshape(-1, 3).copy()
    return vertices, faces


def _parse_with_trimesh(
    label: str, fmt: str, data: bytes, limits: MeshLimits
) -> tuple[list[tuple[Array, IntArray]], int]:
    """Parse with trimesh and flatten the scene graph: one (vertices, faces) per geometry instance."""
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
                _fail(
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
                _fail(label, "parse", f"vertex array of shape {vertices.shape}")
            n_vertices += len(vertices)
            if n_vertices > limits.max_vertices:
                _fail(
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
        raise _error(
            label,
            "parse",
            f"{fmt.upper()} parser failed: {type(exc).__name__}: {str(exc)[:200]}",
            error=type(exc).__name__,
        ) from exc
    return parts, n_ignored


def _concatenate(parts: list[tuple[Array, IntArray]]) -> tuple[Array, IntArray, int]:
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


def _validate_and_build(
    label: str,
    sha256: str,
    units: str,
    kind: str,
    byte_size: int,
    vertices: Array,
    faces: IntArray,
    T_base_mesh: Array,
    limits: MeshLimits,
    *,
    n_parts: int,
    n_ignored: int,
) -> LoadedMesh:
    """Checks 5-6 of the module pipeline on metre-scaled, mesh-frame arrays."""
    n_read = len(faces)
    finite = np.isfinite(vertices).all(axis=1)
    if not finite.all():
        n_bad = int(np.count_nonzero(~finite))
        _fail(
            label,
            "non_finite",
            f"{n_bad} vertices have NaN or Inf coordinates (first index {int(np.argmax(~finite))})",
            n_vertices_non_finite=n_bad,
        )

    out_of_range = (faces < 0).any(axis=1)
    repeated = ~out_of_range & (
        (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    )
    index_ok = ~(out_of_range | repeated)

    used = faces[index_ok]
    if len(used):
        corners = vertices[used.reshape(-1)]
        extent = corners.max(axis=0) - corners.min(axis=0)
        _check_scale(label, units, float(extent.max()), limits)
        tri = vertices[used]
        with np.errstate(all="ignore"):
            area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        zero = np.zeros(n_read, dtype=bool)
        zero[np.flatnonzero(index_ok)] = ~(area > limits.min_face_area_m2)
    else:
        extent = np.zeros(3)
        area = np.zeros(0)
        zero = np.zeros(n_read, dtype=bool)

    keep = index_ok & ~zero
    counts = {
        "n_dropped_out_of_range": int(np.count_nonzero(out_of_range)),
        "n_dropped_repeated_index": int(np.count_nonzero(repeated)),
        "n_dropped_zero_area": int(np.count_nonzero(zero)),
    }
    n_dropped = sum(counts.values())
    fraction = n_dropped / n_read
    if fraction > limits.max_degenerate_fraction or not keep.any():
        _fail(
            label,
            "degenerate_faces",
            f"{n_dropped} of {n_read} faces ({100 * fraction:.1f}%) are degenerate (out-of-range index "
            f"{counts['n_dropped_out_of_range']}, repeated index {counts['n_dropped_repeated_index']}, "
            f"zero area {counts['n_dropped_zero_area']}); the cap is "
            f"{100 * limits.max_degenerate_fraction:.1f}%",
            n_faces_read=n_read,
            degenerate_fraction=fraction,
            max_degenerate_fraction=limits.max_degenerate_fraction,
            **counts,
        )
    if n_dropped:
        _LOG.warning("mesh %r: dropped %d degenerate faces of %d (%s)", label, n_dropped, n_read, counts)

    kept_faces = faces[keep]
    kept_area = area[keep[index_ok]] if len(area) else area
    # Drop unreferenced vertices and merge bit-identical ones; the faces themselves are unchanged.
    referenced = np.zeros(len(vertices), dtype=bool)
    referenced[kept_faces.reshape(-1)] = True
    remap = np.cumsum(referenced) - 1
    unique_vertices, merge = _merge_identical(vertices[referenced])
    kept_faces = merge[remap[kept_faces]]
    n_boundary, n_nonmanifold = _edge_counts(kept_faces, len(unique_vertices))

    extent = unique_vertices.max(axis=0) - unique_vertices.min(axis=0)
    base_vertices = unique_vertices @ T_base_mesh[:3, :3].T + T_base_mesh[:3, 3]
    report = MeshReport(
        source=label,
        format=kind,
        units=units,
        byte_size=byte_size,
        n_parts=n_parts,
        n_ignored_parts=n_ignored,
        n_faces_read=n_read,
        n_faces=len(kept_faces),
        n_vertices=len(unique_vertices),
        n_boundary_edges=n_boundary,
        n_nonmanifold_edges=n_nonmanifold,
        extent_m=_triple(extent),
        bounds_min_m=_triple(base_vertices.min(axis=0)),
        bounds_max_m=_triple(base_vertices.max(axis=0)),
        surface_area_m2=float(kept_area.sum()),
        **counts,
    )
    _LOG.info(
        "mesh %r loaded: %d faces, %d vertices, extent %s m",
        label,
        report.n_faces,
        report.n_vertices,
        report.extent_m,
    )
    return LoadedMesh(
        name=label,
        sha256=sha256,
        units=units,
        vertices=np.ascontiguousarray(base_vertices),
        faces=np.ascontiguousarray(kept_faces),
        T_base_mesh=T_base_mesh,
        report=report,
    )


def _check_scale(label: str, units: str, extent_m: float, limits: MeshLimits) -> None:
    """Refuse meshes whose size is implausible for the declared units, with a hint at the likely fix."""
    if limits.min_extent_m <= extent_m <= limits.max_extent_m:
        return
    too_big = extent_m > limits.max_extent_m
    hint = ""
    if too_big and units == "m" and limits.min_extent_m <= extent_m * 1e-3 <= limits.max_extent_m:
        hint = " -- did you mean mm?"
    elif not too_big and units == "mm" and limits.min_extent_m <= extent_m * 1e3 <= limits.max_extent_m:
        hint = " -- did you mean m?"
    bound = (
        f"above the maximum {limits.max_extent_m} m"
        if too_big
        else f"below the minimum {limits.min_extent_m} m"
    )
    _fail(
        label,
        "scale",
        f"largest extent {extent_m:.6g} m (declared units {units!r}) is {bound}{hint}",
        extent_m=extent_m,
        units=units,
        min_extent_m=limits.min_extent_m,
        max_extent_m=limits.max_extent_m,
    )


def _merge_identical(vertices: Array) -> tuple[Array, IntArray]:
    """Merge bit-identical rows of finite vertices (``-0.0`` counts as ``0.0``), keeping first occurrences.

    Rows are grouped by a 64-bit hash of their bits (one 1-D sort instead of a slow row-wise unique);
    the grouping is then verified exactly, with a row-wise unique as fallback should two rows collide.

    Returns:
        (unique vertices (U, 3), index of each input row's unique vertex (V,)).
    """
    bits = np.ascontiguousarray(vertices + 0.0).view(np.uint64)
    key = _mix64(_mix64(_mix64(bits[:, 0]) ^ bits[:, 1]) ^ bits[:, 2])
    _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    if not np.array_equal(bits[first[inverse]], bits):  # a hash collision: take the exact, slow route
        _, first, inverse = np.unique(bits, axis=0, return_index=True, return_inverse=True)
        inverse = inverse.reshape(-1)
    order = np.argsort(first, kind="stable")  # unique rows in order of first occurrence
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return np.ascontiguousarray(vertices[first[order]] + 0.0), rank[inverse].astype(np.int64)


def _mix64(x: NDArray[np.uint64]) -> NDArray[np.uint64]:
    """The splitmix64 finaliser: every input bit affects every output bit (wrapping uint64 arithmetic).

    Plain multiplicative hashing is not enough here: coordinates read from float32 files have their 29
    low mantissa bits zero, which a multiplication keeps zero.
    """
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def _edge_counts(faces: IntArray, n_vertices: int) -> tuple[int, int]:
    """(edges used once, edges used three or more times) of a triangle list."""
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    keys = edges[:, 0] * np.int64(n_vertices) + edges[:, 1]
    _, uses = np.unique(keys, return_counts=True)
    return int(np.count_nonzero(uses == 1)), int(np.count_nonzero(uses > 2))


def _triple(values: Array) -> tuple[float, float, float]:
    return float(values[0]), float(values[1]), float(values[2])
