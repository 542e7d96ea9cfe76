"""One cache policy for native builds: where a build lives, its key, its lock and its failure marker.

Two kinds of native build are cached side by side in ``cache_dir()/native``: the ahead-of-time numba
extensions of the kernels (:mod:`planner.core.aot`) and the C builds of compiled CasADi functions
(:mod:`planner.kinematics.native`). Both follow this module:

- **Place and key**: a build of ``name`` is the file ``<name>-<key><suffix>``; the key is
  :func:`digest` (the first 24 hex digits of a SHA-256) of everything the build depends on, so a change of
  the sources, the compiler flags or the toolchain gives a new file and an old one is never loaded.
- **Lock**: the builds of one name are serialised by an exclusive ``flock`` on ``<name>.lock``
  (:meth:`NativeBuild.locked`): concurrent processes build once, the others wait and load.
- **Atomic**: a build is written beside its place and renamed into it, so a reader sees the whole file or
  none (the builders do this; a temporary build folder ``<name>-build-*`` that a killed build left is
  removed after :data:`~planner.core.cache.STALE_TMP_S`).
- **Failure marker**: a build that fails the way it would fail again (the compiler exits with an error,
  or there is no compiler to run: :class:`BuildFailed`) leaves ``<file>.failed`` with the compiler's
  output, and every process falls back (numba's JIT, CasADi's virtual machine) without trying again
  until the marker is :data:`FAILED_RETRY_S` old; a build interrupted by a signal or a timeout
  (:class:`BuildInterrupted`) leaves none, and the next process tries again.
- **Damaged file**: a build that does not load is set aside (``<file>.bad``) and built again, once.

:func:`build_once` runs a builder under this policy.
"""

from __future__ import annotations

import hashlib
import logging
import os
import shutil
import subprocess
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from planner.core.cache import STALE_TMP_S, cache_dir

log = logging.getLogger(__name__)

#: After a failed build, processes fall back without trying again for this long [s] (a day).
FAILED_RETRY_S = 86400.0


class BuildFailed(Exception):
    """A build that would fail the same way again (a compiler error, no compiler): marks its key.

    Args:
        reason: One line saying why (the warning).
        report: What the marker file keeps (:func:`failure_report`: exit code, time, the output).
    """

    def __init__(self, reason: str, report: str) -> None:
        super().__init__(reason)
        self.report = report


class BuildInterrupted(Exception):
    """A build stopped from outside (a signal, a timeout): no marker, the next process tries again."""


def failure_report(returncode: int, output: str) -> str:
    """The text of a failure marker: ``exit code N at <time>`` and the end of the build's output."""
    return f"exit code {returncode} at {time.strftime('%Y-%m-%dT%H:%M:%S%z')}\n" + output[-25000:]


def folder() -> Path | None:
    """The folder of every native build (``cache_dir()/native``), or None without a cache folder."""
    root = cache_dir()
    return None if root is None else root / "native"


def digest(parts: Iterable[str | bytes]) -> str:
    """The key of a build: SHA-256 of the parts (each followed by a NUL byte), 24 hex digits."""
    h = hashlib.sha256()
    for part in parts:
        h.update((part.encode() if isinstance(part, str) else part) + b"\0")
    return h.hexdigest()[:24]


