"""Assemble and solve the redundancy-resolution QP of one step.

    minimise    sum_tasks 1/2 |W (J dq - e)|^2 + 1/2 damping |dq|^2
    subject to  G dq <= h            (every limit, linearised)
                -step_max <= dq <= step_max

The QP is dense and tiny (8 variables). Any solver installed for :func:`qpsolvers.solve_qp` can be
selected by name (``"osqp"``, ``"quadprog"``, ...). The default ``"daqp"`` calls the DAQP dual active-set
solver directly with the step bounds as its native simple bounds: the same solver qpsolvers would call,
minus ~25 us of conversion per step (qpsolvers' OSQP path also builds sparse matrices, ~1 ms here; see
``bench/kinematics.py`` for the measured figures).
"""

from __future__ import annotations

from collections.abc import Sequence
from ctypes import c_int
from typing import Any, NamedTuple

import daqp
import numpy as np
from scipy import sparse

from planner.core.exceptions import QPSolveFailed
from planner.core.types import Array
from planner.redundancy.configuration import Configuration
from planner.redundancy.limits import Limit
from planner.redundancy.tasks import Task

DEFAULT_SOLVER = "daqp"


class Problem(NamedTuple):
    """Dense QP: 1/2 x^T P x + q^T x s.t. G x <= h, lb <= x <= ub."""

    P: Array
    q: Array
    G: Array | None
    h: Array | None
    lb: Array | None
    ub: Array | None


def build_problem(
    configuration: Configuration,
    tasks: Sequence[Task],
    limits: Sequence[Limit] = (),
    damping: float = 1e-9,
    step_max: Array | None = None,
) -> Problem:
    """Build the QP of one step from tasks and limits."""
    objectives = [task.compute_qp_objective(configuration) for task in tasks]
    P = sum((o.H for o in objectives), start=np.zeros((configuration.q.shape[0],) * 2))
    P.flat[:: P.shape[0] + 1] += damping
    c = sum((o.c for o in objectives), start=np.zeros(configuration.q.shape[0]))
    cons = [limit.compute_qp_inequalities(configuration) for limit in limits]
    if len(cons) > 1:
        G_all: Array | None = np.vstack([k.G for k in cons])
        h_all: Array | None = np.concatenate([k.h for k in cons])
    elif cons:
        G_all, h_all = cons[0]
    else:
        G_all = h_all = None
    lb = -step_max if step_max is not None else None
    return Problem(P, c, G_all, h_all, lb, step_max)


def solve_problem(problem: Problem, solver: str = DEFAULT_SOLVER) -> Array:
    """Solve a step QP.

    Raises:
        QPSolveFailed: infeasible or the solver failed; ``details`` names the solver.
    """
    if solver == DEFAULT_SOLVER:
        return _solve_daqp(problem)
    import qpsolvers  # the other solvers only (its OSQP back end imports jinja2: start-up of every plan)

    if solver not in qpsolvers.available_solvers:
        raise QPSolveFailed(
            f"QP solver {solver!r} is not available; installed: {sorted(qpsolvers.available_solvers)}",
            solver=solver,
        )
    options = _SOLVER_OPTIONS.get(solver, {})
    P, G = problem.P, problem.G
    if solver in _SPARSE_SOLVERS:
        P = sparse.csc_matrix(P)
        G = None if G is None else sparse.csc_matrix(G)
    x = qpsolvers.solve_qp(P, problem.q, G, problem.h, lb=problem.lb, ub=problem.ub, solver=solver, **options)
    if x is None or not np.all(np.isfinite(x)):
        raise QPSolveFailed(f"redundancy QP has no solution (solver {solver})", solver=solver)
    return np.asarray(x, dtype=float)


#: Tolerances that make the iterative solvers agree with the active-set ones to ~1e-8.
_SOLVER_OPTIONS: dict[str, dict[str, Any]] = {
    "osqp": {"eps_abs": 1e-9, "eps_rel": 1e-9, "polishing": True, "max_iter": 20000, "verbose": False},
}
_SPARSE_SOLVERS = frozenset({"osqp", "scs", "clarabel", "highs", "piqp", "proxqp", "qpalm"})
_INF = 1e30


def _solve_daqp(problem: Problem) -> Array:
    n = problem.P.shape[0]
    ub = problem.ub if problem.ub is not None else np.full(n, _INF)
    lb = problem.lb if problem.lb is not None else np.full(n, -_INF)
    if problem.G is not None and problem.h is not None:
        A, h = problem.G, problem.h
    else:
        A, h = np.zeros((0, n)), np.zeros(0)
    # DAQP treats the first len(bu) - rows(A) constraints as simple bounds on x.
    bu = np.concatenate([ub, h])
    bl = np.concatenate([lb, np.full(h.size, -_INF)])
    x, _, flag, _ = daqp.solve(problem.P, problem.q, A, bu, bl, np.zeros(bu.size, dtype=c_int))
    if flag < 1 or not np.all(np.isfinite(x)):
        raise QPSolveFailed(
            f"redundancy QP has no solution (daqp exit flag {flag})", solver="daqp", flag=int(flag)
        )
    return np.asarray(x, dtype=float)


def solve_step(
    configuration: Configuration,
    tasks: Sequence[Task],
    limits: Sequence[Limit] = (),
    solver: str = DEFAULT_SOLVER,
    damping: float = 1e-9,
    step_max: Array | None = None,
) -> Array:
    """One redundancy-resolution step dq (8,) [m, rad]."""
    return solve_problem(build_problem(configuration, tasks, limits, damping, step_max), solver)
