"""Generated scenarios (planner.generate): the generator itself, and a sample planned end to end.

The sample's profiles are checked against the gate's properties *independently of the gate*: limits on
every sample against ``robot.limits``, at rest at both ends, the start equal to the scenario's start, the
goal reached, and the certified collision check recomputed with a fresh ``CollisionWorld.check_path`` on
the sampled joints with the requested clearance.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from planner.cli import app
from planner.collision.world import CollisionWorld
from planner.core.schemas import Pose
from planner.dynamics.holding import StaticForceCheck
from planner.dynamics.lagrange import Cabin8Dynamics
from planner.gate.requirements import GATE_MOTION_MARGIN_M
from planner.generate import (
    MESH_FORMATS,
    START_EXTRA_M,
    GeneratedCase,
    GeneratorOptions,
    cabin_mesh,
    generate_case,
    mesh_bytes,
    write_case,
)
from planner.meshio.load import load_mesh
from planner.plan.pipeline import plan_scenario as plan
from planner.scenario import load_scenario

#: The tests' cases: a 3 m rail (a short cabin section: quick to build and to plan).
OPTIONS = GeneratorOptions(rail_length_m=3.0)
SEED = 13
#: Cases of SEED planned end to end (1-5 s each with the cabin's first build, on a loaded 2-core machine):
#: drive goals, bays in the side wall and both end walls, a shelf, every mesh format, m and mm. The cases
#: of this seed the planner before the clearance semantics refused (0, 11: goal_in_collision; 8, 12:
#: approach_infeasible; 9, 13: compensation_failed; 3: no_path_within_time_limit) all plan now; 8 (side
#: wall) and 3 (shelf) are in the sample.
SAMPLE: tuple[int, ...] = (2, 5, 10, 4, 6, 7, 1, 15, 8, 3, 18, 19)
#: The six whose generation and planning take longest are marked slow.
SLOW = frozenset({7, 15, 19, 2, 18, 3})

_cases: dict[int, tuple[GeneratedCase, Path]] = {}


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("generated")


def _case(index: int, folder: Path) -> tuple[GeneratedCase, Path]:
    if index not in _cases:
        case = generate_case(SEED, index, OPTIONS)
        _cases[index] = (case, write_case(case, folder))
    return _cases[index]


def test_the_same_seed_gives_identical_files_from_the_cli(folder: Path, tmp_path: Path) -> None:
    """``cabinplan generate`` (a second, independent generation) writes the library's files byte for byte."""
    index = SAMPLE[0]
    case, path = _case(index, folder)
    result = CliRunner().invoke(
        app,
        ["generate", "-o", str(tmp_path), "--count", "1", "--seed", str(SEED), "--start", str(index)]
        + ["--rail-length-m", str(OPTIONS.rail_length_m)],
    )
    assert result.exit_code == 0, result.stderr
    assert json.loads(result.stdout)["scenarios"] == [path.name]
    assert (tmp_path / path.name).read_bytes() == path.read_bytes()
    assert (tmp_path / case.mesh_name).read_bytes() == (folder / case.mesh_name).read_bytes()
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["seed"] == SEED and manifest["cases"][0]["name"] == case.name


def test_case_index_is_independent_of_the_other_cases(folder: Path) -> None:
    case, _ = _case(SAMPLE[1], folder)
    other, _ = _case(SAMPLE[2], folder)
    assert case.scenario["name"] != other.scenario["name"]
    assert case.mesh_bytes != other.mesh_bytes


@pytest.mark.parametrize("index", SAMPLE[:4])
def test_every_generated_start_is_clear_and_holdable_when_loaded_from_its_file(
    index: int, folder: Path
) -> None:
    _, path = _case(index, folder)
    sc = load_scenario(path)
    world = CollisionWorld(sc.robot, sc.cabin, sc.payload)
    clearance = sc.options.clearance_m
    # The start keeps the requested clearance + 20 mm (1 um of rounding in the file allowed for).
    assert world.is_valid(sc.start_q, clearance + START_EXTRA_M - 1e-6)
    assert world.min_distance(sc.start_q).distance_m >= clearance + START_EXTRA_M - 1e-6
    forces = StaticForceCheck(Cabin8Dynamics.of(sc.robot), sc.payload.rigid_payload() if sc.payload else None)
    assert forces.ok(sc.start_q)
    assert not sc.robot.violations(sc.start_q)


def test_mm_and_m_files_of_one_cabin_load_to_the_same_geometry(folder: Path) -> None:
    case, _ = _case(SAMPLE[0], folder)
    assert case.layout is not None and case.T_base_cabin is not None
    loaded = {
        units: load_mesh(
            mesh_bytes(case.layout, "stl", units, case.T_base_cabin, "c"),
            units=units,
            name="c.stl",
            pose=case.T_base_cabin,
        )
        for units in ("m", "mm")
    }
    assert np.array_equal(loaded["m"].faces, loaded["mm"].faces)
    assert np.max(np.abs(loaded["m"].vertices - loaded["mm"].vertices)) <= 2e-6
    ref = cabin_mesh(case.layout)
    assert np.max(np.abs(loaded["m"].bounds_m - np.array(ref.bounds))) <= 2e-6


