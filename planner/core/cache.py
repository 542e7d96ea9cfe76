"""The on-disk cache folder shared by every stage that caches a build, and its size bound.

The stages: clearance grids, parsed meshes, native code. Entries are files named by a hash of what they
were built from, written atomically (a reader sees an old entry or a whole new one), so any entry can be
deleted at any time: the next user rebuilds it. A hit refreshes the entry's modification time
(:func:`touch`); :func:`prune` deletes the least recently used entries once the folder holds more than
:func:`max_bytes` (``$CABINPLAN_CACHE_MAX_BYTES``, default 2 GiB): a generated-cabin benchmark otherwise
leaves gigabytes of grids behind.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

log = logging.getLogger(__name__)

#: Default bound of the cache folder's size [bytes].
DEFAULT_MAX_BYTES = 2 * 1024**3


def cache_dir() -> Path | None:
    """Where builds are cached: ``$CABINPLAN_CACHE_DIR`` (empty: no cache), else the user cache."""
    env = os.environ.get("CABINPLAN_CACHE_DIR")
    if env is not None:
        return Path(env) if env else None
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "cabinplan"


def max_bytes() -> int:
    """The cache folder's size bound [bytes]: ``$CABINPLAN_CACHE_MAX_BYTES``, else 2 GiB."""
    env = os.environ.get("CABINPLAN_CACHE_MAX_BYTES")
    try:
        return max(0, int(env)) if env else DEFAULT_MAX_BYTES
    except ValueError:
        log.warning("CABINPLAN_CACHE_MAX_BYTES=%r is not a whole number of bytes; using 2 GiB", env)
        return DEFAULT_MAX_BYTES


def touch(*paths: Path) -> None:
    """Mark cache entries as just used (their modification time), so pruning keeps them longest."""
    for path in paths:
        try:
            os.utime(path)
        except OSError:
            pass


def prune(folder: Path, patterns: tuple[str, ...], limit: int | None = None) -> int:
    """Delete the least recently used entries matching ``patterns`` until they fit in ``limit`` bytes.

    Returns:
        The number of bytes deleted. Entries another process deletes meanwhile are skipped.
    """
    limit = max_bytes() if limit is None else limit
    entries: list[tuple[float, int, Path]] = []
    for pattern in patterns:
        for path in folder.glob(pattern):
            try:
                st = path.stat()
            except OSError:
                continue
            entries.append((st.st_mtime, st.st_size, path))
    total = sum(size for _, size, _ in entries)
    freed = 0
    for _, size, path in sorted(entries, key=lambda e: e[0]):
        if total - freed <= limit:
            break
        try:
            path.unlink()
            freed += size
        except OSError:
            continue
    if freed:
        log.info("cache %s: %d bytes of least recently used entries deleted", folder, freed)
    return freed
