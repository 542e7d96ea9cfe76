"""`cabinplan plan` and `cabinplan check`: the output contract, refusals, the gate, and invalid inputs."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from planner.cli import app
from planner.scenario.resolve import ResolvedScenario, load_scenario

SCENARIOS = Path(__file__).parent.parent / "scenarios"
EXPECTED = yaml.safe_load((SCENARIOS / "expected.yaml").read_text())
REFUSALS = sorted(p.stem for p in SCENARIOS.glob("refuse-*.yaml"))
TRANSFER = SCENARIOS / "aisle-transfer.yaml"
CONTRACT = {
    "robot",
    "scenario",
    "status",
    "drives",
    "units",
    "sample_period_s",
    "t",
    "position",
    "velocity",
    "acceleration",
    "jerk",
    "effort",
    "joints",
    "duration_s",
    "min_clearance_m",
    "report",
    "provenance",
}

runner = CliRunner()  # click >= 8.2 keeps stdout and stderr apart (result.stdout, result.stderr)


def invoke(*args: str | Path) -> Any:
    return runner.invoke(app, [str(a) for a in args])


def one_line(text: str) -> str:
    lines = text.strip().splitlines()
    assert len(lines) == 1, text
    assert "Traceback" not in text
    return lines[0]


@pytest.fixture(scope="module")
def scenario() -> ResolvedScenario:
    return load_scenario(TRANSFER)


@pytest.fixture(scope="module")
def planned(tmp_path_factory: pytest.TempPathFactory) -> tuple[Any, Path]:
    out = tmp_path_factory.mktemp("plan")
    result = invoke(
        "plan", TRANSFER, "-o", out / "out.json", "--csv", out / "out.csv", "--plot", out / "out.png"
    )
    return result, out


@pytest.fixture(scope="module")
def doc(planned: tuple[Any, Path]) -> dict[str, Any]:
    result, out = planned
    assert result.exit_code == 0, result.stderr
    return json.loads((out / "out.json").read_text())


@pytest.fixture(scope="module")
def tampered(planned: tuple[Any, Path], doc: dict[str, Any]) -> tuple[Any, int]:
    """The planned profile with the velocity of one cruising sample doubled, checked by `check`."""
    _, out = planned
    data = json.loads(json.dumps(doc))
    v = np.array(data["velocity"])
    k = int(np.argmax(np.abs(v[:, 0])))  # the rail at cruise speed
    assert abs(v[k, 0]) > 0.1
    data["velocity"][k] = [2.0 * x for x in data["velocity"][k]]
    path = out / "tampered.json"
    path.write_text(json.dumps(data))
    return invoke("check", TRANSFER, path), k


def test_plan_succeeds_with_one_line_on_stderr(planned: tuple[Any, Path]) -> None:
    result, _ = planned
    assert result.exit_code == 0
    assert result.stdout == ""
    line = one_line(result.stderr)
    assert line.startswith("cabinplan: aisle-transfer: succeeded")


def test_plan_document_follows_the_contract(doc: dict[str, Any], scenario: ResolvedScenario) -> None:
    robot = scenario.robot
    assert CONTRACT <= set(doc)
    assert doc["status"] == "succeeded" and doc["robot"] == robot.name
    assert doc["scenario"] == {"name": "aisle-transfer", "sha256": scenario.scenario_sha256}
    assert doc["provenance"]["scenario_sha256"] == scenario.scenario_sha256
    assert doc["drives"] == list(robot.drive_names)
    assert doc["joints"]["names"] == list(robot.joint_names)
    assert set(doc["units"]["position"]) == set(robot.drive_names)
    assert doc["units"]["t"] == "s" and doc["units"]["position"]["d1"] == "m"
    assert doc["units"]["position"]["theta3"] == "rad" and doc["units"]["effort"]["theta3"] == "N m"
    t = np.array(doc["t"])
    n = len(t)
    assert n > 100 and t.shape == (n,)
    arrays = {k: np.array(doc[k]) for k in ("position", "velocity", "acceleration", "effort")}
    for name, a in arrays.items():
        assert a.shape == (n, 8), name
        assert np.all(np.isfinite(a)), name
    q = np.array(doc["joints"]["position"])
    assert q.shape == (n, 8)
    period = scenario.options.sample_period_s
    assert doc["sample_period_s"] == period
    np.testing.assert_allclose(t, period * np.arange(n), atol=1e-9)
    assert doc["duration_s"] == t[-1]
    # Drive order: the columns are the drives of the scenario, from start to goal, at rest at both ends.
    u, ud = arrays["position"], arrays["velocity"]
    np.testing.assert_allclose(u[0], scenario.start_u, atol=1e-9)
    assert scenario.goal_u is not None
    np.testing.assert_allclose(u[-1], scenario.goal_u, atol=1e-6)
    assert np.all(ud[0] == 0.0) and np.all(ud[-1] == 0.0)
    assert np.all(np.abs(ud) <= 1.01 * robot.limits.v_max)
    np.testing.assert_allclose(q, robot.joints_from_drives(u), atol=1e-9)  # joints follow the drives
    assert doc["min_clearance_m"] >= scenario.options.clearance_m
    assert doc["report"]["gate"]["passed"] is True


def test_plan_writes_csv_and_png(planned: tuple[Any, Path], doc: dict[str, Any]) -> None:
    _, out = planned
    text = (out / "out.csv").read_text()
    n = len(doc["t"])
    assert text.count("\n") == n + 1 and len(text.splitlines()) == n + 1
    rows = list(csv.reader(io.StringIO(text)))
    assert len(rows[0]) == 1 + 5 * 8 and rows[0][0] == "t_s" and rows[0][1].startswith("d1_pos")
    assert rows[0][25] == "d1_jerk_m/s3"
    data = np.array(rows[1:], dtype=float)
    assert data.shape == (n, 41)
    np.testing.assert_allclose(data[:, 25:33], doc["jerk"], rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(data[:, 0], doc["t"], rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(data[:, 1:9], doc["position"], rtol=1e-8, atol=1e-12)
    png = (out / "out.png").read_bytes()
    assert png.startswith(b"\x89PNG\r\n\x1a\n") and len(png) > 1000


def test_check_passes_the_planned_profile(planned: tuple[Any, Path], doc: dict[str, Any]) -> None:
    _, out = planned
    result = invoke("check", TRANSFER, out / "out.json")
    assert result.exit_code == 0, result.stderr
    assert result.stderr == ""
    report = json.loads(result.stdout)
    assert report["passed"] is True
    assert report["samples"] == len(doc["t"])
    assert all(c["passed"] for c in report["checks"])
    assert report["min_clearance_m"] >= 0.01


def test_check_refuses_a_tampered_profile(
    tampered: tuple[Any, int], doc: dict[str, Any], scenario: ResolvedScenario
) -> None:
    result, k = tampered
    assert result.exit_code == 3
    assert one_line(result.stderr).startswith("cabinplan: validation_failed")
    report = json.loads(result.stdout)
    assert report["passed"] is False
    checks = {c["name"]: c for c in report["checks"]}
    assert checks["velocity"]["passed"] is False and checks["velocity"]["sample"] == k
    expected = 2.0 * abs(doc["velocity"][k][0]) / scenario.robot.limits.v_max[0]
    assert checks["velocity"]["worst"] == pytest.approx(expected, rel=1e-12)
    assert report["peak_ratios"]["velocity"] == pytest.approx(expected, rel=1e-12)
    assert checks["consistency"]["passed"] is False


def test_check_reports_the_executed_acceleration_of_a_tampered_step(tampered: tuple[Any, int]) -> None:
    """Doubling one sample's velocity makes dv/dt about 62 m/s^2 on the rail (a_max 0.5) on its two steps."""
    result, k = tampered
    report = json.loads(result.stdout)
    acc = {c["name"]: c for c in report["checks"]}["acceleration"]
    assert acc["passed"] is False
    assert report["peak_ratios"]["acceleration"] > 100.0
    assert acc["sample"] in (k - 1, k)


