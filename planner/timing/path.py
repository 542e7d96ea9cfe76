"""Geometric joint-space paths: straight segments, corner blends and interpolating splines.

A path is a C2 curve q(s) in joint space over s in [0, length] (C1 where a spline meets a line), built from
pieces:

- :class:`LinePiece`: the certified straight segments of the global planner;
- :class:`BlendPiece`: a quintic Bezier replacing the corner at a waypoint w between the points
  a = w - lam * d_in and b = w + lam * d_out (d the segments' constant derivatives dq/ds). Its first
  derivative at its ends equals the neighbouring segments' derivatives and its second derivative is zero
  there, so the path is C2 (curvature-continuous): a time-optimal profile need not stop at the corner, and
  a jerk-limited one need not slow down where the blend begins and ends. The blend stays inside the
  triangle (a, w, b); it is certified by the collision layer like every other motion before it is used;
- :class:`SplinePiece`: a cubic spline through densely tracked configurations (the straight-line
  insertion), C2.

The parameter s is a *time-like* length: each straight segment's length is the time its slowest drive
needs at its velocity limit (at the segment's start), so a uniform grid over s is a balanced grid for
TOPP-RA.

The robot model maps a path to the drive path u(s) = g(q(s)) with its derivatives u' = G q',
u'' = G q'' + (dG/ds) q' (:meth:`planner.robots.base.RobotModel.drive_path`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy.interpolate import CubicSpline

from planner.core.types import Array
from planner.robots.cabin8 import Cabin8


class Piece(ABC):
    """One piece of a joint path over its local parameter s in [0, length]."""

    length: float

    @abstractmethod
    def evaluate(self, s: Array) -> tuple[Array, Array, Array]:
        """q, dq/ds, d2q/ds2 at local parameters s (N,), each (N, 8)."""


@dataclass(frozen=True)
class LinePiece(Piece):
    """q(s) = q0 + (q1 - q0) s / length."""

    q0: Array = field(repr=False)
    q1: Array = field(repr=False)
    length: float

    def evaluate(self, s: Array) -> tuple[Array, Array, Array]:
        """Straight segment: constant derivative, zero curvature."""
        d = (self.q1 - self.q0) / self.length
        q = self.q0[None, :] + s[:, None] * d[None, :]
        return q, np.broadcast_to(d, q.shape).copy(), np.zeros_like(q)


@dataclass(frozen=True)
class BlendPiece(Piece):
    """Quintic Bezier corner blend a -> b at the corner w, over s in [0, length] (tau = s / length).

    Control points a, a + 0.4 (w - a), a + 0.8 (w - a), b + 0.8 (w - b), b + 0.4 (w - b), b: all six lie on
    the corner's two legs, so the curve stays inside the triangle (a, w, b), nearer the corner than a
    quadratic blend between the same ends (its midpoint is w + 0.1875 lam delta, the quadratic's
    w + 0.25 lam delta). With length = 2 lam (a = w - lam d_in, b = w + lam d_out, delta = d_out - d_in)
    its first derivative at the ends is d_in and d_out (C1) and its second derivative is zero there (C2):
    the path's curvature, hence every drive's acceleration at a continuous path speed, does not step
    where a line enters or leaves the blend. In between, d2q/ds2 = 6 tau (1 - tau) delta / length: 1.5
    times the quadratic blend's constant delta / length at its peak, the price of the zero ends.
    """

    a: Array = field(repr=False)
    w: Array = field(repr=False)
    b: Array = field(repr=False)
    length: float

    def evaluate(self, s: Array) -> tuple[Array, Array, Array]:
        """Bezier point, tangent and curvature term (zero at both ends), in closed form.

        q' = d_in + delta (3 tau^2 - 2 tau^3), q = a + length (d_in tau + delta (tau^3 - tau^4 / 2)).
        """
        tau = (s / self.length)[:, None]
        a, w, b = self.a[None, :], self.w[None, :], self.b[None, :]
        lam = 0.5 * self.length
        d_in, d_out = (w - a) / lam, (b - w) / lam
        delta = d_out - d_in
        q = a + self.length * (d_in * tau + delta * (tau**3 - 0.5 * tau**4))
        dq = d_in + delta * (3 * tau**2 - 2 * tau**3)
        ddq = delta * (6 * tau * (1 - tau) / self.length)
        return q, dq, ddq


@dataclass(frozen=True)
class SplinePiece(Piece):
    """Cubic spline (not-a-knot) through configurations at increasing parameters."""

    spline: CubicSpline = field(repr=False)
    length: float

    @classmethod
    def through(cls, s: Array, qs: Array) -> SplinePiece:
        """Spline through ``qs`` (K, 8) at parameters ``s`` (K,), re-based to start at 0."""
        s = np.asarray(s, dtype=float) - float(s[0])
        return cls(CubicSpline(s, np.asarray(qs, dtype=float), axis=0), float(s[-1]))

    def evaluate(self, s: Array) -> tuple[Array, Array, Array]:
        """Spline value and its first two derivatives."""
        return self.spline(s), self.spline(s, 1), self.spline(s, 2)


@dataclass(frozen=True)
class JointPath:
    """Pieces joined end to end; s runs over [0, length]."""

    pieces: tuple[Piece, ...]

    @property
    def length(self) -> float:
        """Total parameter length."""
        return float(sum(p.length for p in self.pieces))

    @cached_property
    def dof(self) -> int:
        """Number of coordinates of the path (cabin8: 8 joints; pprs6: the 6 pose coordinates)."""
        return int(len(self.pieces[0].evaluate(np.zeros(1))[0][0]))

    @property
    def breaks(self) -> Array:
        """Cumulative piece boundaries (n_pieces + 1,)."""
        return np.concatenate([[0.0], np.cumsum([p.length for p in self.pieces])])

    def evaluate(self, s: Array) -> tuple[Array, Array, Array]:
        """q, q', q'' at path parameters s (N,) -> three (N, n joints) arrays."""
        s = np.clip(np.atleast_1d(np.asarray(s, dtype=float)), 0.0, self.length)
        br = self.breaks
        idx = np.clip(np.searchsorted(br, s, side="right") - 1, 0, len(self.pieces) - 1)
        q = np.empty((len(s), self.dof))
        dq = np.empty_like(q)
        ddq = np.empty_like(q)
        for k in np.unique(idx):
            sel = idx == k
            q[sel], dq[sel], ddq[sel] = self.pieces[k].evaluate(s[sel] - br[k])
        return q, dq, ddq

    @property
    def start(self) -> Array:
        """First configuration of the path."""
        return self.evaluate(np.array([0.0]))[0][0]

    @property
    def end(self) -> Array:
        """Last configuration of the path."""
        return self.evaluate(np.array([self.length]))[0][0]


