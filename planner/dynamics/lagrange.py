"""Inverse dynamics of cabin8: Lagrange equations (paper eq. 47-48), drive forces by virtual work (49-53).

Energy model (paper eq. 47 sums the kinetic and potential energy of every member; the paper gives no
numbers, the masses come from the description file):

* the carriage moves with the rail only: ``T = m v_d1^2 / 2``, constant height;
* every other member is a uniform slender bar between two points p0(q), p1(q) -- the stage links AB, CD,
  EF and the platform BC between their joint centres, the column, arm and slide between frame origins
  (2->3, 3->4, 4->6). Integrating over the bar gives the exact kinetic energy
  ``T = m (v0.v0 + v0.v1 + v1.v1) / 6`` (translation plus rotation normal to the bar; a slender bar has no
  inertia about its axis) and ``U = -m g.(p0 + p1)/2``;
* the tool is a point mass at the tool origin; the payload a rigid body with mass m, centre c and
  inertia I_c in the tool frame: ``T = m |v_c|^2 / 2 + omega^T R I_c R^T omega / 2``.
  Slider carriages are taken as massless (no mass is specified for them).

With L = T - U the generalised joint forces are
``tau_q = d/dt(dL/dq_dot) - dL/dq = M(q) q_ddot + (d(dT/dq_dot)/dq) q_dot - dT/dq + dU/dq``,
built by CasADi automatic differentiation and compiled once. Drive forces follow from virtual work:
``tau_q . dq = tau_u . du`` with ``du = G dq`` gives ``tau_u = G^-T tau_q = J_qu^T tau_q`` where
J_qu = dq/du (paper eq. 53 with the force Jacobian of the drive map).
"""

from __future__ import annotations

import weakref
from functools import cached_property

import casadi as ca
import numpy as np

from planner.core.types import Array
from planner.dynamics.payload import RigidPayload
from planner.kinematics import chain, parallel
from planner.kinematics.compiled import CHUNK, SMALL_CHUNK, FastFunction, dense_function, evaluate_mapped
from planner.kinematics.native import native
from planner.robots.cabin8 import Cabin8


def _bar(m: float, p0: ca.SX, p1: ca.SX, q: ca.SX, qd: ca.SX, g: ca.DM) -> tuple[ca.SX, ca.SX]:
    v0 = ca.mtimes(ca.jacobian(p0, q), qd)
    v1 = ca.mtimes(ca.jacobian(p1, q), qd)
    T = m / 6.0 * (ca.dot(v0, v0) + ca.dot(v0, v1) + ca.dot(v1, v1))
    U = -m * ca.dot(g, 0.5 * (p0 + p1))
    return T, U


