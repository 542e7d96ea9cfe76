"""TOPP-RA time laws, sampled at the controller period: every limit on every sample, physics recomputed.

The efforts reported by the sampled profile are recomputed here by an independent route: joint rates from
the drive rates through the drive-map Jacobian (its time derivative by finite differences), then the
inverse dynamics.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest
from scipy.spatial import cKDTree

from planner.collision.bodies import PayloadGeometry
from planner.core.exceptions import RetimingFailed
from planner.dynamics.lagrange import Cabin8Dynamics
from planner.dynamics.payload import RigidPayload
from planner.plan.report import single_drive_lower_bound
from planner.robots.cabin8 import Cabin8
from planner.timing.path import JointPath, LinePiece, blended_polyline, segment_time_length
from planner.timing.profile import DriveProfile, sample_legs
from planner.timing.stage import TimedPath
from planner.timing.toppra import ToppraStage

PERIOD = 0.004
TOL = 1.01
#: Small steps per joint [m, m, m, rad, rad, rad, m, rad].
STEP = np.array([0.25, 0.03, 0.03, 0.06, 0.3, 0.3, 0.06, 0.4])


def grasped(mass: float) -> RigidPayload:
    T = np.eye(4)
    T[2, 3] = 0.20
    return PayloadGeometry(size=(0.40, 0.30, 0.30), T_tool_payload=T, mass=mass).rigid_payload()


def line(robot: Cabin8, q0: np.ndarray, q1: np.ndarray) -> JointPath:
    return JointPath((LinePiece(q0, q1, segment_time_length(robot, q0, q1)),))


@pytest.fixture(scope="module")
def home(robot: Cabin8) -> np.ndarray:
    q = robot.joints_from_drives(robot.home_drives)
    assert not robot.violations(q)
    return q


@pytest.fixture(scope="module")
def rail_path(robot: Cabin8, home: np.ndarray) -> JointPath:
    """1 m along the rail, nothing else moves."""
    q1 = home.copy()
    q1[0] += 1.0
    assert not robot.violations(q1)
    return line(robot, home, q1)


@pytest.fixture(scope="module")
def dyn(robot: Cabin8) -> Cabin8Dynamics:
    return Cabin8Dynamics(robot)


def static_ratio(robot: Cabin8, dyn: Cabin8Dynamics, q: np.ndarray, payload: RigidPayload | None) -> float:
    """Largest drive force needed to hold still at q, as a fraction of its limit."""
    zero = np.zeros(8)
    return float(np.max(np.abs(dyn.inverse_dynamics(q, zero, zero, payload)[1]) / robot.limits.effort_max))


@pytest.fixture(scope="module")
def arm_path(robot: Cabin8, dyn: Cabin8Dynamics, rail_path: JointPath) -> JointPath:
    """Every joint moves: three small admissible steps from the end of the rail move, corners blended.

    The waypoints hold a 30 kg payload with at most 80% of any drive's force at rest, so the velocity and
    acceleration limits, not the forces, shape most of the time law.
    """
    rng = np.random.default_rng(5)
    w = [rail_path.end]
    while len(w) < 4:
        cand = w[-1] + rng.uniform(-1.0, 1.0, 8) * STEP
        if not robot.violations(cand) and static_ratio(robot, dyn, cand, grasped(30.0)) <= 0.8:
            w.append(cand)
    path, blends = blended_polyline(robot, np.array(w), 0.4)
    assert all(b >= 0 for b in blends)
    q = path.evaluate(np.linspace(0.0, path.length, 101))[0]
    assert all(not robot.violations(qi) for qi in q)
    assert max(static_ratio(robot, dyn, qi, grasped(30.0)) for qi in q) <= 0.85
    return path


_timed: dict[tuple[str, float], tuple[TimedPath, DriveProfile]] = {}


def timed(robot: Cabin8, path: JointPath, name: str, mass: float) -> tuple[TimedPath, DriveProfile]:
    """Time law and 4 ms profile of a path (cached per module run)."""
    key = (name, mass)
    if key not in _timed:
        payload = grasped(mass) if mass > 0 else None
        tp = ToppraStage(robot, payload).time_path(path)
        prof, leg_of, _ = sample_legs(robot, [tp], PERIOD, payload)
        assert np.all(leg_of == 0)
        _timed[key] = (tp, prof)
    return _timed[key]


def recomputed_effort(
    robot: Cabin8, dyn: Cabin8Dynamics, prof: DriveProfile, payload: RigidPayload | None, idx: np.ndarray
) -> np.ndarray:
    """Drive forces at samples ``idx`` from the drive motion alone (independent of the sampling code)."""
    out = []
    h = 1e-6
    for i in idx:
        q = robot.joints_from_drives(prof.position[i])
        _, G_inv = robot.drive_map_jacobian(q)
        qd = G_inv @ prof.velocity[i]
        # u_ddot = G q_ddot + G_dot q_dot, G_dot = dG/dq . q_dot by central differences.
        G_dot = (robot.drive_map_jacobian(q + h * qd)[0] - robot.drive_map_jacobian(q - h * qd)[0]) / (2 * h)
        qdd = G_inv @ (prof.acceleration[i] - G_dot @ qd)
        out.append(dyn.inverse_dynamics(q, qd, qdd, payload)[1])
    return np.array(out)


CASES = [("rail", 0.0), ("rail", 30.0), ("arm", 0.0), ("arm", 30.0)]


@pytest.mark.parametrize(("name", "mass"), CASES)
def test_sampled_time_law_respects_every_limit_on_every_sample(
    robot: Cabin8,
    dyn: Cabin8Dynamics,
    rail_path: JointPath,
    arm_path: JointPath,
    name: str,
    mass: float,
) -> None:
    path = rail_path if name == "rail" else arm_path
    tp, prof = timed(robot, path, name, mass)
    lim = robot.limits
    n = len(prof.t)
    assert n > 100
    assert np.all(np.isfinite(prof.velocity)) and np.all(np.isfinite(prof.effort))
    assert np.all(np.abs(prof.velocity) <= TOL * lim.v_max)
    assert np.all(np.abs(prof.acceleration) <= TOL * lim.a_max)
    # What a controller executes between two samples, dv/dt, is held to the limit too.
    assert np.all(np.abs(np.diff(prof.velocity, axis=0)) / PERIOD <= TOL * lim.a_max)
    assert np.all(np.abs(prof.effort) <= TOL * lim.effort_max)
    assert np.all(prof.position >= lim.lower - 1e-9) and np.all(prof.position <= lim.upper + 1e-9)
    # Time: from 0, one period per sample, lasting the time law rounded up to a whole period.
    assert prof.t[0] == 0.0
    assert np.allclose(np.diff(prof.t), PERIOD, rtol=0, atol=1e-12)
    assert tp.duration <= prof.duration_s < tp.duration + PERIOD + 1e-9
    # At rest at both ends, exactly at the path's start and end.
    for k in (0, -1):
        assert np.array_equal(prof.velocity[k], np.zeros(8))
    assert np.array_equal(prof.acceleration[-1], np.zeros(8))
    assert np.max(np.abs(prof.joints[0] - path.start)) <= 1e-12
    assert np.max(np.abs(prof.joints[-1] - path.end)) <= 1e-12
    assert np.max(np.abs(prof.position[-1] - robot.drives_from_joints(path.end))) <= 1e-12
    # The drive positions and the reported joints are the same configurations.
    assert np.max(np.abs(robot.joints_from_drives(prof.position) - prof.joints)) <= 1e-9
    # Positions integrate the velocities (trapezoid rule, within 1% of v_max per step).
    dpos = np.diff(prof.position, axis=0) - 0.5 * PERIOD * (prof.velocity[1:] + prof.velocity[:-1])
    assert np.all(np.abs(dpos) <= 0.01 * lim.v_max * PERIOD)
    # Never faster than the slowest drive moving alone.
    bound = single_drive_lower_bound(robot, prof.position[0], prof.position[-1])
    assert prof.duration_s >= bound - 1e-9


@pytest.mark.parametrize(("name", "mass"), CASES)
def test_reported_efforts_equal_an_independent_inverse_dynamics(
    robot: Cabin8,
    dyn: Cabin8Dynamics,
    rail_path: JointPath,
    arm_path: JointPath,
    name: str,
    mass: float,
) -> None:
    path = rail_path if name == "rail" else arm_path
    _, prof = timed(robot, path, name, mass)
    payload = grasped(mass) if mass > 0 else None
    idx = np.unique(np.concatenate([np.linspace(0, len(prof.t) - 1, 60).astype(int), [1, len(prof.t) - 2]]))
    tau = recomputed_effort(robot, dyn, prof, payload, idx)
    scale = np.maximum(np.abs(tau), 1e-3 * robot.limits.effort_max)
    assert np.max(np.abs(tau - prof.effort[idx]) / scale) <= 1e-6
    if mass > 0:  # the payload's weight is felt: an empty gripper needs different forces
        assert np.max(np.abs(recomputed_effort(robot, dyn, prof, None, idx) - tau)) > 10.0


@pytest.mark.parametrize(("name", "mass"), CASES)
def test_samples_lie_on_the_geometric_path(
    robot: Cabin8, rail_path: JointPath, arm_path: JointPath, name: str, mass: float
) -> None:
    path = rail_path if name == "rail" else arm_path
    _, prof = timed(robot, path, name, mass)
    dense = path.evaluate(np.linspace(0.0, path.length, 200_001))[0]
    spacing = float(np.max(np.linalg.norm(np.diff(dense, axis=0), axis=1)))
    dist, where = cKDTree(dense).query(prof.joints)
    assert np.max(dist) <= spacing
    # ... and move along it forwards only (the nearest dense point never goes back by more than a step).
    assert np.all(np.diff(where) >= -1)
    if name == "rail":  # only the rail moves: every other drive stands exactly still
        assert np.array_equal(prof.velocity[:, 1:], np.zeros((len(prof.t), 7)))
        assert np.all(np.diff(prof.position[:, 0]) >= 0.0)


def test_straight_rail_move_is_close_to_the_single_drive_bound(robot: Cabin8, rail_path: JointPath) -> None:
    _, prof = timed(robot, rail_path, "rail", 0.0)
    bound = single_drive_lower_bound(robot, prof.position[0], prof.position[-1])
    assert bound == pytest.approx(1.0 / 0.25 + 0.25 / 0.5)  # 1 m: cruise 4 s plus v/a
    assert bound <= prof.duration_s <= 1.1 * bound
    # Bang-coast-bang: the rail reaches its velocity limit and its acceleration limit, and on almost every
    # sample one of the two is (nearly) saturated.
    v = np.abs(prof.velocity[:, 0]) / robot.limits.v_max[0]
    a = np.abs(prof.acceleration[:, 0]) / robot.limits.a_max[0]
    assert v.max() >= 0.95 and a.max() >= 0.95
    assert np.mean(np.maximum(v, a) >= 0.95) >= 0.97


def test_doubling_speed_and_quadrupling_acceleration_halves_the_duration(
    robot: Cabin8, rail_path: JointPath, arm_path: JointPath
) -> None:
    """Time scaling: u(t / 2) is feasible for (2 v, 4 a) exactly when u(t) is for (v, a).

    (The forces, which do not scale so, stay far from their limits on these paths.)
    """
    fast = copy.copy(robot)
    fast.limits = dataclasses.replace(
        robot.limits, v_max=2 * robot.limits.v_max, a_max=4 * robot.limits.a_max
    )
    for path in (rail_path, arm_path):
        slow_t = ToppraStage(robot).time_path(path)
        fast_t = ToppraStage(fast).time_path(path)
        assert np.array_equal(fast_t.ss, slow_t.ss)
        assert fast_t.duration == pytest.approx(0.5 * slow_t.duration, rel=1e-6)
        assert np.allclose(fast_t.sd, 2.0 * slow_t.sd, rtol=1e-6, atol=1e-9)


def test_binding_force_limit_holds_on_every_sample(
    robot: Cabin8, dyn: Cabin8Dynamics, rail_path: JointPath
) -> None:
    """A weak rail motor (100 N for some 250 kg): the force, not a_max, limits the rail's acceleration."""
    weak = copy.copy(robot)
    f_max = robot.limits.effort_max.copy()
    f_max[0] = 100.0
    weak.limits = dataclasses.replace(robot.limits, effort_max=f_max)
    payload = grasped(30.0)
    tp = ToppraStage(weak, payload).time_path(rail_path)
    prof, _, _ = sample_legs(weak, [tp], PERIOD, payload)
    _, strong = timed(robot, rail_path, "rail", 30.0)
    f = np.abs(prof.effort) / f_max
    assert np.all(f <= TOL)
    assert f[:, 0].max() >= 0.95  # the force limit is reached ...
    a = np.abs(prof.acceleration[:, 0]) / robot.limits.a_max[0]
    assert a.max() <= 0.9  # ... well before the acceleration limit,
    assert prof.duration_s > strong.duration_s + 0.05  # and it costs time.
    assert np.all(np.abs(prof.velocity) <= TOL * robot.limits.v_max)
    idx = np.arange(0, len(prof.t), 25)
    tau = recomputed_effort(robot, dyn, prof, payload, idx)
    assert np.max(np.abs(tau - prof.effort[idx]) / f_max) <= 1e-6


