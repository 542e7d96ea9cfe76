"""Stiffness calibration (issue 15): known parameters recovered, ill-posed data refused, output usable.

Synthetic measurements from known parameters plus 0.01 mm noise; the written description is the one the
planner loads through a scenario's ``robot_description``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from planner.cli import app
from planner.core.description import StiffnessSpec
from planner.core.exceptions import CalibrationIllPosed, InvalidInput
from planner.dynamics.calibration import (
    DEFAULT_PARAMETERS,
    Measurements,
    calibrate,
    measurements_csv,
    parse_measurements,
)
from planner.dynamics.stiffness import StiffnessModel
from planner.dynamics.stiffness_params import reference_values, with_values
from planner.robots.cabin8 import Cabin8
from tests.conftest import admissible_joints

NOISE_M = 1e-5  # 0.01 mm
NOISE_RAD = 1e-5


def _truth(robot: Cabin8, seed: int) -> tuple[StiffnessSpec, dict[str, float]]:
    base = robot.desc.stiffness
    assert base is not None
    rng = np.random.default_rng(seed)
    ref = reference_values(base)
    true = {n: ref[n] * rng.uniform(0.7, 1.4) for n in DEFAULT_PARAMETERS}
    return with_values(base, true), true


def _measure(
    robot: Cabin8, spec: StiffnessSpec, q: np.ndarray, loads_per_q: int, seed: int, noise: bool = True
) -> Measurements:
    rng = np.random.default_rng(seed)
    qq = np.repeat(q, loads_per_q, axis=0)
    w = np.hstack([rng.uniform(-1000, 1000, (len(qq), 3)), rng.uniform(-300, 300, (len(qq), 3))])
    x = np.einsum("nij,nj->ni", StiffnessModel(robot, spec).compliance(qq), w)
    if noise:
        x[:, :3] += rng.normal(0.0, NOISE_M, (len(qq), 3))
        x[:, 3:] += rng.normal(0.0, NOISE_RAD, (len(qq), 3))
    return Measurements(robot.drives_from_joints(qq), w, x, True)


@pytest.mark.parametrize("seed", [4, 5])
def test_synthetic_parameters_are_recovered_within_five_percent(robot: Cabin8, seed: int) -> None:
    spec, true = _truth(robot, seed)
    data = _measure(robot, spec, admissible_joints(robot, 20, seed=21 + seed), 6, seed)
    cal = calibrate(robot, data)
    for name, value, std in zip(cal.parameters, cal.values, cal.relative_std, strict=True):
        assert value == pytest.approx(true[name], rel=0.05), name
        assert 0 < std < 0.05
    # The residuals are the noise: RMS near 0.01 mm per component, none beyond 5 sigma.
    assert 0.7 * NOISE_M < cal.rms_translation_m < 1.3 * NOISE_M
    assert np.all(cal.residuals[:, 0] < 5 * np.sqrt(3) * NOISE_M)
    assert cal.spec.source == "calibrated" and set(cal.spec.uncertainty or {}) == set(DEFAULT_PARAMETERS)


def test_noise_free_data_are_recovered_exactly(robot: Cabin8) -> None:
    spec, true = _truth(robot, 9)
    data = _measure(robot, spec, admissible_joints(robot, 6, seed=3), 3, 9, noise=False)
    cal = calibrate(robot, data)
    for name, value in zip(cal.parameters, cal.values, strict=True):
        assert value == pytest.approx(true[name], rel=1e-6), name


def test_one_configuration_is_refused(robot: Cabin8) -> None:
    spec, _ = _truth(robot, 4)
    q = admissible_joints(robot, 1, seed=3)
    with pytest.raises(CalibrationIllPosed) as err:
        calibrate(robot, _measure(robot, spec, q, 30, 1))
    assert "distinct configurations" in err.value.message and err.value.details["configurations"] == 1


def test_configurations_closer_than_a_tenth_of_a_millimetre_count_as_one(robot: Cabin8) -> None:
    spec, _ = _truth(robot, 4)
    q = np.repeat(admissible_joints(robot, 1, seed=3), 5, axis=0)
    q[:, 0] += np.linspace(0.0, 4e-4, 5)  # rail jitter of a repeated measurement
    with pytest.raises(CalibrationIllPosed) as err:
        calibrate(robot, _measure(robot, spec, q, 6, 2))
    assert err.value.details["configurations"] == 1


def test_a_parameter_no_load_excites_is_refused_by_name(robot: Cabin8) -> None:
    """Forces at the tool origin, no moments: the theta6 drive (about the tool axis) is invisible."""
    spec, _ = _truth(robot, 4)
    q = np.repeat(admissible_joints(robot, 1, seed=3), 5, axis=0)
    q[:, 0] = np.linspace(0.5, 4.5, 5)  # the rail position does not change the compliance either
    data = _measure(robot, spec, q, 2, 2)
    data = Measurements(data.drives, data.wrench * np.array([1, 1, 1, 0, 0, 0]), data.offset, False)
    with pytest.raises(CalibrationIllPosed) as err:
        calibrate(robot, data)
    assert "k.theta6" in err.value.message and err.value.details["condition"] > 1e6


def test_an_unexcited_parameter_is_named(robot: Cabin8) -> None:
    spec, _ = _truth(robot, 4)
    data = _measure(robot, spec, admissible_joints(robot, 8, seed=5), 3, 3)
    with pytest.raises(CalibrationIllPosed) as err:
        calibrate(robot, data, [*DEFAULT_PARAMETERS, "k.theta3"])
    assert "k.theta3" in err.value.message


def test_bad_files_name_the_line_and_column(robot: Cabin8) -> None:
    g = robot.desc.gravity_m_s2
    with pytest.raises(InvalidInput, match="missing columns"):
        parse_measurements("d1_m,x1_m\n0,0\n", g)
    spec, _ = _truth(robot, 4)
    text = measurements_csv(_measure(robot, spec, admissible_joints(robot, 2, seed=5), 1, 3))
    lines = text.splitlines()
    cells = lines[2].split(",")
    cells[9] = "abc"
    bad = "\n".join([lines[0], lines[1], ",".join(cells)]) + "\n"
    with pytest.raises(InvalidInput, match="line 3, column fy_N: not a number"):
        parse_measurements(bad, g)
    with pytest.raises(InvalidInput, match="unknown stiffness parameters"):
        calibrate(robot, parse_measurements(text, g), ["k.nope"])


def test_cli_writes_a_description_the_planner_uses(robot: Cabin8, tmp_path: Path) -> None:
    spec, true = _truth(robot, 4)
    data = _measure(robot, spec, admissible_joints(robot, 20, seed=25), 6, 4)
    csv_path = tmp_path / "meas.csv"
    csv_path.write_text(measurements_csv(data), encoding="utf-8")
    out = tmp_path / "calibrated.yaml"
    res = CliRunner().invoke(app, ["stiffness", "calibrate", str(csv_path), "-o", str(out)])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert {p["name"] for p in doc["parameters"]} == set(DEFAULT_PARAMETERS)
    assert len(doc["residuals"]) == len(data)
    cal_robot = Cabin8(out)
    cs = cal_robot.desc.stiffness
    assert cs is not None and cs.source == "calibrated"
    assert cs.drives["d5"] == pytest.approx(true["k.d5"], rel=0.05)
    # Same geometry, limits and home; only the stiffness section changed.
    assert cal_robot.desc.model_dump(exclude={"stiffness"}) == robot.desc.model_dump(exclude={"stiffness"})
    # A scenario names it with robot_description (relative to the scenario file).
    from planner.gate.requirements import stiffness_provenance
    from planner.scenario import load_scenario

    scen = yaml.safe_load((Path(__file__).parent.parent / "scenarios" / "aisle-bay-insert.yaml").read_text())
    scen["robot_description"] = "calibrated.yaml"
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(scen), encoding="utf-8")
    sc = load_scenario(tmp_path / "s.yaml")
    assert sc.robot.desc.stiffness is not None and sc.robot.desc.stiffness.source == "calibrated"
    assert sc.robot.description_sha256 != robot.description_sha256
    prov = stiffness_provenance(sc)
    assert prov["source"] == "calibrated" and prov["compensated"] is True


def test_cli_refusal_is_one_line(tmp_path: Path, robot: Cabin8) -> None:
    spec, _ = _truth(robot, 4)
    csv_path = tmp_path / "meas.csv"
    csv_path.write_text(measurements_csv(_measure(robot, spec, admissible_joints(robot, 1, seed=3), 4, 1)))
    res = CliRunner().invoke(app, ["stiffness", "calibrate", str(csv_path), "-o", str(tmp_path / "o.yaml")])
    assert res.exit_code == 2
    assert res.stderr.count("\n") == 1 and "calibration_ill_posed" in res.stderr
    assert not (tmp_path / "o.yaml").exists()


def test_nominal_data_are_not_compensated_by_default(robot: Cabin8, tmp_path: Path) -> None:
    """Guessed (nominal) data: compensation off unless asked, with the predicted sag and a note."""
    from planner.dynamics.paper_fit import NOMINAL_ISSUE7, replace_stiffness_block
    from planner.dynamics.stiffness_params import stiffness_yaml_block
    from planner.gate.requirements import compensates_deflection, stiffness_provenance
    from planner.robots.cabin8 import default_description_path
    from planner.scenario import load_scenario

    text = default_description_path().read_text(encoding="utf-8")
    (tmp_path / "nominal.yaml").write_text(
        replace_stiffness_block(text, stiffness_yaml_block(NOMINAL_ISSUE7))
    )
    scen = yaml.safe_load((Path(__file__).parent.parent / "scenarios" / "aisle-bay-insert.yaml").read_text())
    scen["robot_description"] = "nominal.yaml"
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(scen), encoding="utf-8")
    sc = load_scenario(tmp_path / "s.yaml")
    assert sc.payload is not None and sc.robot.desc.stiffness is not None
    assert sc.robot.desc.stiffness.source == "nominal"
    assert compensates_deflection(sc) is False
    prov = stiffness_provenance(sc)
    assert prov["source"] == "nominal" and prov["compensated"] is False and "not compensated" in prov["note"]
    # Asked for explicitly, it is done, and the note says the data are guesses.
    scen["options"] = {**scen.get("options", {}), "compensate_deflection": True}
    (tmp_path / "s2.yaml").write_text(yaml.safe_dump(scen), encoding="utf-8")
    sc2 = load_scenario(tmp_path / "s2.yaml")
    assert compensates_deflection(sc2) is True and "guesses" in stiffness_provenance(sc2)["note"]
    # The packaged (paper-fit) robot compensates by default.
    sc3 = load_scenario(Path(__file__).parent.parent / "scenarios" / "aisle-bay-insert.yaml")
    assert compensates_deflection(sc3) is True


def test_description_files_are_refused_outside_the_cli() -> None:
    from planner.scenario import resolve_scenario, scenario_from_dict

    scen = yaml.safe_load((Path(__file__).parent.parent / "scenarios" / "aisle-bay-insert.yaml").read_text())
    scen["robot_description"] = "/etc/passwd"
    with pytest.raises(InvalidInput) as err:
        resolve_scenario(scenario_from_dict(scen))
    assert err.value.details["field"] == "robot_description"
