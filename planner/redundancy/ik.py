"""Full-robot inverse kinematics of a 6-D tool pose, resolving the 2 redundant DOF.

The redundancy of cabin8 is two-dimensional and explicit: every solution is q(gamma, d5)
(:mod:`planner.kinematics.closed_form`). The solver

1. evaluates that family on a grid over the whole (gamma, d5) range, vectorised, and scores each
   admissible point by its limit and singularity margins (normalised by comfortable margins) and its
   distance to the reference posture (``near`` if given, else the preferred posture) -- a global choice
   of where on the self-motion manifold to be, which no local method can miss;
2. refines the best point with the redundancy QP of :mod:`planner.redundancy.solve`: the frame task
   (heavily weighted) plus the secondary objectives -- stay near the reference posture, keep margins
   comfortable -- under every drive limit, platform range, slider gap and singularity margin
   (linearised, never crossed) and a trust region;
3. polishes with the frame task alone, which converges quadratically to an exact solution.

If no grid point is admissible (a thin feasible region between grid points), the QP iteration runs from
the least-violating grid points and from random admissible seeds (seeded generator). When nothing
converges to an admissible configuration :class:`GoalUnreachable` reports the best residual and the
constraint that blocked the best candidate.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from planner.core.exceptions import GoalUnreachable, InvalidInput, OutsideWorkspace, QPSolveFailed
from planner.core.so3 import pose_error
from planner.core.types import Array
from planner.kinematics.closed_form import redundant_family
from planner.redundancy.compiled_step import IKStep, StepWeights
from planner.redundancy.solve import DEFAULT_SOLVER, solve_problem
from planner.robots.cabin8 import Cabin8


@dataclass(frozen=True)
class IKOptions:
    """Tuning of :func:`solve_pose_ik`; the defaults reach 1e-10 m / 1e-10 rad."""

    tol_position_m: float = 1e-10
    tol_orientation_rad: float = 1e-10
    max_iterations: int = 60
    polish_threshold: float = 1e-3
    stall_ratio: float = 0.95
    stall_steps: int = 3
    secondary_scale: float = 0.1
    n_seeds: int = 10
    max_solutions: int = 1
    seed: int = 0
    solver: str = DEFAULT_SOLVER
    posture_cost: float = 0.05
    margin_cost: float = 0.2
    lm_damping: float = 1e-3
    limit_gain: float = 0.9
    step_max_m: float = 0.10
    step_max_rad: float = 0.25
    grid_gamma: int = 21
    grid_d5: int = 21
    near_weight: float = 10.0
    preferred_weight: float = 0.5
    refine_iterations: int = 8
    refine_frame_cost: float = 30.0


@dataclass(frozen=True)
class IKSolution:
    """An admissible configuration reaching the target pose."""

    q: Array = field(repr=False)
    u: Array = field(repr=False)
    position_error_m: float
    orientation_error_rad: float
    iterations: int
    min_margin: float
    seed_index: int


def comfort_margins(robot: Cabin8) -> Array:
    """Margin to each bound the secondary objective tries to keep, in each constraint's unit.

    Drives: 5% of their range; platform y 0.02 m, gamma 0.05 rad; slider gaps 0.02 m; sin(CBD) 0.10
    above its bound; link-height ratios 0.05.
    """
    drive = 0.05 * (robot.limits.upper - robot.limits.lower)
    extra = np.array([0.02, 0.05, 0.02, 0.02, 0.10, 0.05, 0.05, 0.05])
    return np.concatenate([drive, extra])


def normalised_margin(robot: Cabin8, q: Array) -> float:
    """Smallest margin of q to any bound, as a fraction of its comfort margin (>= 1 is comfortable)."""
    return float(np.min(robot.margins(q) / comfort_margins(robot)))


def _step_max(robot: Cabin8, opts: IKOptions) -> Array:
    prismatic = np.array([u == "m" for u in robot.joint_units])
    return np.where(prismatic, opts.step_max_m, opts.step_max_rad)


def _validate_target(T: Array) -> Array:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InvalidInput("pose: expected a finite 4x4 homogeneous transform", field="pose")
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise InvalidInput("pose: rotation part is not orthonormal", field="pose")
    return T


class _Attempt:
    def __init__(self, q: Array, err: Array, iterations: int) -> None:
        self.q, self.err, self.iterations = q, err, iterations


def _converge(robot: Cabin8, q0: Array, T_target: Array, q_ref: Array, opts: IKOptions) -> _Attempt:
    """Iterate the step QP from one seed; returns the last iterate and its pose error.

    The secondary objectives' weights shrink in proportion to the pose error (full weight above
    ``secondary_scale``), so they choose where the solution lies while the error is large and fade as
    it closes: the iteration's fixed point is an exact solution, reached quadratically in the end.
    """
    step = IKStep(robot, comfort_margins(robot))
    step_max = _step_max(robot, opts)
    q = np.array(q0, dtype=float)
    err = pose_error(T_target, robot.fk(q))
    size = float(np.max(np.abs(err)))
    stalled = 0
    it = 0
    for it in range(1, opts.max_iterations + 1):  # noqa: B007 - the count is reported
        if (
            float(np.linalg.norm(err[:3])) < opts.tol_position_m
            and float(np.linalg.norm(err[3:])) < opts.tol_orientation_rad
        ):
            it -= 1
            break
        fade = min(1.0, size / opts.secondary_scale) if size > opts.polish_threshold else 0.0
        weights = StepWeights(
            1.0, 1.0, opts.lm_damping, opts.posture_cost * fade, opts.margin_cost * fade, opts.limit_gain
        )
        try:
            dq = solve_problem(step.problem(q, err, q_ref, weights, step_max), opts.solver)
        except QPSolveFailed:
            break
        q = q + dq
        new_err = pose_error(T_target, robot.fk(q))
        new_size = float(np.max(np.abs(new_err)))
        # No progress for a few steps: a limit or a local minimum holds the iterate; give up this seed.
        stalled = stalled + 1 if not new_size < opts.stall_ratio * size else 0
        err, size = new_err, new_size
        if stalled >= opts.stall_steps or not np.isfinite(size):
            break
    return _Attempt(q, err, it)


def _level_rail(robot: Cabin8, q: Array, T_target: Array) -> Array:
    """Shift d1 so the tool is at the target's z (clipped to the rail)."""
    q = q.copy()
    dz = T_target[2, 3] - robot.fk(q)[2, 3]
    q[0] = float(np.clip(q[0] + dz, robot.limits.lower[0] + 1e-6, robot.limits.upper[0] - 1e-6))
    return q


