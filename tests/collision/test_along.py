"""The batched pass over a sampled path: its certificate agrees with ``check_path``, its figure is exact."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from planner.collision.along import AlongPath
from planner.collision.world import CollisionWorld
from planner.gate.requirements import GATE_MOTION_MARGIN_M
from planner.plan.pipeline import Planner
from planner.scenario.resolve import ResolvedScenario, load_scenario

SCENARIO = Path(__file__).parents[1] / "scenarios" / "hatch-bay-insert.yaml"


@pytest.fixture(scope="module")
def insertion() -> tuple[ResolvedScenario, CollisionWorld, np.ndarray]:
    """The hatch-bay insertion's joints around its closest approach (600 samples, every other one)."""
    sc = load_scenario(SCENARIO)
    res = Planner(sc).plan()
    q = sc.robot.joints_from_drives(res.profile.position)
    assert res.gate.min_clearance_at is not None
    k = res.gate.min_clearance_at["sample"]
    return sc, CollisionWorld(sc.robot, sc.cabin, sc.payload), np.ascontiguousarray(q[k - 600 : k + 600 : 2])


def test_certificate_agrees_with_the_motion_walk(
    insertion: tuple[ResolvedScenario, CollisionWorld, np.ndarray],
) -> None:
    sc, world, q = insertion
    exact_min = float(world.clearance_profile(q, include_self=False).min())
    for clearance in (sc.options.clearance_m, exact_min - 0.5e-3, exact_min + 2e-3):
        along = world.along(q).certify(clearance, world.self_clearance, GATE_MOTION_MARGIN_M)
        walk = world.check_path(clearance=clearance, qs=q, motion_margin=GATE_MOTION_MARGIN_M, max_run=128)
        if along.valid:  # never weaker: what it certifies, the walk certifies too
            assert walk.valid
        # A clearance above the exact minimum cannot be certified, by either route.
        if clearance > exact_min:
            assert not along.valid and not walk.valid
            assert along.contacts and along.first_bad is not None
            assert along.contacts[0].bodies[0] == "payload"
    # The requested clearance is certified by both.
    rep = world.along(q).certify(sc.options.clearance_m, world.self_clearance, GATE_MOTION_MARGIN_M)
    assert rep.valid and rep.walked == 0


def test_figure_is_the_exact_minimum_and_the_bound_holds_between_samples(
    insertion: tuple[ResolvedScenario, CollisionWorld, np.ndarray],
) -> None:
    _, world, q = insertion
    along = world.along(q)
    fig = along.clearance()
    exact = world.clearance_profile(q)
    assert fig.tolerance_m == pytest.approx(1e-4)
    assert fig.distance_m <= float(exact.min()) + fig.tolerance_m
    assert fig.distance_m == pytest.approx(float(exact[fig.sample]), abs=fig.tolerance_m)
    assert fig.bodies == world.min_distance(q[fig.sample]).bodies
    assert fig.bound_m <= float(exact.min())
    # Between samples: quarter points of every piece.
    for s in (0.25, 0.5, 0.75):
        inner = (1 - s) * q[:-1] + s * q[1:]
        assert float(world.clearance_profile(inner).min()) >= fig.bound_m - 1e-12
    # The bound is near the figure: within the largest reach of a piece.
    assert fig.distance_m - fig.bound_m <= float(along.reach.max())


def test_bounds_are_below_exact_distances(
    insertion: tuple[ResolvedScenario, CollisionWorld, np.ndarray],
) -> None:
    """Every lower bound the pass holds (kernel bounds, spread, probes) is below the exact distance."""
    _, world, q = insertion
    along: AlongPath = world.along(q[::10])
    along.certify(0.01, world.self_clearance, GATE_MOTION_MARGIN_M)
    along.clearance()
    for k in range(0, along.n, 7):
        d = world.min_distance(along.q[k], include_self=False)
        t = world.names.index(d.bodies[0])
        assert along.lower[k, t] <= d.distance_m + 1e-9


def test_bad_input_names_the_field(insertion: tuple[ResolvedScenario, CollisionWorld, np.ndarray]) -> None:
    from planner.core.exceptions import InvalidInput

    _, world, q = insertion
    for bad in (q[:1], q[:, :5], np.where(np.arange(q.size).reshape(q.shape) == 3, np.nan, q)):
        with pytest.raises(InvalidInput) as info:
            world.along(bad)
        assert info.value.details["field"] == "qs"
