"""Worker processes die with their owner: a parent-death signal and a parent watcher.

The owner of a pool of worker processes (:mod:`planner.core.procpool`: the HTTP service's job workers, a
CLI sweep's or campaign's plan workers) may be SIGKILLed (``kill -9``, the OOM killer) and then runs no
clean-up, so its workers must notice by themselves, or they plan on for nobody:

* each worker asks the kernel for SIGKILL when its parent (the forkserver's main thread, which forked
  it) goes away: ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` (Linux, see prctl(2));
* the forkserver itself was started by whichever owner thread launched the first worker, and a
  parent-death signal fires when that *thread* ends, not the process; so the forkserver instead runs a
  small watcher thread that polls ``getppid()`` and exits as soon as it changes (the owner died and the
  forkserver was re-parented). Its workers then receive their parent-death signal.

Both close the race of a parent that dies before the child is set up: the child compares its parent
with the process it expects and exits at once if they differ.
"""

from __future__ import annotations

import ctypes
import logging
import os
import signal
import sys
import threading
import time

_LOG = logging.getLogger(__name__)

#: prctl(2) option number of PR_SET_PDEATHSIG (linux/prctl.h).
PR_SET_PDEATHSIG = 1

#: Environment variable naming the owner's pid (the service's, or a CLI run's), inherited by the forkserver.
SERVER_PID_ENV = "CABINPLAN_SERVER_PID"

#: Period of the forkserver's parent watcher [s].
WATCH_PERIOD_S = 0.1


def set_parent_death_signal(sig: int = signal.SIGKILL) -> bool:
    """Ask the kernel to send ``sig`` to this process when its parent thread exits (Linux only).

    Returns:
        True when the signal is armed; False on a platform without ``prctl`` (nothing done).
    """
    if not sys.platform.startswith("linux"):
        return False
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) != 0:
        err = ctypes.get_errno()
        _LOG.warning("prctl(PR_SET_PDEATHSIG) failed: %s", os.strerror(err))
        return False
    return True


def process_alive(pid: int) -> bool:
    """Whether a process of that pid exists (signal 0, see kill(2))."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def die_with_parent(server_pid: int | None = None) -> None:
    """Arm the parent-death signal of a worker process; exit now if its owner is already gone.

    Args:
        server_pid: The owner's pid (the service's, or a CLI run's): when given and no longer alive, the
            process exits at once (the parent died between the fork and this call, so the signal would
            never come).
    """
    set_parent_death_signal()
    if server_pid is not None and not process_alive(server_pid):
        os._exit(1)


def watch_parent(expected_parent: int, period_s: float = WATCH_PERIOD_S) -> threading.Thread:
    """Start a daemon thread that ends this process when its parent is no longer ``expected_parent``.

    Used in the forkserver (see the module docstring). The thread only polls ``getppid`` and sleeps, so a
    process forked while it runs inherits no lock it might hold.
    """

    def run() -> None:
        while True:
            if os.getppid() != expected_parent:
                os._exit(0)
            time.sleep(period_s)

    if os.getppid() != expected_parent:
        os._exit(0)
    thread = threading.Thread(target=run, name="cabinplan-parent-watch", daemon=True)
    thread.start()
    return thread


def watch_server_from_env() -> None:
    """In the forkserver: watch the owner named by :data:`SERVER_PID_ENV` (no-op when unset)."""
    value = os.environ.get(SERVER_PID_ENV)
    if value and value.isdigit():
        watch_parent(int(value))


__all__ = [
    "SERVER_PID_ENV",
    "die_with_parent",
    "process_alive",
    "set_parent_death_signal",
    "watch_parent",
    "watch_server_from_env",
]
