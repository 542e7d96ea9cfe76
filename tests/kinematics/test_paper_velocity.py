"""The paper's closed-form stage velocity relations and acceleration terms as oracles (issue 15).

hybrid-8dof-cabin-robot, section 2.2-2.3 (eq. 14-25) and 3.1 (eq. 35-46), evaluated as printed and with the
typos fixed where the fix is certain, against the CasADi AD Jacobians (``Cabin8.stage_jacobian`` = G_p^-1,
``Cabin8.jdot_qdot``). The paper's inputs are ``V_0`` (slider A), ``V_2`` (slider F) and ``V_3`` (slider D)
with V_2, V_3 *relative to A* (its eq. 9 measures from slider A), so ``(x1, x2, x3)_dot = M (V_0, V_2,
V_3)``; its angles are alpha (AB at A), epsilon (EF at F), beta (CD at D), measured from the rail inside the
mechanism, and gamma our platform angle. Its perpendicular direction to BC is ``(sin g, -cos g)`` (eq. 21),
so its ``W_gamma = (m - V_BC^t) / L2`` (eq. 23) is *minus* our gamma rate. README "Where we read the paper
differently" lists the outcome entry by entry.
"""

from __future__ import annotations

import numpy as np
import pytest

from planner.kinematics import chain, parallel
from planner.robots.cabin8 import Cabin8
from tests.conftest import admissible_joints

#: (x1, x2, x3)_dot from (V_0, V_2, V_3): A moves with V_0, D with V_0 + V_3, F with V_0 + V_2.
M = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 1.0], [1.0, 1.0, 0.0]])
#: The paper's output (V_X, V_Y, W_gamma) from ours (x_dot, y_dot, gamma_dot).
S = np.diag([1.0, 1.0, -1.0])


def _angles(robot: Cabin8, q: np.ndarray) -> tuple[float, float, float, float]:
    p = parallel.stage_points(robot.geometry, q[chain.X], q[chain.Y], q[chain.GAMMA])
    (ax, ay), (bx, by), (cx, cy), (dx, dy), (ex, ey), (fx, fy) = (tuple(map(float, pt)) for pt in p)
    alpha = np.arctan2(by - ay, bx - ax)
    eps = np.arctan2(ey - fy, fx - ex)
    beta = np.arctan2(cy - dy, dx - cx)
    return float(alpha), float(eps), float(beta), float(q[chain.GAMMA])


def paper_chain(robot: Cabin8, q: np.ndarray, v: np.ndarray, corrected: bool) -> np.ndarray:
    """(V_X, V_Y, W_gamma) by eq. 17, 19, 22, 23 (printed, or eq. 23 per the paper's own rule)."""
    a, e, b, g = _angles(robot, q)
    L2 = robot.geometry.L2
    V0, V2, V3 = v
    VB = 2 * V2 * np.cos(e) / np.sin(a + e)  # eq. 17
    n, t = VB * np.sin(a - g), VB * np.cos(a - g)  # eq. 19
    m = -2 * np.cos(e) * np.sin(a - g) / np.tan(b + g) / np.sin(a + e) * V2 + V3 * np.cos(b) / np.sin(b + g)
    if corrected:  # the rule the text states: V_K^t = (GI + V_BC^t) / 2, V_K^n = V_BC^n
        VX = n * np.cos(g) + 0.5 * (m + t) * np.sin(g) + V0
        VY = n * np.sin(g) - 0.5 * (m + t) * np.cos(g)
    else:  # eq. 23 as printed
        VX = 0.5 * (m * np.sin(g) + n * np.cos(g)) + V0
        VY = 0.5 * (n * np.sin(g) - m * np.cos(g))
    return np.array([VX, VY, (m - t) / L2])


def paper_j1(robot: Cabin8, q: np.ndarray) -> np.ndarray:
    """J_1 of eq. 25 as printed (cos(lambda) of J12, undefined in the paper, read as cos(gamma))."""
    a, e, b, g = _angles(robot, q)
    L2 = robot.geometry.L2
    s, c = np.sin, np.cos

    def cot(x: float) -> float:
        return float(1.0 / np.tan(x))

    return np.array(
        [
            [1.0, c(e) * s(a - g) * (c(g) - cot(g + b) * s(g)) / s(a + b), c(b) * s(g) / s(g + b)],
            [0.0, -c(b) * c(g) / (2 * s(g + b)), c(e) * s(a - g) * (s(g) + c(g) * cot(g + b)) / s(a + e)],
            [0.0, 2 * c(e) * (c(a - g) - s(a - g) * cot(b + g)) / (L2 * s(a + e)), c(b) / (L2 * s(g + b))],
        ]
    )


@pytest.fixture(scope="module")
def samples(robot: Cabin8) -> np.ndarray:
    return admissible_joints(robot, 25, seed=15)


def _ours(robot: Cabin8, q: np.ndarray) -> np.ndarray:
    return S @ robot.stage_jacobian(q) @ M


def test_eq14_sine_rule_holds(robot: Cabin8, samples: np.ndarray) -> None:
    for q in samples:
        a, e, _, _ = _angles(robot, q)
        assert e == pytest.approx(
            np.arcsin(robot.geometry.L1 * np.sin(a) / (2 * robot.geometry.L4)), abs=1e-12
        )


