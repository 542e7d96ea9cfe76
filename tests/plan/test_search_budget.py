"""The search is bounded by work, the wall clock is only its hard stop, and the refusal says which ended it.

The same scenario and seed give the same plan however loaded the machine is (checked with two busy
processes competing for the two cores); a search that spends its motion-check budget is refused with
``no_path_within_budget`` on any machine; one stopped by the clock is refused with
``no_path_within_time_limit``, never finished differently.
"""

from __future__ import annotations

import dataclasses
import multiprocessing as mp
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planner.core.exceptions import NoPathFound, NoPathWithinBudget
from planner.plan.context import BASELINE, PRODUCT
from planner.plan.pipeline import Planner
from planner.scenario import load_scenario_file, resolve_scenario, scenario_from_dict

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"


def _resolved(name: str, **options: Any) -> Any:
    spec = load_scenario_file(SCENARIOS / f"{name}.yaml")
    data = spec.model_dump(mode="json")
    data["options"].update(options)
    return resolve_scenario(scenario_from_dict(data), base_dir=SCENARIOS)


def _bulky_hatch(**options: Any) -> Any:
    """The hatch pass with a payload too bulky for the hatch: no path exists (the search cannot end early)."""
    spec = load_scenario_file(SCENARIOS / "hatch-pass.yaml")
    data = spec.model_dump(mode="json")
    data["payload"]["box"] = [0.5, 0.5, 0.45]
    data["payload"]["grasp"]["position"] = [0.0, 0.0, 0.3]
    data["options"].update(options)
    return resolve_scenario(scenario_from_dict(data), base_dir=SCENARIOS)


def _burn(stop_at: float) -> None:
    x = 0.0
    while time.monotonic() < stop_at:
        x += 1.0


def test_the_clock_ends_a_search_as_a_time_limit_refusal() -> None:
    sc = _resolved("refuse-time-limit")
    with pytest.raises(NoPathFound) as info:
        Planner(sc).plan()
    assert not isinstance(info.value, NoPathWithinBudget)
    assert info.value.reason == "no_path_within_time_limit"
    assert info.value.details["ended_by"] == "time_limit"
    assert "options.time_limit_s" in info.value.message


def test_the_work_budget_ends_a_search_the_same_way_on_every_run() -> None:
    # Small budgets, so that the work budget (not the generous clock) ends the hopeless search in seconds.
    preset = dataclasses.replace(PRODUCT, quick_motion_checks=60, full_motion_checks=150)
    outcomes = []
    for _ in range(2):
        sc = _bulky_hatch(seed=3, time_limit_s=120.0)
        planner = Planner(sc, preset=preset)
        with pytest.raises(NoPathWithinBudget) as info:
            planner.plan()
        assert info.value.reason == "no_path_within_budget"
        assert info.value.details["ended_by"] == "work_budget"
        assert info.value.details["elapsed_s"] < 0.85 * 120.0
        outcomes.append((info.value.message, planner.report.get("search_attempts")))
    assert outcomes[0] == outcomes[1]


@pytest.mark.parametrize("base", [PRODUCT, BASELINE], ids=["product", "baseline"])
def test_a_refusal_reports_the_work_budget_in_force(base: Any) -> None:
    """The budget a refusal names is the sum of the budgets of the attempts the search ran (issue 26).

    The baseline preset makes one full attempt: its refusal names the full budget alone, not the
    product's quick + full (it named 41 500 for a search that could spend at most 40 000).
    """
    preset = dataclasses.replace(base, quick_motion_checks=40, full_motion_checks=110)
    planner = Planner(_bulky_hatch(seed=3, time_limit_s=120.0), preset=preset)
    with pytest.raises(NoPathWithinBudget) as info:
        planner.plan()
    attempts = [a for a in planner.report["search_attempts"] if a["method"] == "ompl"]
    granted = sum(a["max_checks"] for a in attempts)
    assert info.value.details["motion_check_budget"] == granted
    assert f"({granted} motion checks," in info.value.message
    if base is BASELINE:
        assert attempts == [{"method": "ompl", "max_checks": 110}]
    else:
        assert attempts[0] == {"method": "ompl", "max_checks": 40} and attempts[-1]["max_checks"] == 110
        assert granted >= 150


@pytest.mark.slow
def test_same_scenario_and_seed_give_the_same_plan_under_load() -> None:
    """The hatch pass through the sampling planner, idle and with both cores busy: the same waypoints."""
    idle = Planner(_resolved("hatch-pass", simplify=False, seed=11, time_limit_s=120.0)).plan()
    assert idle.report["search"]["method"] == "ompl"
    ctx = mp.get_context("fork")
    stop_at = time.monotonic() + 120.0
    hogs = [ctx.Process(target=_burn, args=(stop_at,), daemon=True) for _ in range(2)]
    for p in hogs:
        p.start()
    try:
        loaded = Planner(_resolved("hatch-pass", simplify=False, seed=11, time_limit_s=120.0)).plan()
    finally:
        for p in hogs:
            p.kill()
            p.join(timeout=5)
    assert np.array_equal(idle.waypoints, loaded.waypoints)
    assert idle.profile.duration_s == loaded.profile.duration_s
    assert idle.report["search"]["motion_checks"] == loaded.report["search"]["motion_checks"]
