"""A process's start-up: modules loaded without the cyclic garbage collector's passes.

Loading the command line's and a plan's modules (numpy, scipy, pydantic, typer, the planner's own) creates
a few hundred thousand container objects, and the collector's passes over them while they load cost a
``cabinplan plan`` call 40-80 ms (``bench.startup``; a pass over every object each time the oldest
generation is collected). Nothing a module body creates is cyclic garbage worth collecting then, so the
collector waits until the modules are loaded; with ``freeze``, what was loaded is moved to the permanent
generation (:func:`gc.freeze`), so the plan's own collections do not walk the modules' objects again.
"""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager


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
