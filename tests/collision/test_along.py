"""The batched pass over a sampled path: its certificate agrees with ``check_path``, its figure is exact."""

from __future__ import annotations

from pathlib import Path

import fcl
import numpy as np
import pytest

from planner.collision.along import AlongPath
from planner.collision.obstacles import Obstacle
from planner.collision.sweep import body_vertices
from planner.collision.world import CollisionWorld
from planner.gate.requirements import GATE_MOTION_MARGIN_M
from planner.plan.pipeline import Planner
from planner.robots.cabin8 import Cabin8
from planner.scenario.resolve import ResolvedScenario, load_scenario
from tests.conftest import admissible_joints

SCENARIO = Path(__file__).parents[1] / "scenarios" / "hatch-bay-insert.yaml"


@pytest.fixture(scope="module")
def insertion() -> tuple[ResolvedScenario, CollisionWorld, np.ndarray]:
    """The hatch-bay insertion's joints around its closest approach (600 samples, every other one)."""
    sc = load_scenario(SCENARIO)
    res = Planner(sc).plan()
    q = sc.robot.joints_from_drives(res.profile.position)
    assert res.gate.min_clearance_at is not None
    k = res.gate.min_clearance_at["sample"]
    return sc, CollisionWorld(sc.robot, sc.cabin, sc.payload), np.ascontiguousarray(q[k - 600 : k + 600 : 2])


def test_certificate_agrees_with_the_motion_walk(
    insertion: tuple[ResolvedScenario, CollisionWorld, np.ndarray],
) -> None:
    sc, world, q = insertion
    exact_min = float(world.clearance_profile(q, include_self=False).min())
    for clearance in (sc.options.clearance_m, exact_min - 0.5e-3, exact_min + 2e-3):
        along = world.along(q).certify(clearance, world.self_clearance, GATE_MOTION_MARGIN_M)
        walk = world.check_path(clearance=clearance, qs=q, motion_margin=GATE_MOTION_MARGIN_M, max_run=128)
        if along.valid:  # never weaker: what it certifies, the walk certifies too
            assert walk.valid
        # A clearance above the exact minimum cannot be certified, by either route.
        if clearance > exact_min:
            assert not along.valid and not walk.valid
            assert along.contacts and along.first_bad is not None
            assert along.contacts[0].bodies[0] == "payload"
    # The requested clearance is certified by both.
    rep = world.along(q).certify(sc.options.clearance_m, world.self_clearance, GATE_MOTION_MARGIN_M)
    assert rep.valid and rep.walked == 0


def test_figure_is_the_exact_minimum_and_the_bound_holds_between_samples(
    insertion: tuple[ResolvedScenario, CollisionWorld, np.ndarray],
) -> None:
    _, world, q = insertion
    along = world.along(q)
    fig = along.clearance()
    exact = world.clearance_profile(q)
    assert fig.tolerance_m == pytest.approx(1e-4)
    assert fig.distance_m <= float(exact.min()) + fig.tolerance_m
    assert fig.distance_m == pytest.approx(float(exact[fig.sample]), abs=fig.tolerance_m)
    assert fig.bodies == world.min_distance(q[fig.sample]).bodies
    assert fig.bound_m <= float(exact.min())
    # Between samples: quarter points of every piece.
    for s in (0.25, 0.5, 0.75):
        inner = (1 - s) * q[:-1] + s * q[1:]
        assert float(world.clearance_profile(inner).min()) >= fig.bound_m - 1e-12
    # The bound is near the figure: within the largest reach of a piece.
    assert fig.distance_m - fig.bound_m <= float(along.reach.max())


def test_bounds_are_below_exact_distances(
    insertion: tuple[ResolvedScenario, CollisionWorld, np.ndarray],
) -> None:
    """Every lower bound the pass holds (kernel bounds, spread, probes) is below the exact distance."""
    _, world, q = insertion
    along: AlongPath = world.along(q[::10])
    along.certify(0.01, world.self_clearance, GATE_MOTION_MARGIN_M)
    along.clearance()
    for k in range(0, along.n, 7):
        d = world.min_distance(along.q[k], include_self=False)
        t = world.names.index(d.bodies[0])
        assert along.lower[k, t] <= d.distance_m + 1e-9


def test_bad_input_names_the_field(insertion: tuple[ResolvedScenario, CollisionWorld, np.ndarray]) -> None:
    from planner.core.exceptions import InvalidInput

    _, world, q = insertion
    for bad in (q[:1], q[:, :5], np.where(np.arange(q.size).reshape(q.shape) == 3, np.nan, q)):
        with pytest.raises(InvalidInput) as info:
            world.along(bad)
        assert info.value.details["field"] == "qs"


