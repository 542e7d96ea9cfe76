"""Planar stage: closed-form inverse/forward kinematics, assembly mode, measures, errors."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.core.exceptions import OutsideWorkspace
from planner.kinematics import parallel
from planner.robots.cabin8 import Cabin8

G = parallel.StageGeometry(0.40, 0.30, 0.40, 0.25)


def random_poses(n: int, seed: int) -> np.ndarray:
    """Poses inside the admissible stage workspace (rejection on the measures)."""
    rng = np.random.default_rng(seed)
    p = np.column_stack(
        [rng.uniform(-0.3, 0.3, 4 * n), rng.uniform(0.10, 0.36, 4 * n), rng.uniform(-0.35, 0.35, 4 * n)]
    )
    with np.errstate(invalid="ignore"):
        m = parallel.stage_measures(G, *p.T)
    ok = (m["sin_cbd"] >= 0.1) & (m["h_ab"] <= 0.95) & (m["h_cd"] <= 0.95) & (m["h_ef"] <= 0.95)
    return p[ok][:n]


def test_round_trip_thousands_of_poses() -> None:
    poses = random_poses(5000, seed=1)
    assert len(poses) == 5000
    sliders = parallel.inverse(G, poses)
    back = parallel.forward(G, sliders)
    assert np.max(np.abs(back - poses)) < 1e-9
    again = parallel.inverse(G, back)
    assert np.max(np.abs(again - sliders)) < 1e-9


def test_link_lengths_and_branch_hold() -> None:
    poses = random_poses(500, seed=2)
    p = parallel.stage_points(G, *poses.T)
    dist = lambda a, b: np.hypot(a[0] - b[0], a[1] - b[1])  # noqa: E731
    np.testing.assert_allclose(dist(p.A, p.B), G.L1, atol=1e-12)
    np.testing.assert_allclose(dist(p.B, p.C), G.L2, atol=1e-12)
    np.testing.assert_allclose(dist(p.C, p.D), G.L3, atol=1e-12)
    np.testing.assert_allclose(dist(p.E, p.F), G.L4, atol=1e-12)
    np.testing.assert_allclose(p.E[0], 0.5 * (p.A[0] + p.B[0]), atol=1e-15)
    assert np.all(p.A[0] < p.B[0]) and np.all(p.D[0] > p.C[0]) and np.all(p.F[0] > p.E[0])
    assert np.all(p.B[1] > 0) and np.all(p.C[1] > 0)
    cross = (p.C[0] - p.B[0]) * (p.D[1] - p.B[1]) - (p.C[1] - p.B[1]) * (p.D[0] - p.B[0])
    assert np.all(cross < 0), "working assembly mode (C - B) x (D - B) < 0"


def test_forward_matches_paper_eq9() -> None:
    """Eq. (9) in the paper's frame (origin at slider A): alpha from triangle AEF, C and G from it."""
    poses = random_poses(200, seed=3)
    sliders = parallel.inverse(G, poses)
    L1, L2, L3, L4 = G.L1, G.L2, G.L3, G.L4
    for (x1, x2, x3), pose in zip(sliders, poses, strict=True):
        X1, X2 = x3 - x1, x2 - x1  # the paper's slider distances AF and AD
        alpha = np.arccos((L1**2 / 4 + X1**2 - L4**2) / (L1 * X1))
        # beta: angle of DC with the rail (from the closed loop), then the paper's C and G.
        xb, yb = L1 * np.cos(alpha), L1 * np.sin(alpha)
        bd = np.hypot(X2 - xb, yb)
        phi = np.arctan2(yb, X2 - xb)  # angle BDA at D
        beta = phi + np.arccos((L3**2 + bd**2 - L2**2) / (2 * L3 * bd))
        bm = np.sqrt(L2**2 - (L3 * np.sin(beta) - L1 * np.sin(alpha)) ** 2)
        C = np.array([L1 * np.cos(alpha) + bm, L3 * np.sin(beta)])
        Gc = 0.5 * np.array([2 * L1 * np.cos(alpha) + bm, L3 * np.sin(beta) + L1 * np.sin(alpha)])
        gamma = np.arcsin((L3 * np.sin(beta) - L1 * np.sin(alpha)) / L2)
        assert Gc[0] + x1 == pytest.approx(pose[0], abs=1e-9)
        assert Gc[1] == pytest.approx(pose[1], abs=1e-9)
        assert gamma == pytest.approx(pose[2], abs=1e-9)
        assert C[0] + x1 == pytest.approx(pose[0] + 0.5 * L2 * np.cos(pose[2]), abs=1e-9)


