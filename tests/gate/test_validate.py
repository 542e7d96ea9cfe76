"""The validation gate: it passes a real plan, and each tampering of that plan fails its own check.

One real plan (aisle-transfer: 100 kg carried 3.8 m along the aisle) is made once per module; every test
tampers with a copy of its profile and asserts which checks fail -- and that the other checks still ran
and still pass where the tampering does not concern them.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import itertools
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planner.core.exceptions import InvalidInput
from planner.gate.checks import GateReport, GateRequirements, validate_profile
from planner.gate.requirements import DEFLECTION_STEP, deflection_sample_indices, requirements_for
from planner.plan.pipeline import Planner, PlanResult
from planner.robots.cabin8 import Cabin8
from planner.scenario.resolve import ResolvedScenario, load_scenario
from planner.timing.profile import DriveProfile

SCENARIO = Path(__file__).parent.parent / "scenarios" / "aisle-transfer.yaml"
ALL_CHECKS = {
    "finite",
    "time",
    "start",
    "end_at_rest",
    "workspace",
    "position",
    "velocity",
    "acceleration",
    "jerk",
    "effort",
    "consistency",
    "goal",
    "collision",
}


@dataclasses.dataclass(frozen=True)
class Plan:
    sc: ResolvedScenario
    planner: Planner
    result: PlanResult
    req: GateRequirements

    @property
    def robot(self) -> Cabin8:
        return self.sc.robot

    @property
    def profile(self) -> DriveProfile:
        return self.result.profile

    def gate(self, profile: DriveProfile, req: GateRequirements | None = None) -> GateReport:
        pl = self.planner
        return validate_profile(profile, self.robot, pl.world, req or self.req, pl.dynamics)


@pytest.fixture(scope="module")
def plan() -> Plan:
    sc = load_scenario(SCENARIO)
    planner = Planner(sc)
    result = planner.plan()
    return Plan(sc, planner, result, requirements_for(sc, planner.payload))


def outcome(report: GateReport) -> tuple[set[str], set[str]]:
    """(failed check names, passed check names)."""
    failed = {c.name for c in report.checks if not c.passed}
    return failed, {c.name for c in report.checks} - failed


def test_gate_passes_the_real_plan(plan: Plan) -> None:
    assert plan.result.gate.passed, plan.result.gate.summary()
    report = plan.gate(plan.profile)
    assert report.passed, report.summary()
    assert {c.name for c in report.checks} == ALL_CHECKS
    assert report.samples == len(plan.profile.t)
    for name in ("velocity", "acceleration", "effort"):
        assert 0.5 < report.peak_ratios[name] <= 1.01
    assert report.min_clearance_m >= plan.sc.options.clearance_m
    # The profile really moves the payload along the aisle: 3.8 m of rail travel.
    assert plan.profile.position[-1, 0] - plan.profile.position[0, 0] == pytest.approx(3.8, abs=1e-9)


def _peak(values: np.ndarray, limit: np.ndarray) -> tuple[int, int]:
    ratio = np.abs(values) / limit[None, :]
    k, j = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
    return int(k), int(j)


def scale_velocity(plan: Plan) -> dict[str, Any]:
    k, _ = _peak(plan.profile.velocity, plan.robot.limits.v_max)
    v = plan.profile.velocity.copy()
    v[k] *= 1.05
    return {"velocity": v}


def raise_acceleration(plan: Plan) -> dict[str, Any]:
    lim = plan.robot.limits
    k, j = _peak(plan.profile.acceleration, lim.a_max)
    a = plan.profile.acceleration.copy()
    a[k, j] = np.sign(a[k, j]) * 1.05 * lim.a_max[j]
    return {"acceleration": a}


def alter_effort(plan: Plan) -> dict[str, Any]:
    lim = plan.robot.limits
    e = plan.profile.effort.copy()
    m = len(e) // 2
    e[m] += 0.05 * lim.effort_max  # still far below the limits, but not what the motion needs
    assert np.all(np.abs(e[m]) <= lim.effort_max)
    return {"effort": e}


def reverse_time(plan: Plan) -> dict[str, Any]:
    t = plan.profile.t.copy()
    m = len(t) // 2
    t[m] = t[m - 1]
    return {"t": t}


def move_start(plan: Plan) -> dict[str, Any]:
    u = plan.profile.position.copy()
    u[0, 0] += 1e-3
    return {"position": u}


def move_goal(plan: Plan) -> dict[str, Any]:
    u = plan.profile.position.copy()
    u[-1, 0] += 2e-3
    return {"position": u}


def tilt_platform(plan: Plan) -> dict[str, Any]:
    """Slider x3 moved 6 cm at one sample: the stage still assembles, but tilted beyond gamma_max."""
    u = plan.profile.position.copy()
    m = len(u) // 2
    u[m, 3] += 0.06
    q = plan.robot.joints_from_drives(u[m])
    assert [v["name"] for v in plan.robot.violations(q)] == ["gamma"]
    return {"position": u}


def keep_moving(plan: Plan) -> dict[str, Any]:
    v = plan.profile.velocity.copy()
    v[-1, 0] = 1e-6
    return {"velocity": v}


EVERYTHING_ELSE = ALL_CHECKS - {"consistency"}
TAMPERS: list[tuple[Callable[[Plan], dict[str, Any]], set[str], set[str]]] = [
    # (tampering, checks that must fail, checks that must still pass)
    (scale_velocity, {"velocity", "consistency"}, {"finite", "time", "start", "end_at_rest", "goal"}),
    # One sample's acceleration raised (the jerk it implies is reported, not required: the default time
    # law is acceleration-limited).
    (raise_acceleration, {"acceleration"}, ALL_CHECKS - {"acceleration", "jerk"}),
    (alter_effort, {"effort"}, ALL_CHECKS - {"effort"}),
    (reverse_time, {"time"}, EVERYTHING_ELSE - {"time", "acceleration", "jerk"}),
    (move_start, {"start"}, EVERYTHING_ELSE - {"start"}),
    (move_goal, {"goal"}, EVERYTHING_ELSE - {"goal"}),
    (
        tilt_platform,
        {"workspace"},
        {"finite", "time", "start", "end_at_rest", "goal", "velocity", "position"},
    ),
    (keep_moving, {"end_at_rest"}, ALL_CHECKS - {"end_at_rest"}),
]


@pytest.mark.filterwarnings("ignore:divide by zero:RuntimeWarning", "ignore:invalid value:RuntimeWarning")
@pytest.mark.parametrize(("tamper", "must_fail", "must_pass"), TAMPERS, ids=[t[0].__name__ for t in TAMPERS])
def test_each_tampering_fails_its_check_and_every_check_still_runs(
    plan: Plan,
    tamper: Callable[[Plan], dict[str, Any]],
    must_fail: set[str],
    must_pass: set[str],
) -> None:
    original = plan.profile.position.copy()
    report = plan.gate(dataclasses.replace(plan.profile, **tamper(plan)))
    assert np.array_equal(plan.profile.position, original)  # the copy was tampered with, not the plan
    failed, passed = outcome(report)
    assert not report.passed
    assert failed | passed == ALL_CHECKS  # every check ran
    assert must_fail <= failed, report.summary()
    assert must_pass <= passed, report.summary()
    for c in report.failures:
        assert c.detail
    assert report.summary().count(":") >= len(failed)


def test_non_finite_value_fails_the_finite_check(plan: Plan) -> None:
    v = plan.profile.velocity.copy()
    v[len(v) // 2, 0] = np.nan
    report = plan.gate(dataclasses.replace(plan.profile, velocity=v))
    failed, _ = outcome(report)
    assert failed == {"finite"} and not report.passed


def test_workspace_check_names_the_violated_margin(plan: Plan) -> None:
    report = plan.gate(dataclasses.replace(plan.profile, **tilt_platform(plan)))
    check = next(c for c in report.checks if c.name == "workspace")
    assert not check.passed and "gamma" in check.detail and check.sample == len(plan.profile.t) // 2


def _sliders_too_close(plan: Plan) -> np.ndarray:
    """Slider x3 within 5 cm of x1 (minimum gap 10 cm) at one sample: the stage cannot assemble there."""
    u = plan.profile.position.copy()
    m = len(u) // 2
    u[m, 3] = u[m, 1] + 0.05
    assert u[m, 3] - u[m, 1] < plan.robot.desc.parallel_stage.min_slider_gap
    return u


def test_slider_gap_below_minimum_fails_the_workspace_check(plan: Plan) -> None:
    u = _sliders_too_close(plan)
    report = plan.gate(dataclasses.replace(plan.profile, position=u))
    failed, _ = outcome(report)
    assert "workspace" in failed and not report.passed
    check = next(c for c in report.checks if c.name == "workspace")
    assert check.sample == len(u) // 2


def test_a_sample_that_does_not_assemble_does_not_hide_the_other_checks(plan: Plan) -> None:
    u = _sliders_too_close(plan)
    v = plan.profile.velocity.copy()
    k = int(np.argmax(np.max(np.abs(v) / plan.robot.limits.v_max, axis=1)))
    v[k] *= 1.5  # a second, independent fault the report must also list: 150% of the peak velocity
    report = plan.gate(dataclasses.replace(plan.profile, position=u, velocity=v))
    failed, passed = outcome(report)
    assert failed | passed == ALL_CHECKS
    assert {"workspace", "velocity"} <= failed


def _executed_overshoot(plan: Plan) -> DriveProfile:
    """One step of the rail's acceleration phase executes dv/dt = 104% of a_max.

    Every reported acceleration stays within 100% of a_max, the step's dv/dt lies within 5% of a_max of
    the reported accelerations at its ends (what the consistency check tolerates), and the efforts are
    those the modified motion needs: only the acceleration check's dv/dt rows can catch it.
    """
    p, lim, dt = plan.profile, plan.robot.limits, plan.profile.sample_period_s
    k = 90  # inside the rail's constant-acceleration phase (after the jerk-limited ramp)
    ud, udd, eff = p.velocity.copy(), p.acceleration.copy(), p.effort.copy()
    ud[k + 1, 0] = ud[k, 0] + 1.04 * lim.a_max[0] * dt
    udd[k, 0] = lim.a_max[0]
    udd[k + 1, 0] = (ud[k + 2, 0] - ud[k + 1, 0]) / dt
    eff[k : k + 2] = plan.planner.dynamics.drive_efforts(
        p.position[k : k + 2], ud[k : k + 2], udd[k : k + 2], plan.planner.payload
    )
    return dataclasses.replace(p, velocity=ud, acceleration=udd, effort=eff)


def test_executed_overshoot_is_only_visible_in_dv_dt(plan: Plan) -> None:
    lim = plan.robot.limits
    assert abs(plan.profile.acceleration[90, 0]) >= 0.95 * lim.a_max[0]  # in the acceleration phase
    p = _executed_overshoot(plan)
    executed = np.abs(np.diff(p.velocity, axis=0)) / p.sample_period_s / lim.a_max
    assert executed.max() == pytest.approx(1.04, abs=1e-9)
    assert np.max(np.abs(p.acceleration) / lim.a_max) <= 1.0 + 1e-12
    assert np.max(np.abs(p.velocity) / lim.v_max) <= 1.0
    _, passed = outcome(plan.gate(p))
    assert {"velocity", "effort", "consistency"} <= passed


def test_gate_rejects_an_executed_acceleration_above_the_limit(plan: Plan) -> None:
    """Reported accelerations at most 100% of a_max, but one step's dv/dt is 104%: the gate must refuse."""
    report = plan.gate(_executed_overshoot(plan))
    failed, _ = outcome(report)
    assert "acceleration" in failed
    assert not report.passed
    assert report.peak_ratios["acceleration"] == pytest.approx(1.04, abs=1e-6)