def _beside(world: CollisionWorld, qs: np.ndarray, gap_m: float, name: str) -> tuple[Obstacle, ...]:
    """2 cm cubes ``gap_m`` off each face of the carriage at the middle sample (the candidates of a test).

    The carriage moves along its rail only: a cube beside it is passed at a constant distance.
    """
    k = len(qs) // 2
    b = world.names.index("carriage")
    p = world.flat_poses(qs[k])[b]
    R = p[:9].reshape(3, 3).T
    out = []
    for a in range(3):
        for sign in (1.0, -1.0):
            half = 0.5 * world.bodies.shapes[b].size[a]
            T = np.eye(4)
            T[:3, :3] = R
            T[:3, 3] = p[9:12] + sign * (half + gap_m + 0.01) * R[:, a]
            out.append(Obstacle.box(name, (0.02, 0.02, 0.02), T))
    return tuple(out)


def test_the_figure_covers_obstacles_and_reports_allowed_pairs_apart(
    insertion: tuple[ResolvedScenario, CollisionWorld, np.ndarray],
) -> None:
    """An installed unit near the payload: in the certificate and the figure; allowed, only in its own figure.

    Both figures against exact FCL distances at every sample.
    """
    sc, plain, q = insertion
    q = np.ascontiguousarray(q[::4])
    for unit in _beside(plain, q, 0.008, "unit X"):  # a carriage face the path passes at 4 mm or more
        world = CollisionWorld(sc.robot, sc.cabin, sc.payload, obstacles=(unit,))
        exact = world.clearance_profile(q)  # cabin, robot pairs and the unit
        low = float(exact.min())
        near = world.min_distance(q[int(np.argmin(exact))]).bodies
        if near[1] == "unit X" and low > 0.004:
            break
    else:
        pytest.fail("no face of the payload passes the unit")
    along = world.along(q)
    assert along.certify(low - GATE_MOTION_MARGIN_M - 0.002, world.self_clearance, GATE_MOTION_MARGIN_M).valid
    # Within the clearance of the unit: refused, the unit named.
    bad = world.along(q).certify(low + 0.0005, world.self_clearance, GATE_MOTION_MARGIN_M)
    assert not bad.valid and any("unit X" in c.detail for c in bad.contacts)
    fig = along.clearance()
    assert fig.bodies == near
    assert fig.distance_m - fig.tolerance_m <= low <= fig.distance_m + 1e-12
    assert fig.distance_m == pytest.approx(float(exact[fig.sample]), abs=1e-9)
    assert fig.bound_m <= low
    # Allowed: out of the certificate and the figure, measured on its own.
    pairs = frozenset((name, "unit X") for name in world.names)
    allowed = CollisionWorld(sc.robot, sc.cabin, sc.payload, obstacles=(unit,), allowed=pairs)
    along = allowed.along(q)
    assert along.certify(0.005, allowed.self_clearance, GATE_MOTION_MARGIN_M).valid
    fig = along.clearance()
    assert "unit X" not in fig.bodies
    assert fig.distance_m == pytest.approx(float(plain.clearance_profile(q).min()), abs=fig.tolerance_m)
    pair = along.allowed_clearance()
    assert pair is not None and pair.bodies == near
    d_pair = [allowed.obstacle_distance(allowed.flat_poses(x), obstacle="unit X").distance_m for x in q]
    assert pair.distance_m - pair.tolerance_m <= min(d_pair) <= pair.distance_m + 1e-12


def _swept_past(world: CollisionWorld, q_a: np.ndarray, q_b: np.ndarray, gap_m: float) -> Obstacle | None:
    """A 0.2 mm cube ``gap_m`` off the payload's corner at the middle of q_a -> q_b, beside its motion.

    Returned only when the cube is at least 3 mm farther from the payload at both ends than at the middle
    (exact FCL distances of the payload box); None otherwise.
    """
    b = world.names.index("payload")
    shape = world.bodies.shapes[b]
    q_mid = 0.5 * (q_a + q_b)
    poses = [world.flat_poses(x)[b] for x in (q_a, q_mid, q_b)]
    verts = [body_vertices(p[None], shape)[0] for p in poses]
    box = fcl.Box(*shape.size)

    def dist(p: np.ndarray, point: np.ndarray) -> float:
        obj = fcl.CollisionObject(box, fcl.Transform(p[:9].reshape(3, 3).T, p[9:12]))
        dot = fcl.CollisionObject(fcl.Sphere(1e-4), fcl.Transform(point))
        return float(fcl.distance(obj, dot, fcl.DistanceRequest(), fcl.DistanceResult())) - 1e-4

    for c in range(8):
        m = verts[2][c] - verts[0][c]
        m /= np.linalg.norm(m)
        out = verts[1][c] - poses[1][9:12]
        n = out - (out @ m) * m
        n /= np.linalg.norm(n)
        point = verts[1][c] + gap_m * n
        mid = dist(poses[1], point)
        if mid > 0.0 and min(dist(poses[0], point), dist(poses[2], point)) >= mid + 0.003:
            T = np.eye(4)
            T[:3, 3] = point + 1e-4 * n
            return Obstacle.box("unit Z", (2e-4, 2e-4, 2e-4), T)
    return None


