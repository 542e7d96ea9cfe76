"""Scenario files: schema, loading, resolution, hashing and every refusal naming its field.

The example scenario of the contract resolves from YAML and from JSON to the same hash; the pose goal's
tool transform is checked against the grasp independently (tool @ grasp == payload); a mesh payload's
oriented bounding box contains every vertex; and each malformed input is refused with an InvalidInput
whose message starts with the offending field.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import trimesh
import yaml

from planner.core.exceptions import InvalidInput, InvalidMesh, UnknownRobot
from planner.core.schemas import Pose
from planner.meshes import REFERENCE_DIR, reference_cabin_path, reference_cabins, reference_manifest
from planner.meshio import MeshLimits, load_mesh
from planner.scenario.files import MAX_SCENARIO_BYTES, load_scenario_file
from planner.scenario.resolve import load_scenario, resolve_scenario
from planner.scenario.schema import PlanOptions, Scenario, scenario_from_dict, scenario_hash

EXAMPLE_YAML = """\
name: bay3-insert
robot: cabin8
rail_length: 6.0                       # optional, m
cabin:
  mesh: cabin-aisle.stl                # path relative to the scenario file, or a reference cabin name
  units: m                             # m | mm
  pose: {position: [0, 0, 0], orientation: {w: 1, x: 0, y: 0, z: 0}}   # cabin frame in base frame
payload:
  box: [0.45, 0.35, 0.50]              # or mesh: file (+ units)
  mass: 100                            # kg; optional com [m], inertia [kg m^2] (3x3)
  grasp: {position: [0, 0, 0.30], orientation: {w: 1, x: 0, y: 0, z: 0}}   # payload frame in tool frame
start:
  drives: {d1: 0.3, x1: -0.46, x2: 0.46, x3: -0.09, theta3: 0, theta4: -0.5, d5: -0.25, theta6: 0}
goal:                                  # either drives: {...} or pose: (payload frame in base frame)
  pose: {position: [0.80, 0.75, 3.2], orientation: {w: 0.7071, x: 0, y: 0.7071, z: 0}}
  approach: {direction: [1, 0, 0], distance: 0.25}   # optional final straight-line insertion, base frame