def test_larger_clearance_than_the_plan_keeps_fails_the_collision_check(plan: Plan) -> None:
    req = dataclasses.replace(plan.req, clearance_m=plan.result.gate.min_clearance_m + 0.02)
    report = plan.gate(plan.profile, req)
    failed, passed = outcome(report)
    assert failed == {"collision"}, report.summary()
    assert passed == ALL_CHECKS - {"collision"}


def test_payload_pushed_into_the_aisle_wall_fails_the_collision_check(plan: Plan) -> None:
    """The platform slides 0.2 m sideways mid-transfer (smooth bump): the payload meets the aisle wall."""
    robot, p = plan.robot, plan.profile
    n = len(p.t)
    a, b = int(0.3 * n), int(0.7 * n)
    bump = np.zeros(n)
    bump[a:b] = np.sin(np.linspace(0.0, np.pi, b - a)) ** 2
    q = p.joints.copy()
    q[:, 1] += 0.2 * bump
    assert not any(robot.violations(qi) for qi in q[::20])  # still admissible: only the cabin is in the way
    world = plan.planner.world
    assert float(np.min(world.clearance_profile(q[a:b:20]))) < plan.sc.options.clearance_m
    report = plan.gate(dataclasses.replace(p, position=robot.drives_from_joints(q), joints=q))
    failed, passed = outcome(report)
    assert "collision" in failed
    assert failed | passed == ALL_CHECKS
    assert {"finite", "time", "start", "end_at_rest", "goal", "workspace", "position"} <= passed
    check = next(c for c in report.checks if c.name == "collision")
    assert check.sample is not None and a <= check.sample < b


