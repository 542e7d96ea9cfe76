"""`cabinplan` commands for pprs6: JSON out, exit codes 2 (invalid) and 3 (infeasible)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from planner.cli import app

runner = CliRunner()
POSE = '{"x": -0.03, "y": -0.03, "z": 0.19, "phi": 0, "theta": 0, "psi": 0}'
HERE = Path(__file__).parent


def test_ik_then_fk_round_trip() -> None:
    res = runner.invoke(app, ["ik", "pprs6", "--pose", POSE])
    assert res.exit_code == 0, res.output
    drives = json.loads(res.stdout)["drives"]
    assert set(drives) == {"w1", "w2", "beta", "s1", "s2", "s3"}
    assert drives["w1"] == np.float64(0.13)
    res = runner.invoke(app, ["fk", "pprs6", "--drives", json.dumps(drives)])
    assert res.exit_code == 0, res.output
    pose = json.loads(res.stdout)["pose"]
    ik_again = json.loads(runner.invoke(app, ["ik", "pprs6", "--pose", json.dumps(pose)]).stdout)["drives"]
    assert max(abs(ik_again[k] - drives[k]) for k in drives) < 1e-9


def test_exit_codes() -> None:
    res = runner.invoke(app, ["ik", "pprs6", "--pose", POSE.replace("0.19", "0.29")])
    assert res.exit_code == 3 and "s1" in res.stderr
    res = runner.invoke(app, ["ik", "pprs6", "--pose", '{"x": 0}'])
    assert res.exit_code == 2 and "missing" in res.stderr
    res = runner.invoke(app, ["fk", "pprs6", "--drives", '{"w1": 0.1, "w9": 1}'])
    assert res.exit_code == 2 and "w9" in res.stderr
    res = runner.invoke(app, ["workspace", "cabin8"])
    assert res.exit_code == 2
    res = runner.invoke(app, ["ik", "pprs6", "--pose", POSE, "--near", '{"w1": 0.1}'])
    assert res.exit_code == 2 and "near: " in res.stderr
    res = runner.invoke(app, ["fk", "cabin8", "--drives", "{}", "--guess", POSE])
    assert res.exit_code == 2 and "guess: " in res.stderr


def test_fk_from_a_guess_returns_that_assembly_mode() -> None:
    pose = {"x": -0.03, "y": -0.03, "z": 0.19, "phi": 0.0, "theta": 0.0, "psi": 0.2}
    drives = json.loads(runner.invoke(app, ["ik", "pprs6", "--pose", json.dumps(pose)]).stdout)["drives"]
    guess = {**pose, "x": -0.027, "psi": 0.18}
    res = runner.invoke(app, ["fk", "pprs6", "--drives", json.dumps(drives), "--guess", json.dumps(guess)])
    assert res.exit_code == 0, res.output
    got = json.loads(res.stdout)["pose"]
    assert max(abs(got[k] - pose[k]) for k in pose) < 1e-9


def test_robot_summary() -> None:
    res = runner.invoke(app, ["robot", "pprs6"])
    doc = json.loads(res.stdout)
    assert [d["name"] for d in doc["drives"]] == ["w1", "w2", "beta", "s1", "s2", "s3"]
    assert doc["grubler"]["F"] == 6


def test_profile_command(tmp_path: Path) -> None:
    out, png = tmp_path / "p.json", tmp_path / "p.png"
    res = runner.invoke(
        app, ["profile", "pprs6", str(HERE / "paper-path.yaml"), "-o", str(out), "--plot", str(png)]
    )
    assert res.exit_code == 0, res.output
    doc = json.loads(out.read_text())
    assert doc["status"] == "succeeded" and doc["path"]["name"] == "paper-EFGHE"
    assert png.read_bytes().startswith(b"\x89PNG")
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        "waypoints: [{x: 0, y: 0, z: 0.5, phi: 0, theta: 0, psi: 0},\n"
        "            {x: 0, y: 0, z: 0.4, phi: 0, theta: 0, psi: 0}]\n"
    )
    res = runner.invoke(app, ["profile", "pprs6", str(bad), "-o", str(out)])
    assert res.exit_code == 3


def test_workspace_command(tmp_path: Path) -> None:
    png = tmp_path / "ws.png"
    res = runner.invoke(app, ["workspace", "pprs6", "--step", "0.01", "--png", str(png)])
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["volume_m3"] > 0 and png.read_bytes().startswith(b"\x89PNG")
