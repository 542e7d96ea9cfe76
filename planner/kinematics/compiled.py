"""Fast calls into compiled CasADi functions through preallocated buffers.

``casadi.Function.__call__`` costs tens of microseconds for small functions (argument conversion);
``Function.buffer()`` evaluates the same compiled graph into numpy arrays we own for well under a
microsecond of overhead. Outputs are densified when the function is built, so each result buffer holds a
full column-major matrix; :meth:`FastFunction.__call__` returns them reshaped to their natural shape.

Buffers are per thread (a buffer is not re-entrant), so one model can serve a threaded web server.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from typing import Any

import casadi as ca
import numpy as np

from planner.core.types import Array


def dense_function(
    name: str, inputs: Sequence[ca.SX], outputs: Sequence[ca.SX], options: dict[str, Any] | None = None
) -> ca.Function:
    """A CasADi Function whose outputs are dense (so buffer results are full matrices)."""
    return ca.Function(name, list(inputs), [ca.densify(o) for o in outputs], options or {})


class _Slot:
    def __init__(self, fn: ca.Function) -> None:
        self.buf, self.trigger = fn.buffer()
        self.args = [np.zeros(fn.nnz_in(i)) for i in range(fn.n_in())]
        self.res = [np.zeros(fn.nnz_out(i)) for i in range(fn.n_out())]
        # The buffer keeps raw pointers into these arrays, which live as long as the slot.
        for i, a in enumerate(self.args):
            self.buf.set_arg(i, memoryview(a))  # type: ignore[call-arg, arg-type]
        for i, r in enumerate(self.res):
            self.buf.set_res(i, memoryview(r))  # type: ignore[call-arg, arg-type]


class FastFunction:
    """Callable wrapper: ``f(*arrays) -> tuple of arrays`` (copies), shaped like the CasADi outputs."""

    def __init__(self, fn: ca.Function) -> None:
        self.fn = fn
        self._shapes = [(fn.size1_out(i), fn.size2_out(i)) for i in range(fn.n_out())]
        ends = np.cumsum([n1 * n2 for n1, n2 in self._shapes]).tolist()
        self._spans = list(zip([0, *ends[:-1]], ends, strict=True))
        self._local = threading.local()

    def _slot(self) -> _Slot:
        slot: _Slot | None = getattr(self._local, "slot", None)
        if slot is None:
            slot = _Slot(self.fn)
            self._local.slot = slot
        return slot

    def __call__(self, *args: Any) -> tuple[Array, ...]:
        """Evaluate with the given inputs (anything numpy can ravel to the input size)."""
        slot = self._slot()
        for dst, src in zip(slot.args, args, strict=True):
            dst[:] = np.ravel(src, order="F")
        slot.trigger()
        # One copy of every result, then views into it (column-major matrices become F-ordered views).
        flat = np.concatenate(slot.res) if len(slot.res) > 1 else slot.res[0].copy()
        return tuple(
            flat[a:b] if n2 == 1 else flat[a:b].reshape((n1, n2), order="F")
            for (a, b), (n1, n2) in zip(self._spans, self._shapes, strict=True)
        )


#: Grid points per call of the mapped CasADi functions (inputs are padded to a multiple).
CHUNK = 256
#: The chunk of the small mapped variants, for batches of a few dozen points (less padding).
SMALL_CHUNK = 32


def evaluate_mapped(fn: ca.Function, *columns: Array, small: ca.Function | None = None) -> list[Array]:
    """Evaluate a mapped function (``fn.map(k)``) on (N, m_i) row-stacked inputs; (N, p_j) outputs.

    The chunk size k is read from ``fn``; inputs are padded (with their last row) to a multiple of it.
    ``small``, the same function mapped over fewer points, evaluates batches no longer than its chunk.
    Calls go through preallocated buffers (:class:`FastFunction`): an ordinary CasADi call spends about
    0.2 ms converting a (m, k) matrix, more than a 32-point native evaluation itself.
    """
    n = columns[0].shape[0]
    if small is not None and n <= small.size2_in(0):
        fn = small
    fast = _fast(fn)
    chunk = fn.size2_in(0)
    pad = (-n) % chunk
    padded = [np.vstack([c, np.repeat(c[-1:], pad, axis=0)]) if pad else c for c in columns]
    outs: list[list[Array]] = [[] for _ in range(fn.n_out())]
    for start in range(0, n + pad, chunk):
        # A (m, k) CasADi input is column-major: point after point, i.e. the C-order rows of (k, m).
        results = fast(*[p[start : start + chunk].T for p in padded])
        for k, r in enumerate(results):
            outs[k].append(r.T)
    return [np.vstack(o)[:n] for o in outs]


_FAST: dict[int, tuple[ca.Function, FastFunction]] = {}
_FAST_LOCK = threading.Lock()


def _fast(fn: ca.Function) -> FastFunction:
    """The buffered wrapper of a (long-lived) mapped function, made once."""
    entry = _FAST.get(id(fn))
    if entry is None or entry[0] is not fn:
        with _FAST_LOCK:
            entry = (fn, FastFunction(fn))
            _FAST[id(fn)] = entry
    return entry[1]