def random_admissible_joints(
    robot: Cabin8, rng: np.random.Generator, count: int, max_tries: int = 200
) -> Array:
    """Up to ``count`` admissible joint vectors drawn uniformly over the joint box (rejection sampling).

    At most ``max_tries`` vectors are drawn, in one vectorised batch.
    """
    ps = robot.desc.parallel_stage
    lo = robot.limits.lower.copy()
    hi = robot.limits.upper.copy()
    lo[1:4] = [-0.25, ps.y_range[0], -ps.gamma_max]
    hi[1:4] = [0.25, ps.y_range[1], ps.gamma_max]
    q = rng.uniform(lo, hi, size=(max(max_tries, 0), 8))
    return q[robot.admissible_batch(q)][:count].reshape(-1, 8)


@dataclass(frozen=True)
class _Scored:
    q: Array
    score: float
    min_margin: float


def family_candidates(
    robot: Cabin8, T_target: Array, u_ref: Array, ref_weight: float, opts: IKOptions
) -> tuple[list[_Scored], list[_Scored]]:
    """Grid over the redundant family: (admissible candidates best first, least-violating others first).

    Score (lower is better): ``-min(normalised margin, 1) + ref_weight * |u - u_ref|`` with the drive
    distance normalised by each drive's range.
    """
    ps = robot.desc.parallel_stage
    gammas = np.linspace(-ps.gamma_max, ps.gamma_max, opts.grid_gamma)
    d5s = np.linspace(robot.limits.lower[6], robot.limits.upper[6], opts.grid_d5)
    gg, dd = np.meshgrid(gammas, d5s, indexing="ij")
    Q = redundant_family(robot.desc.serial_chain, T_target, gg.ravel(), dd.ravel())
    c = robot.constraint_values_batch(Q)
    margins = np.minimum(c - robot.c_lower, robot.c_upper - c) / comfort_margins(robot)
    worst = np.min(np.where(np.isnan(margins), -np.inf, margins), axis=1)
    span = robot.limits.upper - robot.limits.lower
    dist = np.linalg.norm((c[:, :8] - u_ref) / span, axis=1)
    score = -np.minimum(worst, 1.0) + ref_weight * np.where(np.isfinite(dist), dist, np.inf)
    ok = worst >= 0
    good = [
        _Scored(Q[i], float(score[i]), float(worst[i])) for i in np.flatnonzero(ok)[np.argsort(score[ok])]
    ]
    rest = np.flatnonzero(~ok & np.isfinite(worst))
    bad = [_Scored(Q[i], float(score[i]), float(worst[i])) for i in rest[np.argsort(-worst[rest])]]
    return good, bad


