"""Sweep descriptions: validation naming the field, expansion into ordinary scenarios, stable plan keys."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from planner.core.exceptions import InvalidInput
from planner.meshes import reference_cabin_path, reference_manifest
from planner.scenario import load_scenario_file, scenario_hash
from planner.sweep.expand import expand_sweep
from planner.sweep.spec import load_sweep_file, sweep_from_dict
from tests.sweep.conftest import SCENARIOS, bay_sweep, write_spec


def test_cross_product_of_bays_masses_and_seeds_gives_ordinary_scenarios():
    plans = expand_sweep(sweep_from_dict(bay_sweep()))
    assert len(plans) == 12
    bays = {
        b["id"]: b for c in reference_manifest()["cabins"] if c["name"] == "cabin-aisle" for b in c["bays"]
    }
    base = load_scenario_file(SCENARIOS / "aisle-bay-insert.yaml")
    for plan in plans:
        s = plan.scenario
        assert plan.sha256 == scenario_hash(s)
        bay = bays[plan.labels["bay"]]
        assert s.goal.pose is not None and s.goal.approach is not None
        assert s.goal.pose.position == pytest.approx(bay["center_m"])
        assert s.goal.approach.direction == pytest.approx(bay["insertion_axis"])
        assert s.goal.pose.orientation == base.goal.pose.orientation  # the base goal's orientation
        assert s.goal.approach.distance == base.goal.approach.distance
        assert s.start == base.start and s.cabin == base.cabin
    combos = {(p.labels["bay"], p.scenario.payload.mass, p.scenario.options.seed) for p in plans}
    assert combos == {(b, m, s) for b in ("A2", "A3", "A4") for m in (60.0, 400.0) for s in (1, 2)}
    assert len({p.sha256 for p in plans}) == 12


def test_plan_names_and_hashes_depend_on_content_not_on_order():
    spec = bay_sweep()
    reordered = json.loads(json.dumps(spec))
    reordered["axes"]["payload_mass_kg"] = [400, 60, 90]  # reordered and extended
    a = {p.sha256: p.name for p in expand_sweep(sweep_from_dict(spec))}
    b = {p.sha256: p.name for p in expand_sweep(sweep_from_dict(reordered))}
    assert set(a) < set(b) and len(b) == 18
    assert all(b[h] == n for h, n in a.items())


def test_grid_explicit_list_and_duplicates(tmp_path: Path):
    grid = {
        **bay_sweep(),
        "axes": {"goal": {"grid": {"x": [0.885], "y": [0.675], "z": {"start": 1.5, "stop": 2.7, "num": 3}}}},
    }
    plans = expand_sweep(sweep_from_dict(grid))
    assert [p.scenario.goal.pose.position[2] for p in plans] == pytest.approx([1.5, 2.1, 2.7])
    listed = {
        "name": "listed",
        "base": str(SCENARIOS / "aisle-bay-insert.yaml"),
        "plans": [
            {"bay": "A1", "payload_mass_kg": 90},
            {"bay": "A1", "payload_mass_kg": 90},  # the same plan twice: planned once
            {
                "goal_pose": {"position": [0.885, 0.675, 3.3]},
                "clearance_m": 0.02,
                "start": {
                    "name": "low",
                    "drives": {
                        "d1": 1.2,
                        "x1": -0.46,
                        "x2": 0.46,
                        "x3": -0.09,
                        "theta3": 1.2,
                        "theta4": -0.8,
                        "d5": -0.25,
                        "theta6": 0,
                    },
                },
            },
        ],
    }
    plans = expand_sweep(sweep_from_dict(listed))
    assert len(plans) == 2
    assert plans[0].labels["bay"] == "A1" and plans[0].scenario.payload.mass == 90
    assert plans[1].scenario.options.clearance_m == 0.02 and plans[1].labels["start"] == "low"
    assert plans[1].scenario.start.drives["d1"] == 1.2


def test_relative_base_and_mesh_paths_resolve_from_the_sweep_file(tmp_path: Path):
    base = json.loads(
        json.dumps(load_scenario_file(SCENARIOS / "aisle-bay-insert.yaml").model_dump(mode="json"))
    )
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "cab.stl").write_bytes(reference_cabin_path("cabin-aisle").read_bytes())
    base["cabin"]["mesh"] = "meshes/cab.stl"
    (tmp_path / "base.json").write_text(json.dumps(base))
    spec = write_spec(tmp_path, {"name": "rel", "base": "base.json", "axes": {"seed": [1, 2]}}, "s.yaml")
    plans = expand_sweep(load_sweep_file(spec), spec.parent)
    assert plans[0].scenario.cabin.mesh == str((tmp_path / "meshes" / "cab.stl").resolve())


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"axes": {"payload_mass_kg": [60, -1]}}, "axes.payload_mass_kg[1]"),
        ({"axes": {"goal": {"bays": ["A1"], "poses": [{"position": [0, 0, 1]}]}}}, "axes.goal"),
        ({"axes": {"seed": [1]}, "plans": [{"seed": 2}]}, "sweep"),
        ({"axes": {"clearance": [0.01]}}, "axes.clearance"),
        ({"limits": {"wall_time_limit_s": 0}}, "limits.wall_time_limit_s"),
    ],
)
def test_invalid_descriptions_name_the_field(change, field):
    with pytest.raises(InvalidInput) as err:
        sweep_from_dict({**bay_sweep(), **change})
    assert err.value.details["field"] == field, err.value.message
    assert err.value.message.startswith(field)


@pytest.mark.parametrize(
    ("change", "field", "words"),
    [
        ({"axes": {"goal": {"bays": ["A9"]}}}, "axes.goal.bays[0]", "no bay 'A9'"),
        ({"bays": {"cabin": "cabin-moon"}}, "bays.cabin", "not a cabin of the manifest"),
        ({"base": "missing.yaml"}, "base", "file not found"),
    ],
)
def test_expansion_errors_name_the_field(change, field, words):
    with pytest.raises(InvalidInput) as err:
        expand_sweep(sweep_from_dict({**bay_sweep(), **change}))
    assert err.value.details["field"] == field
    assert words in err.value.message


def test_a_combination_that_is_not_a_valid_scenario_names_the_plan():
    spec = {
        **bay_sweep(),
        "base": str(SCENARIOS / "refuse-overload.yaml"),
        "axes": {"goal": {"bays": ["A1"]}},
    }
    with pytest.raises(InvalidInput, match=r"goal orientation must be given"):
        expand_sweep(sweep_from_dict(spec))
    free = {
        "name": "free",
        "base": {"name": "x", "start": {"drives": {}}, "goal": {"drives": {}}},
        "axes": {"payload_mass_kg": [10]},
    }
    with pytest.raises(InvalidInput, match=r"the base scenario has no payload"):
        expand_sweep(sweep_from_dict(free))


def test_the_cli_refuses_an_invalid_description_with_one_line_and_exit_2(tmp_path: Path):
    from tests.sweep.conftest import invoke

    spec = write_spec(tmp_path, {**bay_sweep(), "axes": {"seed": [-1]}})
    result = invoke("sweep", spec, "-o", tmp_path / "out")
    assert result.exit_code == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in result.stderr
    assert lines[0].startswith("cabinplan: invalid_input: axes.seed[0]:")
    assert not (tmp_path / "out").exists()  # nothing planned, nothing written
