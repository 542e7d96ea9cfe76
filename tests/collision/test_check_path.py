"""check_path certifies the whole polyline, between samples too, and finds the first bad run."""

from __future__ import annotations

import io

import numpy as np
import pytest
import trimesh

from planner.collision.bodies import PayloadGeometry
from planner.collision.oracle import ReferenceWorld
from planner.collision.world import CollisionWorld
from planner.kinematics.parallel import stage_points
from planner.meshio import LoadedMesh, load_mesh
from planner.robots.cabin8 import Cabin8

CLEARANCE_M = 0.01
MOTION_MARGIN_M = 0.005
PLATE_Z_M = 2.55


def home(robot: Cabin8, **changes: float) -> np.ndarray:
    q = robot.joints_from_drives(robot.home_drives)
    for k, v in changes.items():
        q[robot.joint_names.index(k)] = v
    return q


@pytest.fixture(scope="module")
def payload() -> PayloadGeometry:
    grasp = np.eye(4)
    grasp[2, 3] = 0.30
    return PayloadGeometry((0.45, 0.35, 0.50), T_tool_payload=grasp, mass=100.0)


@pytest.fixture(scope="module")
def free(robot: Cabin8, payload: PayloadGeometry) -> CollisionWorld:
    return CollisionWorld(robot, None, payload)


def plate_mesh(robot: Cabin8) -> LoadedMesh:
    """A 2 mm plate across link AB's path at d1 = 2.55 m (as in the thin-wall motion test of test_world)."""
    q = home(robot, d1=2.0)
    with np.errstate(invalid="ignore"):
        pts = stage_points(robot.geometry, q[1], q[2], q[3])
    a, b = np.array(pts.A), np.array(pts.B)
    spot = a + 0.75 * (b - a)
    plate = trimesh.creation.box(
        extents=(0.02, 0.02, 0.002),
        transform=trimesh.transformations.translation_matrix((spot[0], spot[1], PLATE_Z_M)),
    )
    return load_mesh(io.BytesIO(plate.export(file_type="stl")).getvalue(), units="m", name="plate.stl")


@pytest.fixture(scope="module")
def plate_world(robot: Cabin8, payload: PayloadGeometry) -> CollisionWorld:
    return CollisionWorld(robot, plate_mesh(robot), payload)


def rail_samples(robot: Cabin8, d1_from: float, d1_to: float, n: int) -> np.ndarray:
    return np.array([home(robot, d1=d1) for d1 in np.linspace(d1_from, d1_to, n)])


def zig_zag(qs: np.ndarray, amplitude_rad: float = 0.3) -> np.ndarray:
    """Every other sample with the wrist (theta6) and column (theta3) turned away from the chord."""
    out = qs.copy()
    out[1::2, 7] += amplitude_rad
    out[1::2, 4] += 0.5 * amplitude_rad
    return out


def segment_verdicts(world: CollisionWorld, qs: np.ndarray) -> list[bool]:
    pieces = zip(qs[:-1], qs[1:], strict=True)
    return [world.check_motion(a, b, CLEARANCE_M, MOTION_MARGIN_M).valid for a, b in pieces]


def test_samples_on_one_certified_segment_are_one_valid_run(robot: Cabin8, free: CollisionWorld) -> None:
    q_a, q_b = home(robot, d1=1.0, theta3=0.4, theta6=-0.5), home(robot, d1=2.0, theta3=-0.2, theta6=0.5)
    assert free.check_motion(q_a, q_b, CLEARANCE_M, MOTION_MARGIN_M).valid
    qs = q_a + np.linspace(0.0, 1.0, 21)[:, None] * (q_b - q_a)
    rep = free.check_path(qs, CLEARANCE_M, MOTION_MARGIN_M)
    assert rep.valid and rep.first_bad is None and not rep.contacts
    assert rep.motion_checks == 1  # no deviation from the chord: the whole run at once
    assert rep.last_checked == len(qs) - 1


def test_check_path_certifies_between_samples_not_only_at_them(
    robot: Cabin8, plate_world: CollisionWorld, free: CollisionWorld
) -> None:
    """Samples 10 cm apart on either side of a 2 mm plate are all clear; the polyline is not."""
    qs = rail_samples(robot, 2.0, 3.0, 11)
    assert all(plate_world.is_valid(q, CLEARANCE_M) for q in qs), "every sample is clear"
    assert not plate_world.is_valid(home(robot, d1=PLATE_Z_M), 0.0), "but the link crosses the plate"
    assert free.check_path(qs, CLEARANCE_M, MOTION_MARGIN_M).valid, "nothing else is in the way"
    rep = plate_world.check_path(qs, CLEARANCE_M, MOTION_MARGIN_M)
    assert not rep.valid
    assert rep.contacts and rep.contacts[0].bodies == ("link_ab",)
    # Two far-apart samples alone: the chord through the plate is refused as well.
    assert not plate_world.check_path(qs[[0, -1]], CLEARANCE_M, MOTION_MARGIN_M).valid


