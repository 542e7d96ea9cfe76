"""Validating parsed geometry and building the :class:`~planner.meshio.types.LoadedMesh`.

On metre-scaled arrays in the mesh frame: finite vertices, plausible size for the declared units, and
degenerate faces (out-of-range indices, repeated indices, zero area) dropped and counted -- refused when
they are more than ``MeshLimits.max_degenerate_fraction`` of the faces read; then unreferenced vertices
dropped, bit-identical ones merged (faces are unchanged), and the pose ``T_base_mesh`` applied (validated
by :func:`validate_pose`: a rigid transform).
"""

from __future__ import annotations

import logging

import numpy as np
from numpy.typing import ArrayLike, NDArray

from planner.core.types import Array, IntArray
from planner.meshio.types import LoadedMesh, MeshLimits, MeshReport, error, fail

_LOG = logging.getLogger(__name__)

_POSE_TOL = 1e-6


def validate_pose(label: str, pose: ArrayLike | None) -> Array:
    """``T_base_mesh`` as a float (4, 4) rigid transform (identity for ``None``), or ``InvalidMesh``."""
    if pose is None:
        return np.eye(4)
    try:
        T = np.array(pose, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise error(label, "pose", f"pose is not a numeric array: {exc}") from exc
    if T.shape != (4, 4):
        raise error(label, "pose", f"pose must be a 4x4 matrix, got shape {T.shape}", shape=list(T.shape))
    if not np.all(np.isfinite(T)):
        fail(label, "pose", "pose contains NaN or Inf")
    R = T[:3, :3]
    orthonormal_error = float(np.max(np.abs(R.T @ R - np.eye(3))))
    if (
        np.max(np.abs(T[3] - (0.0, 0.0, 0.0, 1.0))) > _POSE_TOL
        or orthonormal_error > _POSE_TOL
        or np.linalg.det(R) <= 0.0
    ):
        fail(
            label,
            "pose",
            "pose must be a rigid transform (orthonormal rotation with det +1, last row 0 0 0 1)",
            orthonormal_error=orthonormal_error,
        )
    T[3] = (0.0, 0.0, 0.0, 1.0)
    return T


def validate_and_build(
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
    file_units: str | None = None,
    tessellation_tolerance_m: float | None = None,
    surface_deviation_m: float = 0.0,
) -> LoadedMesh:
    """Steps 5-6 of the pipeline of :func:`~planner.meshio.load_mesh` on metre-scaled, mesh-frame arrays."""
    n_read = len(faces)
    finite = np.isfinite(vertices).all(axis=1)
    if not finite.all():
        n_bad = int(np.count_nonzero(~finite))
        fail(
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
        _check_scale(label, units, float(extent.max()), limits, hint=kind != "step")
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
        fail(
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
        file_units=file_units,
        tessellation_tolerance_m=tessellation_tolerance_m,
        surface_deviation_m=surface_deviation_m,
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


def _check_scale(label: str, units: str, extent_m: float, limits: MeshLimits, *, hint: bool = True) -> None:
    """Refuse meshes whose size is implausible for the declared units, with a hint at the likely fix.

    No hint for a file that declares its own units (STEP): they are not the caller's to change.
    """
    if limits.min_extent_m <= extent_m <= limits.max_extent_m:
        return
    too_big = extent_m > limits.max_extent_m
    why = ""
    if not hint:
        why = f" (the file's own units are {units})"
    elif too_big and units == "m" and limits.min_extent_m <= extent_m * 1e-3 <= limits.max_extent_m:
        why = " -- did you mean mm?"
    elif not too_big and units == "mm" and limits.min_extent_m <= extent_m * 1e3 <= limits.max_extent_m:
        why = " -- did you mean m?"
    bound = (
        f"above the maximum {limits.max_extent_m} m"
        if too_big
        else f"below the minimum {limits.min_extent_m} m"
    )
    fail(
        label,
        "scale",
        f"largest extent {extent_m:.6g} m (declared units {units!r}) is {bound}{why}",
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
