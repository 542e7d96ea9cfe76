"""Assembly cycles, by physics: forces per payload state, the jump at release, limits, rest, clearances."""

from __future__ import annotations

import json

import fcl
import numpy as np
import pytest
import trimesh

from planner.collision.obstacles import Obstacle
from planner.dynamics.lagrange import Cabin8Dynamics
from planner.dynamics.stiffness import LoadCase, stiffness_model
from planner.robots.geometry import PAYLOAD
from planner.task.cycle import CycleResult
from planner.task.legs import LEG_NAMES, leg, leg_world
from planner.task.resolve import ResolvedCycle

LOADED = {"grasp", "lift_off", "transit", "insertion"}


def _rows(result: CycleResult, name: str, with_previous: bool = True) -> slice:
    lt = next(x for x in result.legs if x.name == name)
    return slice(lt.sample_start - 1 if with_previous else lt.sample_start, lt.sample_end)


def test_legs_cover_the_timeline_in_order(planned: CycleResult, cycle: ResolvedCycle) -> None:
    n = len(planned.profile.t)
    assert [x.name for x in planned.legs] == list(LEG_NAMES)
    assert planned.legs[0].sample_start == 0 and planned.legs[-1].sample_end == n
    for a, b in zip(planned.legs, planned.legs[1:], strict=False):
        assert a.sample_end == b.sample_start
        assert a.t_end_s == pytest.approx(b.t_start_s, abs=1e-12)
    for k, lt in enumerate(planned.legs):
        assert np.all(planned.leg_of[lt.sample_start : lt.sample_end] == k)
        assert (lt.payload == cycle.spec.unit.id) == (lt.name in LOADED)
    period = cycle.spec.options.sample_period_s
    assert np.allclose(np.diff(planned.profile.t), period, atol=1e-12)
    grasp = next(x for x in planned.legs if x.name == "grasp")
    assert grasp.t_end_s - grasp.t_start_s == pytest.approx(
        np.ceil(cycle.grasp_dwell_s / period - 1e-9) * period, abs=1e-9
    )
    kinds = {e.kind: e for e in planned.events}
    assert kinds["attach"].t_s == grasp.t_start_s and kinds["attach"].leg == "grasp"
    assert kinds["detach"].t_s == next(x for x in planned.legs if x.name == "release").t_start_s


def test_forces_follow_each_legs_payload_state(planned: CycleResult, cycle: ResolvedCycle) -> None:
    """Inverse dynamics of every sample with its leg's load gives the reported forces.

    Without the unit on the loaded legs (or with it on the empty ones) it does not.
    """
    p = planned.profile
    dyn = Cabin8Dynamics.of(cycle.robot)
    qd, qdd = dyn.joint_rates_batch(p.joints, p.velocity, p.acceleration)
    lim = cycle.robot.limits.effort_max
    assert p.effort is not None
    for lt in planned.legs:
        s = slice(lt.sample_start, lt.sample_end)
        if lt.sample_end == lt.sample_start:
            continue
        load = cycle.unit_payload if lt.name in LOADED else None
        other = None if lt.name in LOADED else cycle.unit_payload
        tau = dyn.drive_forces_batch(p.joints[s], qd[s], qdd[s], load)
        wrong = dyn.drive_forces_batch(p.joints[s], qd[s], qdd[s], other)
        assert np.max(np.abs(tau - p.effort[s]) / lim) < 1e-6, lt.name
        # 60 kg at the tool: a few percent of some drive's limit at every sample.
        assert np.min(np.max(np.abs(wrong - p.effort[s]) / lim, axis=1)) > 0.02, lt.name