def test_dict_round_trip_is_exact_and_still_passes_the_gate(plan: Plan) -> None:
    p = plan.profile
    data = json.loads(json.dumps(p.to_dict()))  # through real JSON text
    back = DriveProfile.from_dict(data, plan.robot)
    for name in ("t", "position", "velocity", "acceleration", "effort"):
        assert np.array_equal(getattr(back, name), getattr(p, name)), name
    assert back.sample_period_s == p.sample_period_s
    assert back.drive_names == p.drive_names == plan.robot.drive_names
    assert np.max(np.abs(back.joints - p.joints)) <= 1e-12  # recomputed from the drives
    assert data["duration_s"] == p.duration_s == p.t[-1]
    assert data["units"]["effort"]["d1"] == "N" and data["units"]["effort"]["theta3"] == "N m"
    report = plan.gate(back)
    assert report.passed, report.summary()


def _without(key: str) -> Callable[[dict[str, Any]], None]:
    def f(d: dict[str, Any]) -> None:
        del d[key]

    return f


def _set(key: str, value: Callable[[dict[str, Any]], Any]) -> Callable[[dict[str, Any]], None]:
    def f(d: dict[str, Any]) -> None:
        d[key] = value(d)

    return f


BAD_INPUTS: list[tuple[str, Callable[[dict[str, Any]], None], str, str]] = [
    # (id, mutation, expected field, text the message must contain)
    ("missing-velocity", _without("velocity"), "profile.velocity", "missing"),
    ("missing-t", _without("t"), "profile.t", "missing"),
    ("missing-drives", _without("drives"), "profile.drives", "missing"),
    ("missing-period", _without("sample_period_s"), "profile.sample_period_s", "missing"),
    ("renamed-drive", _set("drives", lambda d: [*d["drives"][:-1], "theta7"]), "profile.drives", "theta7"),
    ("reordered-drives", _set("drives", lambda d: d["drives"][::-1]), "profile.drives", "expected"),
    ("seven-columns", _set("position", lambda d: [r[:7] for r in d["position"]]), "profile.position", "8"),
    ("missing-row", _set("effort", lambda d: d["effort"][:-1]), "profile.effort", "rows"),
    ("t-as-matrix", _set("t", lambda d: [[x] for x in d["t"]]), "profile.t", "1-D"),
    ("single-sample", _set("t", lambda d: d["t"][:1]), "profile.t", "at least 2"),
]