def segment_time_length(robot: Cabin8, q0: Array, q1: Array) -> float:
    """Time-like length of a straight joint segment: its slowest drive's time at v_max (>= 1e-6)."""
    G, _ = robot.drive_map_jacobian(q0)
    du = G @ (np.asarray(q1) - np.asarray(q0))
    return float(max(1e-6, np.max(np.abs(du) / robot.limits.v_max)))


def blended_polyline(
    robot: Cabin8, waypoints: Array, blend_fraction: Array | float = 0.4
) -> tuple[JointPath, list[int]]:
    """A C2 path along a polyline with a quintic blend (:class:`BlendPiece`) at every interior waypoint.

    Args:
        robot: The robot (for time-like segment lengths).
        waypoints: (N, 8) joint waypoints (N >= 2).
        blend_fraction: Per interior waypoint (N - 2,) or one value: the blend's half-length as a fraction
            of the shorter neighbouring segment, in [0, 0.5]; 0 keeps a sharp corner.

    Returns:
        The path and, for each interior waypoint, the index of its blend piece (-1 for a sharp corner).
    """
    W = np.asarray(waypoints, dtype=float)
    n = len(W)
    lengths = [segment_time_length(robot, W[i], W[i + 1]) for i in range(n - 1)]
    frac = np.broadcast_to(np.asarray(blend_fraction, dtype=float), (max(n - 2, 0),))
    lam = [float(frac[k - 1]) * min(lengths[k - 1], lengths[k]) if 0 < k < n - 1 else 0.0 for k in range(n)]
    pieces: list[Piece] = []
    blend_index: list[int] = []
    for i in range(n - 1):
        d = (W[i + 1] - W[i]) / lengths[i]
        a = W[i] + lam[i] * d
        b = W[i + 1] - lam[i + 1] * d
        seg_len = lengths[i] - lam[i] - lam[i + 1]
        if seg_len > 1e-9:
            pieces.append(LinePiece(a, b, seg_len))
        if i + 1 < n - 1:
            if lam[i + 1] > 0:
                d_out = (W[i + 2] - W[i + 1]) / lengths[i + 1]
                pieces.append(BlendPiece(b, W[i + 1], W[i + 1] + lam[i + 1] * d_out, 2 * lam[i + 1]))
                blend_index.append(len(pieces) - 1)
            else:
                blend_index.append(-1)
    return JointPath(tuple(pieces)), blend_index