class Cabin8Dynamics:
    """Compiled inverse dynamics and energies of a :class:`Cabin8` model.

    Every method takes the payload as a :class:`RigidPayload` (default: none).
    """

    @classmethod
    def of(cls, robot: Cabin8) -> Cabin8Dynamics:
        """The dynamics of ``robot``, built once per model object (building takes about 0.1 s)."""
        dyn = _BUILT.get(robot)
        if dyn is None:
            dyn = _BUILT[robot] = cls(robot)
        return dyn

    def __init__(self, robot: Cabin8) -> None:
        """Build (and compile) the dynamics of ``robot``; prefer :meth:`of`, which builds once per model."""
        self.robot = robot
        kin = robot.kin
        desc = robot.desc
        q, qd = kin.q_sx, kin.qd_sx
        qdd = ca.SX.sym("qdd", 8)
        par = ca.SX.sym("payload", 10)
        g = ca.DM(desc.gravity_m_s2)
        ms = desc.masses
        frames = kin.frames_sx
        pts = parallel.stage_points(kin.geometry, q[chain.X], q[chain.Y], q[chain.GAMMA], xp=ca)

        def p3(pt: tuple[ca.SX, ca.SX]) -> ca.SX:
            return ca.vertcat(pt[0], pt[1], q[chain.D1])

        def origin(i: int) -> ca.SX:
            return frames[i][0:3, 3]

        T_kin = 0.5 * ms.carriage * qd[chain.D1] ** 2
        U_pot = ca.SX(0)
        bars = [
            (ms.platform, p3(pts.B), p3(pts.C)),
            (ms.link_ab, p3(pts.A), p3(pts.B)),
            (ms.link_cd, p3(pts.C), p3(pts.D)),
            (ms.link_ef, p3(pts.E), p3(pts.F)),
            (ms.column, origin(2), origin(3)),
            (ms.arm, origin(3), origin(4)),
            (ms.slide, origin(4), origin(6)),
        ]
        for m, a, b in bars:
            t, u = _bar(m, a, b, q, qd, g)
            T_kin += t
            U_pot += u
        p_tool = origin(6)
        v_tool = ca.mtimes(ca.jacobian(p_tool, q), qd)
        T_kin += 0.5 * ms.tool * ca.dot(v_tool, v_tool)
        U_pot += -ms.tool * ca.dot(g, p_tool)
        # Payload rigid body.
        m_p, c_p = par[0], par[1:4]
        inertia = ca.vertcat(
            ca.horzcat(par[4], par[7], par[8]),
            ca.horzcat(par[7], par[5], par[9]),
            ca.horzcat(par[8], par[9], par[6]),
        )
        R6 = frames[6][0:3, 0:3]
        p_com = p_tool + ca.mtimes(R6, c_p)
        v_com = ca.mtimes(ca.jacobian(p_com, q), qd)
        omega = ca.mtimes(kin.Jq_sx[3:6, :], qd)
        I_world = ca.mtimes(ca.mtimes(R6, inertia), R6.T)
        T_kin += 0.5 * m_p * ca.dot(v_com, v_com) + 0.5 * ca.dot(omega, ca.mtimes(I_world, omega))
        U_pot += -m_p * ca.dot(g, p_com)

        dT_dqd = ca.gradient(T_kin, qd)
        M = ca.jacobian(dT_dqd, qd)
        bias = ca.mtimes(ca.jacobian(dT_dqd, q), qd) - ca.gradient(T_kin, q)
        grav = ca.gradient(U_pot, q)
        self._energy = FastFunction(dense_function("energy", [q, qd, par], [T_kin, U_pot]))
        self._terms = FastFunction(dense_function("lagrange_terms", [q, qd, par], [M, bias, grav]))

        # The same equations of motion by d'Alembert / virtual work, which is far cheaper to evaluate:
        # every quadratic kinetic-energy term 1/2 sum w_ij v_i.v_j with v_i = J_i(q) q_dot contributes
        # sum_j w_ij J_i^T a_j, a_j = J_j q_ddot + J_j_dot q_dot (products by forward/reverse AD).
        def acc(p: ca.SX) -> ca.SX:
            return ca.jtimes(ca.jtimes(p, q, qd), q, qd) + ca.jtimes(p, q, qdd)

        def pull(p: ca.SX, f: ca.SX) -> ca.SX:
            return ca.jtimes(p, q, f, True)

        tau = ca.SX.zeros(8)
        tau[chain.D1] += ms.carriage * qdd[chain.D1]
        for m, a, b in bars:
            a0, a1 = acc(a), acc(b)
            tau += pull(a, m / 6.0 * (2 * a0 + a1) - 0.5 * m * g) + pull(
                b, m / 6.0 * (a0 + 2 * a1) - 0.5 * m * g
            )
        tau += pull(p_tool, ms.tool * (acc(p_tool) - g))
        tau += pull(p_com, m_p * (acc(p_com) - g))
        omega_dot = ca.jtimes(ca.mtimes(kin.Jq_sx[3:6, :], qd), q, qd) + ca.mtimes(kin.Jq_sx[3:6, :], qdd)
        moment = ca.mtimes(I_world, omega_dot) + ca.cross(omega, ca.mtimes(I_world, omega))
        tau += ca.mtimes(kin.Jq_sx[3:6, :].T, moment)
        tau_u = ca.mtimes(kin.G_inv_sx.T, tau)
        id_fn = dense_function("inverse_dynamics", [q, qd, qdd, par], [tau, tau_u], {"cse": True})
        #: The CasADi virtual-machine evaluation (the reference the native build is tested against).
        self.id_vm = FastFunction(id_fn)
        # Holding forces at rest (q_dot = q_ddot = 0): the gravity part only, a fraction of the work.
        zero = ca.SX.zeros(8)
        static_fn = ca.Function(
            "static_drive_forces",
            [q, par],
            [ca.substitute(tau_u, ca.vertcat(qd, qdd), ca.vertcat(zero, zero))],
        )
        id_native, self._id_map, self._id_map_small, self._static_map, self._static_map_small = native(
            [
                id_fn,
                id_fn.map(CHUNK),
                id_fn.map(SMALL_CHUNK),
                static_fn.map(CHUNK),
                static_fn.map(SMALL_CHUNK),
            ],
            "cabin8_dynamics",
        )
        self._id = FastFunction(id_native)
        lagrange_tau = ca.mtimes(M, qdd) + bias + grav
        self._id_lagrange = FastFunction(dense_function("id_lagrange", [q, qd, qdd, par], [lagrange_tau]))

    def inverse_dynamics(
        self, q: Array, qd: Array, qdd: Array, payload: RigidPayload | None = None
    ) -> tuple[Array, Array]:
        """Generalised joint forces tau_q (8,) and drive forces/torques tau_u (8,) [N, N m].

        Args:
            q: Joint positions (8,) [m, rad].
            qd: Joint velocities (8,).
            qdd: Joint accelerations (8,).
            payload: Payload carried by the tool (default: none).
        """
        tq, tu = self._id(q, qd, qdd, _params(payload))
        return tq, tu

    def drive_forces_batch(
        self, q: Array, qd: Array, qdd: Array, payload: RigidPayload | None = None
    ) -> Array:
        """Drive forces/torques tau_u (N, 8) for joint states q, q_dot, q_ddot given as (N, 8) arrays."""
        q2 = np.atleast_2d(np.asarray(q, dtype=float))
        qd2, qdd2 = np.atleast_2d(qd), np.atleast_2d(qdd)
        p = _params(payload)
        if q2.shape[0] <= SMALL_BATCH:  # a mapped call evaluates a whole chunk: cheaper one by one
            return np.array([self._id(q2[i], qd2[i], qdd2[i], p)[1] for i in range(q2.shape[0])])
        par = np.repeat(p[None, :], q2.shape[0], axis=0)
        return evaluate_mapped(self._id_map, q2, qd2, qdd2, par, small=self._id_map_small)[1]

    def static_forces(self, q: Array, payload: RigidPayload | None = None) -> Array:
        """Drive forces/torques (8,) that hold the joint configuration q (8,) at rest [N, N m].

        :meth:`static_forces_batch`'s row for one configuration (the same call, the same bits).
        """
        return self._id(q, _ZERO8, _ZERO8, _params(payload))[1]

    def static_forces_batch(self, q: Array, payload: RigidPayload | None = None) -> Array:
        """Drive forces/torques (N, 8) that hold joint configurations q (N, 8) at rest [N, N m]."""
        q2 = np.atleast_2d(np.asarray(q, dtype=float))
        if q2.shape[0] <= 2:  # the inverse dynamics at rest, point by point: a mapped call pads to a chunk
            p, zero = _params(payload), np.zeros(8)
            return np.array([self._id(qi, zero, zero, p)[1] for qi in q2])
        par = np.repeat(_params(payload)[None, :], q2.shape[0], axis=0)
        return evaluate_mapped(self._static_map, q2, par, small=self._static_map_small)[0]

    def drive_efforts(self, u: Array, ud: Array, udd: Array, payload: RigidPayload | None = None) -> Array:
        """Drive forces/torques for drive trajectories, (N, 8) arrays -> (N, 8) [N, N m].

        Joint states follow from the drive states: q = FK_stage(u), q_dot = G^-1 u_dot,
        q_ddot = G^-1 (u_ddot - G_dot q_dot) with G_dot q_dot the second derivative of the drive map.
        """
        u2, ud2, udd2 = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (u, ud, udd))
        q = self.robot.joints_from_drives(u2)
        qd, qdd = self.joint_rates_batch(q, ud2, udd2)
        return self.drive_forces_batch(q, qd, qdd, payload)

    def joint_rates(self, q: Array, ud: Array, udd: Array) -> tuple[Array, Array]:
        """Joint velocity and acceleration (q_dot, q_ddot) from drive velocity and acceleration at q."""
        qd, qdd = self._joint_rates(q, ud, udd)
        return qd, qdd

    def joint_rates_batch(self, q: Array, ud: Array, udd: Array) -> tuple[Array, Array]:
        """:meth:`joint_rates` for (N, 8) joint positions and drive velocities / accelerations."""
        q2, ud2, udd2 = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (q, ud, udd))
        if q2.shape[0] <= SMALL_BATCH:
            rows = [self._joint_rates(q2[i], ud2[i], udd2[i]) for i in range(q2.shape[0])]
            return np.array([r[0] for r in rows]), np.array([r[1] for r in rows])
        qd, qdd = evaluate_mapped(self._joint_rates_map, q2, ud2, udd2)
        return qd, qdd

    @cached_property
    def _joint_rates_map(self) -> ca.Function:
        return native([self._joint_rates.fn.map(CHUNK)], "cabin8_joint_rates")[0]

    @cached_property
    def _joint_rates(self) -> FastFunction:
        kin = self.robot.kin
        q = kin.q_sx
        ud = ca.SX.sym("ud", 8)
        udd = ca.SX.sym("udd", 8)
        G_inv = kin.G_inv_sx
        qd = ca.mtimes(G_inv, ud)
        u = kin.drives_sx(q)
        G = ca.jacobian(u, q)
        gdqd = ca.mtimes(ca.jacobian(ca.mtimes(G, kin.qd_sx), q), kin.qd_sx)
        gdqd = ca.substitute(gdqd, kin.qd_sx, qd)
        qdd = ca.mtimes(G_inv, udd - gdqd)
        return FastFunction(dense_function("joint_rates", [q, ud, udd], [qd, qdd]))

    def inverse_dynamics_lagrange(
        self, q: Array, qd: Array, qdd: Array, payload: RigidPayload | None = None
    ) -> Array:
        """tau_q from the Lagrangian (M q_ddot + C q_dot + g): the slow, independent route for checks."""
        return self._id_lagrange(q, qd, qdd, _params(payload))[0]

    def energy(self, q: Array, qd: Array, payload: RigidPayload | None = None) -> tuple[float, float]:
        """Kinetic and potential energy (T, U) [J]; U is zero at height y = 0 (and for the carriage)."""
        T, U = self._energy(q, qd, _params(payload))
        return float(T[0]), float(U[0])

    def terms(self, q: Array, qd: Array, payload: RigidPayload | None = None) -> tuple[Array, Array, Array]:
        """(M(q) 8x8, bias C(q, q_dot) q_dot (8,), gravity dU/dq (8,)) in joint space."""
        M, b, g = self._terms(q, qd, _params(payload))
        return M, b, g


_BUILT: weakref.WeakKeyDictionary[Cabin8, Cabin8Dynamics] = weakref.WeakKeyDictionary()

#: Batches up to this size are evaluated row by row (compiled buffers), larger ones by the mapped function.
SMALL_BATCH = 24


_NO_PAYLOAD = np.zeros(10)
_NO_PAYLOAD.flags.writeable = False


#: Zero joint velocities and accelerations (read-only): the inverse dynamics at rest.
_ZERO8 = np.zeros(8)
_ZERO8.flags.writeable = False


def _params(payload: RigidPayload | None) -> Array:
    return _NO_PAYLOAD if payload is None else payload.params()
