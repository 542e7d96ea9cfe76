"""Scene documents of the viewer (planner/documents/scene.py): the planner's poses, checked independently."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from planner.collision.bodies import body_poses
from planner.collision.world import CollisionWorld
from planner.documents.scene import (
    frame_indices,
    plan_scene,
    pprs6_chain_points,
    refusal_scene,
    workspace_boundary_points,
)
from planner.gate.checks import clearance_probe_indices
from planner.robots.pprs6 import Pprs6
from planner.scenario import load_scenario

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"


@pytest.mark.parametrize("n", [1, 2, 39, 40, 41, 399, 400, 401, 3977, 12000])
def test_frames_keep_the_ends_and_every_gate_probe(n: int) -> None:
    idx = frame_indices(n, 400)
    assert idx[0] == 0 and idx[-1] == n - 1 and np.all(np.diff(idx) > 0)
    assert set(clearance_probe_indices(n).tolist()) <= set(idx.tolist())
    assert len(idx) <= 400 + 42


def test_plan_scene_poses_match_the_reference_route_and_distances_are_exact() -> None:
    sc = load_scenario(SCENARIOS / "aisle-bay-insert.yaml")
    world = CollisionWorld(sc.robot, sc.cabin, sc.payload)
    rng = np.random.default_rng(3)
    # A joint path between the start and a perturbed copy (any admissible-looking motion will do here:
    # the scene poses what it is given).
    q0 = np.asarray(sc.start_q)
    q1 = q0 + np.array([0.6, 0.01, 0.01, 0.05, -0.2, 0.1, 0.05, 0.3])
    s = np.linspace(0.0, 1.0, 57)[:, None]
    q = q0 + s * (q1 - q0)
    t = np.linspace(0.0, 2.8, 57)
    doc = plan_scene(sc, q, t, max_frames=20)
    idx = np.asarray(doc["frames"]["sample"])
    assert doc["frames"]["t_s"] == t[idx].tolist()
    assert [b["name"] for b in doc["bodies"]] == list(world.names)
    # The compiled pose kernel the scene uses against the pure numpy poses of the collision bodies.
    R_ref, p_ref, len_ref = body_poses(sc.robot, world.bodies, q[idx], sc.payload)
    assert np.max(np.abs(np.asarray(doc["frames"]["R"]) - R_ref)) < 1e-12
    assert np.max(np.abs(np.asarray(doc["frames"]["p_m"]) - p_ref)) < 1e-12
    assert np.max(np.abs(np.asarray(doc["frames"]["length_m"]) - len_ref)) < 1e-12
    # The payload frame is FK @ grasp; the payload body is that frame @ its box pose.
    assert sc.payload is not None
    for k in rng.choice(len(idx), 4, replace=False):
        T = sc.robot.fk(q[idx[k]]) @ sc.payload.T_tool_payload
        assert np.allclose(doc["frames"]["payload_frame"][k]["position"], T[:3, 3], atol=1e-12)
        d = world.min_distance(np.ascontiguousarray(q[idx[k]]))
        assert doc["clearance"]["distance_m"][k] == pytest.approx(d.distance_m, abs=1e-12)
        assert doc["clearance"]["pair"][k] == list(d.bodies)
        # The witness points are that far apart (a separated pair).
        a, b = np.asarray(doc["clearance"]["point_a_m"][k]), np.asarray(doc["clearance"]["point_b_m"][k])
        assert np.linalg.norm(a - b) == pytest.approx(d.distance_m, abs=1e-6)
    assert doc["min_clearance_m"] == pytest.approx(min(doc["clearance"]["distance_m"]))
    # Start, goal and the approach line from the scenario.
    assert sc.T_base_payload_goal is not None and sc.approach_direction is not None
    assert np.allclose(doc["goal"]["position"], sc.T_base_payload_goal[:3, 3])
    line = np.asarray(doc["approach"]["to_m"]) - np.asarray(doc["approach"]["from_m"])
    assert np.allclose(line, sc.approach_distance_m * sc.approach_direction)


def test_refusal_scene_shows_the_start_with_its_contacts() -> None:
    sc = load_scenario(SCENARIOS / "refuse-start-in-collision.yaml")
    world = CollisionWorld(sc.robot, sc.cabin, sc.payload)
    doc = refusal_scene(sc, "start_in_collision", {})
    cfg = doc["configuration"]
    assert doc["configuration_source"] == "the start configuration"
    assert cfg["joints"] == np.asarray(sc.start_q).tolist() and cfg["valid"] is False
    expected = world.check_state(np.asarray(sc.start_q), sc.options.clearance_m, all_contacts=True)
    assert cfg["contacts"] == [c.to_dict() for c in expected.contacts] and cfg["contacts"]
    assert "payload" in {b for c in cfg["contacts"] for b in c["bodies"]}
    # Evidence naming a configuration wins over the start.
    q = (np.asarray(sc.start_q) + 0.01).tolist()
    assert refusal_scene(sc, "start_in_collision", {"q": q})["configuration"]["joints"] == q
    # A refusal about nothing in particular shows no configuration.
    assert refusal_scene(sc, "no_path_within_time_limit", {})["configuration"] is None


def test_pprs6_chain_points_close_every_link() -> None:
    robot = Pprs6()
    poses = np.array([[0.0, 0.0, 0.18, 0.0, 0.0, 0.0], [-0.05, -0.05, 0.18, 0.2, 0.05, -0.03]])
    drives = robot.ik(poses)
    pts = pprs6_chain_points(robot, poses, drives)
    lengths = np.linalg.norm(pts["C"] - pts["D"], axis=2)
    assert np.max(np.abs(lengths - np.asarray(robot.geometry.L))) < 1e-9
    # Sliders 1, 2 sit at w_i along their support; chain 3 pivots at R u_3.
    assert np.allclose(pts["B"][:, 0], drives[:, [0]] * robot.geometry.u[0])
    assert np.allclose(pts["B"][:, 2], robot.geometry.B3)


def test_workspace_boundary_points_are_inside_with_an_outside_neighbour() -> None:
    axes = (np.linspace(-1, 1, 21), np.linspace(-1, 1, 21), np.linspace(-1, 1, 21))
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    inside = X**2 + Y**2 + Z**2 <= 0.7**2
    pts = workspace_boundary_points(inside, axes)
    r = np.linalg.norm(pts, axis=1)
    assert len(pts) > 0 and np.all(r <= 0.7 + 1e-12) and np.all(r > 0.7 - 0.1 * np.sqrt(3) - 1e-12)
    assert len(pts) < inside.sum()
