"""Load cabin and payload meshes (STL, OBJ, PLY, GLB/glTF, STEP) into validated triangle soups in metres.

This is the I/O edge of the planner: the collision world and everything behind it work on
:class:`~planner.meshio.types.LoadedMesh` values whose vertices are finite, in metres, expressed in the
robot base frame, and whose faces all index existing vertices and span a non-zero area.

The pipeline of :func:`load_mesh` is, in order:

1. validate the caller's ``units`` and ``pose`` (a rigid 4x4 transform ``T_base_mesh``);
2. read the bytes, refusing anything above ``MeshLimits.max_bytes`` *before* the file is read or parsed;
3. pick the format from the extension and check that the content really is that format (magic bytes,
   binary-STL length ``84 + 50 n``, PLY/GLB headers, glTF JSON); header face and vertex counts are
   checked against the caps here, still before parsing;
4. parse: STL, PLY and GLB/glTF with trimesh (``process=False`` so it neither merges nor drops
   anything), OBJ with a small strict parser of our own (trimesh silently remaps the invalid OBJ index
   ``0`` to the last vertex and crashes on out-of-range indices, which would make the counts dishonest);
   STEP tessellated by OpenCASCADE in a worker process with time and memory limits
   (:mod:`.step`: the file's own units, assemblies flattened with their placements, a chordal tolerance
   whose bound the mesh reports as ``surface_deviation_m``) and its glTF parsed as above;
   a multi-part scene is flattened with its scene-graph transforms;
5. convert to metres (once) and validate: finite vertices, plausible size for the declared units, and
   degenerate faces (out-of-range indices, repeated indices, zero area) dropped and counted -- refused
   when they are more than ``MeshLimits.max_degenerate_fraction`` of the faces read;
6. drop unreferenced vertices, merge bit-identical ones (faces are unchanged), apply the pose.

Any failure raises :class:`~planner.core.exceptions.InvalidMesh` whose message names the file and the
check and whose ``details`` carry ``file``, ``check`` and the measured values; no other exception type
leaves this package. Meshes are treated as triangle shells: they need not be closed (the report says
whether they are).

The rooms of ``planner/meshio/``: :mod:`.types` (limits, reports, the loaded mesh, the error),
:mod:`.sniff` (steps 2-3), :mod:`.parse` (step 4), :mod:`.build` (the pose of step 1, steps 5 and 6) and
this module, the public entry :func:`load_mesh`.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import logging
from collections.abc import Hashable
from pathlib import Path
from typing import Any, get_args

import numpy as np
from numpy.typing import ArrayLike

from planner.core.cache import DATA_PATTERNS, cache_dir, prune, touch, write_atomic
from planner.core.lru import BoundedLRU
from planner.core.types import Array, IntArray
from planner.meshio.build import validate_and_build, validate_pose
from planner.meshio.parse import concatenate, parse_obj, parse_with_trimesh
from planner.meshio.sniff import format_of, read_bytes, sniff
from planner.meshio.step import check_tolerance, tessellate_step
from planner.meshio.types import (
    DEFAULT_TESSELLATION_TOLERANCE_M,
    STEP_EXTENSIONS,
    UNIT_SCALE_M,
    LoadedMesh,
    MeshLimits,
    MeshSource,
    Units,
    error,
    fail,
)

_LOG = logging.getLogger(__name__)


def load_mesh(
    source: MeshSource,
    *,
    units: Units,
    name: str | None = None,
    file_type: str | None = None,
    pose: ArrayLike | None = None,
    limits: MeshLimits | None = None,
    tessellation_tolerance_m: float | None = None,
) -> LoadedMesh:
    """Load, validate and convert one mesh file.

    Args:
        source: A path, or the file's raw bytes (e.g. an HTTP upload).
        units: Length unit of the file's coordinates: ``"m"`` or ``"mm"``. Converted once, to metres.
            This wins over any unit the format itself implies (glTF is metres by specification). A STEP
            file declares its own units, which OpenCASCADE converts: for STEP ``units`` does not apply
            (the report's ``file_units`` says what the file declared).
        name: File name used in messages and, with its extension, to choose the format. Defaults to the
            path's name; required for bytes unless ``file_type`` is given.
        file_type: Format override (``stl``, ``obj``, ``ply``, ``glb``, ``gltf``, ``step``, ``stp``); by
            default the extension of ``name`` (or of the path).
        pose: ``T_base_mesh``, the mesh frame in the robot base frame, a rigid 4x4 transform whose
            translation is in metres; applied after unit conversion. ``None`` means identity.
        limits: Caps and plausibility bounds; defaults to :class:`MeshLimits` ().
        tessellation_tolerance_m: STEP only: the chordal tolerance of the tessellation [m] (default
            :data:`~planner.meshio.types.DEFAULT_TESSELLATION_TOLERANCE_M`, bounds 1e-6 to 1e-2); the
            loaded mesh's ``surface_deviation_m`` bounds how far its triangles lie from the exact surface.

    Returns:
        The validated mesh (vertices in metres, in the base frame) with its load report.

    Raises:
        InvalidMesh: the mesh cannot be used. ``details['check']`` names the failed check, one of
            ``units``, ``pose``, ``name``, ``read``, ``byte_size``, ``format``, ``empty``, ``content``,
            ``stl_length``, ``face_count``, ``vertex_count``, ``external_resource``, ``parse``,
            ``no_faces``, ``non_finite``, ``scale``, ``degenerate_faces``; for STEP also ``tolerance``,
            ``truncated``, ``self_reference``, ``step_timeout``, ``step_memory``.
    """
    limits = MeshLimits() if limits is None else limits
    label = name if name is not None else _default_name(source)
    if units not in UNIT_SCALE_M:
        raise error(
            label, "units", f"units must be one of {list(get_args(Units))}, got {units!r}", units=str(units)
        )
    T_base_mesh = validate_pose(label, pose)
    fmt = format_of(label, source, file_type)
    step = fmt in STEP_EXTENSIONS
    tolerance_m = check_tolerance(
        label,
        DEFAULT_TESSELLATION_TOLERANCE_M if tessellation_tolerance_m is None else tessellation_tolerance_m,
    )
    if not step:
        if tessellation_tolerance_m is not None:
            fail(label, "tolerance", "tessellation_tolerance_m applies to STEP files only")
        tolerance_m = 0.0
    data = read_bytes(label, source, limits)
    if not data:
        fail(label, "empty", "the file is empty (0 bytes)", byte_size=0)
    sha256 = hashlib.sha256(data).hexdigest()
    key = (sha256, fmt, units, label, T_base_mesh.tobytes(), limits, tolerance_m)
    cached = _cache_get(key)
    if cached is not None:  # the same bytes parsed and validated before: the result is immutable
        return cached

    kind = sniff(label, fmt, data, limits)
    step_info: dict[str, Any] = {}
    parts, n_ignored = _parse(label, kind, fmt, data, sha256, limits, tolerance_m, step_info)
    if step:
        # OpenCASCADE converted the file's units and the glTF is in metres: no further scaling.
        units_declared = "+".join(step_info["file_units"]) or "mm"

    mesh_vertices, faces, n_faces_read = concatenate(parts)
    if n_ignored:
        _LOG.warning("mesh %r: skipped %d non-triangle scene part(s)", label, n_ignored)
    if n_faces_read == 0:
        fail(
            label, "no_faces", "the file contains no triangles", n_parts=len(parts), n_ignored_parts=n_ignored
        )

    if step:
        # The tessellated vertices come as float32 (glTF): at most half an ulp off, |x| 2^-24.
        rounding_m = float(np.abs(mesh_vertices).max()) * 2.0**-24 if len(mesh_vertices) else 0.0
        extra: dict[str, Any] = {
            "file_units": units_declared,
            "tessellation_tolerance_m": tolerance_m,
            "surface_deviation_m": tolerance_m + rounding_m,
        }
        units_of_mesh = units_declared
    else:
        mesh_vertices = mesh_vertices * UNIT_SCALE_M[units]
        extra = {}
        units_of_mesh = units
    loaded = validate_and_build(
        label,
        sha256,
        units_of_mesh,
        kind,
        len(data),
        mesh_vertices,
        faces,
        T_base_mesh,
        limits,
        n_parts=len(parts),
        n_ignored=n_ignored,
        **extra,
    )
    _cache_put(key, loaded)
    return loaded


def _parse(
    label: str,
    kind: str,
    fmt: str,
    data: bytes,
    sha256: str,
    limits: MeshLimits,
    tolerance_m: float = 0.0,
    step_info: dict[str, Any] | None = None,
) -> tuple[list[tuple[Array, IntArray]], int]:
    """Step 4 through the on-disk parse cache: a file whose bytes were parsed before is read back.

    A CLI call then never imports trimesh (0.2-1 s of its start-up).

    The cache holds the parser's raw output only (before units, validation and pose), keyed by the
    content hash, the format, our parsing code (its source hash) and trimesh's version, and the caps
    the parse enforced; every later step runs
    as on a fresh parse. A missing, unreadable or foreign entry is parsed anew. A STEP file's entry is the
    tessellation (keyed also by the tolerance and cascadio's version) with the units the file declared
    (``step_info['file_units']``), so a cached STEP cabin starts no worker.
    """
    info = step_info if step_info is not None else {}
    path = _parse_cache_path(kind, fmt, sha256, limits, tolerance_m)
    if path is not None:
        cached = _read_parts(path, info)
        if cached is not None:
            return cached
    if kind == "obj":
        parts, n_ignored = [parse_obj(label, data, limits)], 0
    elif kind == "step":
        tess = tessellate_step(label, data, tolerance_m, limits)
        # The worker's glTF is checked and parsed like an uploaded one (caps, scene graph, instances).
        sniff(label, "glb", tess.glb, limits)
        parts, n_ignored = parse_with_trimesh(label, "glb", tess.glb, limits)
        info["file_units"] = list(tess.file_units)
    else:
        parts, n_ignored = parse_with_trimesh(label, fmt, data, limits)
    if path is not None:
        _write_parts(path, parts, n_ignored, info)
    return parts, n_ignored


#: Version of the layout of a parse-cache entry (bump when :func:`_write_parts` changes).
PARSE_CACHE_LAYOUT = 1


def _parse_cache_path(
    kind: str, fmt: str, sha256: str, limits: MeshLimits, tolerance_m: float = 0.0
) -> Path | None:
    root = cache_dir()
    if root is None:
        return None
    parser = "obj" if kind == "obj" else f"trimesh-{_version('trimesh')}"
    if kind == "step":
        parser += f"-cascadio-{_version('cascadio')}-{tolerance_m!r}"
    tag = f"{PARSE_CACHE_LAYOUT}-{_parser_source()}-{parser}-{limits.max_faces}-{limits.max_vertices}"
    return root / "meshes" / f"{sha256}-{fmt}-{hashlib.sha256(tag.encode()).hexdigest()[:16]}.npz"


@functools.cache
def _parser_source() -> str:
    """SHA-256 of our parsing code (:mod:`.parse`, :mod:`.step`, :mod:`.step_worker`): in every cache key.

    A change to that code invalidates every cached parse: a fixed parser is never shadowed by the output
    of the old one.
    """
    from planner.meshio import parse, step, step_worker

    h = hashlib.sha256()
    for module in (parse, step, step_worker):
        h.update(Path(module.__file__ or "").read_bytes())
    return h.hexdigest()[:16]


@functools.cache
def _version(package: str) -> str:
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def _read_parts(
    path: Path, info: dict[str, Any] | None = None
) -> tuple[list[tuple[Array, IntArray]], int] | None:
    try:
        with np.load(path, allow_pickle=False) as npz:
            n_parts = int(npz["n_parts"])
            parts = [
                (np.asarray(npz[f"v{i}"], dtype=np.float64), np.asarray(npz[f"f{i}"], dtype=np.int64))
                for i in range(n_parts)
            ]
            n_ignored = int(npz["n_ignored"])
            if info is not None and "file_units" in npz.files:
                info["file_units"] = [str(u) for u in npz["file_units"].tolist()]
        touch(path)
        return parts, n_ignored
    except FileNotFoundError:
        return None
    except Exception as exc:  # a truncated or foreign file: parse again (and overwrite it)
        _LOG.warning("mesh parse cache %s unreadable (%s): parsing again", path, exc)
        return None


def _write_parts(
    path: Path, parts: list[tuple[Array, IntArray]], n_ignored: int, info: dict[str, Any] | None = None
) -> None:
    arrays: dict[str, Any] = {"n_parts": np.array(len(parts)), "n_ignored": np.array(n_ignored)}
    if info and "file_units" in info:
        arrays["file_units"] = np.array(info["file_units"], dtype=str)
    for i, (vertices, faces) in enumerate(parts):
        arrays[f"v{i}"] = vertices
        arrays[f"f{i}"] = faces
    try:
        write_atomic(path, lambda f: np.savez(f, **arrays))  # a reader sees the old entry or the new one
        prune(path.parent.parent, DATA_PATTERNS)
    except OSError as exc:  # a read-only or full cache folder only costs the next call a parse
        _LOG.warning("mesh parse cache %s not written: %s", path, exc)


#: Parsed meshes by content hash (and format, units, name, pose, limits): a service resolving many
#: scenarios in the same cabin parses its file once. Meshes are immutable (read-only arrays), so one
#: object is shared. Bounded by entries and by the faces they hold.
MESH_CACHE_ENTRIES = 8
MESH_CACHE_MAX_FACES = 2_000_000
_MESH_CACHE: BoundedLRU[Hashable, LoadedMesh] = BoundedLRU(
    MESH_CACHE_ENTRIES, lambda m: len(m.faces), MESH_CACHE_MAX_FACES
)


def _cache_get(key: Hashable) -> LoadedMesh | None:
    return _MESH_CACHE.get(key)


def _cache_put(key: Hashable, mesh: LoadedMesh) -> None:
    _MESH_CACHE.put(key, mesh)


def clear_mesh_cache() -> None:
    """Forget every parsed mesh (tests, benchmarks)."""
    _MESH_CACHE.clear()


def _default_name(source: MeshSource) -> str:
    if isinstance(source, bytes | bytearray | memoryview):
        return "<bytes>"
    try:
        return Path(source).name
    except TypeError:
        return repr(source)
