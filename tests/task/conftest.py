"""The example cycle planned once per session (and a second cycle in the cabin it leaves)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from planner.task.cycle import CycleResult, plan_cycle
from planner.task.resolve import ResolvedCycle, load_cycle, resolve_cycle
from planner.task.schema import cycle_from_dict

EXAMPLE = Path(__file__).resolve().parent.parent / "cycles" / "aisle-install-A3.yaml"


def example_dict() -> dict[str, Any]:
    """The example cycle document as a mapping (a fresh copy)."""
    data: dict[str, Any] = yaml.safe_load(EXAMPLE.read_text(encoding="utf-8"))
    return data


@pytest.fixture(scope="session")
def cycle() -> ResolvedCycle:
    return load_cycle(EXAMPLE)


@pytest.fixture(scope="session")
def planned(cycle: ResolvedCycle) -> CycleResult:
    return plan_cycle(cycle)


@pytest.fixture(scope="session")
def second_cycle(cycle: ResolvedCycle) -> ResolvedCycle:
    """The next unit (A5) installed from the same dock, A3 now an installed unit of the cabin."""
    data = example_dict()
    a3 = data["unit"]
    data["name"] = "aisle-install-A5"
    data["installed"] = [
        *data["installed"],
        {"id": "A3", "box": a3["box"], "pose": data["bay"]["pose"]},
    ]
    data["unit"] = {**a3, "id": "A5"}
    data["bay"] = {**data["bay"], "pose": {**data["bay"]["pose"], "position": [0.885, 0.675, 3.9]}}
    return resolve_cycle(cycle_from_dict(data), base_dir=EXAMPLE.parent)


@pytest.fixture(scope="session")
def second_planned(second_cycle: ResolvedCycle) -> CycleResult:
    return plan_cycle(second_cycle)
