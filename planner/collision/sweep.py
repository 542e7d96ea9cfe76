"""Swept-hull lower bounds: one query bounds a body's distance over a whole run of samples.

A body is the convex hull of its *vertices* (a box: its 8 corners) or of them grown by a radius (a capsule:
its 2 axis end points grown by its radius). Over a run of samples i..j of a path, take the convex hull H of
the body's vertices at the run's two ends (16 points for a box, 4 for a capsule) and, for each sample s of
the run, e_s = the largest distance of a vertex v_s from the segment between the same vertex at the ends
[v_i, v_j] (a subset of H). Every vertex of the body at s then lies in H grown by e = max_s e_s, which is
convex, so the whole body at s does (grown by the capsule's radius r); hence, for any fixed target C (the
cabin mesh, an obstacle),

    d(body_s, C) >= d(H, C) - e - r    for every sample s in i..j.

When the body only translates along a straight line over the run (a carriage on its rail, a payload on its
insertion line), e = 0 and d(H, C) is the smallest distance of the continuous sweep: one query settles a
*flat* minimum that per-sample Lipschitz bounds could only approach sample by sample. Curved motions make e
grow with the square of the run's length, so halving a run that does not settle converges quickly
(:meth:`planner.collision.along.AlongPath.clearance` does so, best first).

The planner computes d(H, C) compiled, as a certified lower bound (Wolfe's minimum-norm point of the
differences of H's points with the target's: :func:`swept_bound_tree` on the cabin's or an obstacle's
triangle tree, :func:`swept_bound_shape` against the other body of a robot pair). :func:`swept_bound` is
FCL's route, kept for the reference worlds and the tests: H an FCL convex shape (a capsule's end points
thickened to cubes of half size :data:`THICKEN_M` so that H is never flat, :data:`GJK_SLACK_M` subtracted
for the hull's joggled facets). FCL's GJK on such flat hulls can stop *above* the distance (by up to 34 mm
on a robot pair, ``tests/collision/test_sweep.py``), so the planner's certificates do not use it. A hull that
touches the target proves nothing (``-inf``).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import fcl
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import ConvexHull, QhullError

from planner.collision.kernels.buffers import MeshTree
from planner.collision.kernels.codes import ROUND_M
from planner.collision.kernels.entries import DEFAULT as KERNELS
from planner.core.types import Array, IntArray
from planner.robots.geometry import BOX_CORNER_SIGNS, Shape

#: Half size [m] of the cube each capsule end point is thickened to (a flat hull is no FCL convex).
THICKEN_M = 1e-6
#: Subtracted from every hull distance [m]: qhull's joggled facets (~1e-10 m on cabin coordinates) and the
#: tolerance of FCL's GJK (1e-6 relative): a micrometre, far below the figure's 0.1 mm.
GJK_SLACK_M = 1e-6

_REQUEST = fcl.DistanceRequest()


def body_vertices(poses: Array, shape: Shape) -> Array:
    """The body's vertices (n, V, 3) in the base frame at poses (n, 13) (R column-major, centre, length).

    A box: its 8 corners; a capsule: its 2 axis end points (the posed length, ``poses[:, 12]``).
    """
    n = poses.shape[0]
    R = poses[:, :9].reshape(n, 3, 3).transpose(0, 2, 1)  # R[s, :, k]: body axis k in the base frame
    p = poses[:, 9:12]
    if shape.kind == "box":
        local = _local_corners(shape)  # (8, 3)
        Rt = R.transpose(0, 2, 1)  # (R local)^T = local^T R^T, written out (no threaded BLAS for 3 x 3)
        return (
            p[:, None, :]
            + local[None, :, 0, None] * Rt[:, None, 0, :]
            + local[None, :, 1, None] * Rt[:, None, 1, :]
            + local[None, :, 2, None] * Rt[:, None, 2, :]
        )
    half = (0.5 * poses[:, 12])[:, None] * R[:, :, 2]  # (n, 3)
    return np.stack([p - half, p + half], axis=1)


def body_vertices_along(poses: Array, b: int, shape: Shape) -> Array:
    """:func:`body_vertices` of body b at every sample of poses (N, B, 13): compiled, the same bits."""
    return KERNELS.path_vertices(np.ascontiguousarray(poses), b, _local_corners(shape), shape.kind == "box")


def pair_vertices_along(poses: Array, a: int, b: int, shape: Shape) -> Array:
    """Body a's vertices in body b's frame at every sample of poses (N, B, 13) (``shape``: a's).

    :func:`body_vertices` of :func:`relative_poses`, compiled: the same bits.
    """
    local, box = _local_corners(shape), shape.kind == "box"
    return KERNELS.pair_vertices(np.ascontiguousarray(poses), a, b, local, box)


@lru_cache(maxsize=256)
def _local_corners(shape: Shape) -> Array:
    """A box's 8 corners in its frame (8, 3) (a capsule's: unused zeros), read-only."""
    local = (
        BOX_CORNER_SIGNS * (0.5 * np.asarray(shape.size, dtype=float))
        if shape.kind == "box"
        else np.zeros((8, 3))
    )
    local.flags.writeable = False
    return local


def pose_offsets(poses_a: Array, poses_b: Array, shapes: tuple[Shape, ...]) -> Array:
    """How far any point of each body is between two poses of it: (M, B) [m], an upper bound.

    From poses (M, B, 13) each: a box's point p + R c (|c| <= h, its half-diagonal) moves by
    |dp + dR c| <= |dp| + |dR|_F h; a capsule's axis end points p +- z L / 2 move by at most
    |dp| + |d(z L)| / 2, and so does every point of its axis segment (a convex combination of the two).
    A box's distance to anything fixed, and a capsule's (its axis segment's less its radius), differ by no
    more between the two poses.
    """
    # Each body its own task: :func:`task_offsets` (compiled, the same bits as the numpy formula).
    bodies = np.arange(len(shapes), dtype=np.int64)
    return task_offsets(poses_a, poses_b, shapes, bodies, np.full(len(shapes), -1, dtype=np.int64))


@lru_cache(maxsize=256)
def _box_halves(shapes: tuple[Shape, ...]) -> tuple[NDArray[np.bool_], Array]:
    """(which bodies are boxes, each box's half-diagonal [m], 0 for a capsule) of a world's shapes."""
    box = np.array([s.kind == "box" for s in shapes])
    half = np.array([0.5 * float(np.linalg.norm(s.size)) if s.kind == "box" else 0.0 for s in shapes])
    box.flags.writeable = False
    half.flags.writeable = False
    return box, half


def task_offsets(
    poses_a: Array, poses_b: Array, shapes: tuple[Shape, ...], col_a: IntArray, col_b: IntArray
) -> Array:
    """:func:`pose_offsets` per task (M, T): body col_a[t]'s, plus body col_b[t]'s where that is >= 0.

    A task of one body (against the cabin, an obstacle) is as far from anything fixed as its body moves;
    a pair's distance changes by at most both bodies' moves. Compiled, the same bits as the per-body
    offsets summed by numpy.
    """
    box, half = _box_halves(shapes)
    return KERNELS.task_offsets(
        np.ascontiguousarray(poses_a), np.ascontiguousarray(poses_b), box, half, col_a, col_b
    )


def grown_radius(shape: Shape) -> float:
    """The radius the body's vertex hull is grown by: a capsule's radius, 0 for a box."""
    return float(shape.radius) if shape.kind == "capsule" else 0.0


def hull_deviation(verts: Array) -> float:
    """The hull's deviation e: the largest distance of verts[s, v] from [verts[0, v], verts[-1, v]] [m].

    Over every sample s and vertex v of ``verts`` (n, V, 3).
    """
    return KERNELS.hull_deviation(np.ascontiguousarray(verts))  # compiled: :mod:`.kernels.offsets`


def hull_object(verts: Array, shape: Shape) -> fcl.CollisionObject:
    """The FCL convex hull of the body's vertices at the run's two ends (verts (n, V, 3))."""
    pts = np.vstack([verts[0], verts[-1]])
    if shape.kind == "capsule":
        pts = (pts[:, None, :] + THICKEN_M * BOX_CORNER_SIGNS[None]).reshape(-1, 3)
    try:
        hull = ConvexHull(pts, qhull_options="QJ")
    except QhullError:  # all points (nearly) equal: the cube around their centre
        c = pts.mean(axis=0)
        pts = c + (float(np.max(np.abs(pts - c))) + THICKEN_M) * BOX_CORNER_SIGNS
        hull = ConvexHull(pts, qhull_options="QJ")
    simplices = hull.simplices.astype(np.int32)
    faces = np.hstack([np.full((len(simplices), 1), 3, dtype=np.int32), simplices]).ravel()
    return fcl.CollisionObject(
        fcl.Convex(np.ascontiguousarray(hull.points, dtype=float), len(simplices), faces), fcl.Transform()
    )


def relative_poses(poses_a: Array, poses_b: Array) -> Array:
    """Poses (n, 13) of body a in body b's frame, from both bodies' poses (n, 13) in the base frame.

    A pair's distance is body a's distance to body b fixed at the origin: the pair's swept hull is a's
    vertices in b's frame (:func:`swept_bound_shape` against b's shape at the origin).
    """
    n = poses_a.shape[0]
    Ra = poses_a[:, :9].reshape(n, 3, 3).transpose(0, 2, 1)
    Rb = poses_b[:, :9].reshape(n, 3, 3).transpose(0, 2, 1)
    R = np.einsum("nji,njk->nik", Rb, Ra)  # Rb^T Ra
    p = np.einsum("nji,nj->ni", Rb, poses_a[:, 9:12] - poses_b[:, 9:12])
    out = np.empty_like(poses_a)
    out[:, :9] = R.transpose(0, 2, 1).reshape(n, 9)  # column-major again
    out[:, 9:12] = p
    out[:, 12] = poses_a[:, 12]
    return out


def swept_bound_tree(verts: Array, shape: Shape, tree: MeshTree) -> float:
    """:func:`swept_bound` against the cabin's triangle tree, compiled (:mod:`.kernels.mesh`).

    The hull is the vertices at the run's two ends as they are (no hull is built: the minimum-norm search
    needs only the points); its distance is a certified lower bound (FCL's to 1e-11 m where FCL's is exact,
    ``tests/collision/test_mesh_tree.py``), less :data:`~.kernels.codes.ROUND_M` for rounding.
    """
    d = KERNELS.hull_mesh_lower(np.ascontiguousarray(np.vstack([verts[0], verts[-1]])), tree)
    return run_bound(d, verts, shape, ROUND_M)


def swept_bound_shape(verts: Array, shape: Shape, other: Shape, length: float) -> float:
    """:func:`swept_bound` against another body fixed at the origin (a pair), compiled (:mod:`.kernels.mesh`).

    ``other`` centred at the origin in its own frame (a capsule of the posed ``length``); the hull is the
    vertices at the run's two ends as they are. Its distance is a certified lower bound, the hulls' distance
    to rounding where the minimum-norm search converges (``tests/collision/test_sweep.py``: FCL's GJK on
    these flat hulls stopped up to 34 mm above it), less :data:`~.kernels.codes.ROUND_M`.
    """
    if other.kind == "box":
        half, radius = 0.5 * np.asarray(other.size, dtype=float), 0.0
    else:
        half, radius = np.array([0.0, 0.0, 0.5 * length]), float(other.radius)
    points = np.ascontiguousarray(np.vstack([verts[0], verts[-1]]))
    return run_bound(KERNELS.hull_shape_lower(points, half, radius), verts, shape, ROUND_M)


def swept_bound(verts: Array, shape: Shape, target: Any) -> float:
    """Certified lower bound of the body's distance to ``target`` at every sample of a run.

    Args:
        verts: The body's vertices (n, V, 3) at the run's samples, n >= 1 (:func:`body_vertices`).
        shape: The body's shape.
        target: The fixed FCL object (the cabin mesh, an obstacle's mesh, the other body of a pair).

    Returns:
        d(H, target) - e - r - :data:`GJK_SLACK_M`, or ``-inf`` when the hull touches the target.
    """
    d = float(fcl.distance(hull_object(verts, shape), target, _REQUEST, fcl.DistanceResult()))
    return run_bound(d, verts, shape, GJK_SLACK_M)


def run_bound(d: float, verts: Array, shape: Shape, slack: float) -> float:
    """The hull's distance ``d`` less the run's deviation e, the radius r and ``slack``; -inf: it touches."""
    if not d > 0.0:
        return -np.inf
    return d - hull_deviation(verts) - grown_radius(shape) - slack
