"""The aisle campaign (a deep and a front unit of bay A3) searched once per session, in this process.

The search runs on the in-process executor so that the tests can count what the cabin's caches build
across the campaign's cycles; the embedded and Ray executors are tested through the CLI and on Ray.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import yaml

import planner.collision.clearance_grid as clearance_grid
import planner.collision.probes as probes
import planner.collision.world as world
from planner.campaign.run import CampaignResult, CampaignRun
from planner.sweep.run import InlineExecutor
from planner.task.campaign_schema import Campaign, campaign_from_dict

CAMPAIGNS = Path(__file__).resolve().parent.parent / "campaigns"
DEEP_FRONT = CAMPAIGNS / "aisle-deep-front.yaml"


def deep_front(**changes: Any) -> dict[str, Any]:
    """The aisle campaign as a mapping (a fresh copy), with top-level fields changed."""
    data: dict[str, Any] = yaml.safe_load(DEEP_FRONT.read_text(encoding="utf-8"))
    data.update(changes)
    return data


@dataclass
class Searched:
    """The order search of the aisle campaign, run once: what it found and what it built."""

    campaign: Campaign
    out: Path
    run: CampaignRun
    result: CampaignResult
    executor: InlineExecutor
    #: Clearance grids loaded or built, and FCL meshes built, by triangle count.
    grids: Counter[int]
    bvhs: Counter[int]


@pytest.fixture(scope="session")
def searched(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Searched]:
    out = tmp_path_factory.mktemp("campaign") / "out"
    camp = campaign_from_dict(deep_front(order="find"))
    grids: Counter[int] = Counter()
    bvhs: Counter[int] = Counter()
    build, bvh = clearance_grid.cached_build, probes._bvh
    mp = pytest.MonkeyPatch()

    def counting_build(key: str, vertices: Any, faces: Any, step: float) -> Any:
        grids[len(faces)] += 1
        return build(key, vertices, faces, step)

    def counting_bvh(vertices: Any, faces: Any) -> Any:
        bvhs[len(faces)] += 1
        return bvh(vertices, faces)

    # Fresh caches: every grid or cabin mesh this campaign needs is made, and counted, here.
    world._cabin_grid.cache_clear()
    probes.cabin_bvh.cache_clear()
    world._CARRIAGE_TABLES.clear()
    mp.setattr(clearance_grid, "cached_build", counting_build)
    mp.setattr(world, "cached_build", counting_build)
    mp.setattr(probes, "_bvh", counting_bvh)
    try:
        executor = InlineExecutor()
        run = CampaignRun(camp, out, executor, base_dir=DEEP_FRONT.parent)
        result = run.run()
    finally:
        mp.undo()
    yield Searched(camp, out, run, result, executor, grids, bvhs)
