"""Swept-hull bounds: below the exact distance at every sample of a run, exact for a straight translation."""

from __future__ import annotations

import fcl
import numpy as np
import pytest
import trimesh

from planner.collision.sweep import (
    body_vertices,
    body_vertices_along,
    hull_deviation,
    pair_vertices_along,
    pose_offsets,
    relative_poses,
    swept_bound,
    swept_bound_shape,
    task_offsets,
)
from planner.robots.geometry import Shape

BOX = Shape("box", (0.3, 0.2, 0.1))
CAPSULE = Shape("capsule", radius=0.04, length=0.4)


def _room() -> fcl.CollisionObject:
    """The inside of a 2 x 2 x 6 m box room, as a triangle mesh (the cabin of these tests)."""
    m = trimesh.creation.box(extents=(2.0, 2.0, 6.0))
    model = fcl.BVHModel()
    model.beginModel(len(m.vertices), len(m.faces))
    model.addSubModel(np.asarray(m.vertices, dtype=float), np.asarray(m.faces, dtype=np.int32))
    model.endModel()
    return fcl.CollisionObject(model, fcl.Transform())


def shape_object(shape: Shape, length: float) -> fcl.CollisionObject:
    """A body's shape at the origin as an FCL object (a capsule of the posed ``length``): a pair's target."""
    geom = fcl.Box(*shape.size) if shape.kind == "box" else fcl.Capsule(shape.radius, length)
    return fcl.CollisionObject(geom, fcl.Transform())


def _pose(R: np.ndarray, p: np.ndarray, length: float = 0.0) -> np.ndarray:
    return np.concatenate([R.T.ravel(), p, [length]])  # R column-major, centre, capsule length


def _exact(shape: Shape, pose: np.ndarray, target: fcl.CollisionObject) -> float:
    geom = fcl.Box(*shape.size) if shape.kind == "box" else fcl.Capsule(shape.radius, pose[12])
    obj = fcl.CollisionObject(geom, fcl.Transform(pose[:9].reshape(3, 3).T, pose[9:12]))
    return float(fcl.distance(obj, target, fcl.DistanceRequest(), fcl.DistanceResult()))


def _rotation(rng: np.random.Generator) -> np.ndarray:
    return trimesh.transformations.random_rotation_matrix(rng.random(3))[:3, :3]


def test_a_straight_translation_gives_the_exact_minimum_of_its_samples() -> None:
    room, rng = _room(), np.random.default_rng(1)
    for shape in (BOX, CAPSULE):
        for _ in range(20):
            R = _rotation(rng)
            p0 = rng.uniform(-0.4, 0.4, 3)
            u = rng.normal(size=3)
            u *= 0.3 / np.linalg.norm(u)
            poses = np.array([_pose(R, p0 + s * u, shape.length) for s in np.linspace(0.0, 1.0, 201)])
            exact = [_exact(shape, p, room) for p in poses]
            v = swept_bound(body_vertices(poses, shape), shape, room)
            assert v <= min(exact) + 1e-12
            # The hull's distance is the continuous sweep's: the samples' minimum within their spacing.
            assert v >= min(exact) - 0.3 / 200 - 1e-5, (v, min(exact))


def test_curved_runs_and_pairs_are_bounded_from_below_at_every_sample() -> None:
    room, rng = _room(), np.random.default_rng(2)
    for shape in (BOX, CAPSULE):
        for _ in range(20):
            w = rng.normal(size=3)
            p0, R0 = rng.uniform(-0.3, 0.3, 3), _rotation(rng)
            poses = []
            for s in np.linspace(0.0, 1.0, 41):
                a = 0.6 * s
                K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]) / np.linalg.norm(w)
                Rs = np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K
                poses.append(_pose(Rs @ R0, p0 + 0.2 * np.array([np.cos(3 * s), np.sin(3 * s), s]), 0.4))
            poses_a = np.array(poses)
            v = swept_bound(body_vertices(poses_a, shape), shape, room)
            assert v <= min(_exact(shape, p, room) for p in poses_a) + 1e-12
            # The pair (this body, a box fixed 0.6 m away in its own motion): a's vertices in b's frame.
            Rb = _rotation(rng)
            pb = np.tile(_pose(Rb, p0 + np.array([0.6, 0.0, 0.0])), (len(poses_a), 1))
            rel = relative_poses(poses_a, pb)
            target = shape_object(BOX, 0.0)
            v = swept_bound(body_vertices(rel, shape), shape, target)
            other = fcl.CollisionObject(fcl.Box(*BOX.size), fcl.Transform(Rb, pb[0, 9:12]))
            assert v <= min(_exact(shape, p, other) for p in poses_a) + 1e-12