def test_time_law_is_monotone_and_at_rest_at_its_ends(robot: Cabin8, arm_path: JointPath) -> None:
    tp, _ = timed(robot, arm_path, "arm", 30.0)
    assert tp.sd[0] == 0.0 and tp.sd[-1] == 0.0
    assert np.all(tp.sd[1:-1] > 0.0)
    assert np.all(np.diff(tp.t) > 0.0) and np.all(np.diff(tp.ss) > 0.0)
    assert tp.ss[0] == 0.0 and tp.ss[-1] == pytest.approx(arm_path.length, rel=1e-12)
    # state() reproduces the grid and integrates: s(t) is the integral of sd(t) (trapezoid, fine step).
    s, sd, _ = tp.state(tp.t)
    assert np.allclose(s, tp.ss, rtol=0, atol=1e-9) and np.allclose(sd, tp.sd, rtol=0, atol=1e-9)
    t = np.linspace(0.0, tp.duration, 20_001)
    s, sd, sdd = tp.state(t)
    assert np.all(np.diff(s) >= 0.0)
    assert np.allclose(np.diff(s), 0.5 * np.diff(t) * (sd[1:] + sd[:-1]), rtol=0, atol=1e-7)
    assert np.allclose(np.diff(sd), 0.5 * np.diff(t) * (sdd[1:] + sdd[:-1]), rtol=0, atol=1e-3)


