"""Bad cycle input gets one clear error naming the field (or both units); the CLI's exit codes."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import yaml
from typer.testing import CliRunner

from planner.cli import app
from planner.core.exceptions import InvalidInput, UnitNotHoldable
from planner.task.cycle import CycleResult, plan_cycle
from planner.task.resolve import ResolvedCycle, resolve_cycle
from planner.task.schema import cycle_from_dict, cycle_json_schema
from tests.task.conftest import EXAMPLE, example_dict

runner = CliRunner()


def _resolve(data: dict[str, Any]) -> ResolvedCycle:
    return resolve_cycle(cycle_from_dict(data), base_dir=EXAMPLE.parent)


def test_overlapping_installed_units_name_both() -> None:
    data = example_dict()
    data["installed"].append({"id": "B7", "box": [0.2, 0.2, 0.2], "pose": {"position": [0.9, 0.7, 2.15]}})
    with pytest.raises(InvalidInput) as exc:
        _resolve(data)
    assert exc.value.details["field"] == "installed"
    assert "unit A2" in exc.value.message and "unit B7" in exc.value.message


def test_an_occupied_bay_names_the_unit_there() -> None:
    data = example_dict()
    data["bay"]["pose"]["position"] = [0.885, 0.675, 2.1]  # A2's bay
    with pytest.raises(InvalidInput) as exc:
        _resolve(data)
    assert exc.value.details["field"] == "bay.pose" and "unit A2" in exc.value.message


def test_a_dock_in_collision_with_its_fixture() -> None:
    data = example_dict()
    data["dock"]["pose"]["position"][1] -= 0.01  # 7.5 mm into the fixture
    with pytest.raises(InvalidInput) as exc:
        _resolve(data)
    assert exc.value.details["field"] == "dock.pose" and "fixture" in exc.value.message


@pytest.mark.parametrize(
    ("path", "value", "field"),
    [
        (("unit", "mass"), -1, "unit.mass"),
        (("dock", "lift", "distance"), 0, "dock.lift.distance"),
        (("retract", "direction"), [0, 0, 0], "retract.direction"),
        (("dwell", "grasp_s"), 100, "dwell.grasp_s"),
        (("unit", "colour"), "red", "unit.colour"),
        (("unit", "id"), "A2", "unit.id"),
    ],
)
def test_schema_errors_name_the_dotted_field(path: tuple[str, ...], value: Any, field: str) -> None:
    data = example_dict()
    node = data
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    with pytest.raises(InvalidInput) as exc:
        cycle_from_dict(data)
    assert exc.value.details["field"] == field, exc.value.message
    assert exc.value.message.startswith(f"{field}: ")


def test_the_json_schema_is_exportable() -> None:
    schema = cycle_json_schema()
    assert {"unit", "dock", "bay", "retract", "park"} <= set(schema["required"])
    json.dumps(schema)


def test_a_unit_the_robot_cannot_hold_is_refused_with_the_drive_and_its_ratio() -> None:
    data = example_dict()
    data["unit"]["mass"] = 400.0
    with pytest.raises(UnitNotHoldable) as exc:
        plan_cycle(_resolve(data))
    d = exc.value.details
    assert d["drive"] in _resolve(example_dict()).robot.drive_names
    assert d["force_ratio"] > d["allowed_ratio"]
    assert exc.value.details["leg"] == "grasp_line" and "cannot be held at its dock" in exc.value.message


def test_cli_exit_codes(tmp_path: Path, planned: CycleResult, cycle: ResolvedCycle) -> None:
    from planner.documents.cycle import cycle_document

    bad = tmp_path / "bad.yaml"
    data = example_dict()
    data["unit"]["mass"] = "heavy"
    bad.write_text(yaml.safe_dump(data), encoding="utf-8")
    res = runner.invoke(app, ["cycle", str(bad), "-o", str(tmp_path / "out.json")])
    assert res.exit_code == 2 and res.stderr.count("\n") == 1 and "unit.mass" in res.stderr

    heavy = tmp_path / "heavy.yaml"
    data = example_dict()
    data["unit"]["mass"] = 400.0
    data["cabin"]["mesh"] = "cabin-aisle.stl"
    heavy.write_text(yaml.safe_dump(data), encoding="utf-8")
    out = tmp_path / "heavy.json"
    res = runner.invoke(app, ["cycle", str(heavy), "-o", str(out)])
    assert res.exit_code == 3 and "unit_not_holdable" in res.stderr
    refusal = json.loads(out.read_text(encoding="utf-8"))
    assert refusal["status"] == "failed" and refusal["kind"] == "cycle" and refusal["details"]["drive"]

    profile = tmp_path / "cycle.json"
    profile.write_text(json.dumps(cycle_document(cycle, planned)), encoding="utf-8")
    res = runner.invoke(app, ["check", str(EXAMPLE), str(profile)])
    assert res.exit_code == 0, res.stderr
    assert json.loads(res.stdout)["passed"] is True
    doc = json.loads(profile.read_text(encoding="utf-8"))
    k = next(x for x in doc["legs"] if x["name"] == "grasp")["sample_start"] + 2
    doc["velocity"][k][0] = 0.01
    profile.write_text(json.dumps(doc), encoding="utf-8")
    res = runner.invoke(app, ["check", str(EXAMPLE), str(profile)])
    assert res.exit_code == 3 and "dwell" in res.stderr


def test_tessellated_unit_and_fixture_meshes_raise_the_certified_clearance() -> None:
    """A STEP unit or fixture may lie outside its triangles by its deviation: the clearance covers it."""
    from planner.task.resolve import _with_surface_deviation

    base = _resolve(example_dict()).base
    requested = float(base.options.clearance_m)
    assert _with_surface_deviation(base, {}) is base
    assert _with_surface_deviation(base, {"installed[0]": 0.0}) is base
    raised = _with_surface_deviation(base, {"unit": 1e-4, "dock.fixture": 3e-4, "installed[1]": 2e-4})
    # the unit's own deviation plus the largest environment one (the cabin's, 0 here, is already in base)
    assert raised.options.clearance_m == pytest.approx(requested + 4e-4, abs=1e-15)
    assert raised.surface_deviation_m == pytest.approx(4e-4, abs=1e-15)
    assert raised.requested_clearance_m == pytest.approx(requested)
    assert raised.clearance_report()["certified_m"] == pytest.approx(requested + 4e-4)
