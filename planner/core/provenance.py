"""Provenance of a plan: which code, robot description and scene produced it.

A controller can refuse a plan made against an outdated scene by comparing these hashes with its own.
"""

from __future__ import annotations

import hashlib
from functools import lru_cache
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

try:
    __version__ = version("cabinplan")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
    __version__ = "0.0.0+unknown"


@lru_cache(maxsize=1)
def source_sha256() -> str:
    """SHA-256 over the planner package's Python sources and description files (sorted by path)."""
    root = Path(__file__).resolve().parent.parent  # the planner package
    h = hashlib.sha256()
    for path in sorted(p for p in root.rglob("*") if p.suffix in {".py", ".yaml"} and p.is_file()):
        h.update(path.relative_to(root).as_posix().encode())
        h.update(b"\0")
        h.update(path.read_bytes())
    return h.hexdigest()


def code_version() -> dict[str, Any]:
    """``{"version", "source_sha256"}`` of the running planner."""
    return {"version": __version__, "source_sha256": source_sha256()}