@pytest.mark.parametrize("name", REFUSALS)
def test_plan_refuses_with_the_expected_reason(name: str, tmp_path: Path) -> None:
    out = tmp_path / "refusal.json"
    result = invoke("plan", SCENARIOS / f"{name}.yaml", "-o", out)
    assert result.exit_code == 3
    assert result.stdout == ""
    reason = EXPECTED[name]["reason"]
    assert one_line(result.stderr).startswith(f"cabinplan: {reason}: ")
    doc = json.loads(out.read_text())
    assert doc["status"] == "failed" and doc["reason"] == reason
    assert doc["message"] and isinstance(doc["details"], dict)
    assert doc["scenario"]["name"] == name
    assert "position" not in doc  # a refusal carries no trajectory


def _variant(tmp_path: Path, old: str, new: str) -> Path:
    text = TRANSFER.read_text()
    assert old in text
    path = tmp_path / "variant.yaml"
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize(
    ("old", "new", "fragment"),
    [
        ("robot: cabin8\n", "robot: cabin8\ncolour: red\n", "colour: unknown field"),
        ("options: {clearance: 0.01", "options: {clearance: -0.01", "options.clearance: "),
        ("options: {clearance: 0.01", "options: {clearance_m: -0.01", "options.clearance_m: "),
        ("options: {clearance: 0.01", "options: {clearance: 0.01, colour: red", "options.colour: unknown"),
    ],
)
def test_plan_on_invalid_scenario_exits_2_naming_the_field(
    tmp_path: Path, old: str, new: str, fragment: str
) -> None:
    out = tmp_path / "out.json"
    result = invoke("plan", _variant(tmp_path, old, new), "-o", out)
    assert result.exit_code == 2
    line = one_line(result.stderr)
    assert line.startswith("cabinplan: invalid_input: ") and fragment in line
    assert not out.exists()


