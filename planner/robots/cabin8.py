"""cabin8: the 8-DOF hybrid cabin assembly robot (rail + planar 3-slider stage + RRPR arm).

Coordinates:

* joints ``q = (d1, x, y, gamma, theta3, theta4, d5, theta6)``: rail travel, platform pose in the stage
  plane, and the serial chain (m, rad);
* drives ``u = (d1, x1, x2, x3, theta3, theta4, d5, theta6)``: what the motors move. Only the stage
  differs: (x, y, gamma) <-> (x1, x2, x3) by :mod:`planner.kinematics.parallel`.

The drive map is ``u = g(q)`` (closed form), its Jacobian ``G = dg/dq = blockdiag(1, G_p, I_4)``; joint
velocities follow from drive velocities by ``q_dot = G^-1 u_dot`` (G_p^-1 is the paper's parallel-stage
Jacobian J_1 of eq. 24-25). The geometric Jacobian ``J_q`` (6x8) maps q_dot to the tool twist
``(v, omega)`` -- the linear velocity of the tool-frame origin and the angular velocity, both in the base
frame; the drive-space Jacobian is ``J_u = J_q G^-1`` (paper eq. 33-34, which the OCR garbles; we compose
the two maps directly). All of these are CasADi automatic derivatives of one symbolic model, compiled once
per description and evaluated through preallocated buffers.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache, cached_property
from importlib import resources
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import NDArray

from planner.core.description import Hybrid8Description, description_hash, jerk_limits, load_description
from planner.core.exceptions import InvalidInput, LimitViolation
from planner.core.timing_names import default_timing
from planner.core.types import Array
from planner.kinematics import chain, parallel
from planner.kinematics.compiled import CHUNK, FastFunction, dense_function, evaluate_mapped
from planner.kinematics.native import native
from planner.robots.base import DriveLimits, RobotModel
from planner.robots.cabin8_geometry import Cabin8CollisionModel

#: Indices of the stage coordinates in q (x, y, gamma) and in u (x1, x2, x3).
STAGE = slice(1, 4)


@dataclass(frozen=True)
class Constraint:
    """One scalar admissibility quantity c(q) with its bounds (``-inf``/``inf`` when one-sided)."""

    name: str
    lower: float
    upper: float
    unit: str


class Cabin8Kinematics:
    """Compiled symbolic kinematics of one description (shared by every :class:`Cabin8` of it)."""

    def __init__(self, desc: Hybrid8Description) -> None:
        self.desc = desc
        self.geometry = parallel.StageGeometry.from_spec(desc.parallel_stage)
        q = ca.SX.sym("q", 8)
        qd = ca.SX.sym("qd", 8)
        self.q_sx, self.qd_sx = q, qd
        frames = chain.frames_sx(desc.serial_chain, q)
        self.frames_sx = frames
        T = frames[6]
        u = self.drives_sx(q)
        G = ca.jacobian(u, q)
        Gp_inv = ca.inv(G[1:4, 1:4])
        G_inv = ca.SX.eye(8)
        G_inv[1:4, 1:4] = Gp_inv
        Jq = chain.geometric_jacobian_sx(T, q)
        Ju = ca.mtimes(Jq, G_inv)
        jdqd = ca.mtimes(ca.jacobian(ca.mtimes(Jq, qd), q), qd)
        gdqd = ca.mtimes(ca.jacobian(ca.mtimes(G, qd), q), qd)
        jdud = jdqd - ca.mtimes(Ju, gdqd)
        c = self.constraints_sx(q)
        self.G_inv_sx, self.Jq_sx = G_inv, Jq
        self.fk = FastFunction(dense_function("fk", [q], [T]))
        self.fk_jac = FastFunction(dense_function("fk_jac", [q], [T, Jq, Ju]))
        self.drive_map = FastFunction(dense_function("drive_map", [q], [u, G, G_inv]))
        self.jdot_qdot = FastFunction(dense_function("jdot_qdot", [q, qd], [jdqd]))
        # Drive-space bias: with q_dot = G^-1 u_dot, tool acceleration = J_u u_ddot + jdot_udot.
        self.jdot_udot = FastFunction(dense_function("jdot_udot", [q, qd], [jdud]))
        dc = ca.jacobian(c, q)
        self.constraints = FastFunction(dense_function("constraints", [q], [c, dc]))
        # Everything one redundancy-resolution step needs, in one call.
        self.step = FastFunction(dense_function("step", [q], [T, Jq, Ju, c, dc], {"cse": True}))

    def drives_sx(self, q: ca.SX) -> ca.SX:
        """Symbolic drive map u = g(q) (8x1)."""
        pts = parallel.stage_points(self.geometry, q[chain.X], q[chain.Y], q[chain.GAMMA], xp=ca)
        return ca.vertcat(q[0], pts.A[0], pts.D[0], pts.F[0], q[4:8])

    def constraints_sx(self, q: ca.SX) -> ca.SX:
        """Symbolic admissibility vector c(q), in the order of :meth:`Cabin8.constraint_specs`."""
        return ca.vertcat(*constraint_terms(self.geometry, [q[i] for i in range(8)], ca))


def constraint_terms(geometry: parallel.StageGeometry, q: list[Any], xp: Any) -> list[Any]:
    """The admissibility quantities c(q) as a list of scalars/arrays (one source for numpy and CasADi).

    Order: the 8 drives, platform y and gamma, slider gaps x3-x1 and x2-x3, sin(CBD), y_B/L1, y_C/L3,
    y_E/L4 -- the order of :attr:`Cabin8.constraint_specs`.
    """
    pts = parallel.stage_points(geometry, q[chain.X], q[chain.Y], q[chain.GAMMA], xp=xp)
    m = parallel.stage_measures(geometry, q[chain.X], q[chain.Y], q[chain.GAMMA], xp=xp)
    return [
        q[0],
        pts.A[0],
        pts.D[0],
        pts.F[0],
        *q[4:8],
        q[chain.Y],
        q[chain.GAMMA],
        m["gap_fa"],
        m["gap_df"],
        m["sin_cbd"],
        m["h_ab"],
        m["h_cd"],
        m["h_ef"],
    ]


@cache
def _kinematics(path: str) -> tuple[Hybrid8Description, Cabin8Kinematics, str]:
    p = Path(path)
    desc = load_description(p)
    return desc, Cabin8Kinematics(desc), description_hash(p)


def default_description_path() -> Path:
    """Path of the packaged cabin8 description file."""
    return Path(str(resources.files("planner.robots").joinpath("cabin8.yaml")))


class Cabin8(RobotModel):
    """The cabin8 robot: limits, drive <-> joint maps, kinematics and admissibility.

    Args:
        description: Path of a ``kind: hybrid8`` description file (default: the packaged cabin8).
        rail_length: Optional rail length [m]; replaces the upper limit of d1.
    """

    kind = "hybrid8"

    def __init__(self, description: Path | None = None, rail_length: float | None = None) -> None:
        path = (description or default_description_path()).resolve()
        desc, kin, sha = _kinematics(str(path))
        self.desc = desc
        self.kin = kin
        self.geometry = kin.geometry
        self.description_sha256 = sha
        self.name = desc.name
        self.drive_names = desc.drive_names
        self.drive_units = tuple(d.unit for d in desc.drives)
        self.joint_names = desc.joints
        self.joint_units = ("m", "m", "m", "rad", "rad", "rad", "m", "rad")
        upper = desc.upper.copy()
        if rail_length is not None:
            if not np.isfinite(rail_length) or rail_length <= desc.lower[0]:
                raise InvalidInput(
                    f"rail_length: must be a finite length above {desc.lower[0]} m, got {rail_length}",
                    field="rail_length",
                )
            upper[0] = float(rail_length)
        self.rail_length = float(upper[0])
        self.limits = DriveLimits(
            lower=desc.lower.copy(),
            upper=upper,
            v_max=np.array([d.v_max for d in desc.drives]),
            a_max=np.array([d.a_max for d in desc.drives]),
            effort_max=np.array([d.effort_max for d in desc.drives]),
            j_max=jerk_limits(desc.drives),
        )
        ps = desc.parallel_stage
        self.home_drives = self.drives_from_dict(desc.home, field="home")
        specs = [
            Constraint(n, lo, hi, un)
            for n, lo, hi, un in zip(
                self.drive_names, self.limits.lower, self.limits.upper, self.drive_units, strict=True
            )
        ]
        inf = float("inf")
        r = ps.max_link_height_ratio
        specs += [
            Constraint("y", ps.y_range[0], ps.y_range[1], "m"),
            Constraint("gamma", -ps.gamma_max, ps.gamma_max, "rad"),
            Constraint("gap_x3_x1", ps.min_slider_gap, inf, "m"),
            Constraint("gap_x2_x3", ps.min_slider_gap, inf, "m"),
            Constraint("sin_cbd", ps.min_sin_cbd, inf, "1"),
            Constraint("yB_over_L1", -inf, r, "1"),
            Constraint("yC_over_L3", -inf, r, "1"),
            Constraint("yE_over_L4", -inf, r, "1"),
        ]
        self.constraint_specs: tuple[Constraint, ...] = tuple(specs)
        self.c_lower = np.array([s.lower for s in specs])
        self.c_upper = np.array([s.upper for s in specs])

    # ------------------------------------------------------------------ maps
    def drives_from_joints(self, q: Array) -> Array:
        """Drive positions u for joints q, (N, 8) or (8,); raises OutsideWorkspace off the stage domain."""
        q = np.asarray(q, dtype=float)
        u = q.copy()
        u[..., STAGE] = parallel.inverse(self.geometry, q[..., STAGE])
        return u

    def joints_from_drives(self, u: Array) -> Array:
        """Joints q for drive positions u, (N, 8) or (8,); raises OutsideWorkspace off the working branch."""
        u = np.asarray(u, dtype=float)
        q = u.copy()
        q[..., STAGE] = parallel.forward(self.geometry, u[..., STAGE])
        return q

    # ------------------------------------------------------------ kinematics
    def fk(self, q: Array) -> Array:
        """T_base_tool (4x4) for one joint vector."""
        return self.kin.fk(q)[0]

    def drive_path(self, q: Array, dq: Array, ddq: Array) -> tuple[Array, Array, Array]:
        """u, u', u'' of a joint path (N, 8) each (compiled CasADi AD of the drive map, vectorised)."""
        u, du, ddu = evaluate_mapped(_drive_path_function(self.kin), q, dq, ddq)
        return u, du, ddu

    def fk_batch(self, q: Array) -> Array:
        """T_base_tool for (N, 8) joint vectors, shape (N, 4, 4) (numpy, vectorised)."""
        return chain.tool_batch(self.desc.serial_chain, q)

    def frames(self, q: Array) -> Array:
        """Every frame T_base_i, i = 0..6 (base, carriage, platform, 3, 4, 5, tool), shape (N, 7, 4, 4)."""
        return chain.frames_batch(self.desc.serial_chain, q)

    def fk_jacobians(self, q: Array) -> tuple[Array, Array, Array]:
        """(T_base_tool 4x4, J_q 6x8, J_u 6x8) in one compiled call."""
        T, Jq, Ju = self.kin.fk_jac(q)
        return T, Jq, Ju

    def jacobian(self, q: Array) -> Array:
        """Geometric joint-space Jacobian J_q (6x8): q_dot -> (v [m/s], omega [rad/s]) in the base frame."""
        return self.kin.fk_jac(q)[1]

    def drive_jacobian(self, q: Array) -> Array:
        """Drive-space Jacobian J_u = J_q G^-1 (6x8): u_dot -> tool twist."""
        return self.kin.fk_jac(q)[2]

    def drive_map_jacobian(self, q: Array) -> tuple[Array, Array]:
        """(G = du/dq, G^-1 = dq/du), both 8x8, at q."""
        _, G, G_inv = self.kin.drive_map(q)
        return G, G_inv

    def stage_jacobian(self, q: Array) -> Array:
        """Parallel-stage Jacobian d(x, y, gamma)/d(x1, x2, x3) (3x3, paper eq. 24-25) at q."""
        return self.drive_map_jacobian(q)[1][STAGE, STAGE]

    def jdot_qdot(self, q: Array, qd: Array) -> Array:
        """Bias acceleration J_q_dot q_dot (6,), so that tool acceleration = J_q q_ddot + J_q_dot q_dot."""
        return self.kin.jdot_qdot(q, qd)[0]

    def jdot_udot(self, q: Array, ud: Array) -> Array:
        """Drive-space bias (6,), so that the tool acceleration is J_u u_ddot plus this term."""
        _, _, G_inv = self.kin.drive_map(q)
        return self.kin.jdot_udot(q, G_inv @ np.asarray(ud, dtype=float))[0]

    # ---------------------------------------------------------- admissibility
    def constraint_values(self, q: Array) -> tuple[Array, Array]:
        """Admissibility vector and its Jacobian, (c(q), dc/dq), in :attr:`constraint_specs` order."""
        c, dc = self.kin.constraints(q)
        return c, dc

    def constraint_values_batch(self, q: Array) -> Array:
        """c(q) for (N, 8) joint vectors, shape (N, m), numpy-vectorised; NaN where a link cannot close."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        with np.errstate(invalid="ignore"):
            return np.stack(constraint_terms(self.geometry, list(q.T), np), axis=-1)

    def margins_batch(self, q: Array) -> Array:
        """Signed distance of each constraint to its nearest bound for (N, 8) joints, (N, m); NaN outside."""
        c = self.constraint_values_batch(q)
        return np.minimum(c - self.c_lower, self.c_upper - c)

    def violations(self, q: Array, tol: float = 1e-9) -> list[dict[str, Any]]:
        """Every violated limit or margin at q (empty when admissible)."""
        q = np.asarray(q, dtype=float)
        if not np.all(np.isfinite(q)):
            return [{"name": "finite", "value": q.tolist(), "lower": None, "upper": None}]
        c, _ = self.constraint_values(q)
        out = []
        for s, v in zip(self.constraint_specs, c, strict=True):
            if not np.isfinite(v) or v < s.lower - tol or v > s.upper + tol:
                out.append({"name": s.name, "value": float(v), "lower": s.lower, "upper": s.upper})
        return out

    def admissible_batch(self, qs: Array, tol: float = 1e-9) -> NDArray[np.bool_]:
        """For (N, 8) joints: True where every limit and margin holds (as :meth:`violations` is empty)."""
        qs = np.atleast_2d(np.asarray(qs, dtype=float))
        c = self.constraint_values_batch(qs)
        with np.errstate(invalid="ignore"):
            inside = (c >= self.c_lower - tol) & (c <= self.c_upper + tol)
        return np.all(inside, axis=1) & np.all(np.isfinite(qs), axis=1)

    def margins(self, q: Array) -> Array:
        """Signed distance of each constraint to its nearest bound (positive inside), in its own unit."""
        c, _ = self.constraint_values(q)
        return np.minimum(c - self.c_lower, self.c_upper - c)

    def check_admissible(self, q: Array, tol: float = 1e-9) -> None:
        """Raise :class:`LimitViolation` listing every violated limit/margin at q."""
        bad = self.violations(q, tol)
        if bad:
            names = ", ".join(
                f"{b['name']}={b['value']:.6g} not in [{b['lower']:.6g}, {b['upper']:.6g}]"
                if isinstance(b["value"], float)
                else b["name"]
                for b in bad
            )
            raise LimitViolation(f"configuration violates {names}", violations=bad)

    # ------------------------------------------------------------- collision
    def collision_model(self) -> Cabin8CollisionModel:
        """cabin8's bodies, shapes, reach bounds and pose kernels (:mod:`planner.robots.cabin8_geometry`)."""
        return self._collision_model

    @cached_property
    def _collision_model(self) -> Cabin8CollisionModel:
        return Cabin8CollisionModel(self)

    # --------------------------------------------------------------- summary
    @cached_property
    def _summary(self) -> dict[str, Any]:
        ps = self.desc.parallel_stage
        return {
            "name": self.name,
            "kind": self.kind,
            "description": self.desc.description,
            "description_sha256": self.description_sha256,
            "frames": "base: z along the rail (cabin axis), y up (gravity -y), x lateral",
            "joints": [
                {"name": n, "unit": u} for n, u in zip(self.joint_names, self.joint_units, strict=True)
            ],
            "drives": [
                {
                    "name": d.name,
                    "unit": u,
                    "lower": float(lo),
                    "upper": float(hi),
                    "v_max": d.v_max,
                    "a_max": d.a_max,
                    "effort_max": d.effort_max,
                    "j_max": d.j_max,
                    "effort_unit": "N" if u == "m" else "N*m",
                }
                for d, u, lo, hi in zip(
                    self.desc.drives, self.drive_units, self.limits.lower, self.limits.upper, strict=True
                )
            ],
            "parallel_stage": {
                "L1_m": ps.L1,
                "L2_m": ps.L2,
                "L3_m": ps.L3,
                "L4_m": ps.L4,
                "min_slider_gap_m": ps.min_slider_gap,
                "y_range_m": list(ps.y_range),
                "gamma_max_rad": ps.gamma_max,
                "min_sin_cbd": ps.min_sin_cbd,
                "max_link_height_ratio": ps.max_link_height_ratio,
            },
            "serial_chain_mdh": [link.model_dump() for link in self.desc.serial_chain],
            "masses_kg": self.desc.masses.model_dump(),
            "home_drives": self.drives_dict(self.home_drives),
            "default_timing": default_timing(self.limits.j_max is not None),
        }

    def summary(self) -> dict[str, Any]:
        """JSON-serialisable model summary: drives, units, limits, stage geometry, chain, masses."""
        return dict(self._summary)


@cache
def _drive_path_function(kin: Cabin8Kinematics) -> ca.Function:
    """u, u', u'' of a joint path, mapped over CHUNK points (a native build where available)."""
    q = ca.SX.sym("q", 8)
    dq = ca.SX.sym("dq", 8)
    ddq = ca.SX.sym("ddq", 8)
    u = kin.drives_sx(q)
    du = ca.jtimes(u, q, dq)
    ddu = ca.jtimes(du, q, dq) + ca.jtimes(u, q, ddq)
    fn = ca.Function("drive_path", [q, dq, ddq], [u, du, ddu])
    return native([fn.map(CHUNK)], "cabin8_drive_path")[0]
