"""The cabinplan CLI: JSON on stdout, one readable line and the documented exit code on failure."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from planner.cli import app
from planner.robots.cabin8 import Cabin8

runner = CliRunner()
HOME = {
    "d1": 1.0,
    "x1": -0.46,
    "x2": 0.46,
    "x3": -0.09,
    "theta3": 0,
    "theta4": -0.5,
    "d5": -0.25,
    "theta6": 0,
}


def run(*args: str) -> tuple[int, dict | None, str]:
    result = runner.invoke(app, list(args))
    try:
        payload = json.loads(result.stdout) if result.exit_code == 0 else None
    except json.JSONDecodeError:
        payload = None
    return result.exit_code, payload, result.stderr


def test_robot_summary_lists_drives_with_units_and_limits() -> None:
    code, out, _ = run("robot", "cabin8")
    assert code == 0 and out is not None
    names = [d["name"] for d in out["drives"]]
    assert names == ["d1", "x1", "x2", "x3", "theta3", "theta4", "d5", "theta6"]
    theta3 = out["drives"][4]
    assert theta3["unit"] == "rad" and theta3["upper"] == pytest.approx(np.radians(105))
    assert out["parallel_stage"]["L1_m"] == 0.40
    # Jerk limits of issue 14: d1 2 m/s^3, sliders 1.5 m/s^3, theta3 200 deg/s^3, theta6 300 deg/s^3.
    jerk = {d["name"]: d["j_max"] for d in out["drives"]}
    assert jerk["d1"] == 2.0 and jerk["x2"] == 1.5 and jerk["d5"] == 1.5
    assert jerk["theta3"] == pytest.approx(np.radians(200))
    assert jerk["theta6"] == pytest.approx(np.radians(300))
    assert out["default_timing"] == "jerk_limited"  # the default whenever the description has jerk limits
    code, out, _ = run("robot", "pprs6")
    assert code == 0 and out is not None and all(d["j_max"] > 0 for d in out["drives"])
    assert out["default_timing"] == "jerk_limited"


def test_fk_from_drives_and_from_joints_agree(robot: Cabin8) -> None:
    code, out, _ = run("fk", "cabin8", "--drives", json.dumps(HOME))
    assert code == 0 and out is not None
    T = np.array(out["T_base_tool"]).reshape(4, 4)
    q = robot.joints_from_drives(robot.drives_from_dict(HOME))
    np.testing.assert_allclose(T, robot.fk(q), atol=1e-12)
    code2, out2, _ = run("fk", "cabin8", "--joints", json.dumps(out["joints"]))
    assert code2 == 0 and out2 is not None
    np.testing.assert_allclose(out2["T_base_tool"], out["T_base_tool"], atol=1e-9)
    assert out2["drives"] == pytest.approx(HOME, abs=1e-9)


def test_ik_round_trip_through_the_cli(robot: Cabin8) -> None:
    _, fk_out, _ = run("fk", "cabin8", "--drives", json.dumps(HOME))
    assert fk_out is not None
    code, out, _ = run("ik", "cabin8", "--pose", json.dumps(fk_out["pose"]), "--near", json.dumps(HOME))
    assert code == 0 and out is not None
    assert out["drives"] == pytest.approx(HOME, abs=1e-6)
    np.testing.assert_allclose(out["T_base_tool"], fk_out["T_base_tool"], atol=1e-6)


@pytest.mark.parametrize(
    ("args", "code", "fragment"),
    [
        (("ik", "cabin8", "--pose", '{"position": [3.0, 0.8, 2.0]}'), 3, "goal_unreachable"),
        (("ik", "cabin8", "--pose", '{"position": [0.5, 0.8]}'), 2, "pose.position"),
        (
            (
                "ik",
                "cabin8",
                "--pose",
                '{"position": [0.5, 0.8, 1], "orientation": {"w": 2, "x": 0, "y": 0, "z": 0}}',
            ),
            2,
            "unit quaternion",
        ),
        (("ik", "cabin8", "--pose", "{not json"), 2, "--pose: not valid JSON"),
        (("fk", "cabin8", "--drives", '{"d1": 1.0}'), 2, "missing"),
        (("fk", "cabin8", "--drives", json.dumps({**HOME, "x9": 1})), 2, "unknown name"),
        (("fk", "cabin8", "--drives", json.dumps({**HOME, "d1": "a"})), 2, "drives.d1"),
        (("fk", "cabin8", "--drives", json.dumps({**HOME, "x1": 0.3})), 3, "outside_workspace"),
        (("fk", "cabin8"), 2, "exactly one of"),
        (("robot", "cabin9"), 2, "unknown robot"),
    ],
)
def test_failures_are_one_line_with_exit_code(args: tuple[str, ...], code: int, fragment: str) -> None:
    exit_code, _, err = run(*args)
    assert exit_code == code
    lines = err.strip().splitlines()
    assert len(lines) == 1 and fragment in lines[0]
    assert "Traceback" not in err
