"""A generated campaign in CI: valid, reproducible, its blocking pair true by geometry and by the planner."""

from __future__ import annotations

import json

import numpy as np
import pytest

from planner.collision.obstacles import Obstacle
from planner.collision.world import CollisionWorld
from planner.core.schemas import Pose
from planner.generate.cycles import CycleGeneratorOptions, GeneratedCampaign, generate_campaign
from planner.robots.cabin8 import Cabin8
from planner.task.campaign import check_campaign, cycle_document
from planner.task.campaign_schema import Campaign, campaign_from_dict
from planner.task.resolve import resolve_cycle
from planner.task.schema import cycle_from_dict

OPTIONS = CycleGeneratorOptions(units=(3, 3), end_bay_probability=1.0, pair_probability=1.0)
#: Case 2 of seed 0 with these options has an end-wall unit and a blocking pair (a front unit is placed
#: only where it reaches the deep unit's corridor and the arm reaches it: most draws have none).
INDEX = 2


@pytest.fixture(scope="module")
def generated(tmp_path_factory: pytest.TempPathFactory) -> tuple[GeneratedCampaign, Campaign, object]:
    case = generate_campaign(0, INDEX, OPTIONS)
    folder = tmp_path_factory.mktemp("generated")
    (folder / case.mesh_name).write_bytes(case.mesh_bytes)
    return case, campaign_from_dict(case.campaign), folder


def test_the_campaign_is_valid_and_reproducible(generated: tuple) -> None:
    case, camp, folder = generated
    assert 3 <= len(camp.ids) <= 3 and camp.order == "given"
    check_campaign(camp, folder)  # no overlapping units, each unit's own cycle input valid
    again = generate_campaign(0, INDEX, OPTIONS)
    assert again.mesh_bytes == case.mesh_bytes and again.campaign == case.campaign


def _box(camp: Campaign, unit_id: str, shift_m: float = 0.0) -> Obstacle:
    u = camp.unit(unit_id)
    T = Pose.model_validate(u.bay.pose).matrix()
    T[:3, 3] -= shift_m * np.array(u.bay.approach.direction)
    assert u.unit.box is not None
    return Obstacle.box(f"unit {unit_id}", tuple(u.unit.box), T)


def test_the_blocking_pair_is_true_by_geometry(generated: tuple) -> None:
    """The front unit overlaps the deep unit's pre-insertion pose and keeps 30-50 mm from its bay's face."""
    case, camp, _ = generated
    assert case.meta["precedence"], "the options ask for a blocking pair"
    for deep, front in case.meta["precedence"]:
        pre = _box(camp, deep, camp.unit(deep).bay.approach.distance)
        assert pre.distance_to(_box(camp, front)) <= 0.0
        assert _box(camp, deep).distance_to(_box(camp, front)) > 0.03 + camp.options.clearance_m


def test_every_unit_docks_held_along_x_beside_the_lane(generated: tuple) -> None:
    """The end-wall unit too is docked held along +x; no fixture comes near the park posture's ride.

    On the lane a fixture would stop the robot from ever passing the dock (an end-wall unit docked held
    along the rail, in the lane, made every cycle beyond its dock unplannable).
    """
    case, camp, folder = generated
    assert "end" in [u["kind"] for u in case.meta["units"]]
    robot = Cabin8(rail_length=case.meta["rail_length_m"])
    assert camp.park.drives is not None
    park = robot.joints_from_drives(np.array([camp.park.drives[d] for d in robot.drive_names], dtype=float))
    for u in camp.ids:
        unit = camp.unit(u)
        assert np.allclose(unit.dock.approach.direction, [1.0, 0.0, 0.0])
        assert np.allclose(Pose.model_validate(unit.dock.pose).matrix()[:3, 2], [1.0, 0.0, 0.0])
        fixture = Obstacle.box(
            f"fixture {u}", tuple(unit.dock.fixture.box), Pose.model_validate(unit.dock.fixture.pose).matrix()
        )
        world = CollisionWorld(robot, None, None, obstacles=(fixture,))
        for d1 in np.arange(float(park[0]), case.meta["rail_length_m"], 0.05):
            q = park.copy()
            q[0] = d1
            assert world.is_valid(q, camp.options.clearance_m), (u, d1)


def test_the_witnesses_hold_in_the_cycle_each_unit_plans(generated: tuple) -> None:
    """Every unit's cycle in the empty cabin resolves: dock clear of its fixture, bay free, lines sound."""
    _, camp, folder = generated
    for u in camp.ids:
        cyc = resolve_cycle(cycle_from_dict(cycle_document(camp, u, ())), base_dir=folder)
        assert cyc.spec.unit.id == u and not cyc.installed


@pytest.mark.slow
def test_the_planner_finds_the_blocking_pair(generated: tuple) -> None:
    """The deep unit alone plans; after its front unit it is refused, and the refusal names the front unit."""
    from planner.campaign.worker import cycle_outcome
    from planner.task.campaign import verdict_of

    case, camp, folder = generated
    ((deep, front),) = case.meta["precedence"]
    alone = cycle_outcome({"cycle": cycle_document(camp, deep, ()), "base_dir": str(folder)})
    assert alone["status"] == "succeeded", alone["message"]
    after = cycle_outcome({"cycle": cycle_document(camp, deep, (front,)), "base_dir": str(folder)})
    assert after["status"] == "failed"
    details = json.loads(after["document"]).get("details")
    verdict, found = verdict_of(after, frozenset({front}), frozenset(), details)
    assert verdict.blockers == frozenset({front}), after["message"]
