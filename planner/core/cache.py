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
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

log = logging.getLogger(__name__)

#: The cache folder's data entries, pruned together within its size bound: clearance grids, carriage
#: clearance tables, parsed meshes (the compiled builds are pruned by their own pattern).
DATA_PATTERNS = ("grid-*", "carriage-*", "meshes/*.npz")

#: Default bound of the cache folder's size [bytes].
DEFAULT_MAX_BYTES = 2 * 1024**3
#: A temporary file older than this [s] belongs to a writer that died: :func:`prune` deletes it.
STALE_TMP_S = 600.0


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


def write_atomic(path: Path, write: Callable[[IO[Any]], None], text: bool = False) -> None:
    """Write ``path`` through a temporary file in its folder and one rename: whole or not at all.

    The temporary file is removed when writing fails (a full disk); one left by a killed writer is
    removed by :func:`prune`.

    Raises:
        OSError: the entry could not be written (nothing is left behind).
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile(
        "w" if text else "wb", dir=path.parent, suffix=".tmp", delete=False
    ) as tmp:
        name = tmp.name
        try:
            write(tmp)
        except BaseException:
            tmp.close()
            Path(name).unlink(missing_ok=True)
            raise
    try:
        os.replace(name, path)
    except BaseException:
        Path(name).unlink(missing_ok=True)
        raise


def prune(folder: Path, patterns: tuple[str, ...], limit: int | None = None) -> int:
    """Delete the least recently used entries matching ``patterns`` until they fit in ``limit`` bytes.

    Temporary files of writers that died (older than :data:`STALE_TMP_S`) go first, whatever the bound.

    Returns:
        The number of bytes deleted. Entries another process deletes meanwhile are skipped.
    """
    limit = max_bytes() if limit is None else limit
    freed = 0
    now = time.time()
    for stale in (*folder.glob("*.tmp"), *folder.glob("*/*.tmp")):  # writers that died mid-write
        try:
            st = stale.stat()
            if now - st.st_mtime > STALE_TMP_S:
                stale.unlink()
                freed += st.st_size
        except OSError:
            continue
    entries: list[tuple[float, int, Path]] = []
    for pattern in patterns:
        for path in folder.glob(pattern):
            try:
                st = path.stat()
            except OSError:
                continue
            entries.append((st.st_mtime, st.st_size, path))
    total = sum(size for _, size, _ in entries)
    deleted = 0
    for _, size, path in sorted(entries, key=lambda e: e[0]):
        if total - deleted <= limit:
            break
        try:
            path.unlink()
            deleted += size
        except OSError:
            continue
    freed += deleted
    if freed:
        log.info("cache %s: %d bytes of least recently used entries deleted", folder, freed)
    return freed