def test_eq23_with_the_stated_rule_is_the_ad_jacobian(robot: Cabin8, samples: np.ndarray) -> None:
    """Eq. 15-22 hold; eq. 23 holds once written as the paper's own rule V_K^t = (GI + V_BC^t)/2."""
    for q in samples:
        J = np.column_stack([paper_chain(robot, q, np.eye(3)[k], corrected=True) for k in range(3)])
        np.testing.assert_allclose(J, _ours(robot, q), rtol=1e-9, atol=1e-9)


def test_eq23_as_printed_does_not_hold(robot: Cabin8, samples: np.ndarray) -> None:
    """Printed eq. 23 halves V_BC^n and drops V_BC^t: its V_X, V_Y miss; its W_gamma is right."""
    misses = 0
    for q in samples:
        J = np.column_stack([paper_chain(robot, q, np.eye(3)[k], corrected=False) for k in range(3)])
        ours = _ours(robot, q)
        np.testing.assert_allclose(J[2], ours[2], rtol=1e-9, atol=1e-9)
        misses += not np.allclose(J[:2], ours[:2], rtol=1e-3, atol=1e-6)
    assert misses == len(samples)


def test_eq25_entries_that_hold_and_those_that_do_not(robot: Cabin8, samples: np.ndarray) -> None:
    """J11, J21, J31, J33 hold as printed; printed J22 is the J23 entry; J12, J13, J23, J32 do not hold."""
    holds = np.zeros((3, 3), dtype=int)
    for q in samples:
        Jp, ours = paper_j1(robot, q), _ours(robot, q)
        holds += np.isclose(Jp, ours, rtol=1e-9, atol=1e-12)
        assert Jp[1, 1] == pytest.approx(ours[1, 2], rel=1e-9)  # printed J22 = our J23 (entries swapped)
        assert Jp[0, 2] == pytest.approx(2 * ours[0, 2], rel=1e-9)  # printed J13 lacks eq. 23's 1/2
    n = len(samples)
    assert holds[0, 0] == holds[1, 0] == holds[2, 0] == holds[2, 2] == n
    assert holds[0, 1] == holds[0, 2] == holds[1, 1] == holds[1, 2] == holds[2, 1] == 0


def test_eq35_40_stage_acceleration(robot: Cabin8, samples: np.ndarray) -> None:
    """Eq. 35/40: platform acceleration = J1 v_dot + (v^T H) v with H = dJ1/d(inputs), the closed form J1.

    J1 is the corrected closed form of eq. 23 (differentiated by central differences along the input
    velocity: dJ1/dt = sum_k v_k dJ1/ds_k, eq. 38-40); the reference is the AD drive map,
    q_ddot = G^-1 (u_ddot - G_dot q_dot).
    """
    rng = np.random.default_rng(3)
    h = 1e-6
    for q in samples[:10]:
        v, vd = rng.normal(size=3) * 0.05, rng.normal(size=3) * 0.1

        def J1_at(qq: np.ndarray) -> np.ndarray:
            return np.column_stack([paper_chain(robot, qq, np.eye(3)[k], corrected=True) for k in range(3)])

        u = robot.drives_from_joints(q)
        du = np.zeros(8)
        du[1:4] = M @ v
        qp, qm = robot.joints_from_drives(u + h * du), robot.joints_from_drives(u - h * du)
        J1dot = (J1_at(qp) - J1_at(qm)) / (2 * h)
        acc_paper = J1dot @ v + J1_at(q) @ vd
        # Reference: second derivative of the closed-form forward stage along u(t) = u + t du + t^2/2 ddu.
        ddu = np.zeros(8)
        ddu[1:4] = M @ vd
        tt = 1e-4
        qs = [robot.joints_from_drives(u + s * tt * du + 0.5 * (s * tt) ** 2 * ddu) for s in (-1, 0, 1)]
        acc_ref = S @ ((qs[2] - 2 * qs[1] + qs[0])[1:4] / tt**2)
        np.testing.assert_allclose(acc_paper, acc_ref, rtol=1e-4, atol=1e-6)


def test_eq41_46_serial_bias_is_the_hessian_contraction(robot: Cabin8, samples: np.ndarray) -> None:
    """Eq. 41-46: J_dot q_dot = q_dot^T [H] q_dot, H the second-order influence coefficients dJ/dq.

    Against the AD bias ``jdot_qdot`` (the whole chain, stage included), H by central differences of J_q.
    """
    rng = np.random.default_rng(4)
    h = 1e-6
    for q in samples[:10]:
        qd = rng.normal(size=8) * 0.1
        H = np.stack(
            [
                (robot.fk_jacobians(q + h * e)[1] - robot.fk_jacobians(q - h * e)[1]) / (2 * h)
                for e in np.eye(8)
            ]
        )  # H[k] = dJ/dq_k, (8, 6, 8)
        bias = np.einsum("k,kij,j->i", qd, H, qd)
        np.testing.assert_allclose(robot.jdot_qdot(q, qd), bias, rtol=1e-6, atol=1e-8)
