"""A process's start-up: modules loaded without the cyclic garbage collector's passes; the allocator tuned.

Loading the command line's and a plan's modules (numpy, scipy, pydantic, typer, the planner's own) creates
a few hundred thousand container objects, and the collector's passes over them while they load cost a
``cabinplan plan`` call 40-80 ms (``bench.startup``; a pass over every object each time the oldest
generation is collected). Nothing a module body creates is cyclic garbage worth collecting then, so the
collector waits until the modules are loaded; with ``freeze``, what was loaded is moved to the permanent
generation (:func:`gc.freeze`), so the plan's own collections do not walk the modules' objects again.
"""

from __future__ import annotations

import ctypes
import gc
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager

#: glibc's ``mallopt`` parameters (malloc.h) and the values set: blocks up to 32 MiB (glibc's largest
#: threshold on 64 bits) come from the heap, and up to 64 MiB of free memory at its top is kept.
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024
TRIM_THRESHOLD_BYTES = 64 * 1024 * 1024

_TUNED: bool | None = None
_TUNE_LOCK = threading.Lock()


@contextmanager
def loading_modules(freeze: bool = False) -> Iterator[None]:
    """Suspend the cyclic garbage collector while the block imports modules (then as it was before).

    ``freeze``: afterwards move every object alive to the permanent generation (a process's start-up:
    called once, when the command line's modules are loaded).
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if freeze:
            gc.freeze()
        if enabled:
            gc.enable()


def tune_allocator() -> bool:
    """Serve the planner's large temporary arrays from the heap, not from fresh pages (glibc; once).

    The gate and the search allocate arrays of a few megabytes many times a plan (a profile's samples by
    its bodies and tasks). Above glibc's mmap threshold (128 KiB, raised only after a larger block is
    freed) each is a new mapping whose pages the kernel faults in and zeroes: 3 000-6 000 page faults a
    gate on hatch-bay-insert's 5 291 samples, about 5 ms, or none, depending on whether an earlier stage
    happened to free a large enough block. Fixing the thresholds (``mallopt``) makes them come from the
    heap every time, whatever ran before. Returns whether the allocator was tuned (False where the C
    library is not glibc). Called by the command line, the service's workers and every plan's context.
    """
    global _TUNED
    with _TUNE_LOCK:
        if _TUNED is None:
            _TUNED = False
            if sys.platform.startswith("linux"):
                try:  # the process's own symbols: the C library's
                    mallopt = ctypes.CDLL(None).mallopt
                except (OSError, AttributeError):  # no mallopt (not glibc)
                    return False
                mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
                _TUNED = bool(
                    mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
                    and mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)
                )
        return _TUNED
