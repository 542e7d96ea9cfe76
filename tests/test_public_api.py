"""The curated public API (``import planner``): cheap to import, and enough to plan and check a profile."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import planner

SCENARIOS = Path(__file__).parent / "scenarios"


def test_import_planner_loads_no_engine() -> None:
    code = (
        "import sys, planner; heavy = [m for m in ('numba', 'toppra', 'ompl', 'fcl', 'trimesh', 'casadi', "
        "'matplotlib', 'scipy') if m in sys.modules]; print(','.join(heavy))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", f"import planner pulled in {out.stdout.strip()}"


def test_every_public_name_resolves() -> None:
    for name in planner.__all__:
        assert getattr(planner, name) is not None, name
    with pytest.raises(AttributeError):
        _ = planner.no_such_name  # type: ignore[attr-defined]


def test_plan_and_check_through_the_public_api() -> None:
    sc = planner.load_scenario(SCENARIOS / "aisle-transfer.yaml")
    result = planner.plan_scenario(sc)
    assert result.gate.passed
    lim = sc.robot.limits
    assert np.all(np.abs(result.profile.velocity) <= 1.01 * lim.v_max)
    document = planner.result_document(sc, result)
    report = planner.check_profile(sc, document)
    assert report.passed, report.summary()
    # The same use case refuses a profile that runs too fast: every check is recomputed from the document.
    fast = dict(document, velocity=(2.0 * np.asarray(document["velocity"])).tolist())
    failed = {c.name for c in planner.check_profile(sc, fast).failures}
    assert {"velocity", "consistency"} <= failed
    with pytest.raises(planner.InvalidInput) as info:
        planner.check_profile(sc, {"status": "failed"})
    assert info.value.details["field"] == "profile.status"
