"""Campaigns by physics and by their real behaviour: the cabin filling up, the blocker named, the order.

The aisle campaign: unit D goes deep into rack bay A3, unit F is mounted in the aisle 30 mm in front of the
bay's face plate, where D passes on its insertion line. F installed first blocks D; D first, both install.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import fcl
import numpy as np
import trimesh

from planner.campaign.run import CampaignRun
from planner.collision.obstacles import Obstacle
from planner.core.schemas import Pose
from planner.robots.geometry import PAYLOAD
from planner.sweep.run import InlineExecutor
from planner.task.campaign import cycle_document, cycle_key
from planner.task.campaign_schema import campaign_from_dict
from planner.task.legs import leg
from planner.task.resolve import ResolvedCycle, resolve_cycle
from planner.task.schema import cycle_from_dict
from tests.campaign.conftest import DEEP_FRONT, Searched, deep_front

#: Triangles above which an FCL mesh is a cabin's (the aisle cabin has 9 296; a box obstacle 12).
CABIN_SIZED = 1000


def _summary(out: Path) -> dict[str, Any]:
    data: dict[str, Any] = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    return data


def test_the_search_finds_the_order_that_installs_both(searched: Searched) -> None:
    r = searched.result
    assert r.succeeded and r.order == ["D", "F"]
    summary = _summary(searched.out)
    assert summary["status"] == "succeeded" and summary["order"] == ["D", "F"]
    # The refusal that taught it: D with F installed, blocked by F; so D before F.
    assert summary["search"]["constraints"] == [{"unit": "D", "before_one_of": ["F"]}]
    (refusal,) = summary["search"]["refusals"]
    assert refusal["unit"] == "D" and refusal["installed"] == ["F"] and refusal["blockers"] == ["F"]
    # One cycle document per unit in install order, each the cycle of its cabin state, at rest at park.
    for k, unit in enumerate(r.order):
        doc = json.loads((searched.out / f"{k + 1:02d}-{unit}.json").read_text(encoding="utf-8"))
        assert doc["kind"] == "cycle" and doc["status"] == "succeeded"
        assert doc["cycle"]["name"] == f"aisle-deep-front-{unit}"
        assert [x["name"] for x in doc["legs"]][0] == "pre_grasp" and doc["legs"][-1]["name"] == "park"
        v = np.array(doc["velocity"])
        assert np.abs(v[0]).max() < 1e-9 and np.abs(v[-1]).max() < 1e-9
    total = sum(u["duration_s"] for u in summary["units"])
    assert summary["campaign_duration_s"] == total > 0


def test_the_cabins_caches_are_built_once_for_the_whole_campaign(searched: Searched) -> None:
    """Four cycles in three cabin states (none, D, F installed): one clearance grid, and no cabin FCL mesh.

    The cabin's FCL mesh is built at its first use (once per cabin, cached) and the compiled route never
    uses it: not one is built for the whole campaign.
    """
    assert len(searched.executor.ran) == 4
    cabin_grids = sum(n for tris, n in searched.grids.items() if tris > CABIN_SIZED)
    cabin_bvhs = sum(n for tris, n in searched.bvhs.items() if tris > CABIN_SIZED)
    assert cabin_grids == 1, searched.grids
    assert cabin_bvhs == 0, searched.bvhs


def _box_mesh(obstacle: Obstacle) -> fcl.CollisionObject:
    assert obstacle.size is not None
    box = trimesh.creation.box(extents=obstacle.size)
    mesh = fcl.BVHModel()
    mesh.beginModel(len(box.vertices), len(box.faces))
    mesh.addSubModel(np.asarray(box.vertices, dtype=float), np.asarray(box.faces, dtype=np.int32))
    mesh.endModel()
    T = obstacle.T_base_obstacle
    return fcl.CollisionObject(mesh, fcl.Transform(T[:3, :3], T[:3, 3]))


def _min_distance(cyc: ResolvedCycle, joints: np.ndarray, obstacle: Obstacle, held: bool) -> float:
    """Smallest exact FCL distance of any body to ``obstacle`` over every sample (N, 8) (<= 0.5 m, else inf).

    From the robot model's body poses and FCL, not the collision world that planned them. A body whose
    bounding sphere is certainly more than 0.5 m from the obstacle's is not queried at that sample.
    """
    model = cyc.robot.collision_model()
    geom = cyc.held if held else cyc.gripper
    assert geom is not None
    names = (*model.body_names, PAYLOAD)
    shapes = model.shapes(geom.size)
    R, P, L = model.body_poses(joints, names, geom.T_tool_box)
    target = _box_mesh(obstacle)
    centre = obstacle.T_base_obstacle[:3, 3]
    assert obstacle.size is not None
    reach = 0.5 * float(np.linalg.norm(obstacle.size))
    best = np.inf
    for b, body in enumerate(names):
        s = shapes[body]
        for k in range(len(joints)):
            bound = s.bounding_radius if s.kind == "box" else s.radius + 0.5 * L[k, b]
            if np.linalg.norm(P[k, b] - centre) - bound - reach > 0.5:
                continue
            size = s.size if s.kind == "box" else (s.radius, L[k, b])
            g = fcl.Box(*size) if s.kind == "box" else fcl.Capsule(*size)
            d = fcl.distance(target, fcl.CollisionObject(g, fcl.Transform(R[k, b], P[k, b])))
            best = min(best, float(d))
    return best


def test_no_sample_of_the_later_cycle_within_the_clearance_of_the_installed_unit(searched: Searched) -> None:
    """F's cycle after D: at every sample of every motion leg, exact FCL distances to the installed D."""
    camp = searched.campaign
    cyc = resolve_cycle(cycle_from_dict(cycle_document(camp, "F", ("D",))), base_dir=DEEP_FRONT.parent)
    (d_unit,) = [o for o in cyc.installed if o.name == "unit D"]
    # D stands where its own cycle put it: its bay pose.
    assert np.allclose(d_unit.T_base_obstacle, Pose.model_validate(camp.unit("D").bay.pose).matrix())
    doc = json.loads((searched.out / "02-F.json").read_text(encoding="utf-8"))
    joints = np.array(doc["joints"]["position"])
    clearance = camp.options.clearance_m
    measured = {}
    for x in doc["legs"]:
        if x["kind"] == "dwell":
            continue
        rows = joints[max(0, x["sample_start"] - 1) : x["sample_end"]]
        measured[x["name"]] = d = _min_distance(cyc, rows, d_unit, leg(x["name"]).held)
        assert d >= clearance, (x["name"], d)
    assert len(measured) == 7
    # F is installed 0.2 m in front of D: its insertion comes close enough to be measured, not skipped.
    assert measured["insertion"] < 0.5, measured