def test_inverse_matches_paper_eq4() -> None:
    poses = random_poses(200, seed=4)
    x, y, g = poses.T
    L1, L2, L3, L4 = G.L1, G.L2, G.L3, G.L4
    X1 = x - L2 / 2 * np.cos(g) - L1 * np.cos(np.arcsin((y - L2 / 2 * np.sin(g)) / L1))
    X2 = x + L2 / 2 * np.cos(g) + L3 * np.cos(np.arcsin((y + L2 / 2 * np.sin(g)) / L3))
    X3 = (
        X1
        + L1 / 2 * np.cos(np.arcsin((y - L2 / 2 * np.sin(g)) / L1))
        + L4 * np.cos(np.arcsin((y - L2 / 2 * np.sin(g)) / (2 * L4)))
    )
    np.testing.assert_allclose(parallel.inverse(G, poses), np.column_stack([X1, X2, X3]), atol=1e-12)


@pytest.mark.parametrize(
    ("pose", "condition"),
    [
        ([0.0, 0.45, 0.0], "AB reaches the rail"),
        ([0.0, -0.05, 0.0], "B above the rail"),
        ([0.0, 0.10, 1.2], "B above the rail"),
        ([0.0, np.nan, 0.0], "finite pose"),
    ],
)
def test_inverse_refuses_outside_workspace(pose: list[float], condition: str) -> None:
    with pytest.raises(OutsideWorkspace) as err:
        parallel.inverse(G, np.array([[0.0, 0.25, 0.0], pose]))
    assert condition in err.value.details["condition"]
    assert err.value.details["index"] == 1


@pytest.mark.parametrize(
    ("sliders", "condition"),
    [
        ([0.0, 0.5, -0.1], "F right of A"),
        ([-0.9, 0.5, 0.0], "triangle AEF closes"),
        ([-0.46, 1.5, -0.09], "circles about B"),
        ([-0.46, 0.46, -0.34], "A left of B"),
        ([-0.46, 0.1, -0.09], "D right of C"),
        ([np.inf, 0.46, -0.09], "finite sliders"),
    ],
)
def test_forward_refuses_off_branch(sliders: list[float], condition: str) -> None:
    with pytest.raises(OutsideWorkspace) as err:
        parallel.forward(G, np.array(sliders))
    assert condition in err.value.details["condition"]


def test_measures_detect_both_singularity_types(robot: Cabin8) -> None:
    # Type II: C on the line BD -> sin(CBD) = 0; the stage Jacobian blows up as it approaches.
    q = robot.joints_from_drives(robot.home_drives)
    conds = []
    for x2 in (0.46, 0.48, 0.49, 0.50):
        u = robot.home_drives.copy()
        u[2] = x2
        qq = robot.joints_from_drives(u)
        conds.append(
            (parallel.stage_measures(G, *qq[1:4])["sin_cbd"], np.linalg.cond(robot.stage_jacobian(qq)))
        )
    sins, cond = zip(*conds, strict=True)
    assert all(np.diff(sins) < 0) and all(np.diff(cond) > 0)
    # Type I: a link perpendicular to the rail (y_B -> L1) makes du/dq unbounded.
    G_, _ = robot.drive_map_jacobian(q)
    hi = q.copy()
    hi[2] = 0.39
    hi[3] = 0.0
    G_hi, _ = robot.drive_map_jacobian(hi)
    assert np.abs(G_hi).max() > 3 * np.abs(G_).max()


@settings(max_examples=300, deadline=None)
@given(
    x=st.floats(-0.25, 0.25),
    y=st.floats(0.10, 0.36),
    gamma=st.floats(-0.349, 0.349),
)
def test_round_trip_property(x: float, y: float, gamma: float) -> None:
    pose = np.array([x, y, gamma])
    with np.errstate(invalid="ignore"):
        m = parallel.stage_measures(G, x, y, gamma)
    if not (m["sin_cbd"] > 0.05 and m["h_ab"] < 0.99 and m["h_cd"] < 0.99 and m["h_ef"] < 0.99):
        return
    back = parallel.forward(G, parallel.inverse(G, pose))
    assert np.max(np.abs(back - pose)) < 1e-9


@settings(max_examples=300, deadline=None)
@given(x1=st.floats(-0.8, 0.1), x2=st.floats(-0.1, 0.8), x3=st.floats(-0.4, 0.3))
def test_forward_either_assembles_or_refuses(x1: float, x2: float, x3: float) -> None:
    """Any slider triple gives a pose that maps back to it, or a clear OutsideWorkspace."""
    u = np.array([x1, x2, x3])
    try:
        pose = parallel.forward(G, u)
    except OutsideWorkspace as exc:
        assert exc.details["condition"]
        return
    assert np.all(np.isfinite(pose))
    np.testing.assert_allclose(parallel.inverse(G, pose), u, atol=1e-8)
