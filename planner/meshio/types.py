"""The values of the mesh layer and its one error: limits, reports, loaded meshes, ``InvalidMesh``.

Every failure of :func:`planner.meshio.load_mesh` raises :class:`~planner.core.exceptions.InvalidMesh`
through :func:`error`, whose message names the file and the check and whose ``details`` carry ``file``,
``check`` and the measured values.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any, Literal, NoReturn

import numpy as np

from planner.core.exceptions import InvalidInput, InvalidMesh
from planner.core.types import Array, IntArray

if TYPE_CHECKING:
    import trimesh

Units = Literal["m", "mm"]
#: Metres per declared unit.
UNIT_SCALE_M: Mapping[str, float] = {"m": 1.0, "mm": 1e-3}

#: File extensions (lower case, no dot) that :func:`~planner.meshio.load_mesh` accepts.
SUPPORTED_EXTENSIONS: tuple[str, ...] = ("stl", "obj", "ply", "glb", "gltf", "step", "stp")
#: The extensions of STEP (ISO 10303-21) files: exact B-rep geometry, tessellated on load
#: (:mod:`planner.meshio.step`).
STEP_EXTENSIONS: tuple[str, ...] = ("step", "stp")

#: Default chordal tolerance of a STEP tessellation [m]: the tessellated surface lies within this distance
#: of the exact one (OpenCASCADE's linear deflection). 0.1 mm: a hundredth of the default 10 mm clearance,
#: and a 1 m radius cylinder still tessellates to about 450 triangles around.
DEFAULT_TESSELLATION_TOLERANCE_M = 1e-4
#: Bounds of the tessellation tolerance [m]: below 1 um a curved CAD part tessellates to millions of
#: triangles; above 10 mm the tessellation no longer resembles the part.
MIN_TESSELLATION_TOLERANCE_M = 1e-6
MAX_TESSELLATION_TOLERANCE_M = 1e-2

#: A path, or the file's raw bytes.
MeshSource = str | os.PathLike[str] | bytes | bytearray | memoryview


@dataclass(frozen=True)
class MeshLimits:
    """Caps and plausibility bounds applied by :func:`~planner.meshio.load_mesh`.

    Attributes:
        max_bytes: Largest accepted file size [bytes] (checked before the file is read or parsed).
        max_faces: Largest accepted triangle count (header counts are checked before parsing; polygons
            count as the triangles they split into; instanced scene parts count once per instance).
        max_vertices: Largest accepted vertex count (header counts checked before parsing).
        max_degenerate_fraction: Largest accepted fraction of dropped degenerate faces, in [0, 1].
        min_face_area_m2: Faces whose area is at most this [m^2] count as zero-area (degenerate).
        max_extent_m: Largest accepted extent [m] of the mesh's axis-aligned box after unit conversion.
        min_extent_m: Smallest accepted extent [m] (the largest side of the box must reach it).
        step_timeout_s: Wall-clock limit [s] of a STEP file's read and tessellation (in a worker process).
        step_memory_bytes: Address-space limit [bytes] of that worker process.
    """

    max_bytes: int = 200_000_000
    max_faces: int = 2_000_000
    max_vertices: int = 6_000_000
    max_degenerate_fraction: float = 0.10
    min_face_area_m2: float = 1e-12
    max_extent_m: float = 200.0
    min_extent_m: float = 1e-3
    step_timeout_s: float = 60.0
    step_memory_bytes: int = 4 * 1024**3

    def __post_init__(self) -> None:
        for name in ("max_bytes", "max_faces", "max_vertices", "step_memory_bytes"):
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
        if not (math.isfinite(self.step_timeout_s) and self.step_timeout_s > 0.0):
            raise InvalidInput(
                f"MeshLimits.step_timeout_s must be finite and > 0, got {self.step_timeout_s}",
                field="step_timeout_s",
            )


@dataclass(frozen=True)
class MeshReport:
    """What :func:`~planner.meshio.load_mesh` found and did; every count is honest (nothing dropped silently).

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
        file_units: Length units the file itself declares (STEP: every unit its contexts declare, e.g.
            ``"mm"`` or ``"inch"``); ``None`` for formats without declared units.
        tessellation_tolerance_m: STEP: the chordal tolerance the exact surfaces were tessellated with
            [m]; ``None`` for triangle formats.
        surface_deviation_m: Bound of the distance between the loaded triangles and the surface the file
            describes [m]: the tessellation tolerance plus the float32 rounding of the tessellated
            vertices for STEP; 0.0 for triangle formats (their triangles *are* the surface).
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
    file_units: str | None = None
    tessellation_tolerance_m: float | None = None
    surface_deviation_m: float = 0.0

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
        units: Units the file was declared in (the arrays are always in metres); for STEP the units the
            file itself declares.
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

    @property
    def surface_deviation_m(self) -> float:
        """How far the loaded triangles may lie from the surface the file describes [m] (0 for meshes)."""
        return self.report.surface_deviation_m

    def to_trimesh(self) -> trimesh.Trimesh:
        """A fresh :class:`trimesh.Trimesh` copy (no processing, so faces keep their order)."""
        import trimesh  # only here: trimesh costs a CLI call 0.2-1 s of imports

        return trimesh.Trimesh(vertices=self.vertices.copy(), faces=self.faces.copy(), process=False)


def error(label: str, check: str, why: str, **details: Any) -> InvalidMesh:
    """The one error type of the mesh layer, naming the file and the check."""
    return InvalidMesh(f"mesh {label!r}: check '{check}' failed: {why}", file=label, check=check, **details)


def fail(label: str, check: str, why: str, **details: Any) -> NoReturn:
    """Raise :func:`error`."""
    raise error(label, check, why, **details)
