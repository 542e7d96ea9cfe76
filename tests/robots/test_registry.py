"""The robot registry: a third mechanism plugs into the CLI and the API without changes there."""

from __future__ import annotations

import json
import sys
import types
from typing import Any, cast

import pytest
from typer.testing import CliRunner

import planner.robots.registry as registry
import planner.tools as tools_registry
from planner.cli import app
from planner.core.exceptions import InvalidInput, UnknownRobot
from planner.dynamics.lagrange import Cabin8Dynamics
from planner.dynamics.models import drive_dynamics
from planner.robots.base import KinematicsTools


@pytest.fixture
def toy(monkeypatch: pytest.MonkeyPatch) -> str:
    """Register a 'toy' robot (cabin8's model) with its own kinematics tools module."""
    module = types.ModuleType("toy_tools")

    def fk(robot_name: str, drives: Any, joints: Any, guess: Any) -> dict[str, Any]:
        return {"robot": robot_name, "fk_of": drives}

    def ik(robot_name: str, pose: Any, near: Any, seed: int) -> dict[str, Any]:
        return {"robot": robot_name, "ik_of": pose, "seed": seed}

    module.fk, module.ik = fk, ik  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "toy_tools", module)
    cabin8 = registry.entry("cabin8")
    monkeypatch.setitem(registry._ENTRIES, "toy", registry.RobotEntry("toy", cabin8.kind, cabin8.model))
    registry.register_tools("toy", lambda: cast(KinematicsTools, module))
    return "toy"


def test_builtin_tools_follow_the_protocol() -> None:
    for name in registry.available_robots():
        tools = tools_registry.kinematics_tools(name)
        assert callable(tools.fk) and callable(tools.ik)
    with pytest.raises(UnknownRobot) as info:
        tools_registry.kinematics_tools("r2d2")
    assert info.value.details["field"] == "robot"


def test_one_entry_holds_model_tools_and_force_model(toy: str, monkeypatch: pytest.MonkeyPatch) -> None:
    assert set(registry.available_robots()) == {"cabin8", "pprs6", "toy"}
    assert tools_registry.kinematics_tools("cabin8").fk is not tools_registry.kinematics_tools("pprs6").fk
    # The force model follows the mechanism kind of the model object: cabin8's Lagrange model, none for
    # pprs6 (no masses), and the toy robot (cabin8's model under another name) gets cabin8's.
    cabin8 = registry.load_robot("cabin8")
    assert isinstance(drive_dynamics(cabin8), Cabin8Dynamics)
    assert drive_dynamics(registry.load_robot("pprs6")) is None
    assert drive_dynamics(registry.load_robot(toy)) is drive_dynamics(registry.load_robot(toy))
    assert isinstance(drive_dynamics(registry.load_robot(toy)), Cabin8Dynamics)
    # A robot without tools is refused by name, not by a lookup error.
    bare = registry.entry("pprs6")
    monkeypatch.setitem(registry._ENTRIES, "bare", registry.RobotEntry("bare", bare.kind, bare.model))
    with pytest.raises(InvalidInput) as info:
        tools_registry.kinematics_tools("bare")
    assert info.value.details["field"] == "robot" and "no kinematics tools" in info.value.message


def test_a_registered_robot_reaches_the_cli_and_the_api(toy: str, tmp_path) -> None:
    res = CliRunner().invoke(app, ["fk", toy, "--drives", '{"a": 1}'])
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout) == {"robot": "toy", "fk_of": {"a": 1}}
    res = CliRunner().invoke(app, ["ik", toy, "--pose", '{"p": 2}', "--seed", "3"])
    assert json.loads(res.stdout) == {"robot": "toy", "ik_of": {"p": 2}, "seed": 3}

    from tests.api.conftest import make_settings, start_idle_service

    for svc in start_idle_service(make_settings(tmp_path)):
        r = svc.client.post(
            "/api/v1/kinematics/fk", json={"robot": toy, "drives": {"a": 1.0}}, headers=svc.h()
        )
        assert r.status_code == 200 and r.json() == {"robot": "toy", "fk_of": {"a": 1.0}}