def test_overload_on_a_moving_drive_raises_retiming_failed_naming_the_drive(
    robot: Cabin8, dyn: Cabin8Dynamics, arm_path: JointPath
) -> None:
    heavy = grasped(2000.0)
    with pytest.raises(RetimingFailed) as info:
        ToppraStage(robot, heavy).time_path(arm_path)
    exc = info.value
    drive = exc.details["drive"]
    assert drive in robot.drive_names
    assert f"drive {drive}" in exc.message
    j = robot.drive_names.index(drive)
    # The evidence is physical: holding the payload still at that point of the path needs more than the limit.
    q = arm_path.evaluate(np.array([exc.details["path_fraction"] * arm_path.length]))[0][0]
    zero = np.zeros(8)
    tau = dyn.inverse_dynamics(q, zero, zero, heavy)[1]
    assert tau[j] == pytest.approx(exc.details["static_force"], rel=1e-9)
    assert abs(tau[j]) > robot.limits.effort_max[j] == exc.details["limit"]


def test_overload_on_a_standing_drive_raises_retiming_failed(
    robot: Cabin8, dyn: Cabin8Dynamics, rail_path: JointPath
) -> None:
    heavy = grasped(2000.0)
    zero = np.zeros(8)
    tau = dyn.inverse_dynamics(rail_path.start, zero, zero, heavy)[1]
    over = [n for n, t, f in zip(robot.drive_names, tau, robot.limits.effort_max, strict=True) if abs(t) > f]
    assert over and "d1" not in over  # overloaded drives stand still on a rail move
    with pytest.raises(RetimingFailed) as info:
        ToppraStage(robot, heavy).time_path(rail_path)
    assert info.value.details["drive"] in over
    assert f"drive {info.value.details['drive']}" in info.value.message


