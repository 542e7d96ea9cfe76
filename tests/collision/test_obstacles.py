"""Obstacles added to a cabin: certified state and motion checks against exact distances.

The compiled obstacle bounds (:mod:`planner.collision.kernels.obstacles`) against their numpy route
(:class:`~planner.collision.oracle.ReferenceObstacles`) and the exact distances they bound.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import ConvexHull

from planner.collision.bodies import BodySet, PayloadGeometry, Shape, robot_bodies
from planner.collision.obstacles import Obstacle, ObstacleSet
from planner.collision.oracle import ReferenceObstacles, ReferenceWorld
from planner.collision.probes import PENETRATION_M
from planner.collision.sweep import body_vertices
from planner.collision.world import CollisionWorld
from planner.robots.cabin8 import Cabin8
from tests.collision.minimise import qp_distance
from tests.conftest import admissible_joints


@pytest.fixture(scope="module")
def worlds(robot: Cabin8) -> tuple[CollisionWorld, CollisionWorld]:
    payload = PayloadGeometry(size=(0.3, 0.3, 0.2), T_tool_payload=np.diag([1.0, 1, 1, 1]))
    T = np.eye(4)
    T[:3, 3] = [0.25, 0.45, 0.3]
    obstacles = (Obstacle.box("unit X", (0.2, 0.2, 0.2), T),)
    plain = CollisionWorld(robot, None, payload)
    return plain, CollisionWorld(robot, None, payload, obstacles=obstacles)


def test_states_proven_clear_keep_the_clearance(
    worlds: tuple[CollisionWorld, CollisionWorld], robot: Cabin8
) -> None:
    plain, world = worlds
    qs = admissible_joints(robot, 300, seed=3)
    clearance = 0.01
    seen = {True: 0, False: 0}
    for q in qs:
        if not plain.is_valid(q, clearance):
            continue
        d = world.obstacle_distance(world.flat_poses(q)).distance_m
        valid = world.is_valid(q, clearance)
        seen[valid] += 1
        if valid:
            assert d >= clearance, d
        else:  # refused only when a body really is within the clearance (boxes grown as boxes: sqrt(3))
            assert d <= np.sqrt(3) * clearance + 1e-9, d
        assert world.check_state(q, clearance).valid == valid
    assert seen[True] > 10 and seen[False] > 5, seen


def test_certified_motions_keep_the_clearance_between_samples(
    worlds: tuple[CollisionWorld, CollisionWorld], robot: Cabin8
) -> None:
    _, world = worlds
    qs = admissible_joints(robot, 120, seed=5)
    clearance, checked = 0.01, 0
    for q_a, q_b in zip(qs[::2], qs[1::2], strict=True):
        q_b = q_a + 0.3 * (q_b - q_a)
        rep = world.check_motion(q_a, q_b, clearance, 0.002)
        if not rep.valid:
            continue
        checked += 1
        for t in np.linspace(0.0, 1.0, 41):
            q = q_a + t * (q_b - q_a)
            assert world.obstacle_distance(world.flat_poses(q)).distance_m >= clearance
    assert checked > 10


def test_an_allowed_pair_is_left_out_and_measured(robot: Cabin8) -> None:
    payload = PayloadGeometry(size=(0.3, 0.3, 0.2))
    q = admissible_joints(robot, 1, seed=7)[0]
    T = robot.fk(q)
    T[:3, 3] += T[:3, 2] * 0.11  # a 1 cm plate 5 mm past the payload's face (at tool z = 0.1)
    plate = Obstacle.box("unit Y", (0.1, 0.1, 0.01), T)
    strict = CollisionWorld(robot, None, payload, obstacles=(plate,))
    allowed = CollisionWorld(
        robot, None, payload, obstacles=(plate,), allowed=frozenset({("payload", "unit Y")})
    )
    pair = ("payload", "unit Y")
    assert pair in [c.bodies for c in strict.check_state(q, 0.01, all_contacts=True).contacts]
    assert pair not in [c.bodies for c in allowed.check_state(q, 0.01, all_contacts=True).contacts]
    d = allowed.obstacle_distance(allowed.flat_poses(q), obstacle="unit Y", body="payload")
    assert d.distance_m == pytest.approx(0.005, abs=1e-6) and d.bodies == pair
    assert allowed.obstacle_distance(allowed.flat_poses(q)).bodies != pair  # left out of the world's own


def _rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random rotation (QR of a Gaussian matrix, signs fixed, det +1)."""
    Q, R = np.linalg.qr(rng.normal(size=(3, 3)))
    Q = Q * np.sign(np.diag(R))
    return Q if np.linalg.det(Q) > 0 else -Q


