"""An independent route to cabin8's static deflection: a small 3-D Euler-Bernoulli frame finite-element model.

Every flexible member of :mod:`planner.dynamics.stiffness` is one 12-DOF beam element (exact for loads at
its nodes) assembled into a global stiffness matrix with numpy; nothing is composed from compliances.
Joints are kinematic relations between node DOFs, eliminated exactly (master-slave, no penalty numbers):

* a rigid connection of node s to node m at offset r: ``u_s = u_m + phi_m x r``, ``phi_s = phi_m``;
* a joint adds one independent DOF along a unit twist (translation along or rotation about its axis):
  free for a pin (released rotation about the base z axis at A, B, C, D, E, F; with a finite pin
  compliance also three translations along the base axes with springs of its inverse), or with a spring
  of the drive's stiffness for the rail, the sliders, theta3, theta4, d5 and theta6.

The rail carriage hangs on the fixed ground through the rail spring; the slider carriages are rigid on it;
the stage links pin onto the sliders and each other; the column, arm and slide follow through their drive
joints; the tool and the payload are rigid on the last node. Gravity loads every member's weight half at
each of its end nodes (the stage links too, at their own pins, unlike the analytical route which lumps them
at the platform centre). This is the 3-D analogue of the paper's ANSYS check (section 5.2, Table 2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.core.description import Section
from planner.core.types import Array
from planner.dynamics.payload import RigidPayload
from planner.kinematics import chain, parallel
from planner.robots.cabin8 import Cabin8


def element_stiffness(
    p0: Array, p1: Array, z_ref: Array, section: Section, E_Pa: float, G_Pa: float
) -> Array:
    """Global 12x12 stiffness of a 3-D Euler-Bernoulli beam element from p0 to p1.

    Local x runs from p0 to p1, local z is ``z_ref`` made orthogonal to it (the section's b side), local y
    completes the frame (the h side). DOFs per node: (u, v, w, theta_x, theta_y, theta_z), base axes.
    """
    axis = np.asarray(p1, dtype=float) - np.asarray(p0, dtype=float)
    L = float(np.linalg.norm(axis))
    x = axis / L
    z = np.asarray(z_ref, dtype=float) - float(np.dot(z_ref, x)) * x
    z /= np.linalg.norm(z)
    y = np.cross(z, x)
    b, h = section.b, section.h
    A, Iy, Iz = b * h, b**3 * h / 12.0, b * h**3 / 12.0
    J = b * h**3 * (1.0 / 3.0 - 0.21 * h / b)
    k = np.zeros((12, 12))
    ea, gj = E_Pa * A / L, G_Pa * J / L
    for i, j, v in ((0, 0, ea), (0, 6, -ea), (6, 6, ea), (3, 3, gj), (3, 9, -gj), (9, 9, gj)):
        k[i, j] = k[j, i] = v
    # Bending in the local x-y plane (v, theta_z) with E I_z; in x-z (w, theta_y) with E I_y.
    for (dv, dr), EI, sgn in (((1, 5), E_Pa * Iz, 1.0), ((2, 4), E_Pa * Iy, -1.0)):
        idx = [dv, dr, dv + 6, dr + 6]
        c = EI / L**3
        m = c * np.array(
            [
                [12.0, 6 * L * sgn, -12.0, 6 * L * sgn],
                [6 * L * sgn, 4 * L * L, -6 * L * sgn, 2 * L * L],
                [-12.0, -6 * L * sgn, 12.0, -6 * L * sgn],
                [6 * L * sgn, 2 * L * L, -6 * L * sgn, 4 * L * L],
            ]
        )
        k[np.ix_(idx, idx)] = m
    Rt = np.stack([x, y, z])  # rows: local axes in base coordinates
    lam = np.kron(np.eye(4), Rt)
    return lam.T @ k @ lam


@dataclass
class _Node:
    position: Array
    rows: Array  # (6, n_reduced) map from reduced DOFs to this node's DOFs (filled while building)


class FrameModel:
    """Builder and solver of one frame structure (nodes, beams, joints, springs); see the module docstring."""

    def __init__(self) -> None:
        self._nodes: list[_Node] = []
        self._n = 0  # reduced DOFs so far
        self._beams: list[tuple[int, int, Array]] = []
        self._springs: list[tuple[int, float]] = []
        self._cols: list[tuple[int, int, Array]] = []  # (node, reduced dof, 6-vector) entries

    def _new_dofs(self, k: int) -> list[int]:
        out = list(range(self._n, self._n + k))
        self._n += k
        return out

    def ground(self, position: Array) -> int:
        """A fixed node."""
        self._nodes.append(_Node(np.asarray(position, dtype=float), np.zeros((6, 0))))
        return len(self._nodes) - 1

    def free(self, position: Array) -> int:
        """A node with its own six DOFs."""
        dofs = self._new_dofs(6)
        rows = np.zeros((6, self._n))
        rows[:, dofs] = np.eye(6)
        self._nodes.append(_Node(np.asarray(position, dtype=float), rows))
        return len(self._nodes) - 1

    def attach(self, master: int, position: Array, releases: tuple[tuple[Array, float], ...] = ()) -> int:
        """A node rigidly attached to ``master``, plus one DOF per release (unit twist, spring stiffness).

        A release with stiffness 0 is a free joint (pin); otherwise a drive spring along that twist.
        """
        pos = np.asarray(position, dtype=float)
        m = self._nodes[master]
        r = pos - m.position
        A = np.eye(6)
        A[:3, 3:] = -np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])
        dofs = self._new_dofs(len(releases))
        rows = np.zeros((6, self._n))
        rows[:, : m.rows.shape[1]] = A @ m.rows
        for d, (twist, k) in zip(dofs, releases, strict=True):
            rows[:, d] = np.asarray(twist, dtype=float)
            if k > 0:
                self._springs.append((d, float(k)))
        self._nodes.append(_Node(pos, rows))
        return len(self._nodes) - 1

    def beam(self, a: int, b: int, z_ref: Array, section: Section, E_Pa: float, G_Pa: float) -> None:
        """A beam element between nodes a and b."""
        ke = element_stiffness(self._nodes[a].position, self._nodes[b].position, z_ref, section, E_Pa, G_Pa)
        self._beams.append((a, b, ke))

    def _rows(self, i: int) -> Array:
        r = self._nodes[i].rows
        out = np.zeros((6, self._n))
        out[:, : r.shape[1]] = r
        return out

    def solve(self, loads: dict[int, Array]) -> dict[int, Array]:
        """Node displacements (6,) of every loaded or asked node under node wrenches (6,) (base axes).

        Returns the displacement of every node, keyed by node index.
        """
        K = np.zeros((self._n, self._n))
        for a, b, ke in self._beams:
            T = np.vstack([self._rows(a), self._rows(b)])
            K += T.T @ ke @ T
        for d, k in self._springs:
            K[d, d] += k
        f = np.zeros(self._n)
        for i, w in loads.items():
            f += self._rows(i).T @ np.asarray(w, dtype=float)
        scale = float(np.max(np.abs(np.diag(K))))
        u = np.linalg.solve(K / scale, f / scale)
        return {i: self._rows(i) @ u for i in range(len(self._nodes))}


def _trans(axis: Array) -> Array:
    return np.concatenate([np.asarray(axis, dtype=float), np.zeros(3)])


def _rot(axis: Array) -> Array:
    return np.concatenate([np.zeros(3), np.asarray(axis, dtype=float)])


def fe_deflection(
    robot: Cabin8,
    q: Array,
    payload: RigidPayload | None = None,
    T_tool_frame: Array | None = None,
    wrench: Array | None = None,
    gravity: bool = True,
) -> Array:
    """Deflection twist (6,) of the frame origin (translation [m], rotation [rad], base) by the FE model.

    Args:
        robot: The robot (its description's stiffness data and masses).
        q: Joint vector (8,).
        payload: Payload carried by the tool.
        T_tool_frame: Reference frame in the tool frame (default: the tool frame).
        wrench: External wrench (6,) at the frame origin, base axes.
        gravity: Include the weights of links, tool and payload.
    """
    spec = robot.desc.stiffness
    assert spec is not None
    E, G = spec.E_Pa, spec.G_Pa
    sec = spec.sections
    k = spec.drive_stiffness()
    ms = robot.desc.masses
    g = np.asarray(robot.desc.gravity_m_s2, dtype=float)
    q = np.asarray(q, dtype=float)
    T_tf = np.eye(4) if T_tool_frame is None else np.asarray(T_tool_frame, dtype=float)
    F = robot.frames(q[None])[0]
    pts = parallel.stage_points(robot.geometry, q[chain.X], q[chain.Y], q[chain.GAMMA])
    P = {n: np.array([float(px), float(py), q[chain.D1]]) for n, (px, py) in zip("ABCDEF", pts, strict=True)}
    centre = np.array([q[chain.X], q[chain.Y], q[chain.D1]])
    ez, ex = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    # A pin: free about z; with a finite pin stiffness, a translational spring along each base axis.
    c_pin = spec.pin_compliance_m_N
    axes = (ex, np.array([0.0, 1.0, 0.0]), ez)
    pin = ((_rot(ez), 0.0),) + (tuple((_trans(a), 1.0 / c_pin) for a in axes) if c_pin > 0 else ())

    fm = FrameModel()
    ground = fm.ground(P["A"])
    carriage = fm.attach(ground, P["A"], ((_trans(ez), k[0]),))
    slider = {n: fm.attach(carriage, P[n], ((_trans(ex), k[i]),)) for n, i in (("A", 1), ("D", 2), ("F", 3))}
    ab_a = fm.attach(slider["A"], P["A"], pin)
    ab_e = fm.free(P["E"])
    ab_b = fm.free(P["B"])
    fm.beam(ab_a, ab_e, ez, sec.link_ab, E, G)
    fm.beam(ab_e, ab_b, ez, sec.link_ab, E, G)
    ef_f = fm.attach(slider["F"], P["F"], pin)
    ef_e = fm.attach(ab_e, P["E"], pin)
    fm.beam(ef_f, ef_e, ez, sec.link_ef, E, G)
    pl_b = fm.attach(ab_b, P["B"], pin)
    pl_o = fm.free(centre)
    pl_c = fm.free(P["C"])
    fm.beam(pl_b, pl_o, ez, sec.platform, E, G)
    fm.beam(pl_o, pl_c, ez, sec.platform, E, G)
    cd_c = fm.attach(pl_c, P["C"], pin)
    cd_d = fm.attach(slider["D"], P["D"], pin)
    fm.beam(cd_d, cd_c, ez, sec.link_cd, E, G)
    o3, o4, o6 = F[3, :3, 3], F[4, :3, 3], F[6, :3, 3]
    x3, z3, z4, z5, z6 = F[3, :3, 0], F[3, :3, 2], F[4, :3, 2], F[5, :3, 2], F[6, :3, 2]
    col_base = fm.attach(pl_o, centre, ((_rot(z3), k[4]),))  # theta3 about the column's own axis
    n3 = fm.free(o3)
    fm.beam(col_base, n3, x3, sec.column, E, G)
    n4 = fm.free(o4)
    fm.beam(n3, n4, z4, sec.arm, E, G)
    n4_rot = fm.attach(n4, o4, ((_rot(z4), k[5]),))
    n4_slide = fm.attach(n4_rot, o4, ((_trans(z5), k[6]),))
    n6 = fm.free(o6)
    fm.beam(n4_slide, n6, z4, sec.slide, E, G)
    tool = fm.attach(n6, o6, ((_rot(z6), k[7]),))
    T_frame = F[6] @ T_tf
    frame = fm.attach(tool, T_frame[:3, 3])

    loads: dict[int, Array] = {}

    def add(node: int, w: Array) -> None:
        loads[node] = loads.get(node, np.zeros(6)) + w

    if gravity:
        for node, m in (
            (ab_a, 0.5 * ms.link_ab),
            (ab_b, 0.5 * ms.link_ab),
            (ef_f, 0.5 * ms.link_ef),
            (ef_e, 0.5 * ms.link_ef),
            (cd_c, 0.5 * ms.link_cd),
            (cd_d, 0.5 * ms.link_cd),
            (pl_b, 0.5 * ms.platform),
            (pl_c, 0.5 * ms.platform),
            (col_base, 0.5 * ms.column),
            (n3, 0.5 * (ms.column + ms.arm)),
            (n4, 0.5 * (ms.arm + ms.slide)),
            (n6, 0.5 * ms.slide),
            (tool, ms.tool),
        ):
            add(node, np.concatenate([m * g, np.zeros(3)]))
        if payload is not None and payload.mass > 0:
            com = o6 + F[6, :3, :3] @ payload.com_tool
            add(fm.attach(tool, com), np.concatenate([payload.mass * g, np.zeros(3)]))
    if wrench is not None:
        add(frame, np.asarray(wrench, dtype=float))
    u = fm.solve(loads)
    return u[frame]
