"""pprs6 kinematics: IK/FK round trips, closure, Jacobians vs finite differences, mobility."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.core.exceptions import ForwardKinematicsFailed, InvalidInput, OutsideWorkspace
from planner.kinematics import pprs6 as kin
from planner.robots import load_robot
from planner.robots.pprs6 import Pprs6

# Around home (yaw 0.2 rad): yaw in [0.05, 0.35] keeps the samples on home's side of the level-platform
# singularity, where the forward solutions on either side coalesce.
SPAN = np.array([0.03, 0.03, 0.03, 0.15, 0.2, 0.2])


@pytest.fixture(scope="module")
def robot() -> Pprs6:
    model = load_robot("pprs6")
    assert isinstance(model, Pprs6)
    return model


def admissible_poses(robot: Pprs6, n: int, seed: int, max_condition: float = 200.0) -> np.ndarray:
    """N admissible poses around home (rejection sampling), away from singularities."""
    rng = np.random.default_rng(seed)
    x = robot.home_pose + rng.uniform(-1, 1, size=(40 * n, 6)) * SPAN
    x = x[robot.admissible(x)]
    x = x[robot.condition_number(x) < max_condition]
    assert len(x) >= n
    return x[:n]


def test_ik_matches_the_chain_geometry(robot: Pprs6) -> None:
    """Each chain's joint centres have the geometry of the model: slider planes, vertical P, link lengths."""
    x = admissible_poses(robot, 50, seed=1)
    u = robot.ik(x)
    g = robot.geometry
    C = kin.platform_points(g, x).C
    for i in (0, 1):
        D = u[:, i, None] * g.u[i] + u[:, 3 + i, None] * np.array([0, 0, 1.0])
        assert np.allclose(C[:, i] @ g.u[i], u[:, i], atol=1e-15)  # C_i in the plane C . u_i = w_i
        assert np.allclose(np.linalg.norm(C[:, i] - D, axis=1), g.L[i], atol=1e-14)
        assert np.all(C[:, i, 2] > D[:, 2])  # the link points up from D_i to C_i
    beta, s3 = u[:, 2], u[:, 5]
    d = -np.cos(beta)[:, None] * g.u[2] + np.sin(beta)[:, None] * np.array([0, 0, 1.0])
    D3 = g.B3 + s3[:, None] * d
    assert np.allclose(np.linalg.norm(C[:, 2] - D3, axis=1), g.L[2], atol=1e-14)
    # angle between B3 D3 and B3 O is beta (paper eq. 9)
    cosang = np.einsum("na,a->n", D3 - g.B3, -g.B3) / (s3 * g.R)
    assert np.allclose(cosang, np.cos(beta), atol=1e-12)
    # the platform is an equilateral triangle of circumradius r
    assert np.allclose(np.linalg.norm(C[:, 0] - C[:, 1], axis=1), np.sqrt(3) * g.r, atol=1e-14)


def test_closure_residuals_vanish_at_ik(robot: Pprs6) -> None:
    x = admissible_poses(robot, 200, seed=2)
    phi = kin.closure(robot.geometry, robot.ik(x), x)[0]
    assert np.max(np.abs(phi)) < 1e-15


def test_fk_round_trip_from_a_nearby_start(robot: Pprs6) -> None:
    """FK(IK(x)) = x to 1e-9 from a start within 5 mm / 0.05 rad (the FK has several solutions)."""
    x = admissible_poses(robot, 300, seed=3, max_condition=50.0)
    rng = np.random.default_rng(4)
    guess = x + rng.uniform(-1, 1, x.shape) * [0.005, 0.005, 0.005, 0.05, 0.05, 0.05]
    xf = robot.fk(robot.ik(x), guess=guess)
    assert np.max(np.abs(xf - x)) < 1e-9


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-1, 1), min_size=6, max_size=6))
def test_ik_fk_ik_round_trip(offset: list[float]) -> None:
    """For any admissible pose, FK from home returns a pose with the same drives (1e-9), on a branch."""
    robot = load_robot("pprs6")
    assert isinstance(robot, Pprs6)
    x = robot.home_pose + np.array(offset) * SPAN
    if not robot.admissible(x[None])[0] or robot.condition_number(x[None])[0] > 200:
        return
    u = robot.ik(x)
    xf = robot.fk(u)
    assert np.max(np.abs(robot.ik(xf) - u)) < 1e-9
    assert np.max(np.abs(kin.closure(robot.geometry, u, xf)[0])) < 1e-12


def test_fk_tracks_a_motion_continuously(robot: Pprs6) -> None:
    """Started from the previous pose, FK follows a motion exactly (the assembly mode is kept)."""
    s = np.linspace(0, 1, 60)[:, None]
    a, b = robot.home_pose, robot.home_pose + [0.02, -0.02, 0.02, 0.1, 0.08, -0.08]
    x = a + s * (b - a)
    u = robot.ik(x)
    prev = x[0]
    for k in range(len(x)):
        prev = robot.fk(u[k], guess=prev)
        assert np.max(np.abs(prev - x[k])) < 1e-9