def test_the_jump_at_each_load_change_is_the_stiffness_models_deflection_change(
    planned: CycleResult, cycle: ResolvedCycle
) -> None:
    model = stiffness_model(cycle.robot)
    for event, before, after in (("attach", None, cycle.unit_payload), ("detach", cycle.unit_payload, None)):
        e = next(x for x in planned.events if x.kind == event)
        lt = next(x for x in planned.legs if x.name == e.leg)
        q = planned.profile.joints[lt.sample_start - 1]
        x = model.deflections(np.stack([q, q]), LoadCase(None, cycle.T_tool_unit))
        x_loaded = model.deflections(q[None], LoadCase(cycle.unit_payload, cycle.T_tool_unit))[0]
        x_empty = x[0]
        expected = float(np.linalg.norm(x_loaded[:3] - x_empty[:3]))
        assert e.springback_m == pytest.approx(expected, abs=1e-6)
        assert e.springback_m > 1e-5  # a 60 kg unit moves the tool measurably
        assert (before is None) == (event == "attach") and (after is None) == (event == "detach")
    gate = {c.name: c for c in planned.gate.checks}
    release = next(x for x in planned.events if x.kind == "detach")
    assert gate["springback_release"].passed and gate["springback_release"].worst == pytest.approx(
        release.springback_m, abs=1e-12
    )
    assert f"{1e3 * release.springback_m:.3f} mm" in gate["springback_release"].detail


def test_every_sample_within_the_drive_limits(planned: CycleResult, cycle: ResolvedCycle) -> None:
    p, lim = planned.profile, cycle.robot.limits
    tol = 1.01  # the gate's 1%
    assert np.all(p.position >= lim.lower - 1e-9) and np.all(p.position <= lim.upper + 1e-9)
    assert np.all(np.abs(p.velocity) <= tol * lim.v_max)
    assert np.all(np.abs(p.acceleration) <= tol * lim.a_max)
    assert np.all(np.abs(np.diff(p.velocity, axis=0)) / p.sample_period_s <= tol * lim.a_max)
    assert p.effort is not None and np.all(np.abs(p.effort) <= tol * lim.effort_max)
    assert lim.j_max is not None and np.all(np.abs(p.jerk) <= tol * lim.j_max)
    assert np.all(p.velocity[[0, -1]] == 0.0)
    assert np.allclose(p.position[0], cycle.park_u, atol=1e-9) and np.allclose(
        p.position[-1], cycle.park_u, atol=1e-9
    )


def test_the_robot_rests_on_every_dwell(planned: CycleResult) -> None:
    p = planned.profile
    for name in ("grasp", "release"):
        rows = _rows(planned, name)
        assert rows.stop - rows.start > 1
        assert np.all(p.velocity[rows] == 0.0) and np.all(p.acceleration[rows] == 0.0)
        assert np.all(p.position[rows] == p.position[rows.start])


def test_straight_legs_follow_their_lines(planned: CycleResult, cycle: ResolvedCycle) -> None:
    T = cycle.robot.fk_batch(planned.profile.joints) @ cycle.T_tool_unit
    for name, line in (
        ("grasp_line", cycle.grasp_line),
        ("lift_off", cycle.lift_line),
        ("insertion", cycle.insertion_line),
        ("retract", cycle.retract_line),
    ):
        Ts = T[_rows(planned, name)]
        rel = Ts[:, :3, 3] - Ts[0, :3, 3]
        along = rel @ line.direction
        assert np.max(np.linalg.norm(rel - np.outer(along, line.direction), axis=1)) < 1e-6, name
        assert along[-1] == pytest.approx(line.distance_m, abs=1e-6)
        assert np.all(np.diff(along) >= -1e-12)
    end = T[_rows(planned, "grasp_line").stop - 1]
    assert np.allclose(end, cycle.T_base_unit_dock, atol=1e-6)


def _fcl_distance(
    obstacle: Obstacle, shape_kind: str, size: tuple[float, ...], R: np.ndarray, p: np.ndarray
) -> float:
    """Exact distance from one posed body to a box obstacle, by FCL alone (the obstacle as a mesh)."""
    box = trimesh.creation.box(extents=obstacle.size)
    mesh = fcl.BVHModel()
    mesh.beginModel(len(box.vertices), len(box.faces))
    mesh.addSubModel(np.asarray(box.vertices, dtype=float), np.asarray(box.faces, dtype=np.int32))
    mesh.endModel()
    T = obstacle.T_base_obstacle
    a = fcl.CollisionObject(mesh, fcl.Transform(T[:3, :3], T[:3, 3]))
    geom = fcl.Box(*size) if shape_kind == "box" else fcl.Capsule(*size)
    b = fcl.CollisionObject(geom, fcl.Transform(R, p))
    return float(fcl.distance(a, b, fcl.DistanceRequest(), fcl.DistanceResult()))


