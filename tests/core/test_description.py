"""Robot description files: validated on load, errors name the field."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from planner.core.exceptions import InvalidInput, InvalidRobotDescription, UnknownRobot
from planner.robots import available_robots, load_robot
from planner.robots.cabin8 import Cabin8, default_description_path


def _write(tmp_path: Path, mutate) -> Path:  # type: ignore[no-untyped-def]
    raw = yaml.safe_load(default_description_path().read_text())
    mutate(raw)
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


@pytest.mark.parametrize(
    ("mutate", "field"),
    [
        (lambda r: r["drives"][1].update(lower=0.5), "drives.1"),
        (lambda r: r["drives"][2].update(v_max=-1), "drives.2.v_max"),
        (lambda r: r["parallel_stage"].update(L1=0), "parallel_stage.L1"),
        (lambda r: r["parallel_stage"].update(extra=1), "parallel_stage.extra"),
        (lambda r: r["drives"].reverse(), "<root>"),
        (lambda r: r.pop("masses"), "masses"),
        (lambda r: r["drives"][3].update(j_max=0.0), "drives.3.j_max"),
        (lambda r: r["drives"][3].update(j_max=float("inf")), "drives.3.j_max"),
        (lambda r: r["drives"][5].pop("j_max"), "j_max must be given for every drive or for none"),
    ],
)
def test_invalid_descriptions_name_the_field(tmp_path: Path, mutate, field: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(InvalidRobotDescription) as err:
        Cabin8(_write(tmp_path, mutate))
    assert err.value.details["field"] == field or field in err.value.message


def test_unreadable_description(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("drives: [unclosed")
    with pytest.raises(InvalidRobotDescription):
        Cabin8(bad)
    with pytest.raises(InvalidRobotDescription):
        Cabin8(tmp_path / "missing.yaml")


def test_registry_and_rail_length() -> None:
    assert "cabin8" in available_robots()
    assert load_robot("cabin8") is load_robot("cabin8")
    short = load_robot("cabin8", rail_length=3.0)
    assert short.limits.upper[0] == 3.0 and load_robot("cabin8").limits.upper[0] == 6.0
    with pytest.raises(UnknownRobot):
        load_robot("nope")
    with pytest.raises(InvalidInput):
        Cabin8(rail_length=-1.0)


def test_limits_are_immutable_and_match_the_issue(robot: Cabin8) -> None:
    lim = robot.limits
    with pytest.raises(ValueError):
        lim.upper[0] = 9.0
    np.testing.assert_allclose(lim.v_max[[4, 5, 7]], np.radians([20, 20, 30]))
    np.testing.assert_allclose(lim.a_max[[4, 5, 7]], np.radians([40, 40, 60]))
    np.testing.assert_allclose(lim.lower[[4, 5, 7]], np.radians([-105, -85, -180]))
    np.testing.assert_allclose(lim.upper[[4, 5, 7]], np.radians([105, 15, 180]))
    assert robot.home_drives.tolist() == [0.3, -0.46, 0.46, -0.09, 0.0, -0.5, -0.25, 0.0]
    assert not robot.violations(robot.joints_from_drives(robot.home_drives))
