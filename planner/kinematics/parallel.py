"""Planar PRR/PR(PRR)R parallel stage of cabin8: closed-form inverse and forward kinematics.

Geometry (paper Fig. 5, eq. 1-4 and 8-9). Three sliders run on one rail (the stage's y = 0 line):
A = (x1, 0), D = (x2, 0), F = (x3, 0). Link AB (length L1) carries the platform BC (length L2, centre at
the midpoint of BC, gamma the angle of B->C); link CD (L3) closes the loop to D; link EF (L4) joins the
midpoint E of AB to F. Working branch: A left of B, D right of C, F right of E, B and C above the rail, and
the dyad assembly mode (C - B) x (D - B) < 0 (C above the line BD).

Inverse (pose -> sliders, paper eq. 4)::

    B = (x - L2/2 cos g, y - L2/2 sin g),   C = (x + L2/2 cos g, y + L2/2 sin g)
    x1 = x_B - sqrt(L1^2 - y_B^2)
    x2 = x_C + sqrt(L3^2 - y_C^2)
    x3 = x_E + sqrt(L4^2 - y_E^2),          E = (A + B) / 2

Forward (sliders -> pose, paper eq. 9): the triangle A-E-F with sides L1/2, L4 and AF = x3 - x1 gives the
angle alpha of AB by the law of cosines, hence B; C is the intersection of the circles (B, L2) and
(D, L3) on the working side of BD.

Our reading of the OCR'd paper: eq. (9) writes ``cos(alpha) = (L1^2/4 + X1^2 - L4^2) / (L1 X1)`` where
X1 is the slider distance AF (x3 - x1 in our names): that is the law of cosines with AE = L1/2, which we
use. The paper's ``C`` and ``G`` coordinates in eq. (9) take the slider A as the origin; we keep absolute
rail coordinates. Eq. (4)'s third line has the sign of the EF term as printed (F right of E).

The inverse map and the admissibility measures are written once against a tiny math backend so the same
source serves numpy (vectorised over N poses) and CasADi (symbolic, for automatic differentiation).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from planner.core.description import ParallelStageSpec
from planner.core.exceptions import OutsideWorkspace
from planner.core.types import Array


@dataclass(frozen=True)
class StageGeometry:
    """Link lengths [m] of the planar stage (immutable)."""

    L1: float
    L2: float
    L3: float
    L4: float

    @classmethod
    def from_spec(cls, spec: ParallelStageSpec) -> StageGeometry:
        """Build from the validated description block."""
        return cls(spec.L1, spec.L2, spec.L3, spec.L4)


class StagePoints(NamedTuple):
    """Joint centres of the stage in the stage plane, each a pair (x, y) of arrays or expressions."""

    A: tuple[Any, Any]
    B: tuple[Any, Any]
    C: tuple[Any, Any]
    D: tuple[Any, Any]
    E: tuple[Any, Any]
    F: tuple[Any, Any]


def stage_points(g: StageGeometry, x: Any, y: Any, gamma: Any, xp: Any = np) -> StagePoints:
    """Joint centres for a platform pose (x, y, gamma); ``xp`` is ``numpy`` or ``casadi``.

    Args:
        g: Stage geometry.
        x: Platform centre x [m], scalar or shape (N,).
        y: Platform centre y [m].
        gamma: Platform angle [rad].
        xp: Math backend providing ``sin``, ``cos`` and ``sqrt``.

    Returns:
        The six joint centres; the slider points lie on y = 0. Outside the domain of the square roots
        numpy yields NaN (use :func:`inverse` for checked values).
    """
    h = 0.5 * g.L2
    c, s = xp.cos(gamma), xp.sin(gamma)
    xb, yb = x - h * c, y - h * s
    xc, yc = x + h * c, y + h * s
    x1 = xb - xp.sqrt(g.L1**2 - yb**2)
    x2 = xc + xp.sqrt(g.L3**2 - yc**2)
    xe, ye = 0.5 * (x1 + xb), 0.5 * yb
    x3 = xe + xp.sqrt(g.L4**2 - ye**2)
    zero = 0.0 * x
    return StagePoints((x1, zero), (xb, yb), (xc, yc), (x2, zero), (xe, ye), (x3, zero))


def stage_measures(g: StageGeometry, x: Any, y: Any, gamma: Any, xp: Any = np) -> dict[str, Any]:
    """Admissibility measures of a pose, all smooth functions of (x, y, gamma).

    Returns:
        ``sin_cbd``: sin of the angle CBD, signed so it is positive in the working assembly mode
        (forward/type-II singularity of the B-C-D dyad at 0); ``h_ab = y_B/L1``, ``h_cd = y_C/L3``,
        ``h_ef = y_E/L4`` (inverse/type-I singularities, a link perpendicular to the rail, at 1);
        ``gap_fa = x3 - x1`` and ``gap_df = x2 - x3`` [m] (slider spacing).
    """
    p = stage_points(g, x, y, gamma, xp)
    (xb, yb), (xc, yc), (xd, _) = p.B, p.C, p.D
    bc_x, bc_y = xc - xb, yc - yb
    bd_x, bd_y = xd - xb, -yb
    cross = bc_x * bd_y - bc_y * bd_x
    bd = xp.sqrt(bd_x**2 + bd_y**2)
    return {
        "sin_cbd": -cross / (g.L2 * bd),
        "h_ab": yb / g.L1,
        "h_cd": yc / g.L3,
        "h_ef": p.E[1] / g.L4,
        "gap_fa": p.F[0] - p.A[0],
        "gap_df": p.D[0] - p.F[0],
    }


def inverse(g: StageGeometry, pose: Array) -> Array:
    """Slider positions for platform poses, checked (paper eq. 4).

    Args:
        g: Stage geometry.
        pose: (N, 3) or (3,) array of (x [m], y [m], gamma [rad]).

    Returns:
        (N, 3) or (3,) array of slider positions (x1, x2, x3) [m].

    Raises:
        OutsideWorkspace: a link cannot reach the rail (B, C or E outside its link's reach, or below the
            rail); ``details`` names the condition and the first failing index.
    """
    pose = np.asarray(pose, dtype=float)
    single = pose.ndim == 1
    p2 = np.atleast_2d(pose)
    x, y, gamma = p2[:, 0], p2[:, 1], p2[:, 2]
    h = 0.5 * g.L2
    yb = y - h * np.sin(gamma)
    yc = y + h * np.sin(gamma)
    checks = {
        "finite pose": np.all(np.isfinite(p2), axis=1),
        "y_B > 0 (B above the rail)": yb > 0,
        "y_C > 0 (C above the rail)": yc > 0,
        "y_B < L1 (AB reaches the rail)": yb < g.L1,
        "y_C < L3 (CD reaches the rail)": yc < g.L3,
        "y_B/2 < L4 (EF reaches the rail)": 0.5 * yb < g.L4,
    }
    _raise_first_failure(checks, p2, "pose", "platform pose {} outside the stage workspace")
    pts = stage_points(g, x, y, gamma)
    u = np.stack([pts.A[0], pts.D[0], pts.F[0]], axis=-1)
    return u[0] if single else u


def forward(g: StageGeometry, sliders: Array) -> Array:
    """Platform poses for slider positions, closed form on the working branch (paper eq. 9).

    Args:
        g: Stage geometry.
        sliders: (N, 3) or (3,) array of (x1, x2, x3) [m].

    Returns:
        (N, 3) or (3,) array of (x [m], y [m], gamma [rad]).

    Raises:
        OutsideWorkspace: the loop cannot close (triangle AEF or the circles about B and D do not meet),
            or it closes only off the working branch (A right of B, F left of E, D left of C, C below the
            rail). ``details`` names the condition and the first failing index.
    """
    u = np.asarray(sliders, dtype=float)
    single = u.ndim == 1
    u2 = np.atleast_2d(u)
    x1, x2, x3 = u2[:, 0], u2[:, 1], u2[:, 2]
    ae = 0.5 * g.L1
    af = x3 - x1
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        cos_a = (ae**2 + af**2 - g.L4**2) / (2.0 * ae * af)
        sin_a = np.sqrt(1.0 - cos_a**2)
        xb, yb = x1 + g.L1 * cos_a, g.L1 * sin_a
        xe = x1 + ae * cos_a
        bd_x, bd_y = x2 - xb, -yb
        dist = np.hypot(bd_x, bd_y)
        a = (g.L2**2 - g.L3**2 + dist**2) / (2.0 * dist)
        h2 = g.L2**2 - a**2
        hgt = np.sqrt(h2)
        ux, uy = bd_x / dist, bd_y / dist
        # Working mode: C on the left of B->D (normal (-uy, ux)), i.e. (C - B) x (D - B) < 0.
        xc = xb + a * ux - hgt * uy
        yc = yb + a * uy + hgt * ux
    checks = {
        "finite sliders": np.all(np.isfinite(u2), axis=1),
        "x3 > x1 (F right of A)": af > 0,
        "triangle AEF closes (|cos alpha| <= 1)": np.abs(cos_a) <= 1.0,
        "A left of B (cos alpha > 0)": cos_a > 0,
        "B above the rail": yb > 0,
        "F right of E": x3 > xe,
        "circles about B (L2) and D (L3) meet": h2 >= 0,
        "C above the rail": yc > 0,
        "D right of C": x2 > xc,
    }
    _raise_first_failure(checks, u2, "sliders", "sliders {} do not assemble on the working branch")
    pose = np.stack([0.5 * (xb + xc), 0.5 * (yb + yc), np.arctan2(yc - yb, xc - xb)], axis=-1)
    return pose[0] if single else pose


def _raise_first_failure(checks: dict[str, Any], rows: Array, what: str, message: str) -> None:
    """Raise OutsideWorkspace for the first failing condition (in order) at its first failing row."""
    for condition, ok in checks.items():
        ok = np.asarray(ok)
        if not np.all(ok):
            i = int(np.argmin(ok))
            raise OutsideWorkspace(
                f"{message.format(rows[i].tolist())}: {condition} fails",
                condition=condition,
                index=i,
                **{what: rows[i].tolist()},
            )