options: {clearance: 0.01, time_limit_s: 30, seed: 1, sample_period_s: 0.004, planner: RRTConnect}
"""

HOME = {
    "d1": 0.3,
    "x1": -0.46,
    "x2": 0.46,
    "x3": -0.09,
    "theta3": 0,
    "theta4": -0.5,
    "d5": -0.25,
    "theta6": 0,
}


def example() -> dict[str, Any]:
    return yaml.safe_load(EXAMPLE_YAML)


def free_space() -> dict[str, Any]:
    """The example without a cabin (no mesh to load: fast)."""
    data = example()
    del data["cabin"]
    return data


def write(path: Path, data: dict[str, Any]) -> Path:
    if path.suffix == ".json":
        path.write_text(json.dumps(data), encoding="utf-8")
    else:
        path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


def reversed_keys(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: reversed_keys(obj[k]) for k in reversed(list(obj))}
    return obj


def refused(data: Any, field: str) -> InvalidInput:
    with pytest.raises(InvalidInput) as info:
        scenario_from_dict(data)
    exc = info.value
    assert exc.details["field"] == field, exc.message
    assert exc.message.startswith(f"{field}: "), exc.message
    return exc


def refused_on_resolve(
    data: dict[str, Any], field: str, exc_type: type[InvalidInput] = InvalidInput
) -> InvalidInput:
    spec = scenario_from_dict(data)
    with pytest.raises(exc_type) as info:
        resolve_scenario(spec)
    exc = info.value
    assert exc.details["field"] == field, exc.message
    assert exc.message.startswith(f"{field}: "), exc.message
    return exc


# ---------------------------------------------------------------------------------------- reference cabins


def test_reference_cabins_are_the_manifest_and_resolve_with_or_without_extension():
    names = reference_cabins()
    assert names == ("cabin-aisle", "cabin-hatch", "cabin-cluttered", "cabin-tightbay")
    assert reference_manifest() is reference_manifest()  # cached
    for name in names:
        path = reference_cabin_path(name)
        assert path is not None and path.is_file() and path.parent == REFERENCE_DIR
        assert reference_cabin_path(f"{name}.stl") == path
    assert reference_cabin_path("cabin-nowhere") is None
    assert reference_cabin_path("sub/cabin-aisle.stl") is None


# ----------------------------------------------------------------------------------------- the example


@pytest.fixture(scope="module")
def example_resolved(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("example")
    (tmp / "bay3.yaml").write_text(EXAMPLE_YAML, encoding="utf-8")
    write(tmp / "bay3.json", example())
    return load_scenario(tmp / "bay3.yaml"), load_scenario(tmp / "bay3.json")


def test_example_resolves_from_yaml_and_json_to_the_same_scenario(example_resolved):
    from_yaml, from_json = example_resolved
    assert from_yaml.spec == from_json.spec
    assert from_yaml.scenario_sha256 == from_json.scenario_sha256 == scenario_hash(from_yaml.spec)
    r = from_yaml
    robot = r.robot
    # Start: the given drives, and joints that map back onto them (an independent route).
    assert np.array_equal(r.start_u, [HOME[n] for n in robot.drive_names])
    np.testing.assert_allclose(robot.drives_from_joints(r.start_q), r.start_u, atol=1e-12)
    assert robot.limits.upper[0] == 6.0
    # Cabin: the packaged reference cabin, as its manifest documents it.
    assert r.cabin is not None and r.cabin_source == "cabin-aisle"
    record = next(c for c in reference_manifest()["cabins"] if c["name"] == "cabin-aisle")
    assert r.cabin.sha256 == record["sha256"]["stl"]
    assert len(r.cabin.faces) == record["n_faces"]
    # Payload and goal.
    assert r.payload is not None and r.payload.size == (0.45, 0.35, 0.5) and r.payload.mass == 100.0
    assert r.goal_u is None and r.goal_q is None
    assert r.T_base_tool_goal is not None and r.T_base_payload_goal is not None
    np.testing.assert_allclose(
        r.T_base_tool_goal @ r.payload.T_tool_payload, r.T_base_payload_goal, atol=1e-12
    )
    np.testing.assert_allclose(r.approach_direction, [1.0, 0.0, 0.0])
    assert r.approach_distance_m == 0.25
    assert r.options.clearance_m == 0.01 and r.options.seed == 1
    assert not r.start_q.flags.writeable


# ------------------------------------------------------------------------------------------ aliases, hash


def test_clearance_alias_and_canonical_name_both_validate_and_dump_as_clearance_m():
    for key in ("clearance", "clearance_m"):
        opts = PlanOptions.model_validate({key: 0.02})
        assert opts.clearance_m == 0.02
        dumped = opts.model_dump(mode="json")
        assert dumped["clearance_m"] == 0.02 and "clearance" not in dumped
    assert PlanOptions(clearance_m=0.03).clearance_m == 0.03
    a = free_space()
    b = free_space()
    b["options"]["clearance_m"] = b["options"].pop("clearance")
    assert scenario_hash(scenario_from_dict(a)) == scenario_hash(scenario_from_dict(b))
    both = free_space()
    both["options"]["clearance_m"] = 0.01
    refused(both, "options")


def test_hash_is_stable_across_format_key_order_and_defaults_and_changes_with_values(tmp_path):
    base = scenario_hash(scenario_from_dict(free_space()))
    assert scenario_hash(scenario_from_dict(reversed_keys(free_space()))) == base
    assert scenario_hash(load_scenario_file(write(tmp_path / "a.json", reversed_keys(free_space())))) == base
    assert scenario_hash(load_scenario_file(write(tmp_path / "a.yml", free_space()))) == base
    explicit = free_space()
    explicit["options"].update(motion_margin_m=0.005, simplify=True, approach_step_m=0.005)
    explicit["payload"]["com"] = None
    assert scenario_hash(scenario_from_dict(explicit)) == base
    changed = free_space()
    changed["options"]["seed"] = 2
    assert scenario_hash(scenario_from_dict(changed)) != base
    renamed = free_space()
    renamed["name"] = "bay3-insert-b"
    assert scenario_hash(scenario_from_dict(renamed)) != base
    assert len(base) == 64 and int(base, 16) >= 0


def test_yaml_exponent_floats_without_a_dot_are_numbers(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text(EXAMPLE_YAML.replace("clearance: 0.01", "clearance: 5e-3"), encoding="utf-8")
    assert load_scenario_file(path).options.clearance_m == 0.005


# ----------------------------------------------------------------------------------------------- meshes


def test_reference_cabin_by_name_without_extension_and_no_cabin_is_free_space():
    data = example()
    data["cabin"]["mesh"] = "cabin-tightbay"
    r = resolve_scenario(scenario_from_dict(data))
    assert r.cabin is not None and r.cabin_source == "cabin-tightbay"
    assert r.cabin.sha256 == load_mesh(REFERENCE_DIR / "cabin-tightbay.stl", units="m").sha256
    r = resolve_scenario(scenario_from_dict(free_space()))
    assert r.cabin is None and r.cabin_source == "none"


def test_relative_mesh_path_next_to_the_scenario_with_pose_and_units(tmp_path):
    shutil.copy(REFERENCE_DIR / "cabin-tightbay.stl", tmp_path / "my-cabin.stl")
    data = example()
    data["cabin"] = {"mesh": "my-cabin.stl", "pose": {"position": [0.0, 0.0, 1.5]}}
    r = load_scenario(write(tmp_path / "s.yaml", data))
    assert r.cabin is not None and r.cabin_source == str(tmp_path / "my-cabin.stl")
    reference = load_mesh(REFERENCE_DIR / "cabin-tightbay.stl", units="m")
    np.testing.assert_allclose(r.cabin.vertices, reference.vertices + [0.0, 0.0, 1.5], atol=1e-12)
    # Relative to the current directory when no base directory is given.
    with pytest.raises(InvalidInput, match=r"^cabin\.mesh: 'my-cabin.stl' is neither"):
        resolve_scenario(scenario_from_dict(data), base_dir=tmp_path / "elsewhere")


def test_mesh_resolver_wins_and_falls_back_when_it_returns_none(tmp_path):
    stored = (REFERENCE_DIR / "cabin-tightbay.stl").read_bytes()
    data = example()
    data["cabin"]["mesh"] = "stored-17.stl"
    r = resolve_scenario(scenario_from_dict(data), mesh_resolver=lambda name: stored)
    assert r.cabin is not None and r.cabin_source == "stored-17.stl"
    data["cabin"]["mesh"] = "cabin-aisle"
    r = resolve_scenario(scenario_from_dict(data), mesh_resolver=lambda name: None)
    assert r.cabin_source == "cabin-aisle"


def test_mesh_payload_obb_contains_every_vertex(tmp_path):
    T = trimesh.transformations.euler_matrix(0.3, -0.2, 0.5)
    T[:3, 3] = [20.0, -10.0, 50.0]  # mm
    part = trimesh.creation.box(extents=[400.0, 300.0, 200.0], transform=T)
    part.export(tmp_path / "part.stl")
    data = free_space()
    data["payload"] = {"mesh": "part.stl", "units": "mm", "mass": 20.0, "com": [0.02, -0.01, 0.05]}
    r = load_scenario(write(tmp_path / "s.yaml", data))
    payload = r.payload
    assert payload is not None and payload.source == "part.stl"
    np.testing.assert_allclose(sorted(payload.size), [0.2, 0.3, 0.4], atol=1e-6)
    v = np.asarray(part.vertices) * 1e-3
    v_box = (np.linalg.inv(payload.T_payload_box) @ np.column_stack([v, np.ones(len(v))]).T).T[:, :3]
    assert np.all(np.abs(v_box) <= np.asarray(payload.size) / 2 + 1e-6)
    rigid = payload.rigid_payload()
    assert rigid.mass == 20.0 and np.all(np.linalg.eigvalsh(rigid.inertia_tool) > 0)


# ------------------------------------------------------------------------------------------- goals, starts


def test_pose_goal_tool_transform_undoes_the_grasp():
    data = free_space()
    grasp = Pose.from_matrix(trimesh.transformations.euler_matrix(0.4, 0.1, -0.7))
    data["payload"]["grasp"] = {
        "position": [0.05, -0.02, 0.31],
        "orientation": grasp.orientation.model_dump(),
    }
    r = resolve_scenario(scenario_from_dict(data))
    assert r.payload is not None and r.T_base_tool_goal is not None and r.T_base_payload_goal is not None
    G = r.payload.T_tool_payload
    assert np.max(np.abs(r.T_base_tool_goal @ G - r.T_base_payload_goal)) <= 1e-12
    np.testing.assert_allclose(r.T_base_payload_goal, Pose.model_validate(data["goal"]["pose"]).matrix())
    # Without a payload the payload frame is the tool frame.
    del data["payload"]
    r = resolve_scenario(scenario_from_dict(data))
    assert r.T_base_tool_goal is not None and r.T_base_payload_goal is not None
    assert np.array_equal(r.T_base_tool_goal, r.T_base_payload_goal)


def test_approach_direction_is_normalised():
    data = free_space()
    data["goal"]["approach"] = {"direction": [0.0, 3.0, 4.0], "distance": 0.1}
    r = resolve_scenario(scenario_from_dict(data))
    assert r.approach_direction is not None
    np.testing.assert_allclose(r.approach_direction, [0.0, 0.6, 0.8], atol=1e-15)
    assert abs(np.linalg.norm(r.approach_direction) - 1.0) < 1e-15
    del data["goal"]["approach"]
    r = resolve_scenario(scenario_from_dict(data))
    assert r.approach_direction is None and r.approach_distance_m == 0.0


def test_joint_start_and_drive_goal_round_trip(robot):
    data = free_space()
    q_home = robot.joints_from_drives(robot.home_drives)
    data["start"] = {"joints": robot.joints_dict(q_home)}
    data["goal"] = {"drives": dict(HOME, d1=2.0)}
    r = resolve_scenario(scenario_from_dict(data))
    np.testing.assert_allclose(r.start_u, robot.home_drives, atol=1e-12)
    np.testing.assert_allclose(r.start_q, q_home, atol=0)
    assert r.goal_u is not None and r.goal_q is not None and r.goal_u[0] == 2.0
    np.testing.assert_allclose(robot.drives_from_joints(r.goal_q), r.goal_u, atol=1e-12)
    assert r.T_base_tool_goal is None and r.T_base_payload_goal is None and r.approach_direction is None


# -------------------------------------------------------------------------------------- schema refusals


def _set(path: str, value: Any):
    def mutate(data: dict[str, Any]) -> None:
        *parents, leaf = path.split(".")
        node = data
        for p in parents:
            node = node[p]
        node[leaf] = value

    return mutate


def _delete(path: str):
    def mutate(data: dict[str, Any]) -> None:
        *parents, leaf = path.split(".")
        node = data
        for p in parents:
            node = node[p]
        del node[leaf]

    return mutate


SCHEMA_REFUSALS = [
    ("unknown top-level field", _set("foo", 1), "foo"),
    ("unknown nested field", _set("options.foo", 1), "options.foo"),
    ("both box and mesh", _set("payload.mesh", "part.stl"), "payload"),
    ("neither box nor mesh", _delete("payload.box"), "payload"),
    ("units with a box", _set("payload.units", "mm"), "payload"),
    ("both drives and pose", _set("goal.drives", HOME), "goal"),
    ("neither drives, joints nor pose", _set("goal", {}), "goal"),
    (
        "approach with a drives goal",
        _set("goal", {"drives": HOME, "approach": {"direction": [1, 0, 0], "distance": 0.1}}),
        "goal.approach",
    ),
    ("negative clearance (alias key)", _set("options.clearance", -0.01), "options.clearance"),
    ("zero time limit", _set("options.time_limit_s", 0), "options.time_limit_s"),
    ("100 ms controller period", _set("options.sample_period_s", 0.1), "options.sample_period_s"),
    ("unknown planner", _set("options.planner", "RRTsharp"), "options.planner"),
    ("bad cabin units", _set("cabin", {"mesh": "cabin-aisle", "units": "cm"}), "cabin.units"),
    (
        "non-unit quaternion",
        _set("goal.pose.orientation", {"w": 1, "x": 1, "y": 0, "z": 0}),
        "goal.pose.orientation",
    ),
    (
        "huge quaternion (its squares overflow)",
        _set("goal.pose.orientation", {"w": 1e200, "x": 1e200, "y": 0, "z": 0}),
        "goal.pose.orientation",
    ),
    ("goal pose without orientation", _set("goal.pose", {"position": [0.885, 0.675, 2.7]}), "goal.pose"),
    ("negative mass", _set("payload.mass", -1.0), "payload.mass"),
    ("inf mass", _set("payload.mass", float("inf")), "payload.mass"),
    ("numeric string", _set("payload.mass", "100"), "payload.mass"),
    ("boolean drive", _set("start.drives.d1", True), "start.drives.d1"),
    ("negative box side", _set("payload.box", [0.45, -0.35, 0.5]), "payload.box[1]"),
    ("two-element box", _set("payload.box", [0.45, 0.35]), "payload.box[2]"),
    (
        "inertia not symmetric",
        _set("payload.inertia", [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]),
        "payload.inertia",
    ),
    ("inertia not PSD", _set("payload.inertia", [[1, 0, 0], [0, -1, 0], [0, 0, 1]]), "payload.inertia"),
    (
        "inertia violates the triangle inequality",
        _set("payload.inertia", [[1, 0, 0], [0, 1, 0], [0, 0, 3]]),
        "payload.inertia",
    ),
    ("zero approach direction", _set("goal.approach.direction", [0, 0, 0]), "goal.approach.direction"),
    ("approach too long", _set("goal.approach.distance", 1.5), "goal.approach.distance"),
    ("bad name", _set("name", "bay 3"), "name"),
    ("rail too long", _set("rail_length", 60.0), "rail_length"),
    ("missing start", _delete("start"), "start"),
    ("negative seed", _set("options.seed", -1), "options.seed"),
    ("sample period too small", _set("options.sample_period_s", 1e-5), "options.sample_period_s"),
]


@pytest.mark.parametrize(
    ("mutate", "field"), [c[1:] for c in SCHEMA_REFUSALS], ids=[c[0] for c in SCHEMA_REFUSALS]
)
def test_schema_refusals_name_the_field(mutate, field):
    data = free_space()
    mutate(data)
    exc = refused(data, field)
    assert exc.details["errors"][0] == {"field": field, "message": exc.message.split(": ", 1)[1]}


def test_exact_message_of_a_bound_and_of_the_goal_rule():
    data = free_space()
    data["options"] = {"clearance_m": -0.01}
    assert (
        refused(data, "options.clearance_m").message == "options.clearance_m: Input should be greater than 0"
    )
    data = free_space()
    data["goal"] = {}
    assert (
        refused(data, "goal").message == "goal: exactly one of drives, joints or pose is required, got none"
    )


def test_non_finite_numbers_are_refused_from_yaml_and_json(tmp_path):
    path = tmp_path / "nan.yaml"
    path.write_text(EXAMPLE_YAML.replace("mass: 100", "mass: .nan"), encoding="utf-8")
    with pytest.raises(InvalidInput, match=r"^payload\.mass: Input should be a finite number$"):
        load_scenario_file(path)
    data = free_space()
    data["goal"]["pose"]["position"][0] = float("nan")
    path = tmp_path / "nan.json"
    path.write_text(json.dumps(data), encoding="utf-8")  # writes NaN, which json reads back
    with pytest.raises(InvalidInput, match=r"^goal\.pose\.position\[0\]: ") as info:
        load_scenario_file(path)
    assert "finite" in info.value.message


def test_top_level_must_be_a_mapping(tmp_path):
    refused([free_space()], "scenario")
    refused(None, "scenario")
    path = tmp_path / "list.yaml"
    path.write_text("- name: a\n- name: b\n", encoding="utf-8")
    with pytest.raises(InvalidInput, match="^scenario: .*got list") as info:
        load_scenario_file(path)
    assert info.value.details["field"] == "scenario"


# ------------------------------------------------------------------------------------ resolve refusals


def test_unknown_drive_name_in_start_is_named():
    data = free_space()
    data["start"]["drives"]["x4"] = 0.0
    exc = refused_on_resolve(data, "start.drives")
    assert "x4" in exc.message


def test_missing_drive_is_named():
    data = free_space()
    del data["start"]["drives"]["theta6"]
    exc = refused_on_resolve(data, "start.drives")
    assert "theta6" in exc.message and "missing" in exc.message


def test_unknown_joint_in_goal_is_named():
    data = free_space()
    data["goal"] = {"joints": {"d1": 1.0}}
    exc = refused_on_resolve(data, "goal.joints")
    assert "missing" in exc.message


def test_start_drives_outside_the_parallel_workspace():
    data = free_space()
    data["start"]["drives"].update(x1=0.05, x3=-0.05)  # F left of A: the stage cannot assemble
    exc = refused_on_resolve(data, "start.drives")
    assert "workspace" in exc.message and exc.details["condition"] == "x3 > x1 (F right of A)"
    data = free_space()
    data["goal"] = {"drives": dict(HOME, x1=-0.79, x2=0.79, x3=0.0)}  # links too short to close
    exc = refused_on_resolve(data, "goal.drives")
    assert exc.details["condition"]


def test_start_limits_are_not_checked_here():
    data = free_space()
    data["start"]["drives"]["theta6"] = 10.0  # beyond the drive limit: the planner's refusal, not ours
    r = resolve_scenario(scenario_from_dict(data))
    assert r.start_u[7] == 10.0


def test_unknown_cabin_name_lists_the_reference_cabins():
    data = example()
    data["cabin"]["mesh"] = "cabin-nowhere"
    exc = refused_on_resolve(data, "cabin.mesh")
    assert all(name in exc.message for name in reference_cabins())


def test_missing_mesh_files_are_named(tmp_path):
    data = free_space()
    data["cabin"] = {"mesh": "missing.stl"}
    spec = scenario_from_dict(data)
    with pytest.raises(InvalidInput, match=r"^cabin\.mesh: 'missing.stl'"):
        resolve_scenario(spec, base_dir=tmp_path)
    data = free_space()
    data["payload"] = {"mesh": "cabin-aisle.stl"}  # reference names are cabins, not payloads
    with pytest.raises(InvalidInput, match=r"^payload\.mesh: ") as info:
        resolve_scenario(scenario_from_dict(data), base_dir=tmp_path)
    assert "reference" not in info.value.message


def test_unusable_mesh_is_invalid_mesh_prefixed_with_the_field(tmp_path):
    (tmp_path / "bad.stl").write_bytes(b"not an stl at all" * 10)
    data = free_space()
    data["cabin"] = {"mesh": "bad.stl"}
    with pytest.raises(InvalidMesh) as info:
        resolve_scenario(scenario_from_dict(data), base_dir=tmp_path)
    assert info.value.message.startswith("cabin.mesh: mesh 'bad.stl'")
    assert info.value.details["field"] == "cabin.mesh" and info.value.details["check"]
    data["cabin"] = {"mesh": "cabin-aisle", "units": "mm"}  # a 7 mm cabin, below the caller's minimum
    with pytest.raises(InvalidMesh, match=r"^cabin\.mesh: .*check 'scale' failed"):
        resolve_scenario(scenario_from_dict(data), mesh_limits=MeshLimits(min_extent_m=0.5))


def test_unknown_robot_and_rail_length():
    data = free_space()
    data["robot"] = "pprs9"
    refused_on_resolve(data, "robot", UnknownRobot)
    data = free_space()
    data["rail_length"] = 3.0
    assert resolve_scenario(scenario_from_dict(data)).robot.limits.upper[0] == 3.0
    data["rail_length"] = -1.0
    refused(data, "rail_length")


def test_payload_inertia_is_validated_on_resolve_too():
    data = free_space()
    data["payload"]["inertia"] = [[1, 0, 0], [0, 2, 0], [0, 0, 2.5]]
    r = resolve_scenario(scenario_from_dict(data))
    assert r.payload is not None
    np.testing.assert_allclose(r.payload.rigid_payload().inertia_tool, np.diag([1, 2, 2.5]))


# ----------------------------------------------------------------------------------------- file refusals


def test_malformed_yaml_reports_line_and_column(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("name: a\nstart: {drives: [1, 2}\n", encoding="utf-8")
    with pytest.raises(
        InvalidInput, match=r"^scenario: bad\.yaml: invalid YAML at line 2, column \d+: "
    ) as info:
        load_scenario_file(path)
    assert info.value.details["field"] == "scenario"


def test_malformed_json_reports_line_and_column(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text('{"name": "a",\n "start": }', encoding="utf-8")
    with pytest.raises(InvalidInput, match=r"^scenario: bad\.json: invalid JSON at line 2, column 11: "):
        load_scenario_file(path)


def test_duplicate_keys_are_refused(tmp_path):
    path = tmp_path / "dup.yaml"
    path.write_text(EXAMPLE_YAML + "name: other\n", encoding="utf-8")
    with pytest.raises(
        InvalidInput, match=r"^scenario: dup\.yaml: invalid YAML at line 18, .*duplicate key 'name'"
    ):
        load_scenario_file(path)
    path = tmp_path / "dup.json"
    path.write_text('{"name": "a", "name": "b"}', encoding="utf-8")
    with pytest.raises(InvalidInput, match="duplicate key 'name'"):
        load_scenario_file(path)


def test_wrong_extension_missing_empty_and_oversized_files(tmp_path):
    path = tmp_path / "s.txt"
    path.write_text(EXAMPLE_YAML, encoding="utf-8")
    with pytest.raises(InvalidInput, match=r"^scenario: unsupported file extension '\.txt'") as info:
        load_scenario_file(path)
    assert info.value.details["field"] == "scenario"
    with pytest.raises(InvalidInput, match=r"^scenario: nope\.yaml: file not found"):
        load_scenario_file(tmp_path / "nope.yaml")
    (tmp_path / "folder.yaml").mkdir()
    with pytest.raises(InvalidInput, match=r"^scenario: folder\.yaml: not a regular file"):
        load_scenario_file(tmp_path / "folder.yaml")
    (tmp_path / "empty.yaml").write_text("", encoding="utf-8")
    with pytest.raises(InvalidInput, match=r"^scenario: expected a mapping .*empty"):
        load_scenario_file(tmp_path / "empty.yaml")
    big = tmp_path / "big.yaml"
    big.write_text(EXAMPLE_YAML + "#" * MAX_SCENARIO_BYTES, encoding="utf-8")
    with pytest.raises(InvalidInput, match=r"^scenario: big\.yaml: \d+ bytes exceeds the scenario size cap"):
        load_scenario_file(big)
    latin = tmp_path / "latin.yaml"
    latin.write_bytes(EXAMPLE_YAML.encode() + b"# \xe9\n")
    with pytest.raises(InvalidInput, match=r"^scenario: latin\.yaml: not UTF-8"):
        load_scenario_file(latin)


def test_the_model_is_frozen():
    spec = scenario_from_dict(free_space())
    with pytest.raises(ValueError):
        spec.name = "other"
    assert isinstance(spec, Scenario)
