"""Inverse dynamics by physics: power balance, gravity = grad U, virtual work, two independent routes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from planner.core.exceptions import InvalidInput
from planner.dynamics.lagrange import Cabin8Dynamics
from planner.dynamics.payload import RigidPayload, box_inertia
from planner.robots.cabin8 import Cabin8


@pytest.fixture(scope="module")
def dyn(robot: Cabin8) -> Cabin8Dynamics:
    return Cabin8Dynamics(robot)


@pytest.fixture(scope="module")
def payload() -> RigidPayload:
    grasp = np.eye(4)
    grasp[:3, 3] = [0.0, 0.0, 0.30]
    inertia = box_inertia(100.0, (0.45, 0.35, 0.50))
    return RigidPayload.from_grasp(100.0, np.array([0.02, -0.01, 0.03]), inertia, grasp)


def trajectory(q0: np.ndarray, t: float, amp: np.ndarray, freq: np.ndarray) -> tuple[np.ndarray, ...]:
    return q0 + amp * np.sin(freq * t), amp * freq * np.cos(freq * t), -amp * freq**2 * np.sin(freq * t)


def test_power_balance_along_random_trajectories(
    robot: Cabin8, dyn: Cabin8Dynamics, payload: RigidPayload, configs: np.ndarray
) -> None:
    """tau_q . q_dot = dE/dt with E = T + U (no friction): the generalised forces do exactly the work."""
    rng = np.random.default_rng(11)
    for q0 in configs[:25]:
        amp = rng.uniform(-0.05, 0.05, 8)
        freq = rng.uniform(0.3, 2.0, 8)
        for t in (0.1, 0.7, 1.3):
            q, qd, qdd = trajectory(q0, t, amp, freq)
            tau, _ = dyn.inverse_dynamics(q, qd, qdd, payload)
            h = 1e-5
            e = [sum(dyn.energy(*trajectory(q0, t + s, amp, freq)[:2], payload)) for s in (-h, h)]
            de_dt = (e[1] - e[0]) / (2 * h)
            assert tau @ qd == pytest.approx(de_dt, rel=1e-6, abs=1e-6)


def test_static_forces_are_the_gradient_of_potential(
    dyn: Cabin8Dynamics, payload: RigidPayload, configs: np.ndarray
) -> None:
    zero = np.zeros(8)
    for q in configs[:30]:
        tau, _ = dyn.inverse_dynamics(q, zero, zero, payload)
        h = 1e-6
        grad = np.array(
            [
                (dyn.energy(q + h * e, zero, payload)[1] - dyn.energy(q - h * e, zero, payload)[1]) / (2 * h)
                for e in np.eye(8)
            ]
        )
        np.testing.assert_allclose(tau, grad, atol=1e-5 * max(1.0, np.abs(grad).max()))
        assert tau[0] == pytest.approx(0.0, abs=1e-9), "the rail is horizontal: no static rail force"


def test_drive_forces_by_virtual_work(
    robot: Cabin8, dyn: Cabin8Dynamics, payload: RigidPayload, configs: np.ndarray
) -> None:
    rng = np.random.default_rng(5)
    for q in configs[:30]:
        qd, qdd = rng.normal(size=8) * 0.1, rng.normal(size=8) * 0.2
        tau_q, tau_u = dyn.inverse_dynamics(q, qd, qdd, payload)
        G, _ = robot.drive_map_jacobian(q)
        for dq in rng.normal(size=(3, 8)):
            du = G @ dq
            assert tau_u @ du == pytest.approx(tau_q @ dq, rel=1e-9, abs=1e-9)


def test_lagrange_and_dalembert_routes_agree(
    dyn: Cabin8Dynamics, payload: RigidPayload, configs: np.ndarray
) -> None:
    rng = np.random.default_rng(6)
    for q in configs[:30]:
        qd, qdd = rng.normal(size=8) * 0.3, rng.normal(size=8)
        a, _ = dyn.inverse_dynamics(q, qd, qdd, payload)
        b = dyn.inverse_dynamics_lagrange(q, qd, qdd, payload)
        np.testing.assert_allclose(a, b, atol=1e-9 * max(1.0, np.abs(b).max()))


def test_mass_matrix_symmetric_positive_definite(
    dyn: Cabin8Dynamics, payload: RigidPayload, configs: np.ndarray
) -> None:
    for q in configs[:30]:
        M, _, _ = dyn.terms(q, np.zeros(8), payload)
        np.testing.assert_allclose(M, M.T, atol=1e-9)
        assert np.linalg.eigvalsh(M).min() > 0
        # The rail carries every mass: M[d1, d1] is the robot's total mass plus the payload.
        total = sum(dyn.robot.desc.masses.model_dump().values()) + payload.mass
        assert M[0, 0] == pytest.approx(total, rel=1e-12)


def test_drive_efforts_match_joint_route(
    robot: Cabin8, dyn: Cabin8Dynamics, payload: RigidPayload, configs: np.ndarray
) -> None:
    rng = np.random.default_rng(8)
    q = configs[:10]
    u = robot.drives_from_joints(q)
    ud, udd = rng.normal(size=(10, 8)) * 0.05, rng.normal(size=(10, 8)) * 0.1
    efforts = dyn.drive_efforts(u, ud, udd, payload)
    for i in range(10):
        _, G_inv = robot.drive_map_jacobian(q[i])
        qd = G_inv @ ud[i]
        # q_ddot from the time derivative of u = g(q): u_ddot = G q_ddot + G_dot q_dot.
        h = 1e-6
        Gp, _ = robot.drive_map_jacobian(q[i] + h * qd)
        Gm, _ = robot.drive_map_jacobian(q[i] - h * qd)
        gdot_qd = (Gp - Gm) / (2 * h) @ qd
        qdd = G_inv @ (udd[i] - gdot_qd)
        _, tau_u = dyn.inverse_dynamics(q[i], qd, qdd, payload)
        np.testing.assert_allclose(efforts[i], tau_u, atol=1e-5 * max(1.0, np.abs(tau_u).max()))


def test_payload_weight_shows_in_rail_free_directions(
    robot: Cabin8, dyn: Cabin8Dynamics, configs: np.ndarray
) -> None:
    """Adding a point payload of mass m at the tool origin adds exactly -m g . dp/dq to the static forces."""
    zero = np.zeros(8)
    point = RigidPayload(50.0)
    for q in configs[:20]:
        base, _ = dyn.inverse_dynamics(q, zero, zero)
        loaded, _ = dyn.inverse_dynamics(q, zero, zero, point)
        Jv = robot.jacobian(q)[:3]
        expected = -50.0 * Jv.T @ np.array(robot.desc.gravity_m_s2)
        np.testing.assert_allclose(loaded - base, expected, atol=1e-8)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"mass": -1.0}, "payload.mass"),
        ({"mass": float("nan")}, "payload.mass"),
        ({"mass": 1.0, "inertia_tool": np.diag([1.0, 1.0, 3.0])}, "payload.inertia"),
        (
            {"mass": 1.0, "inertia_tool": np.array([[1.0, 0.5, 0], [0, 1.0, 0], [0, 0, 1.0]])},
            "payload.inertia",
        ),
        ({"mass": 1.0, "com_tool": np.array([0.0, np.inf, 0.0])}, "payload.com"),
    ],
)
def test_payload_validation(kwargs: dict, field: str) -> None:
    with pytest.raises(InvalidInput) as err:
        RigidPayload(**kwargs)
    assert err.value.details["field"] == field


def test_native_build_matches_the_casadi_virtual_machine(
    robot: Cabin8, dyn: Cabin8Dynamics, payload: RigidPayload, configs: np.ndarray
) -> None:
    """The C build (single and mapped calls) gives the interpreter's numbers, to rounding."""
    rng = np.random.default_rng(5)
    q = configs[:40]
    qd, qdd = rng.normal(0.0, 0.2, q.shape), rng.normal(0.0, 0.5, q.shape)
    p = payload.params()
    ref = np.array([dyn.id_vm(q[i], qd[i], qdd[i], p)[1] for i in range(len(q))])
    single = np.array([dyn.inverse_dynamics(q[i], qd[i], qdd[i], payload)[1] for i in range(len(q))])
    batch = dyn.drive_forces_batch(q, qd, qdd, payload)
    scale = np.max(np.abs(ref))
    assert np.max(np.abs(single - ref)) <= 1e-12 * scale
    assert np.max(np.abs(batch - ref)) <= 1e-12 * scale