def test_an_obstacle_within_the_clearance_only_between_samples_is_refused(robot: Cabin8) -> None:
    """Samples clear of a unit, the straight piece between them not: the batched pass refuses.

    The piece moves every joint by less than the walk's limit step (so the batched cover, not a walk of
    the piece, decides), and the payload's corner sweeps past a small unit placed beside its midpoint.
    """
    from planner.collision.bodies import PayloadGeometry
    from planner.collision.motion import LIMIT_STEP

    payload = PayloadGeometry(size=(0.3, 0.3, 0.2), T_tool_payload=np.eye(4))
    plain = CollisionWorld(robot, None, payload)
    step = np.full(8, 0.98 * LIMIT_STEP)
    for q_a in admissible_joints(robot, 200, seed=11):
        q_b = q_a + step
        if not (plain.is_valid(q_a, 0.0) and plain.is_valid(q_b, 0.0)):
            continue
        unit = _swept_past(plain, q_a, q_b, 0.002)
        if unit is None:
            continue
        world = CollisionWorld(robot, None, payload, obstacles=(unit,))
        ends = min(world.obstacle_distance(world.flat_poses(x)).distance_m for x in (q_a, q_b))
        mid = world.obstacle_distance(world.flat_poses(0.5 * (q_a + q_b))).distance_m
        clearance = mid + 0.0005
        if ends >= clearance + GATE_MOTION_MARGIN_M + 0.0005:
            break
    else:
        pytest.fail("no piece whose payload corner sweeps past the unit between its samples")
    qs = np.ascontiguousarray(np.linspace(q_a, q_b, 2))
    # Both samples keep the clearance plus the margin: only the piece between them comes closer.
    for x in qs:
        assert world.check_state(x, clearance + GATE_MOTION_MARGIN_M).valid
    rep = world.along(qs).certify(clearance, world.self_clearance, GATE_MOTION_MARGIN_M)
    assert not rep.valid and rep.first_bad == 0
    assert any("unit Z" in c.detail for c in rep.contacts)
    assert not world.check_path(qs, clearance, GATE_MOTION_MARGIN_M).valid
    # Without the unit the same piece is certified.
    assert plain.along(qs).certify(clearance, plain.self_clearance, GATE_MOTION_MARGIN_M).valid


def test_a_window_that_covers_its_own_pieces_but_not_the_one_before_it_ends_in_probes(
    insertion: tuple[ResolvedScenario, CollisionWorld, np.ndarray], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A swept window from sample k + 1 that covers its pieces leaves piece k short: k + 1 is probed next.

    The cover's loop once tried the same window again (and again): a generated cycle's gate never ended.
    Here every window covers (a stubbed swept bound), piece k's own reach is larger than the window's
    spare, and its start is probed already: the loop must move on to probes and exact distances and end.
    """
    from planner.collision.kernels.codes import BOUND, EXACT, PROBED

    sc, plain, q = insertion
    q = np.ascontiguousarray(q[:200])
    unit = _beside(plain, q, 0.05, "unit X")[0]
    world = CollisionWorld(sc.robot, sc.cabin, sc.payload, obstacles=(unit,))
    along = world.along(q)
    t, k, need = along.n_checked - 1, 50, 0.01
    along.lower[:, t] = need + 1e-3
    along.state[:, t] = BOUND
    along.reach[:, t] = 1e-4
    along.reach[k, t] = 0.01  # piece k needs 10 mm of spare between its ends
    along.state[k, t] = PROBED
    swept = []
    monkeypatch.setattr(along, "swept_at", lambda i, j, task: swept.append(i) or need + 0.003)
    probed: list[int] = []

    def probe(s: int, task: int, need_m: float, arrays: object = None) -> None:
        probed.append(s)
        along.state[s, task] = PROBED

    def exact(s: int, task: int, arrays: object = None) -> float:
        along.state[s, task] = EXACT
        along.lower[s, task] = need + 0.006  # both ends exact, 6 + 6 mm: piece k is covered
        return need + 0.006

    monkeypatch.setattr(along, "probe_at", probe)
    monkeypatch.setattr(along, "exact_at", exact)
    left = np.zeros(along.n - 1, dtype=bool)
    along._cover_column(t, need, left)
    assert swept.count(k + 1) == 1 and probed == [k + 1] and not left.any()