def test_drive_jacobian_matches_finite_differences(robot: Pprs6) -> None:
    x = admissible_poses(robot, 40, seed=5)
    J = robot.drive_jacobian(x)
    h = 1e-6
    fd = np.stack([(robot.ik(x + h * e) - robot.ik(x - h * e)) / (2 * h) for e in np.eye(6)], axis=2)
    assert np.max(np.abs(J - fd)) < 1e-7


def test_closure_jacobians_match_finite_differences_and_give_J(robot: Pprs6) -> None:
    """dPhi/dx and dPhi/dq by finite differences; J = -(dPhi/dq)^-1 dPhi/dx (an independent route)."""
    g = robot.geometry
    x = admissible_poses(robot, 20, seed=6)
    u = robot.ik(x) + 1e-3  # off the closure manifold: the Jacobians hold everywhere
    _, A, B = kin.closure(g, u, x)
    h = 1e-6
    fd_x = np.stack(
        [(kin.closure(g, u, x + h * e)[0] - kin.closure(g, u, x - h * e)[0]) / (2 * h) for e in np.eye(6)], 2
    )
    fd_q = np.stack(
        [(kin.closure(g, u + h * e, x)[0] - kin.closure(g, u - h * e, x)[0]) / (2 * h) for e in np.eye(6)], 2
    )
    assert np.max(np.abs(A - fd_x)) < 1e-8
    assert np.max(np.abs(B - fd_q)) < 1e-8
    _, A0, B0 = kin.closure(g, robot.ik(x), x)
    assert np.max(np.abs(-np.linalg.solve(B0, A0) - robot.drive_jacobian(x))) < 1e-10


def test_grubler_count_from_the_joint_list(robot: Pprs6) -> None:
    assert robot.grubler() == {"N": 11, "g": 12, "sum_f": 18, "F": 6}  # paper eq. (4)
    assert kin.grubler([["P", "P", "R", "S"]] * 2 + [["R", "P", "R", "S"]])["F"] == 6
    assert kin.grubler([["S", "P", "S"]] * 6)["F"] == 12  # 6-SPS with its 6 spinning legs


def test_rank_is_six_at_random_configurations(robot: Pprs6) -> None:
    for x in admissible_poses(robot, 20, seed=7):
        m = robot.mobility(x)
        assert m["mobility"] == 6 and m["loop_rank"] == 18
        assert m["chain_ranks"] == [6, 6, 6]  # no constraint screw in any chain (paper section 2.1)
        assert m["closure_rank_pose"] == 6 and m["closure_rank_drives"] == 6


def test_level_unyawed_platform_is_singular_at_beta_90(robot: Pprs6) -> None:
    """Level platform, phi = 0, beta = 90 deg: the three plane constraints meet at O1 (type II)."""
    g = robot.geometry
    # p . u3 = R - r puts C3 over B3 (rho = 0, beta = 90 deg); pick p . u1 = -0.01 m
    p = np.linalg.solve(g.u[[0, 2], :2], [-0.01, g.R - g.r])
    x = np.array([p[0], p[1], 0.19, 0.0, 0.0, 0.0])
    assert robot.ik(x)[2] == pytest.approx(np.pi / 2, abs=1e-12)
    assert robot.condition_number(x[None])[0] > 1e12
    assert robot.mobility(x)["closure_rank_pose"] == 5
    assert robot.condition_number((x + [0, 0, 0, 0.2, 0, 0])[None])[0] < 50


def test_ik_refuses_with_chain_and_limit_named(robot: Pprs6) -> None:
    with pytest.raises(OutsideWorkspace) as exc:
        robot.ik(np.array([-0.03, -0.03, 0.29, 0, 0, 0]))
    assert exc.value.details["drive"] == "s1" and exc.value.details["chain"] == "chain1"
    assert exc.value.details["side"] == "upper"
    with pytest.raises(OutsideWorkspace) as exc:
        robot.ik(np.array([-0.03, 0.15, 0.19, 0, 0, 0]))  # chain 1's link cannot reach C1 (|C1 . v1| > l)
    assert exc.value.details["condition"] == "chain_cannot_close"
    with pytest.raises(InvalidInput):
        robot.ik(np.array([np.nan, 0, 0, 0, 0, 0]))


def test_fk_refuses_out_of_range_and_unassemblable_drives(robot: Pprs6) -> None:
    u = robot.ik(robot.home_pose)
    with pytest.raises(OutsideWorkspace) as exc:
        robot.fk(u + [0.2, 0, 0, 0, 0, 0])
    assert exc.value.details["drive"] == "w1"
    # in range, but no platform closes all three chains: w1 and w2 at opposite extremes, s at the bottom
    bad = np.array([0.08, 0.18, 2.0, 0.0375, 0.1375, 0.0375])
    with pytest.raises(ForwardKinematicsFailed) as exc2:
        robot.fk(bad)
    assert exc2.value.details["residual_m"] > 1e-6