def _refine(robot: Cabin8, q0: Array, T_target: Array, q_ref: Array, opts: IKOptions) -> Array:
    """Move along the self-motion manifold towards the secondary objectives, keeping the pose."""
    step = IKStep(robot, comfort_margins(robot))
    weights = StepWeights(
        opts.refine_frame_cost,
        opts.refine_frame_cost,
        0.0,
        opts.posture_cost,
        opts.margin_cost,
        opts.limit_gain,
    )
    step_max = 0.25 * _step_max(robot, opts)
    q = np.array(q0, dtype=float)
    for _ in range(opts.refine_iterations):
        err = pose_error(T_target, robot.fk(q))
        try:
            dq = solve_problem(step.problem(q, err, q_ref, weights, step_max), opts.solver)
        except QPSolveFailed:
            break
        q = q + dq
        if float(np.max(np.abs(dq))) < 1e-6:
            break
    return q


def _finish(
    robot: Cabin8, q: Array, T_target: Array, q_ref: Array, opts: IKOptions, k: int
) -> IKSolution | None:
    """Polish to an exact solution; None unless it is converged and admissible."""
    attempt = _converge(robot, q, T_target, q_ref, opts)
    pos = float(np.linalg.norm(attempt.err[:3]))
    ori = float(np.linalg.norm(attempt.err[3:]))
    if pos > 10 * opts.tol_position_m or ori > 10 * opts.tol_orientation_rad or robot.violations(attempt.q):
        return None
    u = robot.drives_from_joints(attempt.q)
    return IKSolution(attempt.q, u, pos, ori, attempt.iterations, normalised_margin(robot, attempt.q), k)


def track_pose(
    robot: Cabin8, q_seed: Array, T_target: Array, q_ref: Array, options: IKOptions | None = None
) -> IKSolution | None:
    """Exact IK near ``q_seed``, or ``None`` unless converged and admissible.

    Refines along the self-motion manifold (posture towards ``q_ref``, margins) with the redundancy QP,
    then polishes to the options' tolerance.

    This is the differential-IK step of Cartesian tracking: called with consecutive targets along a line
    and the previous solution as seed, it follows one continuous branch of the redundant family.
    """
    opts = options or IKOptions()
    T_target = _validate_target(T_target)
    refined = _refine(robot, np.asarray(q_seed, dtype=float), T_target, np.asarray(q_ref, dtype=float), opts)
    return _finish(robot, refined, T_target, q_ref, opts, 0)