def _random_obstacles(rng: np.random.Generator, n: int) -> tuple[Obstacle, ...]:
    """Boxes and convex meshes at arbitrary rotations, around the robot's workspace."""
    out = []
    for i in range(n):
        T = np.eye(4)
        T[:3, :3] = _rotation(rng)
        T[:3, 3] = rng.uniform([-0.5, -0.8, -0.2], [1.5, 0.8, 1.2])
        if rng.random() < 0.7:
            out.append(Obstacle.box(f"box {i}", tuple(rng.uniform(0.02, 0.6, 3)), T))
        else:
            points = rng.uniform(-0.3, 0.3, (10, 3)) * rng.uniform(0.1, 1.0, 3)
            hull = ConvexHull(points)
            out.append(Obstacle(f"mesh {i}", T, vertices=points, faces=hull.simplices.astype(np.int64)))
    return tuple(out)


def _random_poses(rng: np.random.Generator, n_states: int, bodies: BodySet) -> np.ndarray:
    """Body poses (N, B, 13) at arbitrary rotations and places; capsules of random lengths up to their own.

    (A capsule's fine cover serves every length up to the shape's, :meth:`Shape.sphere_cover`.)
    """
    n_b = len(bodies.names)
    poses = np.zeros((n_states, n_b, 13))
    for k in range(n_states):
        for b, shape in enumerate(bodies.shapes):
            poses[k, b, :9] = _rotation(rng).T.ravel()  # column-major R
            poses[k, b, 9:12] = rng.uniform([-0.8, -1.0, -0.4], [1.8, 1.0, 1.4])
            poses[k, b, 12] = rng.uniform(0.0, shape.length) if shape.kind == "capsule" else 0.0
    return poses