def _distances_to(
    cycle: ResolvedCycle, result: CycleResult, name: str, obstacle: Obstacle, held: bool
) -> dict[str, float]:
    """Smallest exact distance of each robot body (and the tool's body) to ``obstacle`` on a leg.

    Every sample, from the robot model's numpy body poses and FCL (not the collision world).
    """
    model = cycle.robot.collision_model()
    geom = cycle.held if held else cycle.gripper
    assert geom is not None
    names = (*model.body_names, PAYLOAD)
    shapes = model.shapes(geom.size)
    q = result.profile.joints[_rows(result, name)]
    R, P, L = model.body_poses(q, names, geom.T_tool_box)
    centre = obstacle.T_base_obstacle[:3, 3]
    reach = 0.5 * float(np.linalg.norm(obstacle.size))
    out: dict[str, float] = {}
    for b, body in enumerate(names):
        s = shapes[body]
        best = np.inf
        for k in range(len(q)):
            bound = s.bounding_radius if s.kind == "box" else s.radius + 0.5 * L[k, b]
            if np.linalg.norm(P[k, b] - centre) - bound - reach > 0.05:  # certainly farther than 5 cm
                continue
            size = s.size if s.kind == "box" else (s.radius, L[k, b])
            best = min(best, _fcl_distance(obstacle, s.kind, size, R[k, b], P[k, b]))
        out[body] = best
    return out


def test_no_sample_after_the_release_within_the_clearance_of_the_installed_unit(
    planned: CycleResult, cycle: ResolvedCycle
) -> None:
    """Exact FCL distances at every sample: on the retract only the gripper may be closer.

    The gripper and the unit are the retract's allowed pair; on the way back to park nothing is closer.
    """
    clearance = cycle.spec.options.clearance_m
    retract = _distances_to(cycle, planned, "retract", cycle.bay_unit, held=False)
    park = _distances_to(cycle, planned, "park", cycle.bay_unit, held=False)
    assert all(d >= clearance for body, d in retract.items() if body != PAYLOAD), retract
    assert all(d >= clearance for d in park.values()), park
    assert retract[PAYLOAD] < clearance  # the gripper leaves from the unit it released


def test_a_second_cycle_keeps_the_clearance_of_the_installed_unit(
    second_planned: CycleResult, second_cycle: ResolvedCycle
) -> None:
    """The next unit is carried past A3 (now installed): no body on any leg comes within the clearance."""
    a3 = next(o for o in second_cycle.installed if o.name == "unit A3")
    clearance = second_cycle.spec.options.clearance_m
    for name in LEG_NAMES:
        if leg(name).kind == "dwell":
            continue
        d = _distances_to(second_cycle, second_planned, name, a3, held=leg(name).held)
        assert min(d.values()) >= clearance, (name, d)
    assert second_planned.gate.passed


def test_the_allowed_pairs_are_used_only_on_their_legs(planned: CycleResult, cycle: ResolvedCycle) -> None:
    pairs = {tuple(p["bodies"]): p["legs"] for p in planned.report["allowed_pairs"]}
    assert pairs == {
        ("gripper", "unit A3"): ["grasp_line", "release", "retract"],
        ("unit A3", "fixture of A3"): ["grasp", "lift_off"],
    }
    for name in LEG_NAMES:
        world = leg_world(cycle, leg(name))
        allowed = world.obstacles.allowed if world.obstacles is not None else frozenset()
        assert bool(allowed) == (name in {"grasp_line", "grasp", "lift_off", "release", "retract"}), name
    # Physically: away from its lines the gripper keeps the clearance from the unit on its dock.
    d = _distances_to(cycle, planned, "pre_grasp", cycle.dock_unit, held=False)
    assert d[PAYLOAD] >= cycle.spec.options.clearance_m
    assert _distances_to(cycle, planned, "grasp_line", cycle.dock_unit, held=False)[PAYLOAD] < 1e-3
    gate = [c for c in planned.gate.checks if c.name == "allowed_pair"]
    assert len(gate) == 2 and all("only" in c.detail for c in gate)


