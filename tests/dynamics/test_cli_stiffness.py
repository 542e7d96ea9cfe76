"""``cabinplan stiffness`` and the stiffness document the API serves."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from planner.cli import app
from planner.core.exceptions import InvalidInput
from planner.documents.stiffness import stiffness_document
from planner.robots.cabin8 import Cabin8

runner = CliRunner()
JOINTS = {
    "d1": 1.0,
    "x": 0.0,
    "y": 0.25,
    "gamma": 0.0,
    "theta3": 1.2,
    "theta4": -0.5,
    "d5": -0.25,
    "theta6": 0.0,
}
PAYLOAD = {"mass": 100, "box": [0.45, 0.35, 0.30], "grasp": {"position": [0, 0, 0.2]}}


def run(*args: str) -> tuple[int, dict | None, str]:
    result = runner.invoke(app, list(args))
    payload = json.loads(result.stdout) if result.exit_code == 0 else None
    return result.exit_code, payload, result.stderr


def test_cli_prints_k_c_and_deflection() -> None:
    code, out, _ = run(
        "stiffness", "cabin8", "--joints", json.dumps(JOINTS), "--wrench", "[0, -1000, 0, 0, 0, 0]",
        "--payload", json.dumps(PAYLOAD), "--frame", "payload",
    )  # fmt: skip
    assert code == 0 and out is not None
    K, C = np.array(out["stiffness"]), np.array(out["compliance"])
    np.testing.assert_allclose(K @ C, np.eye(6), atol=1e-7)
    d = out["deflection"]
    # Superposition: the total is gravity plus the wrench's share; a downward force moves the frame down.
    np.testing.assert_allclose(
        np.array(d["total"]["translation_m"]),
        np.array(d["gravity"]["translation_m"]) + np.array(d["wrench"]["translation_m"]),
        rtol=1e-12,
    )
    assert d["wrench"]["translation_m"][1] < 0
    np.testing.assert_allclose(d["wrench"]["translation_m"], -1000.0 * C[:3, 1], rtol=1e-12)
    # The payload frame origin is 0.2 m out along the tool z axis.
    T = np.array(out["T_base_frame"]).reshape(4, 4)
    T_tool = Cabin8().fk(np.array(list(JOINTS.values())))
    np.testing.assert_allclose(T[:3, 3], T_tool[:3, 3] + 0.2 * T_tool[:3, 2], atol=1e-12)


@pytest.mark.parametrize(
    ("args", "code", "message"),
    [
        (["--joints", json.dumps(JOINTS), "--drives", "{}"], 2, "exactly one"),
        (["--joints", json.dumps(JOINTS), "--wrench", "[1, 2]"], 2, "wrench"),
        (["--joints", json.dumps(JOINTS), "--frame", "payload"], 2, "needs a payload"),
        (["--joints", json.dumps(JOINTS), "--payload", '{"mass": -1}'], 2, "payload.mass"),
        (["--joints", json.dumps(JOINTS | {"y": 0.5})], 3, "limit_violation"),
        (["--joints", "{nope"], 2, "--joints"),
        (["--joints", json.dumps(JOINTS), "--wrench", "[1e300, 0, 0, 0, 0, 0]"], 2, "wrench"),
        (["--joints", json.dumps(JOINTS), "--payload", '{"mass": 1e300}'], 2, "payload.mass"),
        (
            [
                "--joints",
                json.dumps(JOINTS),
                "--payload",
                '{"mass": 1, "grasp": {"position": [0, 0, 0], '
                '"orientation": {"w": 0, "x": 0, "y": 0, "z": 1.3e154}}}',
            ],
            2,
            "payload",
        ),
    ],
)
def test_cli_failures_exit_with_the_documented_codes(args: list[str], code: int, message: str) -> None:
    rc, _, err = run("stiffness", "cabin8", *args)
    assert rc == code
    assert message in err and len(err.strip().splitlines()) == 1


def test_document_accepts_drives_and_force_moment_wrench() -> None:
    doc = stiffness_document(
        "cabin8",
        drives={
            "d1": 1.0,
            "x1": -0.46,
            "x2": 0.46,
            "x3": -0.09,
            "theta3": 0,
            "theta4": -0.5,
            "d5": -0.25,
            "theta6": 0,
        },
        wrench={"force": [0, 0, 500.0], "moment": [0, 0, 0]},
    )
    C = np.array(doc["compliance"])
    np.testing.assert_allclose(doc["deflection"]["wrench"]["translation_m"], 500.0 * C[:3, 2], rtol=1e-12)
    # Pushing along the rail moves the tool along the rail (positive work).
    assert doc["deflection"]["wrench"]["translation_m"][2] > 0
    with pytest.raises(InvalidInput):
        stiffness_document("cabin8", joints=JOINTS, frame="world")
