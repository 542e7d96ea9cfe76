"""Geometric joint paths: derivatives by finite differences, C1/C2 joins, blends inside their corner triangle.

Every derivative the pieces and the drive geometry report is checked against central finite differences
of the values (STYLE habit 2), and the drive path against the robot's own closed-form drive map.
"""

from __future__ import annotations

from math import comb

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from planner.robots.cabin8 import Cabin8
from planner.timing.path import (
    BlendPiece,
    JointPath,
    LinePiece,
    Piece,
    SplinePiece,
    blended_polyline,
    segment_time_length,
)

H = 1e-6
#: Typical step sizes per joint for small admissible moves [m, m, m, rad, rad, rad, m, rad].
STEP = np.array([0.3, 0.03, 0.03, 0.06, 0.3, 0.3, 0.08, 0.4])


def small_waypoints(robot: Cabin8, q0: np.ndarray, n: int, seed: int) -> np.ndarray:
    """N admissible waypoints starting at q0, each a small random step from the previous one."""
    rng = np.random.default_rng(seed)
    out = [np.asarray(q0, dtype=float)]
    while len(out) < n:
        cand = out[-1] + rng.uniform(-1.0, 1.0, 8) * STEP
        if not robot.violations(cand):
            out.append(cand)
    return np.array(out)


@pytest.fixture(scope="module")
def waypoints(robot: Cabin8, configs: np.ndarray) -> np.ndarray:
    """Five admissible waypoints with small steps (every one checked against every limit and margin)."""
    w = small_waypoints(robot, configs[3], 5, seed=7)
    assert all(not robot.violations(q) for q in w)
    return w


def fd_check(piece: Piece | JointPath, s: np.ndarray) -> None:
    """Assert q' and q'' equal central differences of q and q' (step 1e-6) to 1e-6 relative."""
    q, dq, ddq = piece.evaluate(s)
    qp, dqp, _ = piece.evaluate(s + H)
    qm, dqm, _ = piece.evaluate(s - H)
    fd_dq = (qp - qm) / (2 * H)
    fd_ddq = (dqp - dqm) / (2 * H)
    scale_1 = max(1.0, float(np.max(np.abs(dq))))
    scale_2 = max(1.0, float(np.max(np.abs(ddq))))
    assert np.max(np.abs(fd_dq - dq)) <= 1e-6 * scale_1
    assert np.max(np.abs(fd_ddq - ddq)) <= 1e-6 * scale_2


def test_line_piece_derivatives_match_finite_differences(waypoints: np.ndarray) -> None:
    piece = LinePiece(waypoints[0], waypoints[1], 2.5)
    s = np.linspace(2 * H, piece.length - 2 * H, 23)
    fd_check(piece, s)
    q, dq, ddq = piece.evaluate(np.array([0.0, piece.length]))
    assert np.array_equal(q[0], waypoints[0])
    assert np.allclose(q[1], waypoints[1], rtol=0, atol=1e-14)
    assert np.allclose(dq[0] * piece.length, waypoints[1] - waypoints[0], rtol=0, atol=1e-14)
    assert np.array_equal(ddq, np.zeros_like(ddq))


def test_blend_piece_derivatives_match_finite_differences(waypoints: np.ndarray) -> None:
    piece = BlendPiece(waypoints[0], waypoints[1], waypoints[2], 1.7)
    fd_check(piece, np.linspace(2 * H, piece.length - 2 * H, 23))
    # End tangents point along the two legs of the corner (the Bezier's defining property).
    _, dq, _ = piece.evaluate(np.array([0.0, piece.length]))
    assert np.allclose(dq[0], 2 * (waypoints[1] - waypoints[0]) / piece.length, rtol=0, atol=1e-12)
    assert np.allclose(dq[1], 2 * (waypoints[2] - waypoints[1]) / piece.length, rtol=0, atol=1e-12)


def test_blend_piece_is_the_quintic_bezier_with_zero_curvature_at_both_ends(waypoints: np.ndarray) -> None:
    """C2 blend: the Bezier of its six control points on the corner's legs, q'' = 0 at both ends."""
    a, w, b = waypoints[0], waypoints[1], waypoints[2]
    piece = BlendPiece(a, w, b, 1.7)
    s = np.linspace(0.0, piece.length, 41)
    q, _, ddq = piece.evaluate(s)
    # Independent route: de Casteljau-free Bernstein sum of the control points.
    ctrl = [a, a + 0.4 * (w - a), a + 0.8 * (w - a), b + 0.8 * (w - b), b + 0.4 * (w - b), b]
    tau = (s / piece.length)[:, None]
    bern = [comb(5, i) * tau**i * (1 - tau) ** (5 - i) for i in range(6)]
    assert np.max(np.abs(sum(bi * ci[None, :] for bi, ci in zip(bern, ctrl, strict=True)) - q)) <= 1e-12
    assert np.max(np.abs(ddq[[0, -1]])) <= 1e-12
    # The curvature term is continuous inside and peaks at 1.5 times the quadratic blend's constant.
    delta = 2 * (b - w) / piece.length - 2 * (w - a) / piece.length
    assert np.max(np.abs(ddq[20] - 1.5 * delta / piece.length)) <= 1e-12
    # Every point is a convex combination of a, w, b (inside the corner triangle).
    coeffs = np.linalg.lstsq(np.column_stack([a - w, b - w]), (q - w).T, rcond=None)[0]
    assert np.all(coeffs >= -1e-12) and np.all(coeffs.sum(axis=0) <= 1 + 1e-12)


