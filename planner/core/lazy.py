"""Deferred imports of modules a dependency imports eagerly but the planner does not use on its hot path.

toppra imports ``matplotlib.pyplot`` when it is imported (for plotting helpers the planner never calls),
which costs a plan call 0.5-1 s of start-up (measured with ``python -X importtime``). :func:`defer` puts a
stand-in module under that name: importing the name is free, and the real module is imported (and takes
the stand-in's place in ``sys.modules``) on the first attribute access, e.g. when a plot is drawn.
"""

from __future__ import annotations

import importlib
import importlib.machinery
import importlib.util
import sys
import types
from typing import Any


class _Deferred(types.ModuleType):
    """A stand-in that imports the real module on first use of any attribute it does not hold itself."""

    def __getattr__(self, attr: str) -> Any:
        real = self.__dict__.get("_deferred_real")
        if real is None:
            name = self.__name__
            if sys.modules.get(name) is self:
                del sys.modules[name]
            real = importlib.import_module(name)
            self.__dict__["_deferred_real"] = real
        return getattr(real, attr)


def defer(name: str) -> None:
    """Stand ``name`` in for until first use; nothing if it is already imported or not installed."""
    if name in sys.modules or importlib.util.find_spec(name.partition(".")[0]) is None:
        return
    module = _Deferred(name)
    module.__spec__ = importlib.machinery.ModuleSpec(name, None)
    sys.modules[name] = module
