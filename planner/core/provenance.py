"""Provenance of a plan: which code, robot description and scene produced it.

A controller can refuse a plan made against an outdated scene by comparing these hashes with its own.
"""

from __future__ import annotations

import hashlib
from functools import lru_cache
from pathlib import Path
from typing import Any


@lru_cache(maxsize=1)
def package_version() -> str:
    """The installed cabinplan's version (read on first use: the package metadata scan costs 50 ms)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("cabinplan")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
        return "0.0.0+unknown"


def __getattr__(name: str) -> Any:
    """``__version__`` on first use (PEP 562)."""
    if name == "__version__":
        return package_version()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


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
    return {"version": package_version(), "source_sha256": source_sha256()}
