"""A small generic TOPP-RA stage for a geometric path given directly in drive space.

cabin8's :class:`~planner.timing.toppra.ToppraStage` works on joint paths with a force model. Mechanisms
without a dynamics model (pprs6) give their path as a callable ``s -> (u(s), u'(s), u''(s))`` on
``[0, length]``; this stage times it rest to rest under

- drive velocity limits ``|u'(s) sd| <= v_max``,
- drive acceleration limits ``|u'(s) sdd + u''(s) sd^2| <= a_max``,

with TOPP-RA (Pham & Pham 2018). As in cabin8's stage, the output keeps TOPP-RA's constant path
acceleration between grid points (toppra's spline output overshoots acceleration limits by ~20% between
grid points), the limits are handed to TOPP-RA scaled by ``safety``, and a leg is slowed uniformly so that
it lasts a whole number of controller periods (the last sample is the end of the path, at rest).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import toppra
import toppra.algorithm
import toppra.constraint
from numpy.typing import NDArray

from planner.core.exceptions import RetimingFailed
from planner.core.types import Array

logging.getLogger("toppra").setLevel(logging.ERROR)

#: s (M,) -> (u (M, n), u' (M, n), u'' (M, n)).
PathFunction = Callable[[Array], tuple[Array, Array, Array]]


@dataclass(frozen=True)
class DrivePath:
    """A geometric drive path u(s), s in [0, length], with its first two derivatives."""

    evaluate: PathFunction
    length: float
    dof: int


@dataclass(frozen=True)
class TimeLaw:
    """Path velocity ``sd`` at grid points ``ss`` (constant sdd in between), times ``t`` at the grid.

    ``scale`` <= 1 slows the law uniformly (t -> t / scale) so that the duration is a whole number of
    periods.
    """

    ss: Array = field(repr=False)
    sd: Array = field(repr=False)
    t: Array = field(repr=False)
    scale: float = 1.0

    @property
    def duration(self) -> float:
        """Duration [s] (after scaling)."""
        return float(self.t[-1] / self.scale)

    def state(self, times: Array) -> tuple[Array, Array, Array]:
        """(s, sd, sdd) at times (M,) in [0, duration] [s]."""
        tau_all = np.clip(np.asarray(times, dtype=float), 0.0, self.duration) * self.scale
        i = np.clip(np.searchsorted(self.t, tau_all, side="right") - 1, 0, len(self.ss) - 2)
        ds = self.ss[i + 1] - self.ss[i]
        sdd = (self.sd[i + 1] ** 2 - self.sd[i] ** 2) / (2.0 * ds)
        tau = tau_all - self.t[i]
        s = np.minimum(self.ss[i] + self.sd[i] * tau + 0.5 * sdd * tau**2, self.ss[i + 1])
        sd = np.maximum(self.sd[i] + sdd * tau, 0.0)
        return s, sd * self.scale, sdd * self.scale**2


class _Adapter(toppra.interpolator.AbstractGeometricPath):
    """toppra's view of a :class:`DrivePath` (cached per grid)."""

    def __init__(self, path: DrivePath) -> None:
        self._path = path
        self._key: bytes | None = None
        self._value: tuple[Array, Array, Array] = (np.zeros(0), np.zeros(0), np.zeros(0))

    def __call__(self, path_positions: Any, order: int = 0) -> Array:
        scalar = np.isscalar(path_positions)
        ss = np.atleast_1d(np.asarray(path_positions, dtype=float))
        key = ss.tobytes()
        if key != self._key:
            self._key, self._value = key, self._path.evaluate(ss)
        out = self._value[order]
        return out[0] if scalar else out

    @property
    def dof(self) -> int:
        return self._path.dof

    @property
    def path_interval(self) -> Array:
        return np.array([0.0, self._path.length])

    @property
    def waypoints(self) -> None:  # pragma: no cover - toppra API
        return None