@pytest.mark.parametrize("fmt", MESH_FORMATS)
def test_every_file_format_loads_to_the_cabin(fmt: str, folder: Path) -> None:
    case, _ = _case(SAMPLE[0], folder)
    assert case.layout is not None and case.T_base_cabin is not None
    ref = cabin_mesh(case.layout)
    data = mesh_bytes(case.layout, fmt, "mm", case.T_base_cabin, "c")  # type: ignore[arg-type]
    mesh = load_mesh(data, units="mm", name=f"c.{fmt}", pose=case.T_base_cabin)
    assert len(mesh.faces) == len(ref.faces)
    assert np.max(np.abs(mesh.bounds_m - np.array(ref.bounds))) <= 1e-5
    # Same triangles: the sorted face centroids agree.
    c_ref = np.sort(np.round(ref.vertices[ref.faces].mean(axis=1), 4), axis=0)
    c_got = np.sort(np.round(mesh.vertices[mesh.faces].mean(axis=1), 4), axis=0)
    assert np.max(np.abs(c_ref - c_got)) <= 2e-4


@pytest.mark.parametrize(
    "index", [pytest.param(i, marks=pytest.mark.slow) if i in SLOW else i for i in SAMPLE]
)
def test_generated_scenario_plans_to_a_profile_with_the_gates_properties(index: int, folder: Path) -> None:
    case, path = _case(index, folder)
    sc = load_scenario(path)
    res = plan(sc)
    robot, prof, lim = sc.robot, res.profile, sc.robot.limits
    u, ud, udd = prof.position, prof.velocity, prof.acceleration
    dt = sc.options.sample_period_s
    tol = 1.01
    assert res.gate.passed, res.gate.summary()
    # Limits on every sample.
    assert np.all(np.isfinite(u))
    assert np.all(u >= lim.lower - 1e-9) and np.all(u <= lim.upper + 1e-9)
    assert np.all(np.abs(ud) <= tol * lim.v_max)
    assert np.all(np.abs(udd) <= tol * lim.a_max)
    assert np.all(np.abs(np.diff(ud, axis=0)) / dt <= tol * lim.a_max)
    assert np.all(np.abs(prof.effort) <= tol * lim.effort_max)
    # The default law is jerk-limited: the change of the sampled acceleration within j_max, every sample
    # on the certified path.
    assert res.report["timing"]["stage"] == "jerk_limited" and lim.j_max is not None
    assert np.all(np.abs(np.diff(udd, axis=0)) / dt <= tol * lim.j_max)
    on_path = next(c for c in res.gate.checks if c.name == "on_path")
    assert on_path.passed and on_path.worst is not None and on_path.worst <= 1e-6
    q = robot.joints_from_drives(u)
    assert not any(robot.violations(qi) for qi in q[:: max(1, len(q) // 300)])
    # At rest at both ends with zero acceleration, starting exactly at the scenario's start.
    assert np.array_equal(ud[0], np.zeros(8)) and np.array_equal(ud[-1], np.zeros(8))
    assert np.all(np.abs(udd[0]) <= 1e-9) and np.array_equal(udd[-1], np.zeros(8))
    assert np.max(np.abs(u[0] - sc.start_u)) <= 1e-9
    # The goal: the drives, or the payload pose (the commanded one when deflection is compensated).
    if sc.goal_u is not None:
        assert np.max(np.abs(u[-1] - sc.goal_u)) <= 1e-6
    else:
        assert sc.T_base_payload_goal is not None and sc.payload is not None
        T_pay = robot.fk(q[-1]) @ sc.payload.T_tool_payload
        T_goal = sc.T_base_payload_goal
        if "goal" in res.report:  # deflection-compensated: the rigid final pose is the command
            cmd = res.report["goal"]["compensated"]
            T_goal = Pose.model_validate({k: cmd[k] for k in ("position", "orientation")}).matrix()
        assert np.linalg.norm(T_pay[:3, 3] - T_goal[:3, 3]) <= 1e-6
        R_err = T_goal[:3, :3].T @ T_pay[:3, :3]
        assert np.arccos(np.clip((np.trace(R_err) - 1) / 2, -1, 1)) <= 1e-6
    # The collision check recomputed on the sampled joints with the requested clearance (fresh world).
    world = CollisionWorld(robot, sc.cabin, sc.payload)
    # The certified walk proves the requested clearance everywhere between samples whatever its step margin;
    # the gate's 1 mm lets it step through a bay with millimetres to spare (the scenario's 5 mm cannot).
    rep = world.check_path(q, sc.options.clearance_m, GATE_MOTION_MARGIN_M)
    assert rep.valid, rep.contacts
    assert prof.duration_s >= res.report["single_drive_lower_bound_s"] - 1e-9
    assert case.meta["goal"] in ("bay-side", "bay-end-far", "bay-end-near", "shelf", "drive")