def test_plan_on_missing_scenario_file_exits_2(tmp_path: Path) -> None:
    result = invoke("plan", tmp_path / "nowhere.yaml", "-o", tmp_path / "out.json")
    assert result.exit_code == 2
    line = one_line(result.stderr)
    assert "scenario: nowhere.yaml: file not found" in line


def test_check_on_a_profile_that_is_not_json_exits_2(tmp_path: Path) -> None:
    path = tmp_path / "profile.json"
    path.write_text("{not json")
    result = invoke("check", TRANSFER, path)
    assert result.exit_code == 2
    assert one_line(result.stderr).startswith("cabinplan: profile: not valid JSON")


def test_check_on_a_binary_profile_exits_2(planned: tuple[Any, Path]) -> None:
    _, out = planned
    result = invoke("check", TRANSFER, out / "out.png")  # the plot: not text, not JSON
    assert result.exit_code == 2
    assert one_line(result.stderr).startswith("cabinplan: profile: ")


def test_check_on_a_refusal_document_exits_2(tmp_path: Path) -> None:
    path = tmp_path / "refusal.json"
    path.write_text(json.dumps({"status": "failed", "reason": "goal_unreachable"}))
    result = invoke("check", TRANSFER, path)
    assert result.exit_code == 2
    assert one_line(result.stderr).startswith("cabinplan: invalid_input: profile: not a drive profile")


def test_the_cli_document_writes_the_numbers_of_the_list_document(scenario: ResolvedScenario) -> None:
    """The CLI writes the sample arrays directly (orjson): parsed, exactly the list form's document."""
    from planner.documents.output import document_bytes, result_document
    from planner.plan.pipeline import plan_scenario

    result = plan_scenario(scenario)
    direct = json.loads(document_bytes(result_document(scenario, result, arrays=True)))
    listed = json.loads(json.dumps(result_document(scenario, result)))
    assert direct == listed
    assert json.loads(document_bytes({"a": np.array([1.0, np.nan, np.inf])})) == {"a": [1.0, None, None]}