def test_native_build_falls_back_to_the_given_functions(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    import casadi as ca

    from planner.kinematics.native import native

    x = ca.SX.sym("x", 2)
    fn = ca.Function("sq", [x], [x * x])
    monkeypatch.setenv("CABINPLAN_NATIVE", "0")
    assert native([fn], "test_sq")[0] is fn
    monkeypatch.setenv("CABINPLAN_NATIVE", "1")
    monkeypatch.setenv("CC", "/nonexistent/cc")  # a compiler that cannot run: the VM, with a warning
    monkeypatch.setenv("CABINPLAN_CACHE_DIR", str(tmp_path))
    assert native([fn], "test_sq")[0] is fn
    monkeypatch.delenv("CC")
    built = native([fn], "test_sq")[0]  # a real build where a compiler exists
    assert float(built(ca.DM([3.0, -2.0]))[1]) == 4.0


def test_dynamics_are_built_once_per_model(robot: Cabin8) -> None:
    assert Cabin8Dynamics.of(robot) is Cabin8Dynamics.of(robot)


def test_batched_joint_rates_match_the_single_route(
    robot: Cabin8, dyn: Cabin8Dynamics, configs: np.ndarray
) -> None:
    """The mapped (native) joint-rate map equals the per-sample one on a batch past SMALL_BATCH."""
    rng = np.random.default_rng(9)
    q = configs[:60]
    ud, udd = rng.normal(size=q.shape) * 0.05, rng.normal(size=q.shape) * 0.1
    qd, qdd = dyn.joint_rates_batch(q, ud, udd)
    for i in range(len(q)):
        qd_i, qdd_i = dyn.joint_rates(q[i], ud[i], udd[i])
        np.testing.assert_allclose(qd[i], qd_i, rtol=0, atol=1e-12)
        np.testing.assert_allclose(qdd[i], qdd_i, rtol=0, atol=1e-10)
    # And G q_dot is the drive velocity (the map inverts the drive Jacobian).
    G = np.array([robot.drive_map_jacobian(qi)[0] for qi in q])
    np.testing.assert_allclose(np.einsum("nij,nj->ni", G, qd), ud, atol=1e-12)


@pytest.mark.parametrize("n", [1, 30, 33, 300])
def test_static_forces_are_the_inverse_dynamics_at_rest(
    dyn: Cabin8Dynamics, payload: RigidPayload, configs: np.ndarray, n: int
) -> None:
    """The gravity-only map equals tau_u(q, 0, 0) for batch sizes on both sides of each chunk."""
    q = np.resize(configs, (n, 8))
    z = np.zeros_like(q)
    static = dyn.static_forces_batch(q, payload)
    full = np.array([dyn.id_vm(q[i], z[i], z[i], payload.params())[1] for i in range(n)])
    assert static.shape == (n, 8)
    np.testing.assert_allclose(static, full, rtol=0, atol=1e-9 * np.abs(full).max())


def test_static_forces_do_not_change_along_the_rail(
    dyn: Cabin8Dynamics, payload: RigidPayload, configs: np.ndarray
) -> None:
    """Gravity is normal to the rail: a posture takes the same holding forces anywhere along it.

    None of them on the rail drive; the transit search checks a posture's forces once, whatever its d1.
    """
    base = dyn.static_forces_batch(configs, payload)
    for d1 in (0.0, 1.7, 5.9):
        moved = configs.copy()
        moved[:, 0] = d1
        np.testing.assert_allclose(
            dyn.static_forces_batch(moved, payload), base, rtol=0, atol=1e-9 * np.abs(base).max()
        )
    np.testing.assert_allclose(base[:, 0], 0.0, atol=1e-9 * np.abs(base).max())
    for i in range(3):  # the one-point route alike
        np.testing.assert_allclose(
            dyn.static_forces_batch(configs[i], payload)[0], base[i], rtol=0, atol=1e-9
        )


def test_one_configurations_holding_verdict_is_the_batch_figures_bit_for_bit(
    dyn: Cabin8Dynamics, payload: RigidPayload, configs: np.ndarray
) -> None:
    """StaticForceCheck.ok (a sampling planner's every state) = ratios' row: the same forces and verdict.

    ``static_forces`` is the one-configuration row of ``static_forces_batch`` (bit for bit); the check's
    verdict is its ratio against the fraction, held and not held both seen (a heavy payload).
    """
    from planner.dynamics.holding import StaticForceCheck

    for q in configs[:2]:
        assert dyn.static_forces(q, payload).tobytes() == dyn.static_forces_batch(q, payload)[0].tobytes()
    heavy = RigidPayload.from_grasp(
        400.0, np.array([0.02, -0.01, 0.03]), box_inertia(400.0, (0.45, 0.35, 0.5)), np.eye(4)
    )
    check = StaticForceCheck(dyn, heavy)
    rng = np.random.default_rng(3)
    qs = np.resize(configs, (400, 8)) + rng.normal(0.0, 0.2, (400, 8)) * np.array([0, 0, 0, 0, 1, 1, 0.2, 1])
    verdicts = [check.ok(q) for q in qs]
    assert verdicts == (check.ratios(qs) <= check.fraction).tolist()
    assert any(verdicts) and not all(verdicts)
