"""Time-parameterisation of a joint path under every drive's velocity, acceleration and force limits.

The stage protocol is :class:`planner.timing.stage.TimingStage`; :class:`ToppraStage` (the
``acceleration_limited`` stage of :mod:`planner.timing.stages`, the default only for a robot without jerk
limits; it also gives the jerk-limited stage its grid's static-force check) runs TOPP-RA (Pham & Pham
2018, reachability analysis) on the drive path u(s) with

- drive velocity limits |u'(s) sd| <= v_max,
- drive acceleration limits |u'(s) sdd + u''(s) sd^2| <= a_max,
- drive force limits (a robot with a dynamics model, :func:`planner.dynamics.models.drive_dynamics`)
  |a(s) sdd + b(s) sd^2 + c(s)| <= F_max, with the inverse dynamics (payload included)
  split as tau_u(q, q' sd, q' sdd + q'' sd^2) = a sdd + b sd^2 + c; the coefficients come from three
  vectorised inverse-dynamics evaluations per grid point (c = tau_u(q, 0, 0), a = tau_u(q, 0, q') - c,
  b = tau_u(q, q', q'') - c),

at rest at both ends. The output keeps TOPP-RA's own assumption -- constant path acceleration between grid
points -- rather than fitting a spline through the grid: toppra's spline output overshoots acceleration
limits by up to 20% between grid points, the constant-acceleration profile stays within a few percent,
and the limits handed to TOPP-RA are scaled by ``safety`` so that the validation gate (1% tolerance)
holds on every sample.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from planner.core.lazy import defer

# toppra imports pyplot eagerly, for plotting helpers the planner never calls.
defer("matplotlib", "matplotlib.pyplot")
import toppra  # noqa: E402
import toppra.algorithm  # noqa: E402
import toppra.constraint  # noqa: E402
from toppra.constraint.linear_constraint import canlinear_colloc_to_interpolate  # noqa: E402

from planner.core.exceptions import RetimingFailed  # noqa: E402
from planner.core.types import Array  # noqa: E402
from planner.dynamics.models import DriveDynamics, drive_dynamics  # noqa: E402
from planner.dynamics.payload import RigidPayload  # noqa: E402
from planner.robots.base import RobotModel  # noqa: E402
from planner.timing.path import BlendPiece, JointPath, SplinePiece  # noqa: E402
from planner.timing.stage import DEFAULT_SAFETY, Safety  # noqa: E402

log = logging.getLogger(__name__)
logging.getLogger("toppra").setLevel(logging.ERROR)


@dataclass(frozen=True)
class ToppraTimedPath:
    """A path with its time law: path velocity ``sd`` at grid points ``ss``, constant sdd in between."""

    path: JointPath
    ss: Array = field(repr=False)
    sd: Array = field(repr=False)
    t: Array = field(repr=False)  # time at each grid point

    @property
    def duration(self) -> float:
        """Duration of the time law [s]."""
        return float(self.t[-1])

    def state(self, times: Array, order: int = 2) -> tuple[Array, ...]:
        """Path parameter and its derivatives (s, sd, sdd; sddd = 0 for ``order`` 3) at times (N,).

        The path acceleration is constant between grid points (TOPP-RA's own assumption), so its jerk is
        zero inside each interval and unbounded at the grid points.
        """
        times = np.clip(np.asarray(times, dtype=float), 0.0, self.duration)
        i = np.clip(np.searchsorted(self.t, times, side="right") - 1, 0, len(self.ss) - 2)
        ds = self.ss[i + 1] - self.ss[i]
        sdd = (self.sd[i + 1] ** 2 - self.sd[i] ** 2) / (2.0 * ds)
        tau = times - self.t[i]
        s = self.ss[i] + self.sd[i] * tau + 0.5 * sdd * tau**2
        sd = self.sd[i] + sdd * tau
        out = (np.minimum(s, self.ss[i + 1]), np.maximum(sd, 0.0), sdd, np.zeros_like(sdd))
        return out[: order + 1]


class _DrivePathAdapter(toppra.interpolator.AbstractGeometricPath):
    """toppra's view of the drive path u(s) (cached per grid)."""

    def __init__(self, path: JointPath, robot: RobotModel) -> None:
        self._path = path
        self._robot = robot
        self._key: bytes | None = None
        self._value: tuple[Array, ...] = ()

    def joint_values(self, ss: Array) -> tuple[Array, ...]:
        ss = np.atleast_1d(np.asarray(ss, dtype=float))
        key = ss.tobytes()
        if key != self._key:
            q, dq, ddq = self._path.evaluate(ss)
            u, du, ddu = self._robot.drive_path(q, dq, ddq)
            self._key, self._value = key, (q, dq, ddq, u, du, ddu)
        return self._value

    def __call__(self, path_positions: Any, order: int = 0) -> Array:
        scalar = np.isscalar(path_positions)
        out = self.joint_values(np.atleast_1d(path_positions))[3 + order]
        return out[0] if scalar else out

    @property
    def dof(self) -> int:
        return self._robot.n_drives

    @property
    def path_interval(self) -> Array:
        return np.array([0.0, self._path.length])

    @property
    def waypoints(self) -> None:  # pragma: no cover - toppra API
        return None


class _DriveForceConstraint(toppra.constraint.LinearConstraint):
    """|tau_u| <= F_max along the path, coefficients from the vectorised inverse dynamics."""

    def __init__(self, dynamics: DriveDynamics, payload: RigidPayload | None, f_max: Array) -> None:
        super().__init__()
        self.set_discretization_type(toppra.constraint.DiscretizationType.Interpolation)
        self.dynamics, self.payload, self.f_max = dynamics, payload, f_max
        self.dof = len(f_max)
        self.identical = False

    def compute_constraint_params(self, path: _DrivePathAdapter, gridpoints: Array) -> tuple[Any, ...]:
        q, dq, ddq = path.joint_values(gridpoints)[:3]
        z = np.zeros_like(q)
        stacked = np.vstack([q, q, q])
        qd = np.vstack([z, z, dq])
        qdd = np.vstack([z, dq, ddq])
        tau = self.dynamics.drive_forces_batch(stacked, qd, qdd, self.payload)
        n = len(gridpoints)
        c, a, b = tau[:n], tau[n : 2 * n] - tau[:n], tau[2 * n :] - tau[:n]
        eye = np.eye(self.dof)
        F = np.repeat(np.vstack([eye, -eye])[None], n, axis=0)
        g = np.repeat(np.concatenate([self.f_max, self.f_max])[None], n, axis=0)
        return canlinear_colloc_to_interpolate(a, b, c, F, g, None, None, gridpoints)


#: Offset of the grid points on either side of a piece boundary (fraction of the path length).
BREAK_OFFSET = 1e-7


def _grid(path: JointPath, step: float, min_points: int, max_points: int) -> Array:
    """Uniform grid over the lines, every piece boundary, its own finer grid inside blends and splines.

    A boundary also gets a point just inside each neighbouring piece: where the path's second derivative
    jumps (a spline meeting a line), a constraint evaluated at the boundary alone sees only one side.
    Inside a curved piece only its own evenly spaced points are used, and no uniform point lies within
    0.1 step of a boundary: a uniform point next to another one made an interval a few hundredths of the
    others, on which TOPP-RA's constant path acceleration swung (-0.12 to 0.69 to -0.06 within 4 ms on a
    quintic blend) between two samples, so the sampled velocities no longer integrated the sampled
    accelerations (the gate's consistency check; hatch-bay-insert seed 6, acceleration-limited).
    """
    length = path.length
    n = int(np.clip(np.ceil(length / step), min_points, max_points))
    breaks = np.asarray(path.breaks, dtype=float)
    inner = breaks[1:-1]
    eps = BREAK_OFFSET * max(length, 1.0)
    uniform = np.linspace(0.0, length, n + 1)
    # Uniform points near a boundary go too (the boundary is a grid point; no sliver interval beside it).
    near = np.abs(uniform[:, None] - breaks[None, :]).min(axis=1) < 0.1 * step
    keep = ~near
    keep[[0, -1]] = True
    pts = [breaks, inner - eps, inner + eps]
    for k, piece in enumerate(path.pieces):
        if isinstance(piece, BlendPiece | SplinePiece):
            a, b = breaks[k], breaks[k + 1]
            keep &= ~((uniform > a) & (uniform < b))
            pts.append(a + np.linspace(0.0, piece.length, int(np.clip(piece.length / (0.25 * step), 8, 400))))
    grid = np.unique(np.concatenate([uniform[keep], *pts]))
    return grid[np.concatenate([[True], np.diff(grid) > 1e-9])]


@dataclass
class ToppraStage:
    """TOPP-RA with drive velocity, acceleration and force limits (see the module docstring).

    Attributes:
        robot: The robot model.
        payload: The carried payload's inertial data (None: empty gripper).
        safety: Fractions of (velocity, acceleration, force) limits handed to TOPP-RA.
        grid_step: Grid spacing in path units (time-like, [s] at full speed). On the reference scenarios
            (6 x 20 seeds) 0.08 gives the durations of 0.04 (and those of 0.02) within 0.01 s, at half the
            cost, and no re-timing where 0.04 needed two: piece boundaries are grid points resolved on
            both sides, and the constant-acceleration output holds between grid points.
    """

    robot: RobotModel
    payload: RigidPayload | None = None
    safety: Safety = DEFAULT_SAFETY
    grid_step: float = 0.08
    min_points: int = 60
    max_points: int = 3000
    name: str = "toppra"

    def __post_init__(self) -> None:
        self.dynamics = drive_dynamics(self.robot)

    def time_path(self, path: JointPath) -> ToppraTimedPath:
        """TOPP-RA time law of ``path`` at rest at both ends (raises RetimingFailed)."""
        lim = self.robot.limits
        sv, sa, sf = self.safety
        adapter = _DrivePathAdapter(path, self.robot)
        vlim = np.column_stack([-sv * lim.v_max, sv * lim.v_max])
        constraints: list[toppra.constraint.Constraint] = [
            toppra.constraint.JointVelocityConstraint(vlim),
            toppra.constraint.JointAccelerationConstraint(
                np.column_stack([-sa * lim.a_max, sa * lim.a_max]),
                discretization_scheme=toppra.constraint.DiscretizationType.Interpolation,
            ),
        ]
        if self.dynamics is not None:
            constraints.append(_DriveForceConstraint(self.dynamics, self.payload, sf * lim.effort_max))
        grid = _grid(path, self.grid_step, self.min_points, self.max_points)
        # A drive that cannot even hold the payload somewhere makes the problem infeasible at any speed
        # (and gives toppra's LP a row 0 * x <= negative, which it divides by): refuse it first, by name.
        overload = self._static_overload(path, grid) if self.dynamics is not None else None
        if overload is not None:
            raise overload
        algo = toppra.algorithm.TOPPRA(constraints, adapter, gridpoints=grid, solver_wrapper="seidel")
        try:
            _, sd, _ = algo.compute_parameterization(0.0, 0.0)
        except (ZeroDivisionError, FloatingPointError, ValueError) as exc:
            raise RetimingFailed(
                f"no time law satisfies the drive limits along the path (TOPP-RA failed: {exc})",
                grid_points=len(grid),
            ) from None
        if sd is None or not np.all(np.isfinite(sd)):
            raise RetimingFailed(
                "no time law satisfies the drive limits along the path (TOPP-RA: not controllable)",
                grid_points=len(grid),
            )
        sd = np.maximum(np.asarray(sd, dtype=float), 0.0)
        ss = np.asarray(algo.gridpoints, dtype=float)
        dt = 2.0 * np.diff(ss) / np.maximum(sd[:-1] + sd[1:], 1e-12)
        return ToppraTimedPath(path, ss, sd, np.concatenate([[0.0], np.cumsum(dt)]))

    def _static_overload(self, path: JointPath, grid: Array) -> RetimingFailed | None:
        """The refusal for the first grid point whose forces at rest exceed a (scaled) limit, if any."""
        lim = self.robot.limits
        sf = self.safety[2]
        assert self.dynamics is not None
        tau = self.dynamics.static_forces_batch(path.evaluate(grid)[0], self.payload)
        over = np.abs(tau) > sf * lim.effort_max
        if not over.any():
            return None
        i, j = np.argwhere(over)[0]
        frac = float(grid[i] / path.length) if path.length > 0 else 0.0
        return RetimingFailed(
            f"drive {self.robot.drive_names[j]} would need {abs(tau[i, j]):.0f} "
            f"(limit {lim.effort_max[j]:.0f}) just to hold the payload at {100 * frac:.0f}% of the path",
            grid_points=len(grid),
            drive=self.robot.drive_names[j],
            static_force=float(tau[i, j]),
            limit=float(lim.effort_max[j]),
            path_fraction=frac,
        )
