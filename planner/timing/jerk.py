"""Jerk-limited timing: the certified path kept exactly, a time law s(t) with bounded drive jerk.

The stage (:class:`JerkLimitedStage`, protocol :class:`~planner.timing.stage.TimingStage`) chooses the
time law of a fixed geometric path by a linear program per leg in the path parameter (two for a leg with
a tight blend), solved by HiGHS (:func:`_highs`); only s(t) changes, so every position is q(s(t)) on the
certified path.

**Variables.** On a grid 0 = s_0 < ... < s_N = L (the path length): x_i = sd^2 and y_i = sdd at s_i,
the path acceleration linear in s between grid points, so x' = 2 y gives, exactly,
x_{i+1} = x_i + (y_i + y_{i+1}) ds_i (the trapezoid rule is exact for a linear integrand). Rest at both
ends with zero acceleration: x_0 = x_N = y_0 = y_N = 0. The first and last intervals are constant-jerk
phases from and into rest (s = J t^3 / 6, so x = c s^{4/3}, y = x' / 2 and x_1 = 1.5 y_1 ds_0: a law linear
in s there would take infinitely long to leave rest); their path jerk J = sqrt(y_1^3 / (6 ds_0)) is
bounded by bounding y_1. The grid is refined towards both ends (:data:`END_LEVELS`) and along blends.

**Constraints** (the drive path u(s) of the robot, its derivatives u', u'', u''' along s):

- velocity |u'_j| sd <= v_max: a bound on x_i, and a row at the middle of each interval;
- acceleration |u'_j y + u''_j x| <= a_max at every grid point and interval middle;
- force (a robot with a dynamics model) |A_j y + B_j x + C_j| <= F_max, the inverse dynamics with the
  payload split as in :mod:`planner.timing.toppra` (C at rest, A per unit sdd, B per unit sd^2);
- jerk: the drive jerk is d/dt (u' sdd + u'' sd^2) = sd (u' y' + 3 u'' y + u''' x) with y' = dy/ds
  constant on each interval. It is bilinear in sd; bounding sd by a reference speed sd_ref >= sd (the LP
  also imposes x <= sd_ref^2) makes it linear and conservative,
  |u'_j y' + 3 u''_j y + u'''_j x| <= j_max / sd_ref, imposed at both ends of every interval.

Rows that cannot bind (their largest value over the bounds the other rows imply is below their limit)
are dropped before the solve: per grid point one or two drives bind, and HiGHS's time grows with the rows.

**Reference speed.** The time-optimal acceleration-limited law on the same grid
(:func:`planner.timing.acc_reference.acceleration_limited`, the forward-backward pass) averaged in time over
one acceleration ramp a_max / j_max (a box filter: on a straight line that cruises this is the
time-optimal jerk-limited law, Biagiotti & Melchiorri, *Trajectory Planning for Automatic Machines and
Robots*, 2008, sec. 4.2.3). Where the jerk binds elsewhere (blends, moves too short to cruise) the LP
stays below it; where it stays far below (a tight blend, whose curvature changes over millimetres, is
crossed at a fraction of the reference speed) for more than :data:`REFINE_SHARE` of the leg's time, the
LP is solved once more with the reference there lowered to :data:`TRUST`^2 times its law (still
conservative), which loosens the jerk rows the first solve over-tightened.

**Objective.** The duration sum_i h_i / sqrt(x_i) (h_i the grid share of point i), by its epigraph over
:data:`TANGENTS` of the convex 1 / sqrt(x): maximising sum x_i instead (the acceleration-limited
optimum) let the jerk LP stop at one point to gain speed elsewhere.

**Check.** The law is sampled at the controller period exactly as the gate sees it (jerk = the change of
the sampled acceleration over one period; velocity, acceleration, force); an excess re-solves with that
limit's fraction tightened, and a law that still fails after :data:`MAX_ITERATIONS` is refused
(:class:`~planner.core.exceptions.RetimingFailed`), never returned.

The path must be curvature-continuous (C2) for a finite jerk at speed: the planner's corner blends are
(:class:`~planner.timing.path.BlendPiece`). Where u'' still jumps at a piece boundary (a path built
elsewhere), the drive acceleration steps by Delta u'' sd^2 within one period, so sd is capped there to
keep that step within :data:`JUMP_SHARE` of one period's jerk budget.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.optimize import linprog

try:  # HiGHS's bindings as scipy ships them (see _highs)
    from scipy.optimize._highspy import _core
except ImportError:  # pragma: no cover
    _core = None

from planner.core.exceptions import RetimingFailed
from planner.core.timing_names import JERK_LIMITED
from planner.core.types import Array
from planner.dynamics.models import drive_dynamics
from planner.dynamics.payload import RigidPayload
from planner.robots.base import RobotModel
from planner.timing.acc_reference import acceleration_limited
from planner.timing.path import JointPath, LinePiece
from planner.timing.stage import DEFAULT_SAFETY, Safety
from planner.timing.toppra import ToppraStage, ToppraTimedPath

log = logging.getLogger(__name__)

#: Re-solves of one path after a sampled limit excess before the stage refuses it.
MAX_ITERATIONS = 6
#: A law longer than this many times the path's time at full speed (+ 1 s) stops inside the path: refused.
MAX_SLOWDOWN = 100.0
#: Fraction of one period's jerk budget a curvature jump of the path may take (paths that are not C2).
JUMP_SHARE = 0.8
#: Fractions of the jerk limits the LP aims at, and how far above it a sampled law is still accepted
#: (the gate allows 1% above the limits).
JERK_TARGET = 0.96
JERK_SLACK = 0.04
#: Geometric refinement of the grid towards each end (END_LEVELS points, each END_RATIO times nearer the
#: end): the constant-jerk ramp from rest covers only s ~ J t^3 / 6 (0.02 path units for the rail's 0.25 s
#: ramp), and there sd changes by large factors per interval (halvings lost 1-3% of the duration).
END_LEVELS = 20
END_RATIO = 0.5**0.5
#: Sub-steps per grid interval of the time integral t(s) = int ds / sd (4-point Gauss-Legendre each).
SUBSTEPS = 4
#: Where the LP's law stays below its reference by more than TRUST^2 in x, it is solved once more with the
#: reference lowered to TRUST^2 times the law there (see _solve).
TRUST = 1.3
#: ... when those places take more than this share of the leg's time (on the suite: the legs with a tight
#: blend, a third of the blended ones; the others gain < 0.5% for another LP).
REFINE_SHARE = 0.05
#: Tangent points of the time objective, as fractions of the reference speed's x = sd^2.
TANGENTS = np.array([1.0, 0.4, 0.1])


@dataclass(frozen=True)
class JerkTimedPath:
    """A path with the LP's time law: x = sd^2 and y = sdd at grid points ``s``, y linear in between.

    The first and last intervals are constant-jerk phases from and into rest (see the module docstring).
    """

    path: JointPath
    s: Array = field(repr=False)  # (N + 1,) grid
    x: Array = field(repr=False)  # (N + 1,) sd^2 at the grid points
    y: Array = field(repr=False)  # (N + 1,) sdd at the grid points
    t: Array = field(repr=False)  # (N + 1,) time at the grid points
    _sub_s: Array = field(repr=False)  # (N, SUBSTEPS + 1) offsets into each interval
    _sub_t: Array = field(repr=False)  # (N, SUBSTEPS + 1) time from each interval's start

    @classmethod
    def of(cls, path: JointPath, s: Array, x: Array, y: Array) -> JerkTimedPath:
        """The time law of the grid values (x, y), its times integrated from t(s) = int ds / sd."""
        ds = np.diff(s)
        n = len(ds)
        x = np.maximum(np.asarray(x, dtype=float), 0.0)
        x[[0, -1]] = 0.0
        y = np.asarray(y, dtype=float).copy()
        y[[0, -1]] = 0.0
        sub_s = ds[:, None] * np.linspace(0.0, 1.0, SUBSTEPS + 1)[None, :]
        # Gauss-Legendre (4 points) on each sub-step of int 1 / sqrt(x(sigma)), x quadratic in sigma.
        g, wg = np.polynomial.legendre.leggauss(4)
        a, b = sub_s[:, :-1], sub_s[:, 1:]
        mid, half = (a + b) / 2, (b - a) / 2
        sig = mid[:, :, None] + half[:, :, None] * g[None, None, :]
        xs = _x_inside(x, y, ds, np.arange(n)[:, None, None], sig)
        with np.errstate(divide="ignore"):
            f = 1.0 / np.sqrt(np.maximum(xs, 1e-300))
        dt = np.sum(f * wg[None, None, :], axis=2) * half
        sub_t = np.concatenate([np.zeros((n, 1)), np.cumsum(dt, axis=1)], axis=1)
        # The end phases in closed form: t = (6 ds / J)^(1/3), s = J t^3 / 6.
        for i in (0, n - 1):
            k = 1 if i == 0 else n - 1
            J = _end_jerk(abs(y[k]), ds[i])
            if i == 0:
                sub_t[i] = np.cbrt(6.0 * sub_s[i] / J)
            else:
                sub_t[i] = np.cbrt(6.0 * ds[i] / J) - np.cbrt(6.0 * (ds[i] - sub_s[i]) / J)
        t = np.concatenate([[0.0], np.cumsum(sub_t[:, -1])])
        return cls(path, np.asarray(s, dtype=float), x, y, t, sub_s, sub_t)

    @property
    def duration(self) -> float:
        """Duration of the time law [s]."""
        return float(self.t[-1])

    def state(self, times: Array, order: int = 2) -> tuple[Array, ...]:
        """s, sd, sdd (and sddd for ``order`` 3) at times (N,) in [0, duration]."""
        tq = np.clip(np.atleast_1d(np.asarray(times, dtype=float)), 0.0, self.duration)
        n = len(self.s) - 1
        ds = np.diff(self.s)
        i = np.clip(np.searchsorted(self.t, tq, side="right") - 1, 0, n - 1)
        tau = tq - self.t[i]
        # Interior intervals: invert t(sigma) on the sub-steps by cubic Hermite interpolation
        # (d sigma / dt = sd), then sd and sdd from the interval's model.
        st, ss = self._sub_t[i], self._sub_s[i]
        k = np.clip(np.sum(st[:, 1:] <= tau[:, None], axis=1), 0, SUBSTEPS - 1)
        rows = np.arange(len(tq))
        t0, t1 = st[rows, k], st[rows, k + 1]
        s0, s1 = ss[rows, k], ss[rows, k + 1]
        v0 = np.sqrt(np.maximum(_x_inside(self.x, self.y, ds, i, s0), 0.0))
        v1 = np.sqrt(np.maximum(_x_inside(self.x, self.y, ds, i, s1), 0.0))
        h = np.maximum(t1 - t0, 1e-300)
        u = np.clip((tau - t0) / h, 0.0, 1.0)
        h00, h10 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u
        h01, h11 = -2 * u**3 + 3 * u**2, u**3 - u**2
        sigma = np.clip(h00 * s0 + h10 * h * v0 + h01 * s1 + h11 * h * v1, 0.0, ds[i])
        w = (self.y[i + 1] - self.y[i]) / ds[i]
        sd = np.sqrt(np.maximum(_x_inside(self.x, self.y, ds, i, sigma), 0.0))
        sdd = self.y[i] + w * sigma
        sddd = sd * w
        # The end phases in closed form.
        for end in (0, n - 1):
            sel = i == end
            if not sel.any():
                continue
            kk = 1 if end == 0 else n - 1
            J = _end_jerk(abs(self.y[kk]), ds[end])
            if end == 0:
                r = tau[sel]
                sigma[sel], sd[sel], sdd[sel], sddd[sel] = J * r**3 / 6, J * r**2 / 2, J * r, J
            else:
                r = np.maximum(self._sub_t[end, -1] - tau[sel], 0.0)
                sigma[sel] = ds[end] - J * r**3 / 6
                sd[sel], sdd[sel], sddd[sel] = J * r**2 / 2, -J * r, J
        s = np.clip(self.s[i] + sigma, 0.0, self.path.length)
        out = (s, sd, sdd, sddd)
        return out[: order + 1]


def _x_inside(x: Array, y: Array, ds: Array, i: Any, sigma: Array) -> Array:
    """Path speed squared at offset sigma into interval i: x_i + 2 y_i sigma + w sigma^2 (w = dy/ds)."""
    return x[i] + 2.0 * y[i] * sigma + (y[i + 1] - y[i]) / ds[i] * sigma**2


def _end_jerk(y_inner: float, ds_end: float) -> float:
    """Path jerk of a constant-jerk phase from rest reaching sdd = ``y_inner`` after ``ds_end``."""
    return float(np.sqrt(max(y_inner, 1e-12) ** 3 / (6.0 * ds_end)))


@dataclass(frozen=True)
class _Coefficients:
    """The drive path and the force split at the grid points (see the module docstring)."""

    du: Array  # (N + 1, m) u'
    du_mid: Array  # (N, m) u' at the middle of each interval
    ddu: Array  # (N + 1, m) u'' (from the right at a piece boundary)
    ddu_left: Array  # (N + 1, m) u'' from the left (differs at a boundary where the path is not C2)
    ddu_mid: Array  # (N, m) u'' at the middle of each interval
    dddu: Array  # (2, N, m) u''' at the start and the end of each interval
    force: tuple[Array, Array, Array] | None  # A, B, C (N + 1, m)


@dataclass(frozen=True)
class _Sampled:
    """A law sampled at the controller period: the peak ratios to the limits."""

    velocity: float
    acceleration: float
    effort: float
    jerk: float


@dataclass
class JerkLimitedStage:
    """Jerk-limited timing of a path by an LP in the path parameter (see the module docstring).

    Attributes:
        robot: The robot model (its limits must include jerk limits).
        payload: The carried payload's inertial data (None: empty gripper).
        safety: Fractions of the (velocity, acceleration, force) limits the law may use; the acceleration
            fraction also scales the jerk target (:data:`JERK_TARGET`), so a re-timing after a jerk
            failure tightens it.
        sample_period_s: The controller period the law is checked at (the gate's jerk is the change of
            the sampled acceleration over one period).
        grid_step: Grid spacing in path units (time-like, [s] at full speed); blends get half of it (at
            least 8 intervals) and each end :data:`END_LEVELS` points more. On the suite 0.15 gives the
            durations of 0.08 within 0.1% with a third of the rows (0.2: within 0.2%).
        min_points: Fewest grid intervals of a leg (before the end refinement).
        max_points: Most grid intervals of a leg (before the end refinement).
    """

    robot: RobotModel
    payload: RigidPayload | None = None
    safety: Safety = DEFAULT_SAFETY
    sample_period_s: float = 0.004
    grid_step: float = 0.15
    min_points: int = 24
    max_points: int = 3000
    name: str = JERK_LIMITED

    def __post_init__(self) -> None:
        if self.robot.limits.j_max is None:
            raise RetimingFailed(f"robot {self.robot.name!r} has no jerk limits in its description")
        self.dynamics = drive_dynamics(self.robot)

    def time_path(self, path: JointPath) -> JerkTimedPath:
        """The jerk-limited law of ``path``, rest to rest (raises RetimingFailed)."""
        s = self._grid(path)
        if self.dynamics is not None:
            overload = ToppraStage(self.robot, self.payload, self.safety)._static_overload(path, s)
            if overload is not None:
                raise overload
        coef = self._coefficients(path, s)
        sv, sa, sf = self.safety
        j_target = JERK_TARGET * sa / DEFAULT_SAFETY[1]  # the jerk target tightens with the acceleration
        frac = [sv, sa, sf, j_target]
        targets = (min(1.005, sv + 0.01), min(1.0, sa + 0.02), min(1.0, sf + 0.02))
        last: _Sampled | None = None
        for _ in range(MAX_ITERATIONS):
            x, y = self._solve(path, s, coef, (frac[0], frac[1], frac[2], frac[3]))
            timed = JerkTimedPath.of(path, s, x, y)
            if not np.isfinite(timed.duration) or timed.duration > MAX_SLOWDOWN * (path.length + 1.0):
                # A law that (nearly) stops inside the path: the LP found no way through at speed.
                raise RetimingFailed(
                    f"the jerk-limited law would take {timed.duration:.3g} s for a path of "
                    f"{path.length:.3g} s at full speed",
                    stage=self.name,
                )
            last = self._sample(timed)
            if log.isEnabledFor(logging.DEBUG):
                log.debug(
                    "fractions %s: duration %.3f s, v %.3f a %.3f f %.3f j %.3f",
                    np.round(frac, 3),
                    timed.duration,
                    last.velocity,
                    last.acceleration,
                    last.effort,
                    last.jerk,
                )
            ratios = (last.velocity, last.acceleration, last.effort)
            over = [r > tgt for r, tgt in zip(ratios, targets, strict=True)]
            j_over = last.jerk > j_target + JERK_SLACK
            if not any(over) and not j_over:
                return timed
            for k, r in enumerate(ratios):
                if over[k]:
                    frac[k] *= 0.998 * targets[k] / r
            if j_over:
                frac[3] *= 0.998 * (j_target + JERK_SLACK) / last.jerk
        assert last is not None
        raise RetimingFailed(
            f"no jerk-limited time law within the drive limits after {MAX_ITERATIONS} re-timings (peak "
            f"ratios: velocity {last.velocity:.3f}, acceleration {last.acceleration:.3f}, force "
            f"{last.effort:.3f}, jerk {last.jerk:.3f})",
            stage=self.name,
        )

    # ------------------------------------------------------------------ pieces
    def _grid(self, path: JointPath) -> Array:
        """Uniform grid with every piece boundary, curved pieces refined, each end refined geometrically."""
        length = path.length
        n = int(np.clip(np.ceil(length / self.grid_step), self.min_points, self.max_points))
        uniform = np.linspace(0.0, length, n + 1)
        keep = np.ones(len(uniform), dtype=bool)
        pts = [path.breaks]
        for k, piece in enumerate(path.pieces):
            if not isinstance(piece, LinePiece):  # its own evenly spaced points only (no sliver intervals)
                a = path.breaks[k]
                keep &= ~((uniform > a) & (uniform < path.breaks[k + 1]))
                m = int(np.clip(np.ceil(piece.length / (0.5 * self.grid_step)), 8, 400))
                pts.append(a + np.linspace(0.0, piece.length, m + 1))
        pts.append(uniform[keep])
        end = min(self.grid_step, 0.25 * length) * np.power(END_RATIO, np.arange(1.0, END_LEVELS + 1))
        pts += [end, length - end]
        grid = np.unique(np.clip(np.concatenate(pts), 0.0, length))
        keep = np.concatenate([[True], np.diff(grid) > 1e-9 * max(length, 1.0)])
        grid = grid[keep]
        grid[-1] = length
        return grid

    def _coefficients(self, path: JointPath, s: Array) -> _Coefficients:
        """u', u'' (both sides of the piece boundaries), u''' per interval and the force split."""
        q, dq, ddq = path.evaluate(s)
        _, du, ddu = self.robot.drive_path(q, dq, ddq)
        ddu_left = ddu.copy()
        inner = np.flatnonzero(np.isin(s, path.breaks[1:-1]))
        if len(inner):
            eps = 1e-9 * max(path.length, 1.0)
            ql, dql, ddql = path.evaluate(s[inner] - eps)
            ddu_left[inner] = self.robot.drive_path(ql, dql, ddql)[2]
        # u''' at both ends of each interval: u'' quadratic through its ends and midpoint (exact for the
        # blends' quadratic q'' along a joint-space path; u''' may step at a piece boundary).
        ds = np.diff(s)[:, None]
        qm, dqm, ddqm = path.evaluate(0.5 * (s[1:] + s[:-1]))
        _, du_mid, ddu_mid = self.robot.drive_path(qm, dqm, ddqm)
        a, mid, b = ddu[:-1], ddu_mid, ddu_left[1:]
        dddu = np.stack([(-3 * a + 4 * mid - b) / ds, (a - 4 * mid + 3 * b) / ds])
        force = None
        if self.dynamics is not None:
            z = np.zeros_like(q)
            tau = self.dynamics.drive_forces_batch(
                np.vstack([q, q, q]), np.vstack([z, z, dq]), np.vstack([z, dq, ddq]), self.payload
            )
            n = len(s)
            force = (tau[n : 2 * n] - tau[:n], tau[2 * n :] - tau[:n], tau[:n])
        return _Coefficients(du, du_mid, ddu, ddu_left, ddu_mid, dddu, force)

    def _solve(
        self, path: JointPath, s: Array, c: _Coefficients, frac: tuple[float, float, float, float]
    ) -> tuple[Array, Array]:
        """The jerk LP (see the module docstring): grid values x = sd^2, y = sdd.

        Columns: x_0..x_N, y_0..y_N, then the time epigraph tau_1..tau_{N-1} of the inner points.
        """
        lim = self.robot.limits
        assert lim.j_max is not None
        sv, sa, sf, sj = frac
        n = len(s) - 1
        ds = np.diff(s)
        X, Y, T = np.arange(n + 1), n + 1 + np.arange(n + 1), 2 * (n + 1) + np.arange(n - 1)
        pts, iv = np.arange(1, n), np.arange(1, n - 1)  # inner points, inner intervals
        v_max, a_max = sv * lim.v_max, sa * lim.a_max
        du_abs = np.maximum(np.abs(c.du), 1e-300)
        # Bounds. Velocity at each point and the middle of its intervals (u' changes along a blend);
        # the speed caps where u'' jumps; rest at both ends.
        x_max = np.min(np.minimum(v_max / du_abs, 1e3) ** 2, axis=1)
        x_mid = np.min(np.minimum(v_max / np.maximum(np.abs(c.du_mid), 1e-300), 1e3) ** 2, axis=1)
        x_max[:-1] = np.minimum(x_max[:-1], x_mid)
        x_max[1:] = np.minimum(x_max[1:], x_mid)
        jump = np.abs(c.ddu - c.ddu_left)
        if np.any(jump > 0):
            budget = JUMP_SHARE * sj * lim.j_max * self.sample_period_s
            x_max = np.minimum(x_max, np.min(budget / np.maximum(jump, 1e-300), axis=1))
        jm = sj * lim.j_max
        y_lo, y_hi = np.full(n + 1, -np.inf), np.full(n + 1, np.inf)
        # Constant-jerk end phases: J = sqrt(y^3 / (6 ds)) <= the path jerk every drive allows there.
        for k, inner, e in ((0, 1, 0), (n, n - 1, n - 1)):
            J = float(np.min(jm / np.maximum(du_abs[k], du_abs[inner])))
            y_end = float(np.cbrt(6.0 * ds[e] * J**2))
            if k == 0:
                y_hi[inner] = y_end
            else:
                y_lo[inner] = -y_end
        y_lo[[0, n]] = y_hi[[0, n]] = 0.0
        # |y| at each point is at most what its tightest acceleration row allows (for pruning).
        y_best = np.full(n + 1, np.inf)
        for ddu in (c.ddu, c.ddu_left):
            y_best = np.minimum(y_best, np.min((a_max + np.abs(ddu) * x_max[:, None]) / du_abs, axis=1))

        # Dynamics: x_{i+1} = x_i + (y_i + y_{i+1}) ds_i; the end phases x = 1.5 |y| ds.
        rows = _Rows()  # the equalities first (row_lo = row_hi = 0), then the inequalities
        rows.add([X[iv + 1], X[iv], Y[iv], Y[iv + 1]], [1.0, -1.0, -ds[iv], -ds[iv]], np.zeros(len(iv)))
        rows.add(
            [X[[1, n - 1]], Y[[1, n - 1]]], [1.0, np.array([-1.5 * ds[0], 1.5 * ds[n - 1]])], np.zeros(2)
        )
        n_eq = rows.n
        # Acceleration and force rows at the inner points (both sides of a boundary where u'' jumps).
        left = pts[np.any(jump[pts] > 0, axis=1)]
        for ddu, at in ((c.ddu, pts), (c.ddu_left, left)):
            rows.two_sided([X[at], Y[at]], [ddu[at], c.du[at]], a_max, None, [x_max[at], y_best[at]])
        if c.force is not None:
            A, B, C = c.force
            rows.two_sided(
                [X[pts], Y[pts]], [B[pts], A[pts]], sf * lim.effort_max, C[pts], [x_max[pts], y_best[pts]]
            )
        # The middle of each inner interval (x is quadratic there, u' and u'' change along a blend):
        # x_mid = x_i + ds (0.75 y_i + 0.25 y_{i+1}) within the velocity bound there, and the
        # acceleration rows with y_mid = (y_i + y_{i+1}) / 2.
        if len(iv):
            rows.add([X[iv], Y[iv], Y[iv + 1]], [1.0, 0.75 * ds[iv], 0.25 * ds[iv]], x_mid[iv])
            dm, ddm = c.du_mid[iv], c.ddu_mid[iv]
            d = ds[iv, None]
            y_mid = np.maximum(y_best[iv], y_best[iv + 1])
            rows.two_sided(
                [X[iv], Y[iv], Y[iv + 1]],
                [ddm, 0.75 * d * ddm + 0.5 * dm, 0.25 * d * ddm + 0.5 * dm],
                a_max,
                None,
                [x_mid[iv], y_mid, y_mid],
            )

        # The reference: the acceleration-limited law (forward-backward pass), averaged over a ramp time.
        ref = [
            (c.ddu, c.du, np.broadcast_to(a_max, c.du.shape)),
            (-c.ddu, -c.du, np.broadcast_to(a_max, c.du.shape)),
        ]
        if c.force is not None:
            A, B, C = c.force
            ref += [(B, A, sf * lim.effort_max - C), (-B, -A, sf * lim.effort_max + C)]
        cx, cy, cb = (np.hstack([r[k] for r in ref]) for k in range(3))
        x_acc = acceleration_limited(ds, cx, cy, cb, x_max)
        window = float(np.max(a_max / jm))  # the ramp time of the slowest acceleration change
        x_ref = np.maximum(np.minimum(x_acc, self._box_reference(path, s, x_acc, window)), 1e-12)
        h = (ds[:-1] + ds[1:]) / 2  # each inner point's share of the path
        nc = 3 * n + 1
        cost = np.zeros(nc)
        cost[T] = 1.0

        def solve(x_cap: Array) -> Array:
            """The LP with x <= x_cap and the jerk rows linearised at sd_ref = sqrt(x_cap)."""
            lp = rows.copy()
            self._jerk_rows(lp, c, ds, np.sqrt(x_cap), jm, x_cap, y_best)
            # The time sum h_i / sqrt(x_i), by its epigraph over tangents of the convex 1 / sqrt(x).
            xr = x_cap[1:-1, None] * TANGENTS[None, :]
            slope = -0.5 * h[:, None] * xr**-1.5
            icpt = h[:, None] * xr**-0.5 - slope * xr
            k = len(TANGENTS)
            lp.add([np.repeat(X[1:-1], k), np.repeat(T, k)], [slope.ravel(), -1.0], -icpt.ravel())
            lo = np.concatenate([np.zeros(n + 1), y_lo, np.zeros(n - 1)])
            hi = np.concatenate([x_cap, y_hi, np.full(n - 1, np.inf)])
            lo[X[[0, n]]] = hi[X[[0, n]]] = 0.0
            A, row_hi = lp.matrix(nc)
            row_lo = np.full(len(row_hi), -np.inf)
            row_lo[:n_eq] = row_hi[:n_eq]
            z, message = _highs(cost, A, row_lo, row_hi, lo, hi)
            if z is None:
                raise RetimingFailed(
                    f"no time law satisfies the drive limits along the path (HiGHS: {message})",
                    stage=self.name,
                )
            return z

        z = solve(x_ref)
        # Where the law stays far below its reference (a tight blend: the jerk binds at a speed the
        # reference does not know), the jerk rows assumed too high a speed: once more with the reference
        # lowered there to TRUST^2 times the law (still conservative: x <= the new cap).
        x1 = np.maximum(z[X], 0.0)
        low = x1[1:-1] * TRUST**2 < x_ref[1:-1]
        dt = h / np.sqrt(np.maximum(x1[1:-1], 1e-12))  # each inner point's share of the duration
        if np.sum(dt[low]) > REFINE_SHARE * np.sum(dt):
            x_cap = x_ref.copy()
            x_cap[1:-1] = np.where(low, np.maximum(x1[1:-1] * TRUST**2, 1e-12), x_ref[1:-1])
            z = solve(x_cap)
        return np.maximum(z[X], 0.0), z[Y]

    def _box_reference(self, path: JointPath, s: Array, x: Array, window: float) -> Array:
        """sd^2 at the grid of the acceleration-limited law averaged over one acceleration ramp time.

        On a straight line that cruises, this box filter of the time law is the time-optimal jerk-limited
        law (Biagiotti & Melchiorri 2008, sec. 4.2.3); it is the jerk LP's reference speed.
        """
        sd = np.sqrt(x)
        dt_grid = 2.0 * np.diff(s) / np.maximum(sd[:-1] + sd[1:], 1e-12)
        base = ToppraTimedPath(path, s, sd, np.concatenate([[0.0], np.cumsum(dt_grid)]))
        lag = 16
        dt = window / lag
        t = np.arange(0.0, base.duration + window + dt, dt)
        s0 = base.state(t, 0)[0]
        s0 = np.where(t > base.duration, path.length, s0)
        past = np.concatenate([np.zeros(lag), s0[:-lag]])
        sd_box = (s0 - past) / window
        # The averaged law's position: the trapezoid rule of s0 over the window.
        cs = np.concatenate([[0.0], np.cumsum((s0[1:] + s0[:-1]) / 2 * dt)])
        cs_past = np.concatenate([np.zeros(lag), cs[:-lag]])
        pos = np.maximum.accumulate((cs - cs_past) / window)
        return np.asarray(np.interp(s, pos, sd_box**2))

    def _jerk_rows(
        self, rows: _Rows, c: _Coefficients, ds: Array, sd_ref: Array, jm: Array, x_box: Array, y_best: Array
    ) -> None:
        """|u'_j (y_{i+1} - y_i) / ds_i + 3 u''_j y_k + u'''_j x_k| <= j_max / sd_ref_k at both ends k.

        Pruned: row j bounds |y'| by (bound + E) / |u'_j| and is implied where (bound - E) / |u'_j| lies
        above the tightest such bound (E: the largest |3 u'' y + u''' x| within the bounds).
        """
        n = len(ds)
        iv = np.arange(1, n - 1)
        X, Y = np.arange(n + 1), n + 1 + np.arange(n + 1)
        for end in (0, 1):
            k = iv + end
            ddu = c.ddu[k] if end == 0 else c.ddu_left[k]
            du, dddu = c.du[k], c.dddu[end, iv]
            bound = jm[None, :] / np.maximum(sd_ref[k], 1e-9)[:, None]
            E = 3 * np.abs(ddu) * y_best[k, None] + np.abs(dddu) * x_box[k, None]
            dua = np.maximum(np.abs(du), 1e-300)
            w_best = np.min((bound + E) / dua, axis=1)
            ii, jj = np.nonzero(dua * w_best[:, None] + E >= bound * (1 - 1e-9))
            i, kk, w = iv[ii], k[ii], du[ii, jj] / ds[iv[ii]]
            rows.add_pairs(
                [Y[i + 1], Y[i], Y[kk], X[kk]], [w, -w, 3 * ddu[ii, jj], dddu[ii, jj]], bound[ii, jj], None
            )

    def _sample(self, timed: JerkTimedPath) -> _Sampled:
        """The law sampled at the controller period, as the gate sees it (peak ratios to the limits)."""
        lim = self.robot.limits
        assert lim.j_max is not None
        dt = self.sample_period_s
        n = max(1, int(np.ceil(timed.duration / dt - 1e-9)))
        t = np.linspace(0.0, timed.duration, n + 1)  # the sampler's slowed grid (whole periods)
        h = t[1] - t[0]
        s, sd, sdd = timed.state(t, 2)
        q, dq, ddq = timed.path.evaluate(s)
        _, du, ddu = self.robot.drive_path(q, dq, ddq)
        ud = du * sd[:, None]
        udd = du * sdd[:, None] + ddu * (sd**2)[:, None]
        udd[[0, -1]] = 0.0
        jerk = np.abs(np.diff(udd, axis=0)) / h / lim.j_max[None, :]
        effort = 0.0
        if self.dynamics is not None:
            qd = dq * sd[:, None]
            qdd = dq * sdd[:, None] + ddq * (sd**2)[:, None]
            # Every 3rd sample: the forces change slowly, the gate checks every sample and a re-timing
            # with tighter force limits follows a failure there.
            tau = self.dynamics.drive_forces_batch(q[::3], qd[::3], qdd[::3], self.payload)
            effort = float(np.max(np.abs(tau) / lim.effort_max[None, :]))
        return _Sampled(
            velocity=float(np.max(np.abs(ud) / lim.v_max[None, :])),
            acceleration=float(np.max(np.abs(udd) / lim.a_max[None, :])),
            effort=effort,
            jerk=float(jerk.max(initial=0.0)),
        )


class _Rows:
    """Sparse LP rows sum_t coef_t z[col_t] <= rhs, collected as triplets (one matrix at the end)."""

    def __init__(self) -> None:
        self.r: list[Any] = []
        self.c: list[Any] = []
        self.v: list[Array] = []
        self.b: list[Array] = []
        self.n = 0

    def add(self, cols: list[Any], coefs: list[Any], rhs: Array) -> None:
        """Rows with one term per entry of ``cols`` (index arrays (k,)), coefficients (k,) or scalars."""
        k = len(rhs)
        if k == 0:
            return
        r = self.n + np.arange(k)
        for col, coef in zip(cols, coefs, strict=True):
            self.r.append(r)
            self.c.append(np.asarray(col))
            self.v.append(np.broadcast_to(np.asarray(coef, dtype=float), (k,)))
        self.b.append(np.asarray(rhs, dtype=float))
        self.n += k

    def add_pairs(self, cols: list[Any], coefs: list[Any], bound: Array, offset: Array | None) -> None:
        """Two-sided rows |sum coef z + offset| <= bound."""
        o = np.zeros_like(bound) if offset is None else offset
        self.add(cols, coefs, bound - o)
        self.add(cols, [-np.asarray(cf) for cf in coefs], bound + o)

    def two_sided(
        self, cols: list[Any], coefs: list[Array], bound: Array, offset: Array | None, box: list[Array]
    ) -> None:
        """|sum_t coef_t z_t + offset| <= bound per point and drive (coefs (k, m)), the rows that can bind.

        A row whose largest value with each |z_t| <= box_t (k,) (bounds the kept rows imply) stays below
        its limit is dropped.
        """
        b = np.broadcast_to(bound, coefs[0].shape)
        o = np.zeros_like(coefs[0]) if offset is None else offset
        peak = np.abs(o) + sum(
            np.abs(cf) * np.minimum(bx, 1e12)[:, None] for cf, bx in zip(coefs, box, strict=True)
        )
        ii, jj = np.nonzero(peak >= b * (1 - 1e-9))
        self.add_pairs([col[ii] for col in cols], [cf[ii, jj] for cf in coefs], b[ii, jj], o[ii, jj])

    def copy(self) -> _Rows:
        """A row set with these rows, to add more to."""
        out = _Rows()
        out.r, out.c, out.v, out.b, out.n = list(self.r), list(self.c), list(self.v), list(self.b), self.n
        return out

    def matrix(self, n_cols: int) -> tuple[sp.csc_matrix, Array]:
        """The rows as one sparse matrix (n rows, n_cols) and their right-hand sides."""
        if not self.b:
            return sp.csc_matrix((0, n_cols)), np.zeros(0)
        M = sp.coo_matrix(
            (np.concatenate(self.v), (np.concatenate(self.r), np.concatenate(self.c))), shape=(self.n, n_cols)
        )
        return M.tocsc(), np.concatenate(self.b)


def _highs(
    cost: Array, A: sp.csc_matrix, row_lo: Array, row_hi: Array, col_lo: Array, col_hi: Array
) -> tuple[Array | None, str]:
    """Minimise cost . z subject to row_lo <= A z <= row_hi, col_lo <= z <= col_hi (HiGHS).

    HiGHS is called through the bindings scipy ships (``scipy.optimize._highspy``, the ones behind
    ``linprog(method="highs")``): ``linprog``'s input checks and its per-column Python loop over the
    bound multipliers cost as much as the solve on these LPs. They are scipy's private module (scipy is
    pinned exactly); without them, the same LP goes through the public ``linprog`` (:func:`_linprog`, the
    same solutions, tested), so a scipy that moves them costs speed, never a wrong law.

    Returns:
        The solution (None if the LP has none) and HiGHS's status message.
    """
    if _core is None:
        return _linprog(cost, A, row_lo, row_hi, col_lo, col_hi)
    lp = _core.HighsLp()
    lp.num_col_, lp.num_row_ = A.shape[1], A.shape[0]
    lp.col_cost_, lp.col_lower_, lp.col_upper_ = cost, col_lo, col_hi
    lp.row_lower_, lp.row_upper_ = row_lo, row_hi
    m = lp.a_matrix_
    m.format_ = _core.MatrixFormat.kColwise
    m.num_col_, m.num_row_ = A.shape[1], A.shape[0]
    m.start_, m.index_, m.value_ = A.indptr, A.indices, A.data
    highs = _core._Highs()
    highs.setOptionValue("output_flag", False)
    highs.passModel(lp)
    highs.run()
    status = highs.getModelStatus()
    message = highs.modelStatusToString(status)
    if status != _core.HighsModelStatus.kOptimal:
        return None, message
    return np.asarray(highs.getSolution().col_value), message


def _linprog(
    cost: Array, A: sp.csc_matrix, row_lo: Array, row_hi: Array, col_lo: Array, col_hi: Array
) -> tuple[Array | None, str]:
    """:func:`_highs` through the public ``linprog`` (slower): two-sided rows become two one-sided ones."""
    A = sp.csr_matrix(A)
    eq = row_lo == row_hi
    upper = ~eq & np.isfinite(row_hi)
    lower = ~eq & np.isfinite(row_lo)
    res = linprog(
        cost,
        A_ub=sp.vstack([A[upper], -A[lower]]).tocsc(),
        b_ub=np.concatenate([row_hi[upper], -row_lo[lower]]),
        A_eq=A[eq] if eq.any() else None,
        b_eq=row_hi[eq] if eq.any() else None,
        bounds=np.column_stack([col_lo, col_hi]),
        method="highs",
    )
    return (np.asarray(res.x) if res.status == 0 else None), str(res.message)
