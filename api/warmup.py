"""Preloaded by the job forkserver: imports the planner and plans one reference-like scenario, once.

Every job process is forked from the forkserver, so it inherits what this warm-up loaded (compiled
CasADi functions, the compiled kernels loaded from their ahead-of-time build, the reference cabin's clearance
grid, matplotlib's font cache) and starts planning at once instead of spending seconds warming up.
Importing this module has that side effect on purpose; nothing else imports it.
"""

from __future__ import annotations

import logging
import time

from api.examples import aisle_bay_goal, docked
from api.worker import plan_job

_LOG = logging.getLogger(__name__)

#: A bay insertion in the reference aisle cabin with a 60 kg box payload, a pose goal and a straight
#: approach: every stage and kernel a typical job uses (on a fresh machine the kernels are built here, once,
#: 15-30 s -- numba's JIT, ~45 s, without a C compiler -- and cached; afterwards the warm-up takes a few
#: seconds).
WARMUP_SCENARIO = {
    "name": "warmup",
    "robot": "cabin8",
    "cabin": {"mesh": "cabin-aisle", "units": "m"},
    "payload": {
        "box": [0.45, 0.35, 0.30],
        "mass": 60,
        "grasp": {"position": [0, 0, 0.20], "orientation": {"w": 1, "x": 0, "y": 0, "z": 0}},
    },
    "start": docked(),
    "goal": aisle_bay_goal(),
    "options": {"seed": 1, "time_limit_s": 300},
}


def warm_up() -> float:
    """Plan :data:`WARMUP_SCENARIO` (result discarded); returns the time it took [s]."""
    t0 = time.perf_counter()
    try:
        plan_job(
            {"id": "warmup", "scenario": WARMUP_SCENARIO, "meshes": {}, "empty_dir": "/nonexistent"}, _ignore
        )
    except Exception:  # a warm-up failure must not stop the forkserver: jobs then just start cold
        _LOG.exception("job warm-up failed")
    return time.perf_counter() - t0


def _ignore(_stage: str, _fraction: float) -> None:
    return None


#: What cycle and campaign jobs import beyond a plan's (:mod:`api.cycles`), imported once here.
def preload_tasks() -> None:
    """Import the cycle and campaign modules, so that their jobs fork with them loaded."""
    try:
        import planner.campaign.run
        import planner.campaign.worker
        import planner.documents.cycle
        import planner.task.cycle  # noqa: F401 - the imports are the point
    except Exception:  # jobs then import them themselves
        _LOG.exception("job warm-up: the task modules not preloaded")


warm_up()
preload_tasks()
