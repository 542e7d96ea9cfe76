"""The IK step QP assembled in one compiled CasADi call (the hot loop of :mod:`planner.redundancy.ik`).

It builds exactly the QP that :func:`planner.redundancy.solve.build_problem` builds from
``FrameTask + PostureTask + MarginTask`` and ``AdmissibilityLimit`` (the tests check the two agree), but
as a single compiled function of (q, pose error, reference, weights), so one step costs one CasADi call
plus one DAQP solve instead of a few dozen small numpy operations.

Infinite bounds are passed as +-1e9: the rows stay (fixed structure) and are never active.
"""

from __future__ import annotations

from functools import cache
from typing import NamedTuple

import casadi as ca
import numpy as np

from planner.core.types import Array
from planner.kinematics.compiled import FastFunction, dense_function
from planner.redundancy.solve import Problem
from planner.robots.cabin8 import Cabin8, Cabin8Kinematics

_BIG = 1e9


class StepWeights(NamedTuple):
    """Weights of one IK step (see the task classes for their meaning)."""

    position_cost: float
    orientation_cost: float
    lm_damping: float
    posture_cost: float
    margin_cost: float
    limit_gain: float
    damping: float = 1e-9


@cache
def _step_function(kin: Cabin8Kinematics) -> FastFunction:
    q = kin.q_sx
    m = int(kin.constraints_sx(q).shape[0])
    err = ca.SX.sym("err", 6)
    q_ref = ca.SX.sym("q_ref", 8)
    comfort = ca.SX.sym("comfort", m)
    lo = ca.SX.sym("lo", m)
    hi = ca.SX.sym("hi", m)
    w = ca.SX.sym("w", 7)
    w_pos, w_ori, lm, w_post, w_marg, gain, damp = (w[i] for i in range(7))
    J = kin.Jq_sx
    c = kin.constraints_sx(q)
    dc = ca.jacobian(c, q)
    # Frame task with Levenberg-Marquardt damping.
    wv = ca.vertcat(w_pos, w_pos, w_pos, w_ori, w_ori, w_ori)
    We = wv * err
    WJ = ca.mtimes(ca.diag(wv), J)
    H = ca.mtimes(WJ.T, WJ) + (lm * ca.dot(We, We) + damp) * ca.SX.eye(8)
    f = -ca.mtimes(WJ.T, We)
    # Posture task (identity Jacobian).
    H += w_post**2 * ca.SX.eye(8)
    f += -(w_post**2) * (q_ref - q)
    # Margin task: restore comfortable distance to the nearest bound of every constraint.
    d_up, d_lo = hi - c, c - lo
    near_up = d_up < d_lo
    margin = ca.if_else(near_up, d_up, d_lo)
    sign = ca.if_else(near_up, -1.0, 1.0)
    deficit = ca.fmax(comfort - margin, 0.0) / comfort
    active = deficit > 0
    Jm = ca.mtimes(ca.diag(active * sign / comfort), dc)
    H += w_marg**2 * ca.mtimes(Jm.T, Jm)
    f += -(w_marg**2) * ca.mtimes(Jm.T, deficit)
    # Admissibility limits, upper rows then lower rows.
    G = ca.vertcat(dc, -dc)
    h = gain * ca.vertcat(hi - c, c - lo)
    fn = dense_function("ik_step", [q, err, q_ref, comfort, lo, hi, w], [H, f, G, h], {"cse": True})
    return FastFunction(fn)


class IKStep:
    """Compiled step-QP builder for one robot (bounds and comfort margins bound at construction)."""

    def __init__(self, robot: Cabin8, comfort: Array) -> None:
        self._fn = _step_function(robot.kin)
        self._lo = np.where(np.isfinite(robot.c_lower), robot.c_lower, -_BIG)
        self._hi = np.where(np.isfinite(robot.c_upper), robot.c_upper, _BIG)
        self._comfort = np.asarray(comfort, dtype=float)

    def problem(self, q: Array, err: Array, q_ref: Array, weights: StepWeights, step_max: Array) -> Problem:
        """The step QP at q for the pose error ``err`` (see :func:`planner.core.so3.pose_error`)."""
        H, f, G, h = self._fn(
            q, err, q_ref, self._comfort, self._lo, self._hi, np.asarray(weights, dtype=float)
        )
        return Problem(H, f, G, h, -step_max, step_max)