@pytest.mark.parametrize(
    ("mutate", "field", "text"), [b[1:] for b in BAD_INPUTS], ids=[b[0] for b in BAD_INPUTS]
)
def test_from_dict_refuses_malformed_profiles_naming_the_field(
    plan: Plan, mutate: Callable[[dict[str, Any]], None], field: str, text: str
) -> None:
    data = plan.profile.to_dict()
    mutate(data)
    with pytest.raises(InvalidInput) as info:
        DriveProfile.from_dict(data, plan.robot)
    assert info.value.details["field"] == field
    assert text in info.value.message


@pytest.mark.parametrize("kind", ["ragged", "text"])
def test_from_dict_names_the_malformed_array(plan: Plan, kind: str) -> None:
    data = plan.profile.to_dict()
    if kind == "ragged":
        data["velocity"][5] = data["velocity"][5][:7]
    else:
        data["velocity"][5][2] = "fast"
    with pytest.raises(InvalidInput) as info:
        DriveProfile.from_dict(data, plan.robot)
    assert info.value.details["field"] == "profile.velocity"
    assert info.value.message.startswith("profile.velocity: ")


def test_csv_has_a_header_and_one_row_per_sample_that_parse_back(plan: Plan) -> None:
    p = plan.profile
    rows = list(csv.reader(io.StringIO(p.to_csv())))
    header, body = rows[0], rows[1:]
    assert len(header) == 41 == 1 + 5 * 8 and len(set(header)) == 41
    assert header[0] == "t_s"
    for j, (name, unit) in enumerate(zip(p.drive_names, p.drive_units, strict=True)):
        assert header[1 + j] == f"{name}_pos_{unit}"
        assert header[9 + j].startswith(f"{name}_vel_") and header[17 + j].startswith(f"{name}_acc_")
        assert header[25 + j] == f"{name}_jerk_{unit}/s3"
        assert header[33 + j] == f"{name}_effort_{'N' if unit == 'm' else 'Nm'}"
    assert len(body) == len(p.t) and all(len(r) == 41 for r in body)
    data = np.array(body, dtype=float)
    expected = np.column_stack([p.t, p.position, p.velocity, p.acceleration, p.jerk, p.effort])
    np.testing.assert_allclose(data, expected, rtol=1e-8, atol=0.0)