def test_the_gate_report_is_true(planned: CycleResult) -> None:
    assert planned.gate.passed, planned.gate.summary()
    names = {c.name for c in planned.gate.checks}
    assert {"effort", "dwell", "collision", "line", "grasp", "bay", "park", "springback_release"} <= names
    assert planned.gate.min_clearance_m >= 0.01


def test_the_document_round_trips_through_the_independent_check(
    planned: CycleResult, cycle: ResolvedCycle
) -> None:
    from planner.documents.cycle import cycle_document
    from planner.task.check import check_cycle

    doc = json.loads(json.dumps(cycle_document(cycle, planned)))
    assert doc["kind"] == "cycle" and doc["cycle"]["sha256"] == cycle.sha256
    assert len(doc["leg"]) == len(doc["t"]) and [x["name"] for x in doc["legs"]] == list(LEG_NAMES)
    assert {e["kind"] for e in doc["events"]} == {"attach", "detach"}
    report = check_cycle(cycle, doc)
    assert report.passed, report.summary()
    # A release dwell that creeps by a millimetre is caught.
    lt = next(x for x in doc["legs"] if x["name"] == "release")
    k = lt["sample_start"] + 1
    doc["position"][k][0] += 1e-3
    bad = check_cycle(cycle, doc)
    assert {c.name for c in bad.failures} >= {"dwell"}


def test_a_release_whose_springback_ends_within_the_clearance_is_refused(
    planned: CycleResult, cycle: ResolvedCycle
) -> None:
    """An obstacle 5 mm from the arm at the release (within the 10 mm clearance): refused, bodies and mm."""
    import dataclasses

    from planner.core.exceptions import ReleaseInCollision
    from planner.plan.context import PlanContext
    from planner.task.cycle import _check_release
    from planner.task.legs import leg_scenario

    q = planned.profile.joints[_rows(planned, "release").stop - 1]
    sc = leg_scenario(cycle, leg("retract"), q, goal_q=q)
    world = leg_world(cycle, leg("retract"))
    _, P, _ = world.poses(q)
    arm = world.names.index("arm")
    T = np.eye(4)
    T[:3, 3] = P[0, arm] + np.array([0.0, 0.07 + 0.005 + 0.005, 0.0])  # 5 mm above the arm capsule
    probe = Obstacle.box("probe", (0.01, 0.01, 0.01), T)
    ctx = PlanContext.build(dataclasses.replace(sc, obstacles=(*sc.obstacles, probe)))
    with pytest.raises(ReleaseInCollision) as exc:
        _check_release(cycle, ctx, q)
    assert "probe" in exc.value.message and " mm from probe" in exc.value.message
    assert exc.value.details["springback_m"] == pytest.approx(
        next(e for e in planned.events if e.kind == "detach").springback_m, abs=1e-9
    )


def test_the_cycle_figure_is_the_exact_minimum_over_every_sample(
    planned: CycleResult, cycle: ResolvedCycle
) -> None:
    """min_clearance_m against exact FCL distances at every sample, each leg's in its own world."""
    gate = planned.gate
    at = gate.min_clearance_at
    assert at is not None and gate.min_clearance_bound_m is not None
    q = planned.profile.joints
    lowest, where = np.inf, None
    for lt in planned.legs:
        world = leg_world(cycle, leg(lt.name))
        rows = _rows(planned, lt.name, with_previous=lt.sample_start > 0)
        d = world.clearance_profile(q[rows])  # cabin, robot pairs, obstacles (allowed pairs apart)
        k = int(np.argmin(d))
        if d[k] < lowest:
            lowest, where = float(d[k]), (lt.name, rows.start + k)
        if lt.name == at["leg"]:  # the figure is the exact distance at its sample, in its leg's world
            exact = world.min_distance(q[at["sample"]])
            assert gate.min_clearance_m == pytest.approx(exact.distance_m, abs=1e-9)
    # An exact distance at a sample (never below the lowest), and no sample lower by more than the tolerance.
    figure = gate.min_clearance_m
    assert figure - at["tolerance_m"] <= lowest <= figure + 1e-9, (lowest, where, at)
    assert at["tolerance_m"] <= 5e-4
    assert gate.min_clearance_bound_m <= lowest
    assert at["t_s"] == pytest.approx(planned.profile.t[at["sample"]])
    labels = {"unit A3", "gripper", "cabin", "unit A2", "fixture of A3", *leg_world(cycle, leg("park")).names}
    assert set(at["bodies"]) <= labels, at


