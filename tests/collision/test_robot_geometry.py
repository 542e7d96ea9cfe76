"""The collision world takes its robot through the model's CollisionModel, not by name.

What a robot supplies (bodies, shapes, adjacency, rail body, kernel code and parameters, ratio rows) is
what the world builds from: a model that changes a piece changes the world accordingly, and a robot without
geometry is refused with the reason.
"""

from __future__ import annotations

import numpy as np
import pytest

from planner.collision.bodies import PayloadGeometry
from planner.collision.kernels.packed import unpack
from planner.collision.world import CollisionWorld
from planner.core.exceptions import InvalidInput
from planner.meshes import REFERENCE_DIR
from planner.meshio import load_mesh
from planner.robots.cabin8 import Cabin8
from planner.robots.cabin8_geometry import Cabin8CollisionModel
from planner.robots.pprs6 import Pprs6
from tests.conftest import admissible_joints

MESHES = REFERENCE_DIR


class _NoRailModel(Cabin8CollisionModel):
    """cabin8's geometry without the rail body: the carriage is bounded by its spheres like any body."""

    rail_body = None


class _NoRailCabin8(Cabin8):
    def collision_model(self) -> Cabin8CollisionModel:
        return _NoRailModel(self)


def _payload() -> PayloadGeometry:
    grasp = np.eye(4)
    grasp[2, 3] = 0.30
    return PayloadGeometry((0.45, 0.35, 0.50), T_tool_payload=grasp, mass=100.0)


def test_the_world_is_built_from_the_models_pieces(robot: Cabin8) -> None:
    world = CollisionWorld(robot, None, _payload())
    model = robot.collision_model()
    assert world.model is model
    assert world.names == (*model.body_names, "payload")
    assert all(not model.adjacent(world.names[a], world.names[b]) for a, b in world.bodies.pairs)
    u = unpack(world._kernel.fbuf, world._kernel.ibuf)
    assert u.kernel == model.kernel
    np.testing.assert_array_equal(u.params, model.kernel_params)
    assert tuple(u.ratio_rows) == model.ratio_rows
    np.testing.assert_array_equal(u.c_lo, model.admissibility.c_lower - 1e-9)
    assert [u.kinds[b] for b in range(len(world.names))] == [model.kind_code(n) for n in world.names]


def test_a_model_without_a_rail_body_gives_the_same_verdicts(robot: Cabin8) -> None:
    """The rail body's exact table only tightens a bound: without it every verdict stays the same."""
    mesh = load_mesh(MESHES / "cabin-aisle.stl", units="m")
    payload = _payload()
    world = CollisionWorld(robot, mesh, payload)
    bare = CollisionWorld(_NoRailCabin8(), mesh, payload)
    assert bare._carriage_table is None
    assert unpack(bare._kernel.fbuf, bare._kernel.ibuf).carriage == -1
    qs = admissible_joints(robot, 120, seed=5)
    qs[:, 0] = np.random.default_rng(5).uniform(0.2, 5.8, len(qs))
    verdicts = [world.is_valid(q) for q in qs]
    assert 0 < sum(verdicts) < len(qs)  # both kinds of state occur
    assert [bare.is_valid(q) for q in qs] == verdicts
    # Both bounds of the carriage (its spheres; the exact table) are lower bounds of its exact distance.
    carriage = world.names.index("carriage")
    for q in qs[:10]:
        exact = world._probes.distance(world._state(q), True, carriage)[0]
        assert bare._state(q).cabin_lb[carriage] <= exact + 1e-9
        assert world._state(q).cabin_lb[carriage] <= exact + 1e-9


def test_a_robot_without_collision_geometry_is_refused() -> None:
    with pytest.raises(InvalidInput, match="has no collision geometry"):
        CollisionWorld(Pprs6())


def test_sphere_covers_and_cabin_keys_are_computed_once_per_shape_and_mesh() -> None:
    """Every world asks for the same covers and the same cabin key: built once, shared read-only."""
    from planner.collision.world import cabin_key
    from planner.robots.geometry import Shape

    box = Shape("box", (0.31, 0.2, 0.12))
    centres, radii = box.sphere_cover(0.1)
    again = Shape("box", (0.31, 0.2, 0.12)).sphere_cover(0.1)
    assert again[0] is centres and again[1] is radii
    with pytest.raises(ValueError):
        centres[0, 0] = 1.0
    # The cover is the box's: 4 x 2 x 2 cells of at most 0.1 m, one sphere around each.
    assert centres.shape == (16, 3) and np.allclose(radii, 0.5 * np.linalg.norm([0.31 / 4, 0.1, 0.06]))
    points = np.random.default_rng(3).uniform(-1.0, 1.0, (2000, 3)) * np.array([0.155, 0.1, 0.06])
    inside = np.linalg.norm(points[:, None, :] - centres[None], axis=2) <= radii[None]
    assert inside.any(axis=1).all()  # the union of the spheres contains the box
    assert box.sphere_cover(0.2)[0].shape == (2, 3)  # another cell, another cover (2 x 1 x 1)
    mesh = load_mesh(MESHES / "cabin-aisle.stl", units="m")
    key = cabin_key(mesh)
    assert cabin_key(mesh) is key
    assert key[1] == mesh.vertices.tobytes() and key[2] == mesh.faces.astype(np.int64).tobytes()
    moved = np.eye(4)
    moved[0, 3] = 0.5
    other = load_mesh(MESHES / "cabin-aisle.stl", units="m", pose=moved)
    assert cabin_key(other)[0] != key[0]  # the same file at another pose is another geometry
