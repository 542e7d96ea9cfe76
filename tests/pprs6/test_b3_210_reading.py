"""The README's claim about the paper's 210 deg placement of B_3 (eq. 10), measured (issue 15).

Eq. (10) puts chain 3's base revolute B_3 at 210 deg while eq. (7) keeps its platform joint C_3 at 240
deg. Two readings: (b) only B_3 (and the axis v_3 of its revolute) at 210 deg, C_3 at 240 deg -- the
printed equations; (c) the whole chain 3, C_3 included, at 210 deg. The workspace at the level platform
differs a lot between them; the README quotes both.
"""

from __future__ import annotations

import numpy as np
import pytest

from planner.kinematics import pprs6 as kin
from planner.kinematics.workspace import two_pass_search
from planner.robots.pprs6 import Pprs6


def _admissible(robot: Pprs6, b3_deg: float, c3_deg: float):  # type: ignore[no-untyped-def]
    g = robot.geometry
    a = np.radians(b3_deg)
    u3, v3 = np.array([np.cos(a), np.sin(a), 0.0]), np.array([-np.sin(a), np.cos(a), 0.0])
    gc = kin.Pprs6Geometry(r=g.r, R=g.R, L=g.L, support_angles=(*g.support_angles[:2], np.radians(c3_deg)))

    def f(p: np.ndarray) -> np.ndarray:
        x = np.zeros((len(p), 6))
        x[:, :3] = p
        C = kin.platform_points(gc, x).C
        inv = kin.inverse_from_points(g, C)  # chains 1 and 2 as the model
        q, ok = inv.drives.copy(), inv.reachable.copy()
        C3 = C[:, 2]
        rho, h, b = g.R - C3 @ u3, C3[:, 2], C3 @ v3
        disc = g.L[2] ** 2 - b**2
        good = disc > 0
        q[:, 2] = np.arctan2(h, rho)
        q[:, 5] = np.where(good, np.sqrt(rho**2 + h**2) - np.sqrt(np.where(good, disc, 1.0)), np.nan)
        ok[:, 2] = good
        return np.asarray(ok.all(axis=1) & robot.within_limits(q).all(axis=1))

    return f


def _workspace(robot: Pprs6, b3_deg: float, c3_deg: float):  # type: ignore[no-untyped-def]
    g = robot.geometry
    reach = g.R + g.r + max(g.L)
    bounds = np.array([[-reach, reach], [-reach, reach], [-g.r - max(g.L), 0.5]])
    return two_pass_search(_admissible(robot, b3_deg, c3_deg), bounds, 0.01, 0.02)


@pytest.fixture(scope="module")
def robot() -> Pprs6:
    return Pprs6()


def test_the_model_reading_is_the_packaged_workspace(robot: Pprs6) -> None:
    ws = _workspace(robot, 240.0, 240.0)
    np.testing.assert_allclose(ws.extents_m[:, 0], [-0.080, -0.100, 0.1314], atol=1e-3)
    np.testing.assert_allclose(ws.extents_m[:, 1], [0.020, 0.0346, 0.2375], atol=1e-3)
    assert ws.volume_m3 == pytest.approx(0.70e-3, rel=0.03)


def test_b3_alone_at_210_deg_shrinks_the_workspace(robot: Pprs6) -> None:
    """Printed eq. 10 with eq. 7: Y from -92 mm, Z from 103 mm, 0.43 dm^3 (not 'same X and Y, Z from 121')."""
    ws = _workspace(robot, 210.0, 240.0)
    np.testing.assert_allclose(ws.extents_m[:, 0], [-0.080, -0.0918, 0.1027], atol=1.5e-3)
    np.testing.assert_allclose(ws.extents_m[:, 1], [0.020, 0.0346, 0.2375], atol=1.5e-3)
    assert ws.volume_m3 == pytest.approx(0.43e-3, rel=0.05)


def test_whole_chain3_at_210_deg_keeps_x_and_y(robot: Pprs6) -> None:
    """The README's old figure belongs to this reading: same X and Y extents, Z from 121 mm, 0.71 dm^3."""
    ws = _workspace(robot, 210.0, 210.0)
    np.testing.assert_allclose(ws.extents_m[:, 0], [-0.080, -0.100, 0.1206], atol=1.5e-3)
    np.testing.assert_allclose(ws.extents_m[:, 1], [0.020, 0.0346, 0.2375], atol=1.5e-3)
    assert ws.volume_m3 == pytest.approx(0.71e-3, rel=0.05)
