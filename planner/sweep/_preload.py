"""Preloaded by the sweep's forkserver: imports the planner and plans one warm-up plan, once.

It first watches the driver (:func:`planner.core.lifeline.watch_server_from_env`: it exits when the
driver is gone, even SIGKILLed, and its plan processes with it). Every plan process forks from the
forkserver and inherits what this loaded (compiled kernels, the
cabin's clearance grid), so it starts planning at once. The warm-up task is a JSON file named by the
environment variable ``CABINPLAN_SWEEP_WARMUP`` (set by :class:`planner.sweep.run.EmbeddedExecutor`
before the forkserver starts); without it only the imports are done. Importing this module has that side
effect on purpose; nothing else imports it.
"""

from __future__ import annotations

import atexit
import gc
import logging
import os
import pickle
import sys

from planner.core.lifeline import watch_server_from_env
from planner.sweep.task import warm_up

_LOG = logging.getLogger(__name__)


def _warm() -> None:
    path = os.environ.get("CABINPLAN_SWEEP_WARMUP")
    task = None
    if path:
        try:
            with open(path, "rb") as fh:  # written by this sweep's driver (a private temporary file)
                task = pickle.load(fh)
        except (OSError, ValueError, pickle.UnpicklingError, AttributeError, ImportError):
            _LOG.warning("sweep warm-up task %s unreadable; warming up imports only", path)
    warm_up(task)
    # Forked children share the forkserver's heap copy-on-write; a garbage collection in a child would
    # touch (and so copy) every object. Frozen objects are left out of collections.
    gc.collect()
    gc.freeze()
    if "ompl" in sys.modules:
        # The forkserver ends when the driver does; OMPL's bindings would then print reference-leak
        # warnings at interpreter exit onto the driver's terminal (as the CLI's own exit avoids, see
        # planner.cli.main). Its plan processes end through multiprocessing's own os._exit.
        atexit.register(os._exit, 0)


watch_server_from_env()  # first: a driver killed during the warm-up takes the forkserver with it
_warm()