def _same_bounds(got: np.ndarray, ref: np.ndarray) -> None:
    """Equal to the numpy route to float rounding, and never above it (bounds are certificates)."""
    assert got.shape == ref.shape
    np.testing.assert_array_equal(np.isinf(got), np.isinf(ref))
    finite = np.isfinite(ref)
    assert np.all(got[finite] <= ref[finite] + 1e-12 * (1.0 + np.abs(ref[finite])))
    np.testing.assert_allclose(got[finite], ref[finite], rtol=0, atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_compiled_obstacle_bounds_equal_the_numpy_route(seed: int) -> None:
    """The compiled bounds are the numpy route's at random poses, obstacles, allowed pairs and thresholds.

    Rotated boxes and meshes, box and capsule bodies (random lengths), some pairs allowed (+inf), scalar and
    per-body thresholds (the fine cover refines a body wherever a coarse bound is not above its threshold).
    The bounds are also below the exact FCL distance of every pair checked.
    """
    rng = np.random.default_rng(seed)
    bodies = _bodies()
    obstacles = _random_obstacles(rng, int(rng.integers(1, 6)))
    pairs = [(b, o.name) for b in bodies.names for o in obstacles]
    allowed = frozenset(p for p in pairs if rng.random() < 0.15)
    fast = ObstacleSet(obstacles, bodies, allowed)
    ref = ReferenceObstacles(obstacles, bodies, allowed)
    poses = _random_poses(rng, 6, bodies)
    n_b = len(bodies.names)
    for flat in poses:
        for threshold in (-1.0, 0.0, float(rng.uniform(0.0, 0.6)), np.inf, rng.uniform(-0.2, 0.8, (n_b, 1))):
            got = fast.lower_bounds(flat, threshold)
            _same_bounds(got, ref.lower_bounds(flat, threshold))
        lb = fast.lower_bounds(flat, np.inf)
        for b, o in zip(*np.nonzero(np.isfinite(lb)), strict=True):
            if rng.random() < 0.2:  # a sample of the pairs: FCL distances cost ~0.1 ms
                d = fast.distance(flat, int(b), int(o))[0]  # overlapping: <= 0 (-1 without a depth)
                assert lb[b, o] <= max(d, 0.0) + 1e-9, (b, o, lb[b, o], d)
    for allowed_too in (False, True):
        _same_bounds(
            fast.coarse_bounds_batch(poses, allowed_too), ref.coarse_bounds_batch(poses, allowed_too)
        )
    rows = np.array([4, 0, 4, 2], dtype=np.int64)
    for b in range(n_b):
        _same_bounds(fast.fine_bounds_batch(poses, rows, b), ref.fine_bounds_batch(poses, rows, b))
    assert fast.fine_bounds_batch(poses, np.zeros(0, dtype=np.int64), 0).shape == (0, len(obstacles))


def _bodies() -> BodySet:
    payload = PayloadGeometry(size=(0.45, 0.35, 0.5), T_tool_payload=np.eye(4))
    return robot_bodies(Cabin8().collision_model(), payload)


def test_the_numpy_route_gives_the_same_verdicts_and_reports(
    worlds: tuple[CollisionWorld, CollisionWorld], robot: Cabin8
) -> None:
    """The numpy route decides states and motions as the compiled world does.

    :class:`ReferenceWorld`: the obstacles' bounds by :class:`ReferenceObstacles`, poses by CasADi.
    """
    _, world = worlds
    plan = world.obstacles
    assert plan is not None
    rng = np.random.default_rng(21)
    obstacles = (*plan.obstacles, *_random_obstacles(rng, 3))
    fast = CollisionWorld(robot, None, world.payload, obstacles=obstacles)
    ref = ReferenceWorld(robot, None, world.payload, obstacles=obstacles)
    assert isinstance(ref.obstacles, ReferenceObstacles)
    qs = admissible_joints(robot, 80, seed=23)
    verdicts, motions = set(), set()
    for q_a, q_b in zip(qs[:-1], qs[1:], strict=True):
        valid = fast.is_valid(q_a, 0.01)
        verdicts.add(valid)
        assert valid == ref.is_valid(q_a, 0.01)
        assert fast.check_state(q_a, 0.01, all_contacts=True) == ref.check_state(q_a, 0.01, all_contacts=True)
        q_b = q_a + 0.2 * (q_b - q_a)
        got, want = fast.check_motion(q_a, q_b, 0.01), ref.check_motion(q_a, q_b, 0.01)
        assert (got.valid, got.contacts) == (want.valid, want.contacts)
        motions.add((got.valid, bool(got.contacts) and got.contacts[0].kind == "obstacle"))
    assert verdicts == {True, False}
    assert {(True, False), (False, True)} <= motions, motions  # valid ones, and ones an obstacle refuses


def _body_points(flat_b: np.ndarray, shape: Shape) -> tuple[np.ndarray, float]:
    """A body's vertices (a box's corners, a capsule's axis end points) at pose (13,), and its radius."""
    verts = body_vertices(flat_b[None], shape)[0]
    return verts, (float(shape.radius) if shape.kind == "capsule" else 0.0)


def _triangles(obstacle: Obstacle) -> tuple[np.ndarray, np.ndarray]:
    """The obstacle's triangles in the base frame as (vertices, faces) (from its tree: its own copy)."""
    tris = obstacle.tree().tris.reshape(-1, 3)
    return tris, np.arange(len(tris), dtype=np.int64).reshape(-1, 3)


def test_compiled_probes_and_distances_are_fcls_verdicts_and_exact_distances() -> None:
    """The compiled route (each obstacle's triangle tree) against FCL's (the reference route).

    Rotated boxes and convex meshes, box and capsule bodies at random poses: every distance is at most
    FCL's (plus 1e-9 m) and, where FCL's is above it by more than a micrometre (its GJK stops early), equal
    to an independent minimisation; witness points are that far apart. Probes on the body grown to just
    below and just above its distance (grazing) give FCL's verdicts, and the exact distance's.
    """
    rng = np.random.default_rng(31)
    bodies = _bodies()
    obstacles = _random_obstacles(rng, 8)
    fast = ObstacleSet(obstacles, bodies)
    ref = ReferenceObstacles(obstacles, bodies)
    assert fast.compiled and not ref.compiled
    compared = above = grazing = 0
    for flat in _random_poses(rng, 60, bodies):
        lb = fast.lower_bounds(flat, 0.3)
        for b, o in zip(*np.nonzero(lb <= 0.3), strict=True):
            b, o = int(b), int(o)
            d, p_body, p_obs = fast.distance(flat, b, o)
            d_fcl = ref.distance(flat, b, o)[0]
            compared += 1
            if d_fcl <= 0.0 or d <= 0.0:
                assert d == d_fcl == PENETRATION_M, (b, o, d, d_fcl)
                assert fast.hit(flat, b, o, 0.0) and ref.hit(flat, b, o, 0.0)
                continue
            assert d <= d_fcl + 1e-9, (b, o, d, d_fcl)
            assert abs(np.linalg.norm(p_body - p_obs) - d) < 1e-9
            if d_fcl - d > 1e-6:
                above += 1
                verts, radius = _body_points(flat[b], bodies.shapes[b])
                v, f = _triangles(obstacles[o])
                assert abs(d + radius - qp_distance(verts, v, f, d_fcl + radius)) < 1e-8, (b, o)
            # A box grown by g is a box (its corners g sqrt(3) further out), as FCL grows it: it touches
            # where d <= g and may where d <= g sqrt(3); a capsule grown by g touches exactly where d <= g.
            reach = np.sqrt(3.0) if bodies.shapes[b].kind == "box" else 1.0
            for grow in (d * (1 - 1e-3), d * (1 + 1e-3), d / reach * (1 - 1e-3), d / reach * (1 + 1e-3)):
                got = fast.hit(flat, b, o, grow)
                assert got == ref.hit(flat, b, o, grow), (b, o, grow, d)
                if grow >= d or grow * reach < d:
                    assert got == (grow >= d), (b, o, grow, d)
                grazing += 1
    assert compared > 300 and grazing > 300, (compared, grazing)
    assert above > 0  # FCL's distance above the truth somewhere: the case this route exists for


def test_a_body_inside_a_box_obstacle_touches_it() -> None:
    """A body wholly inside a box obstacle touches none of its triangles: it still touches the obstacle.

    The probe says so (FCL's box primitive agrees), the distance is a penetration
    (:data:`~planner.collision.probes.PENETRATION_M`), and a swept run there bounds nothing.
    """
    bodies = _bodies()
    T = np.eye(4)
    T[:3, 3] = [0.4, 0.1, 0.5]
    room = (Obstacle.box("crate", (3.0, 3.0, 3.0), T),)
    fast, ref = ObstacleSet(room, bodies), ReferenceObstacles(room, bodies)
    flat = np.zeros((len(bodies.names), 13))
    flat[:, [0, 4, 8]] = 1.0
    flat[:, 9:12] = [0.4, 0.1, 0.5]
    flat[:, 12] = [s.length if s.kind == "capsule" else 0.0 for s in bodies.shapes]
    for b, shape in enumerate(bodies.shapes):
        assert fast.hit(flat, b, 0, 0.0) and ref.hit(flat, b, 0, 0.0)
        assert fast.distance(flat, b, 0)[0] == PENETRATION_M == ref.distance(flat, b, 0)[0]
        verts = body_vertices(np.repeat(flat[b][None], 3, axis=0), shape)
        assert fast.swept_bound(verts, shape, 0) == -np.inf == ref.swept_bound(verts, shape, 0)
    flat[:, 9:12] = [0.4, 0.1, 5.0]  # well outside: clear, and both routes measure the same distance
    for b in range(len(bodies.names)):
        assert not fast.hit(flat, b, 0, 0.0)
        assert fast.distance(flat, b, 0)[0] == pytest.approx(ref.distance(flat, b, 0)[0], abs=2e-4)


def test_swept_bounds_on_obstacles_are_certified() -> None:
    """A run's compiled swept bound is below every sample's exact distance, and near FCL's bound."""
    rng = np.random.default_rng(37)
    bodies = _bodies()
    obstacles = _random_obstacles(rng, 6)
    fast, ref = ObstacleSet(obstacles, bodies), ReferenceObstacles(obstacles, bodies)
    checked = 0
    for a, z in zip(_random_poses(rng, 40, bodies), _random_poses(rng, 40, bodies), strict=True):
        for b, shape in enumerate(bodies.shapes):
            # a straight run of the body's centre from a to a + 0.1 (z - a), its rotation fixed
            run = np.repeat(a[b][None], 9, axis=0)
            run[:, 9:12] += np.linspace(0.0, 0.1, 9)[:, None] * (z[b, 9:12] - a[b, 9:12])
            verts = body_vertices(run, shape)
            for o in range(len(obstacles)):
                bound = fast.swept_bound(verts, shape, o)
                if not np.isfinite(bound) or bound > 0.3:
                    continue
                checked += bound > 0.0
                flats = np.repeat(a[None], len(run), axis=0)
                flats[:, b] = run
                exact = min(fast.distance(f, b, o)[0] for f in flats)
                assert bound <= max(exact, 0.0) + 1e-12, (b, o, bound, exact)  # a touch: -1
                assert bound >= ref.swept_bound(verts, shape, o) - 1e-5, (b, o)
    assert checked > 50, checked
