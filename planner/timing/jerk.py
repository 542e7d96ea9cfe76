"""Jerk-limited timing: the certified path kept exactly, a time law s(t) with bounded drive jerk.

The stage (:class:`JerkLimitedStage`, protocol :class:`~planner.timing.stage.TimingStage`) starts from
the TOPP-RA time law s_0(t) (:class:`~planner.timing.toppra.ToppraStage`: velocity, acceleration and force
limits, constant path acceleration between grid points, duration D) and averages it over a moving window
of width T (a box filter, the classic way a drive controller makes a trapezoid velocity profile
jerk-limited; Biagiotti & Melchiorri, *Trajectory Planning for Automatic Machines and Robots*, 2008,
sec. 4.2.3):

    s(t) = (1/T) int_{t-T}^{t} s_0(tau) dtau,   s_0 = 0 before 0 and L (the path length) after D,

so that, exactly,

    sd(t) = (s_0(t) - s_0(t-T)) / T,  sdd(t) = (sd_0(t) - sd_0(t-T)) / T,
    sddd(t) = (sdd_0(t) - sdd_0(t-T)) / T.

s(t) is monotone in [0, L] (an average of a monotone function), lasts D + T, starts and ends at rest with
zero acceleration, and its path acceleration is continuous (piecewise linear): the path jerk is bounded by
the path acceleration's range over T. Only s(t) changes: every position is q(s(t)) on the certified path.
For a straight rest-to-rest line with a window T = a_max / j_max of the limiting drive this *is* the
time-optimal jerk-limited profile (the trapezoid's ramps become the optimum's constant-jerk phases); the
tests compare it with Ruckig's optimum.

The drive jerk is u''' = u' sddd + 3 u'' sd sdd + u''' sd^3 (u(s) the drive path), so two more effects are
checked, by sampling the result at the controller period exactly as the gate does (jerk = the change of the
sampled acceleration over one period, velocity, acceleration, force):

- where the path's curvature jumps (a straight segment entering a blend: u'' jumps, so the drive
  acceleration u' sdd + u'' sd^2 steps by Delta u'' sd^2 within one period) the path speed is capped so
  that the step stays within :data:`JUMP_SHARE` of one period's jerk budget,
  sd^2 |Delta u''_j| <= JUMP_SHARE j_max_j T_c; the cap is handed to TOPP-RA around the break
  (:attr:`ToppraStage.path_speed_cap`) and lowered until the averaged law meets it. This is what a
  jerk-limited law costs on the planner's quadratic corner blends (C1, not C2): their curvature steps at
  both ends, so the path must be crossed there slowly (a C2 blend would remove the cost, but changes the
  certified path);
- the window is the smallest T with max_t |a_j(t) - a_j(t - T)| <= j_max_j T for every drive's
  TOPP-RA acceleration a_j (a fixed point from the acceleration range / j_max, which bounds it), widened
  while the sampled jerk exceeds its limit; velocity, acceleration and force excesses tighten the limits
  handed to TOPP-RA.

A law that still fails after :data:`MAX_ITERATIONS` is refused (:class:`RetimingFailed`), never returned.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from planner.core.exceptions import RetimingFailed
from planner.core.types import Array
from planner.dynamics.models import drive_dynamics
from planner.dynamics.payload import RigidPayload
from planner.robots.base import RobotModel
from planner.timing.path import JointPath
from planner.timing.toppra import BREAK_OFFSET, ToppraStage, ToppraTimedPath

log = logging.getLogger(__name__)

#: Re-timings of one path before the stage refuses it.
MAX_ITERATIONS = 8
#: Fraction of one period's jerk budget a curvature jump of the path may take.
JUMP_SHARE = 0.8
#: Fraction of the jerk limits the stage aims at (the gate allows 1% above the limits), and how far above
#: it a law is still accepted.
JERK_TARGET = 0.97
JERK_SLACK = 0.015


@dataclass(frozen=True)
class JerkTimedPath:
    """A path with the box-filtered time law of a TOPP-RA law ``base`` (window ``window_s``)."""

    path: JointPath
    base: ToppraTimedPath = field(repr=False)
    window_s: float
    _S: Array = field(repr=False)  # int_0^{t_i} s_0 at the base grid times

    @classmethod
    def of(cls, base: ToppraTimedPath, window_s: float) -> JerkTimedPath:
        """The averaged law of ``base`` over ``window_s``."""
        ss, sd, t = base.ss, base.sd, base.t
        dt = np.diff(t)
        sdd = _base_sdd(base)
        inc = ss[:-1] * dt + sd[:-1] * dt**2 / 2 + sdd * dt**3 / 6
        return cls(base.path, base, float(window_s), np.concatenate([[0.0], np.cumsum(inc)]))

    @property
    def duration(self) -> float:
        """Duration of the time law [s]: TOPP-RA's plus the window."""
        return self.base.duration + self.window_s

    def _base_state(self, t: Array) -> tuple[Array, Array, Array, Array]:
        """The integral of s_0, and s_0, sd_0, sdd_0 at times t (any real): at rest outside [0, D]."""
        b = self.base
        D, L = b.duration, b.path.length
        tc = np.clip(t, 0.0, D)
        i = np.clip(np.searchsorted(b.t, tc, side="right") - 1, 0, len(b.ss) - 2)
        sdd_i = _base_sdd(b)[i]
        tau = tc - b.t[i]
        s = b.ss[i] + b.sd[i] * tau + 0.5 * sdd_i * tau**2
        sd = b.sd[i] + sdd_i * tau
        S = self._S[i] + b.ss[i] * tau + b.sd[i] * tau**2 / 2 + sdd_i * tau**3 / 6
        before, after = t < 0.0, t > D
        s = np.where(before, 0.0, np.where(after, L, np.minimum(s, b.ss[i + 1])))
        sd = np.where(before | after, 0.0, np.maximum(sd, 0.0))
        sdd = np.where(before | after, 0.0, sdd_i)
        S = np.where(before, 0.0, np.where(after, self._S[-1] + L * (t - D), S))
        return S, s, sd, sdd

    def state(self, times: Array, order: int = 2) -> tuple[Array, ...]:
        """s, sd, sdd (and sddd for ``order`` 3) at times (N,) in [0, duration] (see the module docstring)."""
        t = np.clip(np.asarray(times, dtype=float), 0.0, self.duration)
        T = self.window_s
        S1, s1, sd1, sdd1 = self._base_state(t)
        S0, s0, sd0, sdd0 = self._base_state(t - T)
        s = np.clip((S1 - S0) / T, 0.0, self.path.length)
        out = (s, np.maximum((s1 - s0) / T, 0.0), (sd1 - sd0) / T, (sdd1 - sdd0) / T)
        return out[: order + 1]