def test_spline_piece_derivatives_match_finite_differences(waypoints: np.ndarray) -> None:
    s_knots = np.array([3.0, 3.8, 5.1, 5.9, 7.2])  # not starting at 0: the piece re-bases it
    piece = SplinePiece.through(s_knots, waypoints)
    assert piece.length == pytest.approx(4.2, abs=1e-15)
    fd_check(piece, np.linspace(2 * H, piece.length - 2 * H, 31))
    # It interpolates the tracked configurations at their (re-based) parameters ...
    q = piece.evaluate(s_knots - 3.0)[0]
    assert np.max(np.abs(q - waypoints)) <= 1e-12
    # ... and is C2 at the interior knots (second derivative continuous from both sides).
    for sk in s_knots[1:-1] - 3.0:
        left = piece.evaluate(np.array([sk - 1e-9]))[2]
        right = piece.evaluate(np.array([sk + 1e-9]))[2]
        assert np.max(np.abs(left - right)) <= 1e-6 * max(1.0, float(np.max(np.abs(left))))
    # Same curve as an independently built spline.
    ref = CubicSpline(s_knots - 3.0, waypoints, axis=0)
    s = np.linspace(0.0, piece.length, 17)
    assert np.allclose(piece.evaluate(s)[0], ref(s), rtol=0, atol=1e-12)


def test_joint_path_derivatives_match_finite_differences_inside_pieces(
    robot: Cabin8, waypoints: np.ndarray
) -> None:
    path, _ = blended_polyline(robot, waypoints, 0.4)
    br = path.breaks
    s = np.concatenate([np.linspace(a + 1e-4, b - 1e-4, 7) for a, b in zip(br[:-1], br[1:], strict=True)])
    fd_check(path, s)


Ends = tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def _piece_ends(path: JointPath) -> list[Ends]:
    """For each interior boundary: (end of piece k, start of piece k + 1) as (q, dq) pairs."""
    out: list[Ends] = []
    for p, nxt in zip(path.pieces[:-1], path.pieces[1:], strict=True):
        q0, dq0, _ = p.evaluate(np.array([p.length]))
        q1, dq1, _ = nxt.evaluate(np.array([0.0]))
        out.append(((q0[0], dq0[0]), (q1[0], dq1[0])))
    return out


@pytest.mark.parametrize("fraction", [0.1, 0.4, 0.5])
def test_blended_polyline_is_c2_and_starts_and_ends_at_the_waypoints(
    robot: Cabin8, waypoints: np.ndarray, fraction: float
) -> None:
    path, blend_index = blended_polyline(robot, waypoints, fraction)
    n = len(waypoints)
    assert len(blend_index) == n - 2 and all(i >= 0 for i in blend_index)
    assert all(isinstance(path.pieces[i], BlendPiece) for i in blend_index)
    ends = _piece_ends(path)
    assert ends, "a five-waypoint blended path has several pieces"
    for (q0, dq0), (q1, dq1) in ends:
        assert np.max(np.abs(q0 - q1)) <= 1e-9
        assert np.max(np.abs(dq0 - dq1)) <= 1e-9
    # C2: the curvature term is zero on both sides of every boundary (lines and the blends' ends).
    for k, (p, nxt) in enumerate(zip(path.pieces[:-1], path.pieces[1:], strict=True)):
        left = p.evaluate(np.array([p.length]))[2]
        right = nxt.evaluate(np.array([0.0]))[2]
        assert np.max(np.abs(left)) <= 1e-9 and np.max(np.abs(right)) <= 1e-9, k
    assert np.array_equal(path.start, waypoints[0])
    assert np.max(np.abs(path.end - waypoints[-1])) <= 1e-12
    # Cutting corners with blends does not change the time-like length: each blend of length 2 lam
    # replaces lam of each neighbouring segment.
    lengths = [segment_time_length(robot, a, b) for a, b in zip(waypoints[:-1], waypoints[1:], strict=True)]
    assert path.length == pytest.approx(sum(lengths), rel=1e-12)


def test_blended_polyline_passes_through_its_sharp_corners(robot: Cabin8, waypoints: np.ndarray) -> None:
    fractions = np.array([0.4, 0.0, 0.3])
    path, blend_index = blended_polyline(robot, waypoints, fractions)
    assert blend_index[1] == -1 and blend_index[0] >= 0 and blend_index[2] >= 0
    q_breaks = path.evaluate(path.breaks)[0]
    # The sharp corner (waypoint 2) is a piece boundary of the path, hit exactly.
    assert np.min(np.max(np.abs(q_breaks - waypoints[2]), axis=1)) <= 1e-12
    # The blended corners are cut: the path keeps a positive distance from waypoints 1 and 3.
    s = np.linspace(0.0, path.length, 4001)
    q = path.evaluate(s)[0]
    for k in (1, 3):
        assert np.min(np.linalg.norm(q - waypoints[k], axis=1)) > 1e-4
    # Value continuity everywhere, tangent continuity except at the sharp corner.
    kinks = 0
    for (q0, dq0), (q1, dq1) in _piece_ends(path):
        assert np.max(np.abs(q0 - q1)) <= 1e-9
        kinks += int(np.max(np.abs(dq0 - dq1)) > 1e-9)
    assert kinks == 1