def polish_pose(
    robot: Cabin8, q: Array, T_target: Array, options: IKOptions | None = None
) -> IKSolution | None:
    """Exact IK at ``q`` itself (no move along the self-motion manifold), or ``None`` unless admissible.

    For a point of the closed-form redundant family (already exact to rounding): polished to the options'
    tolerance where it stands, where :func:`track_pose` would first move it towards its secondary objectives.
    """
    opts = options or IKOptions()
    q = np.asarray(q, dtype=float)
    return _finish(robot, q, _validate_target(T_target), q, opts, 0)


def solve_pose_ik(
    robot: Cabin8,
    T_target: Array,
    near_drives: Array | None = None,
    preferred_drives: Array | None = None,
    options: IKOptions | None = None,
) -> IKSolution:
    """An admissible joint configuration whose tool frame is at ``T_target``.

    Args:
        robot: The robot model.
        T_target: Tool pose in the base frame (4x4).
        near_drives: Optional drive vector (8,): the solution nearest to it is preferred.
        preferred_drives: Preferred posture for the secondary objective (default: the robot's home).
        options: Solver tuning.

    Returns:
        The chosen solution; FK of ``solution.q`` matches the target to the options' tolerances and every
        limit and margin holds.

    Raises:
        InvalidInput: the target or ``near_drives`` is malformed / outside the drive workspace.
        GoalUnreachable: no admissible configuration reaches the pose; ``details`` has the best
            residual, the blocking constraint and the number of seeds tried.
    """
    opts = options or IKOptions()
    T_target = _validate_target(T_target)
    pref_u = robot.home_drives if preferred_drives is None else np.asarray(preferred_drives, dtype=float)
    try:
        q_pref = robot.joints_from_drives(pref_u)
        q_near = (
            None if near_drives is None else robot.joints_from_drives(np.asarray(near_drives, dtype=float))
        )
    except OutsideWorkspace as exc:
        raise InvalidInput(f"near/preferred drives: {exc.message}", field="near") from exc
    q_ref = q_near if q_near is not None else q_pref
    u_ref = robot.drives_from_joints(q_ref)
    weight = opts.near_weight if q_near is not None else opts.preferred_weight
    good, bad = family_candidates(robot, T_target, u_ref, weight, opts)
    for k, cand in enumerate(good[: opts.max_solutions + 2]):
        refined = _refine(robot, cand.q, T_target, q_ref, opts)
        sol = _finish(robot, refined, T_target, q_ref, opts, k) or _finish(
            robot, cand.q, T_target, q_ref, opts, k
        )
        if sol is not None:
            return sol
    # No admissible grid point: iterate from the least-violating ones and from random admissible seeds.
    rng = np.random.default_rng(opts.seed)
    seeds = [c.q for c in bad[:3]]
    seeds += [_level_rail(robot, q, T_target) for q in random_admissible_joints(robot, rng, opts.n_seeds)]
    best_err = (np.inf, np.inf)
    for k, seed_q in enumerate(seeds):
        attempt = _converge(robot, seed_q, T_target, q_ref, opts)
        pos, ori = float(np.linalg.norm(attempt.err[:3])), float(np.linalg.norm(attempt.err[3:]))
        if max(pos, ori) < max(best_err) and not robot.violations(attempt.q):
            best_err = (pos, ori)
        sol = _finish(robot, attempt.q, T_target, q_ref, opts, len(good) + k)
        if sol is not None:
            return sol
    blocking = robot.violations(bad[0].q) if bad else []
    names = sorted({v["name"] for v in blocking})
    raise GoalUnreachable(
        "pose unreachable: no admissible configuration"
        + (f" (closest candidates violate {', '.join(names)})" if names else " (the arm cannot reach it)")
        + f"; best admissible residual {best_err[0]:.3g} m, {best_err[1]:.3g} rad",
        best_position_error_m=best_err[0],
        best_orientation_error_rad=best_err[1],
        blocking=names,
        seeds=len(seeds),
    )
