"""Forward kinematics: three independent routes agree (CasADi, numpy batch, the paper's eq. 13)."""

from __future__ import annotations

import numpy as np
import pytest

from planner.robots.cabin8 import Cabin8

A2, A3, A4, D3, D6 = 0.0, 0.485, 0.050, 0.261, 0.010


def paper_eq13(q: np.ndarray) -> np.ndarray:
    """T_base_tool by the paper's closed form (eq. 13), with its three OCR typos corrected.

    * n_z is printed ``-c3 c6 - s4 s6 - s3``; the product rule gives ``-c3 c6 - s3 s4 s6``;
    * o_x is printed ``... - (sin a) c6 c4 - (cos a) c3 c4``; it is
      ``cos a s3 s6 - c6 (sin a c4 - cos a c3 s4)`` (o_y rotated by -90 deg, as n_x is n_y rotated);
    * p_y prints ``-a4 [s4 cos a - sin a c3 s4]`` and ``-d6 [s4 cos a + sin a c3 c4]``; both brackets are
      ``a_y``-shaped: ``s4 cos a - sin a c3 c4`` (like p_x, whose a4 and d6 terms are a4 a_x and d6 a_x).
    """
    d1, X, Y, al, t3, t4, d5, t6 = q
    c3, s3, c4, s4, c6, s6 = np.cos(t3), np.sin(t3), np.cos(t4), np.sin(t4), np.cos(t6), np.sin(t6)
    ca, sa = np.cos(al), np.sin(al)
    n = [
        -s6 * (c4 * sa - ca * c3 * s4) - c6 * ca * s3,
        s6 * (c4 * ca + sa * c3 * s4) - c6 * sa * s3,
        -c3 * c6 - s3 * s4 * s6,
    ]
    o = [
        ca * s3 * s6 - c6 * (sa * c4 - ca * c3 * s4),
        c6 * (ca * c4 + c3 * s4 * sa) + sa * s3 * s6,
        c3 * s6 - s3 * c6 * s4,
    ]
    a = [s4 * sa + ca * c3 * c4, c4 * c3 * sa - ca * s4, -s3 * c4]
    p = [
        X
        + A2 * ca
        - D3 * sa
        + A4 * (s4 * sa + ca * c3 * c4)
        + d5 * (c4 * sa - ca * c3 * s4)
        + D6 * (s4 * sa + ca * c3 * c4)
        + A3 * ca * c3,
        Y
        + D3 * ca
        + A2 * sa
        - A4 * (s4 * ca - sa * c3 * c4)
        - d5 * (c4 * ca + sa * c3 * s4)
        - D6 * (s4 * ca - sa * c3 * c4)
        + A3 * sa * c3,
        d1 - A3 * s3 - A4 * s3 * c4 - s3 * c4 * D6 + s3 * d5 * s4,
    ]
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = n, o, a, p
    return T


def test_casadi_numpy_and_paper_agree(robot: Cabin8) -> None:
    rng = np.random.default_rng(7)
    q = rng.uniform(-3, 3, size=(500, 8))
    batch = robot.fk_batch(q)
    frames = robot.frames(q)
    for i in range(q.shape[0]):
        T = robot.fk(q[i])
        np.testing.assert_allclose(T, batch[i], atol=1e-12)
        np.testing.assert_allclose(T, frames[i, 6], atol=1e-12)
        np.testing.assert_allclose(T, paper_eq13(q[i]), atol=1e-12)


def test_frames_are_rigid_transforms(robot: Cabin8, configs: np.ndarray) -> None:
    frames = robot.frames(configs)
    R = frames[..., :3, :3]
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_allclose(frames[..., 3, :], np.broadcast_to([0, 0, 0, 1.0], frames[..., 3, :].shape))


def test_link_lengths_from_table1(robot: Cabin8, configs: np.ndarray) -> None:
    f = robot.frames(configs)
    o = f[..., :3, 3]
    # Column 0.261 m straight up the platform's y axis; arm 0.485 m; slide offset 0.05 m and d5.
    np.testing.assert_allclose(np.linalg.norm(o[:, 3] - o[:, 2], axis=1), D3, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(o[:, 4] - o[:, 3], axis=1), A3, atol=1e-12)
    np.testing.assert_allclose(
        np.linalg.norm(o[:, 5] - o[:, 4], axis=1), np.hypot(A4, configs[:, 6]), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.norm(o[:, 6] - o[:, 5], axis=1), D6, atol=1e-12)
    # The rail moves everything along z and nothing else.
    shifted = configs.copy()
    shifted[:, 0] += 0.7
    np.testing.assert_allclose(
        robot.fk_batch(shifted)[:, :3, 3] - robot.fk_batch(configs)[:, :3, 3],
        np.broadcast_to([0, 0, 0.7], (len(configs), 3)),
        atol=1e-12,
    )


def test_drive_joint_maps_round_trip(robot: Cabin8, configs: np.ndarray) -> None:
    u = robot.drives_from_joints(configs)
    np.testing.assert_allclose(robot.joints_from_drives(u), configs, atol=1e-9)
    np.testing.assert_array_equal(u[:, [0, 4, 5, 6, 7]], configs[:, [0, 4, 5, 6, 7]])


@pytest.mark.parametrize("n", [1, 7])
def test_batch_shapes(robot: Cabin8, configs: np.ndarray, n: int) -> None:
    assert robot.fk_batch(configs[:n]).shape == (n, 4, 4)
    assert robot.frames(configs[:n]).shape == (n, 7, 4, 4)


def test_rotation_angles_match_the_rotation_log_over_the_whole_range() -> None:
    """The vectorised angle equals |log R| from 0 to pi (near 0 and near pi included)."""
    from scipy.spatial.transform import Rotation

    from planner.core.so3 import rotation_angles, rotation_log

    rng = np.random.default_rng(4)
    axes = rng.normal(size=(200, 3))
    axes /= np.linalg.norm(axes, axis=1)[:, None]
    angles = np.concatenate([[0.0, 1e-9, 1e-4, np.pi - 1e-7, np.pi], rng.uniform(0.0, np.pi, 195)])
    R = Rotation.from_rotvec(axes * angles[:, None]).as_matrix()
    got = rotation_angles(R)
    np.testing.assert_allclose(got, angles, atol=1e-7)
    np.testing.assert_allclose(got, [np.linalg.norm(rotation_log(r)) for r in R], atol=1e-7)
