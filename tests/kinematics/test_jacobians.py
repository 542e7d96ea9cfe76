"""Every Jacobian against central finite differences (step 1e-6), J-dot q-dot against d/dt along paths."""

from __future__ import annotations

import numpy as np

from planner.core.so3 import rotation_log
from planner.robots.cabin8 import Cabin8

H = 1e-6


def twist_fd(robot: Cabin8, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
    """Tool twist (v; omega) of the motion q + t dq at t = 0, by central differences of the FK."""
    Tp, Tm = robot.fk(q + H * dq), robot.fk(q - H * dq)
    v = (Tp[:3, 3] - Tm[:3, 3]) / (2 * H)
    w = rotation_log(Tp[:3, :3] @ Tm[:3, :3].T) / (2 * H)
    return np.concatenate([v, w])


def test_joint_jacobian_matches_fd(robot: Cabin8, configs: np.ndarray) -> None:
    worst = 0.0
    for q in configs[:100]:
        J = robot.jacobian(q)
        fd = np.column_stack([twist_fd(robot, q, e) for e in np.eye(8)])
        worst = max(worst, float(np.abs(J - fd).max()))
    assert worst < 1e-7


def test_drive_jacobian_matches_fd_through_the_stage(robot: Cabin8, configs: np.ndarray) -> None:
    worst = 0.0
    for q in configs[:100]:
        u = robot.drives_from_joints(q)
        Ju = robot.drive_jacobian(q)
        cols = []
        for e in np.eye(8):
            Tp = robot.fk(robot.joints_from_drives(u + H * e))
            Tm = robot.fk(robot.joints_from_drives(u - H * e))
            v = (Tp[:3, 3] - Tm[:3, 3]) / (2 * H)
            w = rotation_log(Tp[:3, :3] @ Tm[:3, :3].T) / (2 * H)
            cols.append(np.concatenate([v, w]))
        worst = max(worst, float(np.abs(Ju - np.column_stack(cols)).max()))
    assert worst < 1e-6


def test_stage_and_drive_map_jacobians(robot: Cabin8, configs: np.ndarray) -> None:
    for q in configs[:100]:
        G, G_inv = robot.drive_map_jacobian(q)
        fd = np.column_stack(
            [
                (robot.drives_from_joints(q + H * e) - robot.drives_from_joints(q - H * e)) / (2 * H)
                for e in np.eye(8)
            ]
        )
        assert np.abs(G - fd).max() < 1e-6
        np.testing.assert_allclose(G @ G_inv, np.eye(8), atol=1e-9)
        u = robot.drives_from_joints(q)
        Jp = robot.stage_jacobian(q)
        fd_p = np.column_stack(
            [
                (robot.joints_from_drives(u + H * e)[1:4] - robot.joints_from_drives(u - H * e)[1:4])
                / (2 * H)
                for e in np.eye(8)[1:4]
            ]
        )
        assert np.abs(Jp - fd_p).max() < 1e-5 * max(1.0, np.abs(Jp).max())


def test_constraint_jacobian_matches_fd(robot: Cabin8, configs: np.ndarray) -> None:
    for q in configs[:50]:
        _, dc = robot.constraint_values(q)
        fd = np.column_stack(
            [
                (robot.constraint_values(q + H * e)[0] - robot.constraint_values(q - H * e)[0]) / (2 * H)
                for e in np.eye(8)
            ]
        )
        assert np.abs(dc - fd).max() < 1e-6


def _path(q0: np.ndarray, t: float, rng_amp: np.ndarray, freq: np.ndarray) -> tuple[np.ndarray, ...]:
    q = q0 + rng_amp * np.sin(freq * t)
    qd = rng_amp * freq * np.cos(freq * t)
    qdd = -rng_amp * freq**2 * np.sin(freq * t)
    return q, qd, qdd


def test_jdot_qdot_matches_derivative_along_trajectories(robot: Cabin8, configs: np.ndarray) -> None:
    """Tool acceleration = J q_ddot + J_dot q_dot, checked against d/dt of J(q(t)) q_dot(t)."""
    rng = np.random.default_rng(3)
    for q0 in configs[:40]:
        amp = rng.uniform(-0.02, 0.02, 8)
        freq = rng.uniform(0.5, 3.0, 8)
        t, h = 0.3, 1e-5
        q, qd, qdd = _path(q0, t, amp, freq)
        qp, qdp, _ = _path(q0, t + h, amp, freq)
        qm, qdm, _ = _path(q0, t - h, amp, freq)
        acc_fd = (robot.jacobian(qp) @ qdp - robot.jacobian(qm) @ qdm) / (2 * h)
        acc = robot.jacobian(q) @ qdd + robot.jdot_qdot(q, qd)
        assert np.abs(acc - acc_fd).max() < 1e-7


def test_drive_space_bias_matches_derivative(robot: Cabin8, configs: np.ndarray) -> None:
    """The same in drive space: tool acceleration = J_u u_ddot + jdot_udot(q, u_dot) along u(t)."""
    rng = np.random.default_rng(4)
    for q0 in configs[:40]:
        u0 = robot.drives_from_joints(q0)
        amp = rng.uniform(-0.002, 0.002, 8)  # stay inside the admissible stage workspace
        freq = rng.uniform(0.5, 3.0, 8)
        t, h = 0.2, 1e-5
        u, ud, udd = _path(u0, t, amp, freq)
        up, udp, _ = _path(u0, t + h, amp, freq)
        um, udm, _ = _path(u0, t - h, amp, freq)
        qp, qm = robot.joints_from_drives(up), robot.joints_from_drives(um)
        acc_fd = (robot.drive_jacobian(qp) @ udp - robot.drive_jacobian(qm) @ udm) / (2 * h)
        q = robot.joints_from_drives(u)
        acc = robot.drive_jacobian(q) @ udd + robot.jdot_udot(q, ud)
        assert not robot.violations(q)
        assert np.abs(acc - acc_fd).max() < 1e-6 * (1.0 + np.abs(acc).max())
