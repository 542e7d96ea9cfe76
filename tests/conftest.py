"""Shared fixtures: the reference robot and admissible random configurations."""

from __future__ import annotations

import importlib.machinery
import shutil
from pathlib import Path

import numpy as np
import pytest

from planner.robots.cabin8 import Cabin8


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
    from planner.timing import reference

    for module in (DEFAULT.module, reference.kernels()):
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