def test_a_profile_sampled_at_another_period_than_the_controllers_is_refused(plan: Plan) -> None:
    """10x slower, sampled every 40 ms: within every limit, but a 4 ms controller would run it 10x fast."""
    p = plan.profile
    k = 10.0
    slow = dataclasses.replace(
        p,
        t=p.t * k,
        sample_period_s=p.sample_period_s * k,
        velocity=p.velocity / k,
        acceleration=p.acceleration / k**2,
        effort=plan.planner.dynamics.drive_efforts(
            p.position, p.velocity / k, p.acceleration / k**2, plan.planner.payload
        ),
    )
    report = plan.gate(slow)
    failed, _ = outcome(report)
    assert "time" in failed
    assert "controller period" in next(c for c in report.checks if c.name == "time").detail
    # The same profile is fine where the controller period is 40 ms.
    relaxed = dataclasses.replace(plan.req, sample_period_s=p.sample_period_s * k)
    assert "time" not in outcome(plan.gate(slow, relaxed))[0]


def test_a_final_sample_still_accelerating_is_not_at_rest(plan: Plan) -> None:
    udd = plan.profile.acceleration.copy()
    udd[-1, 0] = 0.01
    report = plan.gate(dataclasses.replace(plan.profile, acceleration=udd))
    assert "end_at_rest" in outcome(report)[0]


def test_approach_check_refuses_overshooting_the_goal_and_backing_out() -> None:
    """Poses on the insertion line (x into the bay): straight in passes; past the goal or back out fails."""
    from planner.gate.checks import _approach_check

    goal = np.eye(4)
    goal[:3, 3] = [0.8, 0.7, 2.7]
    req = GateRequirements(
        start_u=np.zeros(8),
        clearance_m=0.01,
        motion_margin_m=0.001,
        T_base_payload_goal=goal,
        approach_direction=np.array([1.0, 0.0, 0.0]),
        approach_distance_m=0.3,
    )

    def poses(xs: np.ndarray) -> np.ndarray:
        T = np.repeat(goal[None], len(xs), axis=0)
        T[:, 0, 3] = goal[0, 3] + xs
        return T

    straight = np.concatenate([np.linspace(-0.3, 0.0, 50)])
    assert _approach_check(poses(straight), req).passed
    past = np.concatenate([np.linspace(-0.3, 0.05, 50), np.linspace(0.05, 0.0, 10)])
    assert not _approach_check(poses(past), req).passed
    back = np.concatenate(
        [np.linspace(-0.3, -0.1, 30), np.linspace(-0.1, -0.15, 5), np.linspace(-0.15, 0, 20)]
    )
    assert not _approach_check(poses(back), req).passed