def test_blend_stays_inside_its_corner_triangle(robot: Cabin8, waypoints: np.ndarray) -> None:
    path, blend_index = blended_polyline(robot, waypoints, 0.45)
    for i in blend_index:
        piece = path.pieces[i]
        assert isinstance(piece, BlendPiece)
        # Barycentric coordinates by least squares (independent of the Bezier formula): the affine hull of
        # (a, w, b) contains the point and every coordinate is in [0, 1].
        A = np.vstack([np.column_stack([piece.a, piece.w, piece.b]), np.ones((1, 3))])
        q = piece.evaluate(np.linspace(0.0, piece.length, 41))[0]
        for qi in q:
            lam, *_ = np.linalg.lstsq(A, np.concatenate([qi, [1.0]]), rcond=None)
            assert np.max(np.abs(A @ lam - np.concatenate([qi, [1.0]]))) <= 1e-12
            assert np.all(lam >= -1e-9) and np.all(lam <= 1 + 1e-9)


def test_zero_blend_fraction_gives_the_polyline_itself(robot: Cabin8, waypoints: np.ndarray) -> None:
    path, blend_index = blended_polyline(robot, waypoints, 0.0)
    assert blend_index == [-1] * (len(waypoints) - 2)
    assert len(path.pieces) == len(waypoints) - 1
    assert all(isinstance(p, LinePiece) for p in path.pieces)
    assert np.max(np.abs(path.evaluate(path.breaks)[0] - waypoints)) <= 1e-12
    # Every point of the path lies on its segment, as a convex combination of the two waypoints.
    br = path.breaks
    for k in range(len(waypoints) - 1):
        s = np.linspace(br[k], br[k + 1], 9)[1:-1]
        q = path.evaluate(s)[0]
        alpha = (s - br[k]) / (br[k + 1] - br[k])
        expected = waypoints[k] + alpha[:, None] * (waypoints[k + 1] - waypoints[k])
        assert np.max(np.abs(q - expected)) <= 1e-12


def test_drive_geometry_matches_the_drive_map_and_its_finite_differences(
    robot: Cabin8, waypoints: np.ndarray
) -> None:
    path, _ = blended_polyline(robot, waypoints, 0.4)
    br = path.breaks
    s = np.concatenate([np.linspace(a + 1e-3, b - 1e-3, 5) for a, b in zip(br[:-1], br[1:], strict=True)])
    u, du, ddu = robot.drive_path(*path.evaluate(s))

    def g(x: np.ndarray) -> np.ndarray:
        return robot.drives_from_joints(path.evaluate(x)[0])

    assert np.max(np.abs(u - g(s))) <= 1e-12
    fd_du = (g(s + H) - g(s - H)) / (2 * H)
    assert np.max(np.abs(fd_du - du)) <= 1e-6 * max(1.0, float(np.max(np.abs(du))))
    h2 = 1e-4  # second differences need a larger step (rounding error ~ eps / h^2)
    fd_ddu = (g(s + h2) - 2 * g(s) + g(s - h2)) / h2**2
    assert np.max(np.abs(fd_ddu - ddu)) <= 1e-5 * max(1.0, float(np.max(np.abs(ddu))))
    # u' = G q' with the robot's own drive-map Jacobian.
    q, dq, _ = path.evaluate(s)
    G = np.array([robot.drive_map_jacobian(qi)[0] for qi in q])
    assert np.max(np.abs(np.einsum("nij,nj->ni", G, dq) - du)) <= 1e-12


def test_segment_time_length_is_the_slowest_drive_time_at_its_velocity_limit(
    robot: Cabin8, waypoints: np.ndarray
) -> None:
    v_max = robot.limits.v_max
    for q0, q1 in zip(waypoints[:-1], waypoints[1:], strict=True):
        dq = q1 - q0
        # G dq by central differences of the closed-form drive map (independent of the CasADi Jacobian).
        g_dq = (robot.drives_from_joints(q0 + H * dq) - robot.drives_from_joints(q0 - H * dq)) / (2 * H)
        expected = float(np.max(np.abs(g_dq) / v_max))
        assert segment_time_length(robot, q0, q1) == pytest.approx(expected, rel=1e-6)
    # A pure rail move of 1 m at 0.25 m/s takes 4 s; a null segment keeps a tiny positive length.
    q0 = waypoints[0]
    q1 = q0.copy()
    q1[0] += 1.0
    assert segment_time_length(robot, q0, q1) == pytest.approx(1.0 / v_max[0], rel=1e-12)
    assert segment_time_length(robot, q0, q0) == 1e-6
