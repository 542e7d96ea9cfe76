"""Shared fixtures: the reference robot and admissible random configurations; the suite's xdist groups."""

from __future__ import annotations

import importlib.machinery
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from planner.robots.cabin8 import Cabin8

#: Folders whose tests run together on one xdist worker: their session fixtures (the searched campaign, the
#: embedded sweep, the planned cycles) are computed once, and the two local Rays (a sweep's, a campaign's)
#: never run side by side (a test kills the Ray workers it finds by their title).
TOGETHER = {"sweep": "sweep-campaign", "campaign": "sweep-campaign", "task": "task"}


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Every test in an xdist group (``make test`` runs ``-n 2 --dist loadgroup``): its module's or folder's.

    A module's tests stay on one worker, so its module fixtures (a service, a planned scenario) are set up
    once; the folders of :data:`TOGETHER` share a group. Without ``-n`` the marks do nothing.
    """
    root = Path(__file__).resolve().parent
    for item in items:
        if item.get_closest_marker("xdist_group") is not None:
            continue
        rel = item.path.resolve().relative_to(root)
        folder = rel.parts[0] if len(rel.parts) > 1 else ""
        item.add_marker(pytest.mark.xdist_group(TOGETHER.get(folder, rel.as_posix())))


@pytest.fixture(scope="session")
def robot() -> Cabin8:
    return Cabin8()


def admissible_joints(robot: Cabin8, n: int, seed: int) -> np.ndarray:
    """N admissible joint vectors drawn uniformly (rejection sampling), reproducible by seed."""
    rng = np.random.default_rng(seed)
    ps = robot.desc.parallel_stage
    lo = robot.limits.lower.copy()
    hi = robot.limits.upper.copy()
    lo[1:4] = [-0.3, ps.y_range[0], -ps.gamma_max]
    hi[1:4] = [0.3, ps.y_range[1], ps.gamma_max]
    out: list[np.ndarray] = []
    while len(out) < n:
        cand = rng.uniform(lo, hi, size=(4 * n, 8))
        for q in cand:
            if not robot.violations(q):
                out.append(q)
                if len(out) == n:
                    break
    return np.array(out)


@pytest.fixture(scope="session")
def configs(robot: Cabin8) -> np.ndarray:
    return admissible_joints(robot, 300, seed=42)


@pytest.fixture(scope="session", autouse=True)
def compiled_kernels() -> None:
    """The compiled kernels resolved once, before any test points ``CABINPLAN_CACHE_DIR`` elsewhere.

    The ahead-of-time build in the session's cache folder (built now if missing, as ``make`` does), or
    numba's JIT (``CABINPLAN_KERNELS=jit``, no cache folder): a test that switches the cache folder must
    not make the first kernel call build the kernels into its temporary folder.
    """
    from planner.collision.kernels.entries import DEFAULT
    from planner.timing import acc_reference

    for module in (DEFAULT.module, acc_reference.kernels()):
        built = getattr(module, "__file__", "")
        if built.endswith(importlib.machinery.EXTENSION_SUFFIXES[0]):
            SESSION_BUILDS.append(Path(built))


#: The ahead-of-time kernel builds the session uses (none under the JIT).
SESSION_BUILDS: list[Path] = []


def share_compiled_kernels(cache_root: Path) -> None:
    """Copy the session's ahead-of-time kernel builds into another cache folder (for a child process).

    A child process pointed at a fresh cache folder would otherwise build them there first (~15 s).
    """
    for built in SESSION_BUILDS:
        (cache_root / "native").mkdir(parents=True, exist_ok=True)
        shutil.copy2(built, cache_root / "native" / built.name)


def plan_in_a_fresh_process(
    scenario: Path, out: Path, watched: tuple[str, ...], env: dict[str, str] | None = None
) -> tuple[subprocess.CompletedProcess[str], list[str]]:
    """Run ``cabinplan plan SCENARIO -o OUT`` in a new interpreter; also which of ``watched`` it imported.

    A module counts as imported when it is a real module object at the end (a deferred stand-in of
    :mod:`planner.core.lazy` that was never touched does not).
    """
    root = Path(__file__).resolve().parents[1]
    code = (
        "import json, sys\n"
        f"sys.argv = ['cabinplan', 'plan', {str(scenario)!r}, '-o', {str(out)!r}]\n"
        "from planner import cli\n"
        "try:\n"
        "    cli.app(standalone_mode=False)\n"
        "finally:\n"
        f"    watched = {watched!r}\n"
        "    loaded = sorted(m for m in watched if type(sys.modules.get(m)).__name__ == 'module')\n"
        "    print('LOADED', json.dumps(loaded))\n"
    )
    run = subprocess.run(
        [sys.executable, "-c", code], cwd=root, env=env or dict(os.environ), capture_output=True, text=True
    )
    assert run.returncode == 0, run.stderr[-2000:]
    line = next(ln for ln in run.stdout.splitlines() if ln.startswith("LOADED "))
    return run, json.loads(line[len("LOADED ") :])