def _nearby_poses(rng: np.random.Generator, n_bodies: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Random poses (n, B, 13) of B bodies, and each moved a little (a turn under 0.05 rad, ~1 cm)."""
    poses_a = np.empty((n, n_bodies, 13))
    poses_b = np.empty_like(poses_a)
    for k in range(n):
        for b in range(n_bodies):
            R = _rotation(rng)
            p = rng.normal(size=3)
            poses_a[k, b] = _pose(R, p, 0.3 + 0.1 * rng.random())
            step = trimesh.transformations.rotation_matrix(0.05 * rng.random(), rng.normal(size=3))[:3, :3]
            poses_b[k, b] = _pose(step @ R, p + 0.01 * rng.normal(size=3), 0.3 + 0.1 * rng.random())
    return poses_a, poses_b


def test_pose_offsets_bound_every_vertex_move_and_are_the_plain_formula_bit_for_bit() -> None:
    """Each body's offset bounds how far any of its vertices moves; the written-out sums change no bit.

    The plain formula: |dp| + |dR|_F h (a box, h its half-diagonal) or |dp| + |d(z L)| / 2 (a capsule),
    summed by np.sum.
    """
    shapes = (BOX, CAPSULE, Shape("box", (0.05, 0.6, 0.2)))
    poses_a, poses_b = _nearby_poses(np.random.default_rng(11), len(shapes), 300)
    got = pose_offsets(poses_a, poses_b, shapes)
    d = poses_b - poses_a
    half = np.array([0.5 * np.linalg.norm(s.size) if s.kind == "box" else 0.0 for s in shapes])
    dzl = poses_b[:, :, 6:9] * poses_b[:, :, 12:13] - poses_a[:, :, 6:9] * poses_a[:, :, 12:13]
    plain = np.sqrt(np.sum(d[:, :, 9:12] ** 2, axis=2)) + np.where(
        np.array([s.kind == "box" for s in shapes])[None, :],
        np.sqrt(np.sum(d[:, :, :9] ** 2, axis=2)) * half[None, :],
        0.5 * np.sqrt(np.sum(dzl**2, axis=2)),
    )
    assert np.array_equal(got, plain)
    for b, shape in enumerate(shapes):
        moved = np.linalg.norm(
            body_vertices(poses_b[:, b], shape) - body_vertices(poses_a[:, b], shape), axis=2
        )
        assert np.all(moved.max(axis=1) <= got[:, b] + 1e-15)


def test_hull_deviation_is_the_largest_distance_from_the_chords_bit_for_bit() -> None:
    """The compiled deviation is the numpy formula's, bit for bit; a straight run's is zero (to rounding)."""
    rng = np.random.default_rng(5)
    for n, v in ((1, 8), (2, 2), (7, 8), (300, 8)):
        verts = np.cumsum(rng.normal(0.0, 0.01, (n, v, 3)), axis=0)
        a, b = verts[0], verts[-1]
        ab = b - a
        den = (ab * ab).sum(axis=1)
        rel = verts - a[None]
        t = (rel * ab[None]).sum(axis=2) / np.where(den > 0.0, den, 1.0)[None]
        off = rel - np.clip(t, 0.0, 1.0)[..., None] * ab[None]
        assert hull_deviation(verts) == float(np.sqrt(np.max((off * off).sum(axis=2))))
    line = np.linspace(0.0, 1.0, 50)[:, None, None] * np.array([[0.3, -0.2, 0.1], [0.0, 0.0, 0.0]])[None]
    assert hull_deviation(line) < 1e-15  # rounding only


def test_compiled_vertices_along_a_path_are_the_numpy_formulas_bit_for_bit() -> None:
    """A body's vertices at every sample, and body a's in body b's frame, as body_vertices(relative_poses)."""
    rng = np.random.default_rng(17)
    shapes = (BOX, CAPSULE, Shape("box", (0.05, 0.6, 0.2)))
    n = 400
    poses = np.empty((n, len(shapes), 13))
    for k in range(n):
        for b in range(len(shapes)):
            poses[k, b] = _pose(_rotation(rng), rng.normal(size=3), 0.3 + 0.1 * rng.random())
    for b, shape in enumerate(shapes):
        assert np.array_equal(body_vertices_along(poses, b, shape), body_vertices(poses[:, b], shape))
        for a, other in enumerate(shapes):
            if a == b:
                continue
            want = body_vertices(relative_poses(poses[:, b], poses[:, a]), shape)
            assert np.array_equal(pair_vertices_along(poses, b, a, shape), want), (b, other)
    with pytest.raises(ValueError, match="body index"):
        body_vertices_along(poses, 3, BOX)


def test_task_offsets_are_each_task_s_bodies_offsets_bit_for_bit() -> None:
    """A single body's column is its own offset, a pair's the sum of both (as numpy adds them)."""
    shapes = (BOX, CAPSULE, Shape("box", (0.05, 0.6, 0.2)))
    poses_a, poses_b = _nearby_poses(np.random.default_rng(23), len(shapes), 200)
    per_body = pose_offsets(poses_a, poses_b, shapes)
    col_a = np.array([0, 1, 2, 0, 1, 2], dtype=np.int64)
    col_b = np.array([-1, -1, -1, 1, 2, -1], dtype=np.int64)
    got = task_offsets(poses_a, poses_b, shapes, col_a, col_b)
    want = np.column_stack(
        [per_body[:, 0], per_body[:, 1], per_body[:, 2], per_body[:, 0] + per_body[:, 1]]
        + [per_body[:, 1] + per_body[:, 2], per_body[:, 2]]
    )
    assert np.array_equal(got, want)
    with pytest.raises(ValueError, match="col_b"):
        task_offsets(poses_a, poses_b, shapes, col_a, np.array([3, -1, -1, 1, 2, -1], dtype=np.int64))
    with pytest.raises(ValueError, match="col_a"):
        task_offsets(poses_a, poses_b, shapes, np.array([-1], dtype=np.int64), np.array([-1], dtype=np.int64))


def _hull_distance(points: np.ndarray, half: np.ndarray, radius: float) -> float:
    """conv(points)'s distance to the box [-half, half] grown by radius, by an independent minimisation.

    The squared distance of a hull point sum_i l_i p_i to the box is convex in the weights l (on the
    simplex): SLSQP from the centroid and from the nearest vertex, the smaller.
    """
    from scipy.optimize import minimize

    def sq(lam: np.ndarray) -> float:
        return float(np.sum(np.maximum(np.abs(lam @ points) - half, 0.0) ** 2))

    n, best = len(points), np.inf
    nearest = int(np.argmin([sq(np.eye(n)[i]) for i in range(n)]))
    for lam0 in (np.full(n, 1.0 / n), 0.9 * np.eye(n)[nearest] + 0.1 / n):  # convex: two starts suffice
        res = minimize(
            sq,
            lam0,
            bounds=[(0.0, 1.0)] * n,
            constraints=[{"type": "eq", "fun": lambda lam: float(lam.sum() - 1.0)}],
            method="SLSQP",
            options={"ftol": 1e-18, "maxiter": 500},
        )
        best = min(best, np.sqrt(sq(res.x)))
    return max(best - radius, 0.0)


def test_a_pairs_hull_bound_is_its_distance_where_fcls_gjk_said_34_mm_more() -> None:
    """The pair's swept bound: the compiled minimum-norm search, exact where FCL's GJK overstated.

    Recorded on hatch-bay-insert's gate: link_ab (a capsule, r = 30 mm) in the payload box's frame over a
    run where neither moved relative to the other. The hull of its end points is a segment (thickened by
    a micrometre for FCL's convex); FCL 0.11's GJK gave 0.7577 m to the payload's box with its nearest
    point on a corner, where the segment is 0.7235 m from the box's face. A lower bound 34 mm above the
    distance would have let a pair's run be covered, or its samples be left out of the clearance figure,
    on a false premise.
    """
    a = np.array([-4.4920565864431470e-17, -6.7495263945751827e-01, -1.1230179723245257e00])
    b = np.array([-3.3603755310868693e-17, -3.9217341742652395e-01, -8.4011178365494998e-01])
    verts = np.array([[a, b], [a, b]])  # (2 samples, 2 capsule ends, 3)
    payload = Shape("box", (0.45, 0.35, 0.3))
    s = np.linspace(0.0, 1.0, 200_001)[:, None]
    segment = a + s * (b - a)
    exact = float(
        np.min(np.linalg.norm(np.maximum(np.abs(segment) - 0.5 * np.array(payload.size), 0.0), axis=1))
    )
    assert exact == pytest.approx(0.7234767, abs=1e-6)
    v = swept_bound_shape(verts, Shape("capsule", radius=0.03, length=0.4), payload, 0.0)
    assert exact - 0.03 - 1e-8 <= v <= exact - 0.03


@pytest.mark.parametrize("kind", ["box", "capsule"])
def test_the_pairs_compiled_hull_bound_is_the_hull_distance_from_below(kind: str) -> None:
    """hull_shape_lower against an independent minimisation: never above it, within 1e-7 m of it.

    Random hulls (a box's 16 corners or a capsule's 4 ends at a run's two ends, some runs without
    motion, some touching) against a box, a box grown by a radius, and a capsule (a segment grown).
    """
    from planner.collision.kernels.entries import DEFAULT as KERNELS

    rng = np.random.default_rng(7)
    shape = BOX if kind == "box" else CAPSULE
    seen_touching = seen_apart = 0
    for case in range(60):
        poses = np.array([_pose(_rotation(rng), rng.uniform(-0.5, 0.5, 3), shape.length) for _ in range(2)])
        if case % 5 == 0:
            poses[1] = poses[0]  # no relative motion: the same points twice
        points = np.ascontiguousarray(body_vertices(poses, shape).reshape(-1, 3))
        for half, radius in (
            (np.array([0.2, 0.1, 0.15]), 0.0),
            (np.array([0.2, 0.1, 0.15]), 0.03),
            (np.array([0.0, 0.0, 0.2]), 0.05),
        ):
            got = KERNELS.hull_shape_lower(points, half, radius)
            ref = _hull_distance(points, half, radius)
            assert got <= ref + 1e-12, (case, got, ref)
            assert got >= ref - 1e-7, (case, got, ref)
            seen_touching += ref == 0.0
            seen_apart += ref > 0.0
    assert seen_touching and seen_apart


def test_a_pairs_swept_bound_is_below_both_bodies_distance_at_every_sample() -> None:
    """swept_bound_shape on curved relative runs: below the exact FCL distance of the posed bodies."""
    rng = np.random.default_rng(3)
    for shape_a, shape_b in ((CAPSULE, BOX), (BOX, CAPSULE), (BOX, BOX), (CAPSULE, CAPSULE)):
        for _ in range(10):
            w = rng.normal(size=3)
            K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]) / np.linalg.norm(w)
            p0, R0 = rng.uniform(-0.3, 0.3, 3), _rotation(rng)
            rel = []
            for s in np.linspace(0.0, 1.0, 33):
                Rs = np.eye(3) + np.sin(0.5 * s) * K + (1 - np.cos(0.5 * s)) * K @ K
                p = p0 + np.array([0.5, 0.0, 0.0]) + 0.15 * np.array([np.cos(2 * s), np.sin(2 * s), s])
                rel.append(_pose(Rs @ R0, p, shape_a.length))
            rel_a = np.array(rel)
            v = swept_bound_shape(body_vertices(rel_a, shape_a), shape_a, shape_b, shape_b.length)
            other = shape_object(shape_b, shape_b.length)
            exact = min(_exact(shape_a, p, other) for p in rel_a)
            assert v <= exact + 1e-12, (v, exact)