def test_a_cycle_passing_within_the_clearance_of_an_installed_unit_is_refused(
    planned: CycleResult, cycle: ResolvedCycle
) -> None:
    """An installed unit 5 mm from the carried unit on the transit: the cycle gate refuses, naming both."""
    import dataclasses

    from planner.collision.world import CollisionWorld
    from planner.gate.cycle import validate_cycle
    from planner.task.cycle import cycle_requirements

    req = cycle_requirements(cycle, planned.legs)
    transit = next(x for x in req.legs if x.name == "transit")
    world = transit.world
    q = planned.profile.joints[(transit.sample_start + transit.sample_end) // 2]
    flat = world.flat_poses(q)
    b = world.names.index(PAYLOAD)
    R, c = flat[b, :9].reshape(3, 3).T, flat[b, 9:12]
    half = 0.5 * np.asarray(world.bodies.shapes[b].size)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = c + (half[2] + 0.005 + 0.01) * R[:, 2]  # a 2 cm cube 5 mm off the unit's top face
    extra = Obstacle.box("unit X9", (0.02, 0.02, 0.02), T)
    assert world.obstacles is not None
    crowded = CollisionWorld(
        cycle.robot,
        world.cabin,
        world.payload,
        obstacles=(*world.obstacles.obstacles, extra),
        allowed=world.obstacles.allowed,
    )
    assert world.obstacle_distance(flat).distance_m > 0.005  # the others are farther
    assert crowded.obstacle_distance(flat).distance_m == pytest.approx(0.005, abs=1e-6)
    legs = tuple(dataclasses.replace(x, world=crowded) if x.name == "transit" else x for x in req.legs)
    report = validate_cycle(planned.profile, cycle.robot, dataclasses.replace(req, legs=legs))
    assert not report.passed
    bad = [c for c in report.failures if c.name == "collision"]
    assert bad and "transit" in bad[0].detail and "unit X9" in bad[0].detail, bad


def test_a_retract_leaving_a_tight_release_is_certified_as_walked_towards_it(
    cycle: ResolvedCycle, planned: CycleResult
) -> None:
    """A certified walk needs its margin where it starts; a straight segment is certified either way.

    A generated cycle's retract was refused: the slide 11.98 mm from the cabin at the release, 12 mm
    needed to start a walk (the planner's clearance plus MIN_MARGIN_M), although the same segment walked
    towards the release is certified with the full 5 mm margin. Here the example's retract, with the
    clearance set 0.3 mm below the exact distance at its release (the slide and the installed unit, 20 mm),
    which grows along the retract: a walk cannot start at the release, the segment is certified, and what
    is certified holds at every one of 401 points by exact distances.
    """
    from planner.plan.motion import MIN_MARGIN_M, certify_motion

    lt = next(x for x in planned.legs if x.name == "retract")
    q_release, q_retract = (
        planned.profile.joints[lt.sample_start - 1],
        planned.profile.joints[lt.sample_end - 1],
    )
    world = leg_world(cycle, leg("retract"))
    exact = world.clearance_profile(np.linspace(q_release, q_retract, 401), include_self=False)
    clearance = float(exact[0]) - 0.0003
    assert 0.0003 < MIN_MARGIN_M and int(np.argmin(exact)) == 0  # the release is the tightest point
    leaving = world.check_motion(q_release, q_retract, clearance, 0.005)
    assert not leaving.valid and leaving.t_fail == 0.0  # the walk cannot start there
    assert certify_motion(world, q_release, q_retract, clearance, 0.005).valid
    assert certify_motion(world, q_retract, q_release, clearance, 0.005).valid
    # Closer than the clearance at the release: refused either way.
    for a, b in ((q_release, q_retract), (q_retract, q_release)):
        assert not certify_motion(world, a, b, float(exact[0]) + 0.0001, 0.005).valid
