"""The on-disk cache folder shared by every stage that caches a build (clearance grids, native code)."""

from __future__ import annotations

import os
from pathlib import Path


def cache_dir() -> Path | None:
    """Where builds are cached: ``$CABINPLAN_CACHE_DIR`` (empty: no cache), else the user cache."""
    env = os.environ.get("CABINPLAN_CACHE_DIR")
    if env is not None:
        return Path(env) if env else None
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "cabinplan"