def test_legs_are_sampled_back_to_back_at_rest_at_every_boundary(
    robot: Cabin8, dyn: Cabin8Dynamics, rail_path: JointPath, arm_path: JointPath
) -> None:
    payload = grasped(30.0)
    stage = ToppraStage(robot, payload)
    legs = [stage.time_path(p) for p in (rail_path, arm_path, line(robot, arm_path.end, rail_path.end))]
    prof, leg_of, _ = sample_legs(robot, legs, PERIOD, payload)
    lim = robot.limits
    steps = [int(np.ceil(leg.duration / PERIOD - 1e-9)) for leg in legs]
    assert len(prof.t) == sum(steps) + 1
    assert np.allclose(np.diff(prof.t), PERIOD, rtol=0, atol=1e-12)
    assert list(np.unique(leg_of)) == [0, 1, 2]
    boundaries = np.cumsum(steps)[:-1]
    for k, b in enumerate(boundaries):
        assert np.all(leg_of[:b] <= k) and leg_of[b] == k + 1
        assert np.array_equal(prof.velocity[b], np.zeros(8))
        assert np.max(np.abs(prof.joints[b] - legs[k].path.end)) <= 1e-12
        assert np.max(np.abs(prof.joints[b] - legs[k + 1].path.start)) <= 1e-12
        # Just before the boundary the robot is already slow: it decelerates into the stop.
        assert np.all(np.abs(prof.velocity[b - 1]) <= lim.a_max * PERIOD * TOL)
    for k in (0, -1):
        assert np.array_equal(prof.velocity[k], np.zeros(8))
    assert np.max(np.abs(prof.joints[-1] - rail_path.end)) <= 1e-12
    assert np.all(np.abs(prof.velocity) <= TOL * lim.v_max)
    assert np.all(np.abs(prof.acceleration) <= TOL * lim.a_max)
    assert np.all(np.abs(np.diff(prof.velocity, axis=0)) / PERIOD <= TOL * lim.a_max)
    assert np.all(np.abs(prof.effort) <= TOL * lim.effort_max)
    idx = np.concatenate([boundaries - 1, boundaries, boundaries + 1])
    tau = recomputed_effort(robot, dyn, prof, payload, idx)
    assert np.max(np.abs(tau - prof.effort[idx]) / lim.effort_max) <= 1e-6
