"""Load cabin and payload meshes (STL, OBJ, PLY, GLB/glTF) into validated triangle soups in metres.

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

import hashlib
import logging
from pathlib import Path
from typing import get_args

from numpy.typing import ArrayLike

from planner.meshio.build import validate_and_build, validate_pose
from planner.meshio.parse import concatenate, parse_obj, parse_with_trimesh
from planner.meshio.sniff import format_of, read_bytes, sniff
from planner.meshio.types import UNIT_SCALE_M, LoadedMesh, MeshLimits, MeshSource, Units, error, fail

_LOG = logging.getLogger(__name__)


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
        raise error(
            label, "units", f"units must be one of {list(get_args(Units))}, got {units!r}", units=str(units)
        )
    T_base_mesh = validate_pose(label, pose)
    fmt = format_of(label, source, file_type)
    data = read_bytes(label, source, limits)
    if not data:
        fail(label, "empty", "the file is empty (0 bytes)", byte_size=0)
    sha256 = hashlib.sha256(data).hexdigest()

    kind = sniff(label, fmt, data, limits)
    if kind == "obj":
        parts, n_ignored = [parse_obj(label, data, limits)], 0
    else:
        parts, n_ignored = parse_with_trimesh(label, fmt, data, limits)

    mesh_vertices, faces, n_faces_read = concatenate(parts)
    if n_ignored:
        _LOG.warning("mesh %r: skipped %d non-triangle scene part(s)", label, n_ignored)
    if n_faces_read == 0:
        fail(
            label, "no_faces", "the file contains no triangles", n_parts=len(parts), n_ignored_parts=n_ignored
        )

    mesh_vertices = mesh_vertices * UNIT_SCALE_M[units]
    return validate_and_build(
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


def _default_name(source: MeshSource) -> str:
    if isinstance(source, bytes | bytearray | memoryview):
        return "<bytes>"
    try:
        return Path(source).name
    except TypeError:
        return repr(source)