def _base_sdd(base: ToppraTimedPath) -> Array:
    """TOPP-RA's constant path acceleration of each grid interval."""
    return np.asarray((base.sd[1:] ** 2 - base.sd[:-1] ** 2) / (2.0 * np.diff(base.ss)))


@dataclass(frozen=True)
class _Sampled:
    """A law sampled at the controller period: the peak ratios and where the jerk peaks."""

    velocity: float
    acceleration: float
    effort: float
    jerk: float  # away from curvature jumps
    jump_ratio: Array  # per jump break: the jerk ratio of the period that crosses it
    jump_speed: Array  # per jump break: the path speed there
    acc: Array = field(repr=False)  # (N, n_drives) sampled drive accelerations
    times: Array = field(repr=False)


@dataclass
class JerkLimitedStage:
    """Jerk-limited timing of a path (see the module docstring).

    Attributes:
        robot: The robot model (its limits must include jerk limits).
        payload: The carried payload's inertial data (None: empty gripper).
        safety: Fractions of the (velocity, acceleration, force) limits the law may use; the acceleration
            fraction also scales the jerk target (:data:`JERK_TARGET`), so a re-timing after a jerk
            failure tightens it.
        sample_period_s: The controller period the law is checked at (the gate's jerk is the change of
            the sampled acceleration over one period).
    """

    robot: RobotModel
    payload: RigidPayload | None = None
    safety: tuple[float, float, float] = (0.995, 0.97, 0.97)
    sample_period_s: float = 0.004
    grid_step: float = 0.08
    min_points: int = 60
    max_points: int = 3000
    name: str = "jerk_limited"

    def __post_init__(self) -> None:
        if self.robot.limits.j_max is None:
            raise RetimingFailed(f"robot {self.robot.name!r} has no jerk limits in its description")
        self.dynamics = drive_dynamics(self.robot)

    def time_path(self, path: JointPath) -> JerkTimedPath:
        """The jerk-limited law of ``path``, rest to rest (raises RetimingFailed)."""
        lim = self.robot.limits
        assert lim.j_max is not None
        sv, sa, sf = self.safety
        targets = (min(1.0, sv + 0.004), min(1.0, sa + 0.02), min(1.0, sf + 0.02))
        j_target = JERK_TARGET * sa / 0.97
        breaks, need = self._jump_caps(path, j_target)
        caps = need.copy()  # the caps handed to TOPP-RA, lowered until the averaged law meets ``need``
        scale = [sv, sa, sf]
        # Until TOPP-RA's law gives the window: the window of a drive ramping its full acceleration range.
        assert lim.j_max is not None
        window = float(np.max(2.0 * lim.a_max / lim.j_max))
        known = False
        last: _Sampled | None = None
        base: ToppraTimedPath | None = None
        for _ in range(MAX_ITERATIONS):
            if base is None:
                base = self._toppra((scale[0], scale[1], scale[2]), breaks, caps, window).time_path(path)
            if not known:
                window, known = self._window(base, j_target), True
            timed = JerkTimedPath.of(base, window)
            last = self._sample(timed, breaks)
            if log.isEnabledFor(logging.DEBUG):
                log.debug(
                    "window %.3f s: v %.3f a %.3f f %.3f j %.3f jumps %s",
                    window,
                    last.velocity,
                    last.acceleration,
                    last.effort,
                    last.jerk,
                    np.round(last.jump_ratio, 3),
                )
            over = [
                r > tgt
                for r, tgt in zip((last.velocity, last.acceleration, last.effort), targets, strict=True)
            ]
            bad = last.jump_ratio > j_target + JERK_SLACK
            if not any(over) and not bad.any() and last.jerk <= j_target + JERK_SLACK:
                return timed
            # Limit excesses and curvature jumps need a new TOPP-RA law; the jerk alone a wider window.
            for k, r in enumerate((last.velocity, last.acceleration, last.effort)):
                if over[k]:
                    scale[k] *= 0.998 * targets[k] / r
                    base = None
            if bad.any():
                lower = np.sqrt(j_target / last.jump_ratio[bad]) * 0.97
                caps[bad] = np.minimum(caps[bad], last.jump_speed[bad]) * lower
                base = None
            if last.jerk > j_target + JERK_SLACK:
                window *= 1.01 * last.jerk / j_target
        assert last is not None
        raise RetimingFailed(
            f"no jerk-limited time law within the drive limits after {MAX_ITERATIONS} re-timings (peak "
            f"ratios: velocity {last.velocity:.3f}, acceleration {last.acceleration:.3f}, force "
            f"{last.effort:.3f}, jerk {max(last.jerk, float(np.max(last.jump_ratio, initial=0.0))):.3f})",
            stage=self.name,
        )

    # ------------------------------------------------------------------ pieces
    def _toppra(
        self, scale: tuple[float, float, float], breaks: Array, caps: Array, window: float
    ) -> ToppraStage:
        """The TOPP-RA stage with the current limit fractions and the speed caps at curvature jumps.

        The averaged speed where the path crosses break b is the mean of TOPP-RA's speed over the
        window's positions, which lie within c T of b when that speed is at most c there: the cap c holds
        over [b - c T, b + c T]. The zone's ends and points inside it are grid points (TOPP-RA's x = sd^2
        is linear between grid points, so the cap holds between them too).
        """
        half = caps * window * 1.05 + 1e-6
        extra = (breaks[:, None] + half[:, None] * np.linspace(-1.0, 1.0, 9)[None, :]).ravel()

        def cap(s: Array) -> Array:
            near = np.abs(s[:, None] - breaks[None, :]) <= half[None, :]
            return np.asarray(np.min(np.where(near, caps[None, :], np.inf), axis=1))

        return ToppraStage(
            self.robot,
            self.payload,
            scale,
            self.grid_step,
            self.min_points,
            self.max_points,
            path_speed_cap=cap if len(breaks) else None,
            extra_points=extra if len(breaks) else None,
        )

    def _jump_caps(self, path: JointPath, j_target: float) -> tuple[Array, Array]:
        """Inner breaks where u'' jumps, and the path speed each allows: sd^2 |Delta u''| <= share j T_c."""
        inner = np.asarray(path.breaks, dtype=float)[1:-1]
        if len(inner) == 0:
            return np.zeros(0), np.zeros(0)
        eps = BREAK_OFFSET * max(path.length, 1.0)
        lo = self.robot.drive_path(*path.evaluate(inner - eps))[2]
        hi = self.robot.drive_path(*path.evaluate(inner + eps))[2]
        jump = np.abs(hi - lo)
        assert self.robot.limits.j_max is not None
        budget = JUMP_SHARE * j_target * self.robot.limits.j_max * self.sample_period_s
        with np.errstate(divide="ignore"):
            speed = np.sqrt(np.min(budget[None, :] / jump, axis=1))
        keep = speed < 1e3
        return inner[keep], speed[keep]

    def _window(self, base: ToppraTimedPath, j_target: float) -> float:
        """Smallest window T with max_t |a_j(t) - a_j(t-T)| <= j_target j_max T (fixed point, see above)."""
        assert self.robot.limits.j_max is not None
        jm = j_target * self.robot.limits.j_max
        dt = self.sample_period_s
        t = np.arange(0.0, base.duration + dt, dt)
        s, sd, sdd = base.state(t, 2)
        _, du, ddu = self.robot.drive_path(*base.path.evaluate(s))
        a = du * sdd[:, None] + ddu * (sd**2)[:, None]
        a = np.vstack([np.zeros((1, a.shape[1])), a, np.zeros((1, a.shape[1]))])  # at rest outside
        T = float(np.max((a.max(axis=0) - a.min(axis=0)) / jm))
        for _ in range(3):
            lag = max(1, int(np.ceil(T / dt)))
            pad = np.vstack([np.zeros((lag, a.shape[1])), a, np.zeros((lag, a.shape[1]))])
            diff = np.max(np.abs(pad[lag:] - pad[:-lag]), axis=0)
            T = min(T, float(np.max(diff / jm)))
        return max(T, 4.0 * dt)

    def _sample(self, timed: JerkTimedPath, breaks: Array) -> _Sampled:
        """The law sampled at the controller period, as the gate sees it (peak ratios to the limits)."""
        lim = self.robot.limits
        assert lim.j_max is not None
        dt = self.sample_period_s
        n = int(np.ceil(timed.duration / dt - 1e-9))
        t = np.linspace(0.0, timed.duration, n + 1)  # the sampler's slowed grid (whole periods)
        h = t[1] - t[0]
        s, sd, sdd = timed.state(t, 2)
        q, dq, ddq = timed.path.evaluate(s)
        _, du, ddu = self.robot.drive_path(q, dq, ddq)
        ud = du * sd[:, None]
        udd = du * sdd[:, None] + ddu * (sd**2)[:, None]
        udd[-1] = 0.0
        jerk = np.abs(np.diff(udd, axis=0)) / h / lim.j_max[None, :]
        # Steps that cross a curvature jump: their jerk is the jump's (bounded by the speed cap).
        step = np.searchsorted(s, breaks, side="left") - 1
        step = np.clip(step, 0, len(jerk) - 1)
        jump_ratio = jerk[step].max(axis=1) if len(step) else np.zeros(0)
        jump_speed = sd[np.clip(step + 1, 0, len(sd) - 1)] if len(step) else np.zeros(0)
        mask = np.ones(len(jerk), dtype=bool)
        mask[step] = False
        smooth = float(jerk[mask].max(initial=0.0))
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
            jerk=smooth,
            jump_ratio=jump_ratio,
            jump_speed=jump_speed,
            acc=udd,
            times=t,
        )