def test_a_given_order_names_the_true_blocker(searched: Searched) -> None:
    """F first: D's cycle is refused, blocked by F, and D alone plans, so F is what blocks it.

    The refusal's distance is inside the clearance. The given order plans nothing new: both of its cycles
    were planned by the search (same cabin state, same hash).
    """
    executor = InlineExecutor()
    camp = campaign_from_dict(deep_front(order="given"))
    run = CampaignRun(camp, searched.out, executor, base_dir=DEEP_FRONT.parent)
    result = run.run()
    assert executor.ran == []  # the feasibility cache: same hashes, no plan
    assert not result.succeeded and result.order == ["F", "D"]
    f, d = result.units
    assert f["status"] == "planned" and d["status"] == "refused"
    assert d["blockers"] == ["F"]
    (line,) = d["blocking"]
    assert line.startswith("unit F, installed first, ") and line.endswith(": install D before F")
    assert "transit leg" in line
    summary = _summary(searched.out)
    assert summary["message"].startswith("unit D, installed second: cycle refused: unit F, installed first")
    assert (searched.out / "01-F.json").exists() and (searched.out / "02-D.refused.json").exists()
    refusal = json.loads((searched.out / "02-D.refused.json").read_text(encoding="utf-8"))
    best = refusal["details"]["best"]
    assert "unit F" in best["bodies"] and best["distance_m"] < best["required_m"]
    # The counterfactual: D in the same cabin without F plans (the search planned it first).
    alone = run.job("D", ())
    assert run.journal.rows[alone.sha256]["status"] == "succeeded"


def test_cycle_keys_are_the_cabin_state_not_the_order_or_the_name() -> None:
    camp = campaign_from_dict(deep_front())
    renamed = campaign_from_dict(deep_front(name="another-line"))
    listed = campaign_from_dict(deep_front(units=list(reversed(deep_front()["units"]))))
    keys = {cycle_key(cycle_document(c, "F", ("D",)), DEEP_FRONT.parent) for c in (camp, renamed, listed)}
    assert len(keys) == 1
    other = cycle_key(cycle_document(camp, "F", ()), DEEP_FRONT.parent)
    assert other not in keys
    # A changed option is another cycle.
    slower = campaign_from_dict(deep_front(options={"clearance_m": 0.012, "seed": 1}))
    assert cycle_key(cycle_document(slower, "F", ("D",)), DEEP_FRONT.parent) not in keys