def test_zig_zag_is_split_into_runs_and_stays_correct(robot: Cabin8, free: CollisionWorld) -> None:
    straight = rail_samples(robot, 1.0, 2.0, 11)
    zz = zig_zag(straight)
    rep_straight = free.check_path(straight, CLEARANCE_M, MOTION_MARGIN_M)
    rep_zz = free.check_path(zz, CLEARANCE_M, MOTION_MARGIN_M)
    assert rep_straight.valid and rep_zz.valid
    assert rep_zz.motion_checks > rep_straight.motion_checks
    assert rep_zz.last_checked == len(zz) - 1
    # Agrees with checking every straight piece on its own.
    assert all(segment_verdicts(free, zz))


def test_zig_zag_through_the_plate_is_refused_at_the_right_run(
    robot: Cabin8, plate_world: CollisionWorld
) -> None:
    """A long zig-zag rail move up to the plate is refused at the run holding the first touching piece.

    The failing run starts at or before the first touching piece (every run before it was certified), and
    no further back than one run (32 samples).
    """
    qs = zig_zag(rail_samples(robot, 0.5, 2.6, 43))
    verdicts = segment_verdicts(plate_world, qs)
    assert False in verdicts
    first_touch = verdicts.index(False)
    assert first_touch > 32  # far enough from the start that the run boundaries matter
    rep = plate_world.check_path(qs, CLEARANCE_M, MOTION_MARGIN_M)
    assert not rep.valid and rep.first_bad is not None
    assert rep.first_bad <= first_touch < rep.first_bad + 32
    assert rep.last_checked == rep.first_bad
    # Everything before the failing run holds on its own.
    assert plate_world.check_path(qs[: rep.first_bad + 1], CLEARANCE_M, MOTION_MARGIN_M).valid


def test_single_configuration_is_a_state_check(robot: Cabin8, plate_world: CollisionWorld) -> None:
    on_plate = home(robot, d1=PLATE_Z_M)
    rep = plate_world.check_path(on_plate[None, :], CLEARANCE_M)
    assert not rep.valid and rep.first_bad == 0 and rep.motion_checks == 0
    clear = home(robot, d1=1.0)
    assert plate_world.check_path(clear[None, :], CLEARANCE_M).valid


def test_a_detour_is_not_certified_by_its_clear_chord(robot: Cabin8, plate_world: CollisionWorld) -> None:
    """Out along the rail through the plate and back: the chord is clear, the polyline is not.

    The chord is a wrist turn at d1 = 2; a run is certified only with the polyline's deviation from its
    chord added.
    """
    q_a, q_b = home(robot, d1=2.0), home(robot, d1=2.0, theta6=0.5)
    assert plate_world.check_motion(q_a, q_b, CLEARANCE_M, MOTION_MARGIN_M).valid
    out = home(robot, d1=2.0 + 2 * (PLATE_Z_M - 2.0))
    qs = np.array([q_a, out, q_b])
    assert plate_world.is_valid(out, CLEARANCE_M)  # beyond the plate: every sample is clear
    rep = plate_world.check_path(qs, CLEARANCE_M, MOTION_MARGIN_M)
    assert not rep.valid and rep.first_bad == 0
    assert rep.motion_checks == 1  # the first piece alone already fails


def test_a_run_refused_only_for_its_extra_is_split_not_refused(
    robot: Cabin8, plate_world: CollisionWorld
) -> None:
    """A wobbly rail move that ends a few millimetres beyond clearance + margin from the plate is certified.

    With a large extra budget the last run's chord is asked for far more room than there is, so it fails;
    the run is halved down to pieces that hold, as checking each piece alone shows.
    """
    d1s = np.linspace(2.0, PLATE_Z_M, 400)
    room = next(
        d for d in d1s[::-1] if plate_world.is_valid(home(robot, d1=d), CLEARANCE_M + MOTION_MARGIN_M + 0.003)
    )
    qs = rail_samples(robot, 1.0, room, 41)
    qs[1::2, 7] += 0.01  # the wrist wobbles by 10 mrad
    assert all(segment_verdicts(plate_world, qs))
    assert not plate_world.check_motion(qs[0], qs[-1], CLEARANCE_M + 0.02, MOTION_MARGIN_M).valid
    rep = plate_world.check_path(qs, CLEARANCE_M, MOTION_MARGIN_M, max_run=64, max_extra_m=0.02)
    assert rep.valid and rep.last_checked == len(qs) - 1
    assert rep.motion_checks > 1


def test_one_cabin_file_in_two_units_gets_two_carriage_tables(robot: Cabin8) -> None:
    """The carriage's clearance table follows the geometry as loaded, not the file's bytes alone."""
    slab = trimesh.creation.box(
        extents=(2.0, 0.05, 12.0), transform=trimesh.transformations.translation_matrix((0.0, -0.4, 5.0))
    )
    data = io.BytesIO(slab.export(file_type="stl")).getvalue()
    in_m = CollisionWorld(robot, load_mesh(data, units="m", name="cabin.stl"), None)
    in_mm = CollisionWorld(robot, load_mesh(data, units="mm", name="cabin.stl"), None)
    assert in_m._carriage_table is not in_mm._carriage_table
    q = home(robot, d1=0.006)  # on the millimetre slab's carriage: a contact
    reference = ReferenceWorld(robot, load_mesh(data, units="mm", name="cabin.stl"), None)
    assert not reference.check_state(q, CLEARANCE_M).valid
    assert not in_mm.is_valid(q, CLEARANCE_M) and not in_mm.check_state(q, CLEARANCE_M).valid