@pytest.fixture(scope="module")
def soft_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder with a cabin8 description carrying the issue-7 (nominal) stiffness guesses.

    They sag by millimetres under 100 kg (the paper-fit data by a fraction of that), which is what the
    sagging-robot checks below need to be visible; a scenario names it with ``robot_description``.
    """
    from planner.dynamics.paper_fit import NOMINAL_ISSUE7, replace_stiffness_block
    from planner.dynamics.stiffness_params import stiffness_yaml_block
    from planner.robots.cabin8 import default_description_path

    d = tmp_path_factory.mktemp("soft")
    text = default_description_path().read_text(encoding="utf-8")
    (d / "cabin8.yaml").write_text(replace_stiffness_block(text, stiffness_yaml_block(NOMINAL_ISSUE7)))
    return d


def _carry(d1_goal: float, soft_dir: Path) -> ResolvedScenario:
    from planner.scenario import resolve_scenario, scenario_from_dict

    home = {"x1": -0.46, "x2": 0.46, "x3": -0.09, "theta3": 1.2, "theta4": -0.8, "d5": -0.25, "theta6": 0.0}
    return resolve_scenario(
        scenario_from_dict(
            {
                "name": "carry",
                "robot": "cabin8",
                "robot_description": "cabin8.yaml",
                "payload": {"box": [0.45, 0.35, 0.3], "mass": 100, "grasp": {"position": [0, 0, 0.2]}},
                "start": {"drives": {"d1": 1.0, **home}},
                "goal": {"drives": {"d1": d1_goal, **home}},
                "options": {"seed": 1, "time_limit_s": 60},
            }
        ),
        base_dir=soft_dir,
        robot_description_files=True,
    )


def test_deflected_joints_put_the_payload_where_it_sags_to(soft_dir: Path) -> None:
    from planner.dynamics.stiffness import deflected_pose, stiffness_model
    from planner.gate.checks import deflected_joints

    sc = _carry(1.3, soft_dir)
    res = Planner(sc).plan()
    assert sc.payload is not None
    q = res.profile.joints
    q_def, sag = deflected_joints(sc.robot, q, sc.payload.rigid_payload(), sc.payload.T_tool_payload)
    assert 1e-3 < sag < 1e-2  # a 100 kg payload sags by millimetres
    for i in (0, len(q) // 2, len(q) - 1):
        x = stiffness_model(sc.robot).deflection(q[i], sc.payload.rigid_payload(), sc.payload.T_tool_payload)
        want = deflected_pose(sc.robot.fk(q[i]) @ sc.payload.T_tool_payload, x.twist)
        got = sc.robot.fk(q_def[i]) @ sc.payload.T_tool_payload
        np.testing.assert_allclose(got, want, atol=2e-6)
    # Every sample: predicted at a subsample (by motion, not by index) and interpolated in between, the
    # payload frame sits within 3 um of where the model puts it at that very sample.
    x = stiffness_model(sc.robot).deflection_along(q, sc.payload.rigid_payload(), sc.payload.T_tool_payload)
    T_pay = sc.robot.fk_batch(q) @ sc.payload.T_tool_payload
    want_p = T_pay[:, :3, 3] + x[:, :3]
    got_p = (sc.robot.fk_batch(q_def) @ sc.payload.T_tool_payload)[:, :3, 3]
    assert float(np.linalg.norm(got_p - want_p, axis=1).max()) < 3e-6
    assert len(deflection_sample_indices(q)) < len(q) / 4  # a subsample indeed


def test_legs_of_one_load_share_one_evaluation_with_each_legs_own_numbers(soft_dir: Path) -> None:
    """deflected_joints_of over a profile cut in legs gives, bit for bit, each leg's deflected_joints."""
    from planner.gate.checks import deflected_joints, deflected_joints_of

    sc = _carry(1.3, soft_dir)
    q = Planner(sc).plan().profile.joints
    assert sc.payload is not None
    load, T = sc.payload.rigid_payload(), sc.payload.T_tool_payload
    cuts = [0, 1, 40, len(q) // 2, len(q) // 2 + 1, len(q)]  # a one-sample leg, a rest, the rest of it
    legs = [q[a : max(b, a + 1)] for a, b in itertools.pairwise(cuts)]
    legs.append(np.repeat(q[7:8], 30, axis=0))  # a dwell: one configuration repeated
    together = deflected_joints_of(sc.robot, legs, load, T)
    for leg, (q_def, sag) in zip(legs, together, strict=True):
        alone, sag_alone = deflected_joints(sc.robot, leg, load, T)
        assert q_def.shape == leg.shape and np.array_equal(q_def, alone) and sag == sag_alone
    assert deflected_joints_of(sc.robot, [], load, T) == []


def test_deflection_samples_follow_the_motion_not_the_clock() -> None:
    rest = np.tile(np.linspace(0.0, 1.0, 8), (500, 1))
    assert deflection_sample_indices(rest).tolist() == [0, 499]  # a dwell: its two ends
    rail = rest.copy()
    rail[:, 0] = np.linspace(0.0, 3.0, 500)  # the rail alone moves: the sag does not change
    assert deflection_sample_indices(rail).tolist() == [0, 499]
    line = rest.copy()
    line[:, 4] += np.linspace(0.0, 0.02, 500)  # 20 mrad of theta3 in 500 samples: every 2 mrad
    idx = deflection_sample_indices(line)
    assert 10 <= len(idx) <= 12 and np.all(np.diff(line[idx, 4]) <= DEFLECTION_STEP + 0.02 / 499 + 1e-12)
    long = rest.copy()
    long[:, 4] += np.linspace(0.0, 3.0, 500)
    assert len(deflection_sample_indices(long)) == 500  # fast motion: every sample (up to 300 even ones)


def test_a_plate_the_rigid_robot_clears_but_the_sagging_payload_touches_is_refused(soft_dir: Path) -> None:
    """A plate under the payload's lowest corner: certified for the rigid robot, not for the sagging one.

    Placed from the predicted sag of the soft (nominal) stiffness data: the gap is the requirement plus half
    the predicted drop of that corner.
    """
    import trimesh

    from planner.collision.world import CollisionWorld
    from planner.gate.checks import deflected_joints
    from planner.gate.requirements import GATE_MOTION_MARGIN_M
    from planner.meshio import load_mesh

    sc = _carry(1.3, soft_dir)
    res = Planner(sc).plan()
    assert sc.payload is not None
    q = res.profile.joints
    corners = np.array([[sx, sy, sz, 1.0] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    corners[:, :3] *= np.array(sc.payload.size) / 2

    def lowest(qi: np.ndarray) -> np.ndarray:
        P = (corners @ (sc.robot.fk(qi) @ sc.payload.T_tool_box).T)[:, :3]
        return P[np.argmin(P[:, 1])]

    low = lowest(q[-1])
    q_def, _ = deflected_joints(sc.robot, q[-1:], sc.payload.rigid_payload(), sc.payload.T_tool_payload)
    drop = float(low[1] - lowest(q_def[-1])[1])
    assert drop > 1e-4  # the payload sags
    clearance = 0.0005
    gap = clearance + GATE_MOTION_MARGIN_M + 0.5 * drop
    plate = trimesh.creation.box(extents=(0.04, 0.01, 0.04))
    plate.apply_translation([low[0], low[1] - gap - 0.005, low[2]])
    world = CollisionWorld(
        sc.robot, load_mesh(plate.export(file_type="stl"), units="m", name="p.stl"), sc.payload
    )
    assert world.min_distance(q[-1], include_self=False).distance_m == pytest.approx(gap, abs=1e-6)
    req = dataclasses.replace(requirements_for(sc, sc.payload.rigid_payload()), clearance_m=clearance)
    rigid = validate_profile(res.profile, sc.robot, world, dataclasses.replace(req, deflection_check=False))
    assert next(c for c in rigid.checks if c.name == "collision").passed
    report = validate_profile(res.profile, sc.robot, world, req)
    check = next(c for c in report.checks if c.name == "collision")
    assert not check.passed and "sag" in check.detail
