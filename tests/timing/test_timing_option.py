"""``options.timing``: the stage a plan uses, the gate's jerk requirement, and the caller's-profile check."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import yaml

from planner.core.exceptions import InvalidInput
from planner.documents.output import result_document
from planner.gate.check_profile import check_profile
from planner.gate.requirements import requirements_for
from planner.plan.context import timing_factory
from planner.plan.pipeline import Planner
from planner.robots.cabin8 import Cabin8, default_description_path
from planner.scenario.resolve import ResolvedScenario, load_scenario
from planner.timing import stages
from planner.timing.jerk import JerkLimitedStage
from planner.timing.toppra import ToppraStage

TRANSFER = Path(__file__).parent.parent / "scenarios" / "aisle-transfer.yaml"


@pytest.fixture(scope="module")
def scenario() -> ResolvedScenario:
    return load_scenario(TRANSFER)


def timed(sc: ResolvedScenario, timing: str | None) -> ResolvedScenario:
    return dataclasses.replace(sc, options=sc.options.model_copy(update={"timing": timing}))


def timing_of(sc: ResolvedScenario) -> str:
    return stages.select(sc.options.timing, sc.robot).name


def test_default_is_jerk_limited_with_jerk_limits_and_acceleration_limited_without(
    scenario: ResolvedScenario, tmp_path: Path
) -> None:
    assert scenario.options.timing is None and scenario.robot.limits.j_max is not None
    assert timing_of(scenario) == "jerk_limited"
    assert scenario.robot.summary()["default_timing"] == "jerk_limited"
    stage = timing_factory(scenario)(scenario.robot, None, (0.995, 0.97, 0.97))
    assert isinstance(stage, JerkLimitedStage) and stage.name == "jerk_limited"
    assert stage.sample_period_s == scenario.options.sample_period_s
    assert requirements_for(scenario, None).jerk_limited
    # The scenario option still chooses TOPP-RA alone, and the gate then does not bind the jerk.
    accel = timed(scenario, "acceleration_limited")
    assert timing_of(accel) == "acceleration_limited"
    assert isinstance(timing_factory(accel)(scenario.robot, None, (0.98, 0.92, 0.92)), ToppraStage)
    assert not requirements_for(accel, None).jerk_limited
    raw = yaml.safe_load(default_description_path().read_text())
    for d in raw["drives"]:
        d.pop("j_max")
    path = tmp_path / "nojerk.yaml"
    path.write_text(yaml.safe_dump(raw))
    plain = dataclasses.replace(scenario, robot=Cabin8(path))
    assert plain.robot.limits.j_max is None
    assert timing_of(plain) == "acceleration_limited"
    assert plain.robot.summary()["default_timing"] == "acceleration_limited"
    with pytest.raises(InvalidInput) as err:
        timing_of(timed(plain, "jerk_limited"))
    assert err.value.details["field"] == "options.timing"
    with pytest.raises(InvalidInput) as err:
        timing_factory(timed(plain, "jerk_limited"))
    assert err.value.details["field"] == "options.timing"


def test_the_registry_names_every_stage_the_schema_accepts() -> None:
    from typing import get_args

    from planner.core.timing_names import TimingName
    from planner.scenario.schema import PlanOptions

    assert set(stages.STAGES) == set(get_args(TimingName))
    assert set(get_args(PlanOptions.model_fields["timing"].annotation)) - {type(None)} == {TimingName}
    for name, entry in stages.STAGES.items():
        assert entry.name == name
        assert entry.binds_jerk == entry.needs_jerk_limits  # only the jerk stage needs and binds them


def test_an_acceleration_limited_plan_passes_its_gate_but_not_a_jerk_limited_check(
    scenario: ResolvedScenario,
) -> None:
    sc = timed(scenario, "acceleration_limited")
    res = Planner(sc).plan()
    assert res.report["timing"]["stage"] == "toppra" and res.report["timing"]["stage_s"] > 0
    jerk = next(c for c in res.gate.checks if c.name == "jerk")
    assert jerk.passed and "not required" in jerk.detail and jerk.worst is not None and jerk.worst > 5
    assert next(c for c in res.gate.checks if c.name == "on_path").passed
    doc = result_document(sc, res)
    # The same document checked against jerk-limited requirements: refused.
    report = check_profile(timed(scenario, "jerk_limited"), doc)
    assert {c.name for c in report.failures} == {"jerk"}
    assert check_profile(sc, doc).passed


def test_a_jerk_limited_plan_reports_its_stage_and_passes_the_caller_check(
    scenario: ResolvedScenario,
) -> None:
    scenario = timed(scenario, "jerk_limited")
    res = Planner(scenario).plan()
    assert res.report["timing"]["stage"] == "jerk_limited"
    assert 0 < res.report["timing"]["stage_s"] < 5
    checks = {c.name: c for c in res.gate.checks}
    assert checks["jerk"].passed and checks["jerk"].worst is not None and checks["jerk"].worst <= 1.01
    assert checks["on_path"].passed and checks["on_path"].worst is not None
    assert checks["on_path"].worst <= 1e-6
    doc = result_document(scenario, res)
    assert len(doc["jerk"]) == len(doc["t"]) and len(doc["jerk"][0]) == 8
    assert check_profile(scenario, doc).passed