def time_drive_path(
    path: DrivePath,
    v_max: Array,
    a_max: Array,
    period_s: float,
    grid_points: int = 400,
    safety: tuple[float, float] = (0.995, 0.97),
) -> TimeLaw:
    """TOPP-RA time law of ``path``, rest to rest, lasting a whole number of ``period_s``.

    Raises:
        RetimingFailed: TOPP-RA finds no law (the message says why).
    """
    sv, sa = safety
    v = np.asarray(v_max, dtype=float)
    a = np.asarray(a_max, dtype=float)
    constraints = [
        toppra.constraint.JointVelocityConstraint(np.column_stack([-sv * v, sv * v])),
        toppra.constraint.JointAccelerationConstraint(
            np.column_stack([-sa * a, sa * a]),
            discretization_scheme=toppra.constraint.DiscretizationType.Interpolation,
        ),
    ]
    grid = np.linspace(0.0, path.length, grid_points + 1)
    algo = toppra.algorithm.TOPPRA(constraints, _Adapter(path), gridpoints=grid, solver_wrapper="seidel")
    try:
        _, sd, _ = algo.compute_parameterization(0.0, 0.0)
    except (ZeroDivisionError, FloatingPointError, ValueError) as exc:
        raise RetimingFailed(f"TOPP-RA failed on the drive path: {exc}", grid_points=len(grid)) from None
    if sd is None or not np.all(np.isfinite(sd)):
        raise RetimingFailed("TOPP-RA: the drive path is not controllable", grid_points=len(grid))
    sd = np.maximum(np.asarray(sd, dtype=float), 0.0)
    ss = np.asarray(algo.gridpoints, dtype=float)
    dt = 2.0 * np.diff(ss) / np.maximum(sd[:-1] + sd[1:], 1e-12)
    t = np.concatenate([[0.0], np.cumsum(dt)])
    n_periods = max(1, int(np.ceil(t[-1] / period_s - 1e-9)))
    return TimeLaw(ss, sd, t, scale=float(t[-1] / (n_periods * period_s)))


@dataclass(frozen=True)
class SampledLegs:
    """Samples of consecutive legs at the controller period, arrays (N samples, n drives).

    ``leg`` (N,) is the leg index of each sample (a sample on a boundary belongs to the earlier leg) and
    ``s`` (N,) its path parameter in that leg.
    """

    t: Array
    position: Array
    velocity: Array
    acceleration: Array
    leg: NDArray[np.int64]
    s: Array


def sample_legs(paths: list[DrivePath], laws: list[TimeLaw], period_s: float) -> SampledLegs:
    """Sample legs executed one after the other (each at rest at its ends) every ``period_s``."""
    ts, us, vs, accs, legs, ss = [], [], [], [], [], []
    t0 = 0.0
    for k, (path, law) in enumerate(zip(paths, laws, strict=True)):
        n = int(round(law.duration / period_s))
        local = np.arange(0 if k == 0 else 1, n + 1).astype(float) * period_s
        local[-1] = law.duration if n > 0 else 0.0
        s, sd, sdd = law.state(local)
        u, du, ddu = path.evaluate(s)
        ts.append(t0 + np.arange(0 if k == 0 else 1, n + 1) * period_s)
        us.append(u)
        v = du * sd[:, None]
        # Every leg runs rest to rest: its end (and the first leg's start) is exactly at rest, not at the
        # rounding residue of TOPP-RA's terminal path velocity.
        v[-1] = 0.0
        if k == 0:
            v[0] = 0.0
        vs.append(v)
        accs.append(du * sdd[:, None] + ddu * (sd**2)[:, None])
        legs.append(np.full(len(local), k, dtype=np.int64))
        ss.append(s)
        t0 += n * period_s
    return SampledLegs(
        np.concatenate(ts),
        np.vstack(us),
        np.vstack(vs),
        np.vstack(accs),
        np.concatenate(legs),
        np.concatenate(ss),
    )