@dataclass(frozen=True)
class NativeBuild:
    """One build's place in the cache: ``<folder>/<name>-<key><suffix>``, its lock and its marker.

    Attributes:
        where: The folder (:func:`folder`).
        name: The build's name (``[A-Za-z0-9_]``), the stem of its files and of its lock.
        key: The :func:`digest` of what it is built from.
        suffix: The file suffix (``.so``, or the interpreter's extension-module suffix).
    """

    where: Path
    name: str
    key: str
    suffix: str

    @classmethod
    def of(cls, name: str, key: str, suffix: str) -> NativeBuild | None:
        """The build of ``name`` for ``key`` in the cache folder (None without one)."""
        where = folder()
        return None if where is None else cls(where, name, key, suffix)

    @property
    def path(self) -> Path:
        """The build's file."""
        return self.where / f"{self.name}-{self.key}{self.suffix}"

    @property
    def marker(self) -> Path:
        """The failure marker of this key (the build's file name plus ``.failed``)."""
        return self.path.with_name(self.path.name + ".failed")

    @property
    def lock_path(self) -> Path:
        """The lock file that serialises the builds of this name (every key)."""
        return self.where / f"{self.name}.lock"

    @contextmanager
    def locked(self) -> Iterator[None]:
        """Hold the build lock for the ``with`` block (the folder is created first)."""
        self.where.mkdir(parents=True, exist_ok=True)
        with BuildLock(self.lock_path):
            yield

    def failed_recently(self) -> bool:
        """Whether the build failed less than :data:`FAILED_RETRY_S` ago (an older marker is removed)."""
        try:
            age = time.time() - self.marker.stat().st_mtime
        except FileNotFoundError:
            return False
        if age < FAILED_RETRY_S:
            return True
        self.marker.unlink(missing_ok=True)
        return False

    def record_failure(self, report: str) -> None:
        """Leave the failure marker (nothing where the folder cannot be written: the next process retries)."""
        try:
            self.marker.write_text(report, encoding="utf-8")
        except OSError as exc:
            log.warning("could not write the failure marker %s (%s)", self.marker, exc)

    def clear_failure(self) -> None:
        """Remove the failure marker (a build of this key succeeded)."""
        self.marker.unlink(missing_ok=True)

    def set_aside(self) -> Path:
        """Rename a build that does not load to ``<file>.bad`` (kept for inspection); returns that path."""
        bad = self.path.with_name(self.path.name + ".bad")
        os.replace(self.path, bad)
        return bad

    def remove_stale_build_folders(self) -> None:
        """Delete the build folders ``<name>-build-*`` a killed build left (older than STALE_TMP_S)."""
        now = time.time()
        for stale in self.where.glob(f"{self.name}-build-*"):
            try:
                if stale.is_dir() and now - stale.stat().st_mtime > STALE_TMP_S:
                    shutil.rmtree(stale, ignore_errors=True)
            except OSError:
                pass


class BuildLock:
    """An exclusive ``flock`` on a file for the ``with`` block (no lock where ``fcntl`` is missing)."""

    def __init__(self, lock_path: Path) -> None:
        self.path = lock_path
        self.fd: int | None = None

    def __enter__(self) -> None:
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not POSIX
            return
        self.fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        fcntl.flock(self.fd, fcntl.LOCK_EX)

    def __exit__(self, *exc: object) -> None:
        if self.fd is not None:
            os.close(self.fd)  # closing releases the lock
            self.fd = None


def build_once(build: NativeBuild, make: Callable[[], None], warn: Callable[[str], None]) -> bool:
    """Make the build under the cache policy; whether its file is there afterwards.

    Nothing is tried while a failure marker is younger than :data:`FAILED_RETRY_S`. Otherwise, under the
    lock (another process may be building it: it is then loaded, not built twice), stale build folders
    are removed and ``make`` runs unless the file appeared meanwhile. ``make`` writes ``build.path``
    atomically and raises :class:`BuildFailed` (the marker is left) or :class:`BuildInterrupted` (none);
    a :class:`subprocess.TimeoutExpired` counts as interrupted.

    Args:
        build: The build's place.
        make: Builds it.
        warn: Called with the reason when there is no build (the caller warns once and falls back).
    """
    if build.failed_recently():
        warn(f"an earlier build failed, see {build.marker}")
        return False
    with build.locked():
        build.remove_stale_build_folders()
        if not build.path.is_file() and not build.failed_recently():
            try:
                make()
            except BuildFailed as exc:
                build.record_failure(exc.report)
                warn(f"the build failed: {exc}")
                return False
            except (BuildInterrupted, subprocess.TimeoutExpired) as exc:
                warn(f"the build was interrupted ({exc}); the next process tries again")
                return False
    if build.failed_recently():
        warn(f"the build failed, see {build.marker}")
        return False
    return build.path.is_file()
