"""Fixtures of the sweep tests: small sweeps of the reference scenarios, written as sweep files."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import pytest
import yaml

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"

# Before anything imports Ray: a local Ray of these tests binds every server to 127.0.0.1
# (planner.sweep.run.RAY_LOOPBACK_ENV).
os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")


def scenario(name: str) -> dict[str, Any]:
    data: dict[str, Any] = yaml.safe_load((SCENARIOS / f"{name}.yaml").read_text(encoding="utf-8"))
    return data


def bay_sweep(name: str = "bays") -> dict[str, Any]:
    """12 plans: three aisle bays x 60 kg (feasible) and 400 kg (refused at the start) x 2 seeds."""
    return {
        "name": name,
        "base": str(SCENARIOS / "aisle-bay-insert.yaml"),
        "axes": {"goal": {"bays": ["A2", "A3", "A4"]}, "payload_mass_kg": [60, 400], "seed": [1, 2]},
        "limits": {"grace_s": 10},
    }


def stuck_base() -> dict[str, Any]:
    """The hatch pass with a payload too bulky for the hatch: a search that finds nothing.

    It ends by its work budget (``no_path_within_budget``) after about 8 s on a fast 2-core VM, longer on a
    slower one, unless a wall-clock limit kills it first (``tests/sweep/test_run.py``: STUCK_LIMIT_S).
    """
    data = scenario("hatch-pass")
    data["payload"]["box"] = [0.5, 0.5, 0.45]
    data["payload"]["grasp"]["position"] = [0.0, 0.0, 0.3]
    data["options"]["time_limit_s"] = 20
    data["options"]["seed"] = 11
    return data


def write_spec(folder: Path, spec: dict[str, Any], name: str = "sweep.json") -> Path:
    path = folder / name
    path.write_text(json.dumps(spec), encoding="utf-8")
    return path


@pytest.fixture
def bays_spec(tmp_path: Path) -> Path:
    return write_spec(tmp_path, bay_sweep())


def invoke(*args: str | Path) -> Any:
    from typer.testing import CliRunner

    from planner.cli import app

    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.fixture(scope="session")
def embedded_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[dict[str, Any]]]:
    """The 12-plan bay sweep run once embedded on 2 worker processes: (output folder, rows)."""
    from planner.sweep.results import read_parquet

    folder = tmp_path_factory.mktemp("embedded")
    spec = write_spec(folder, bay_sweep())
    result = invoke("sweep", spec, "-o", folder / "out", "--workers", "2")
    assert result.exit_code == 0, result.stderr
    return folder / "out", read_parquet(folder / "out" / "results.parquet")
