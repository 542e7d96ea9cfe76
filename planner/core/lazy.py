"""Deferred imports of modules a dependency imports eagerly but the planner does not use on its hot path.

toppra imports ``matplotlib.pyplot`` when it is imported (for plotting helpers the planner never calls),
which costs a plan call 0.3-1 s of start-up, matplotlib itself included (measured with
``python -X importtime``). :func:`defer` puts a
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
        child = sys.modules.get(f"{self.__name__}.{attr}")
        if isinstance(child, _Deferred):  # ``import pkg.sub as x`` reads ``sub`` off the package
            return child
        return getattr(self._real(), attr)

    def _real(self) -> types.ModuleType:
        real = self.__dict__.get("_deferred_real")
        if real is None:
            name = self.__name__
            parent = sys.modules.get(name.rpartition(".")[0])
            if isinstance(parent, _Deferred):  # the package first, so the submodule finds its real path
                parent._real()
            if sys.modules.get(name) is self:
                del sys.modules[name]
            real = importlib.import_module(name)
            self.__dict__["_deferred_real"] = real
        return real


def defer(*names: str) -> None:
    """Stand each of ``names`` in for until first use; nothing for one already imported or not installed.

    Name a package before its submodules (``defer("matplotlib", "matplotlib.pyplot")``): importing the
    submodule then imports neither.
    """
    for name in names:
        if name in sys.modules or importlib.util.find_spec(name.partition(".")[0]) is None:
            continue
        module = _Deferred(name)
        module.__spec__ = importlib.machinery.ModuleSpec(name, None)
        sys.modules[name] = module
