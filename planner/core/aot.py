"""Ahead-of-time builds of numba kernels: one extension module per layer that owns kernels, cached on disk.

numba compiles a kernel on first use and keeps it in its own on-disk cache, but even a cached kernel costs
a fresh process the import of numba and llvmlite (~0.1 s), its type registries on the first load (~0.14 s)
and 2-20 ms per further kernel. An extension module built by ``numba.pycc`` from the same kernels imports
in well under a millisecond and needs neither numba nor llvmlite at run time.

A layer describes its extension as an :class:`Extension`: the module name, the source files the kernels
are compiled from, the module holding the ``@njit`` kernels (a function returning it, so that numba is
imported only when the JIT is used) and the exported entries with their argument
types (:class:`Entry`, in a small type language: ``"f8"``, ``"i8"``, ``"b1"`` scalars, ``"f8[2]"`` a
read-only C-contiguous 2-D float64 array, ``"f8[2]w"`` a writable one, tuples ``"(i8,f8[1])"``,
``"none"``). :func:`kernels` gives the entries of the extension when its build for this key is in the
cache folder (``cache_dir()/native/<name>-<key><suffix>``), building it first when it is missing (in a
subprocess), and numba's JIT dispatchers of the same functions otherwise: no cache folder
(``CABINPLAN_CACHE_DIR=""``), ``CABINPLAN_KERNELS=jit``, or a build that failed (no C compiler: one
warning). The lock, the key, the failure marker (later processes do not try again for a day; a build
killed by a signal or a timeout leaves none) and the damaged file set aside and made again once are the
cache policy of every native build, :mod:`planner.core.builds`.

The key is a hash of the kernel source files (and of this module), the numba, llvmlite, numpy and Python
versions, the platform and the target CPU. By default a build is compiled for this machine's CPU (``host``):
its model and feature flags are part of the key, so a cache folder shared with another machine never loads
code for the wrong CPU. ``CABINPLAN_AOT_CPU=generic`` compiles for the architecture's baseline instead
(x86-64 without AVX, say): a portable build, whose key holds only the architecture, that loads on any
machine of it -- a container image builds its kernels that way, in a stage with a C compiler, for machines
it has never seen. :func:`kernels` takes this machine's own build when there is one, else a portable one,
and builds only when neither is there (for the target ``CABINPLAN_AOT_CPU`` says).

The extension's entries do not check their arguments: an array of another dtype, layout or number of
dimensions is read as if it had the declared one (wrong numbers or a crash). Each layer therefore reaches
them only through Python wrappers that check every array (:func:`check_array`) and convert scalars.
This module imports numba only to build.
"""

from __future__ import annotations

import contextlib
import importlib.machinery
import importlib.util
import logging
import os
import platform
import subprocess
import sys
import sysconfig
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from planner.core import builds
from planner.core.builds import BuildFailed, BuildInterrupted, NativeBuild
from planner.core.cache import prune, touch

log = logging.getLogger(__name__)

#: ``CABINPLAN_KERNELS``: ``auto`` (the default: the ahead-of-time build, built on first use) or ``jit``.
MODES = ("auto", "jit")
#: Target CPUs of the builds: ``host``, the machine's own (as numba's JIT; its identity is part of the key),
#: and ``generic``, the architecture's baseline (portable: only the architecture is in the key).
CPU_TARGETS = ("host", "generic")
#: The default target (``CABINPLAN_AOT_CPU`` unset).
TARGET_CPU = "host"
#: Longest a build may take [s] before the JIT is used instead.
BUILD_TIMEOUT_S = 900.0
#: After a failed build, plans use the JIT without trying again for this long [s] (the cache policy's).
FAILED_RETRY_S = builds.FAILED_RETRY_S
#: Set by a first-use build for its child process: the build lock is already held.
LOCK_HELD_ENV = "CABINPLAN_AOT_LOCK_HELD"

_DTYPES = {"f8": np.dtype(np.float64), "i8": np.dtype(np.int64), "b1": np.dtype(np.bool_)}


@dataclass(frozen=True)
class Entry:
    """One exported kernel: its name in the kernels module, argument types and return type."""

    name: str
    args: tuple[str, ...]
    returns: str


@dataclass(frozen=True)
class Extension:
    """A layer's extension module: what it is compiled from and what it exports.

    Attributes:
        name: The extension module's name (``[A-Za-z0-9_]``), also the stem of its cache entries.
        kernels_module: Returns the module holding the ``@njit`` functions of ``entries`` (importing it:
            numba is imported then).
        builder_module: The dotted name of the module that builds it when run as ``python -m`` (the
            child process of a first-use build).
        sources: Every source file the kernels are compiled from (their bytes are in the key).
        entries: The exported kernels.
    """

    name: str
    kernels_module: Callable[[], ModuleType]
    builder_module: str
    sources: tuple[Path, ...]
    entries: tuple[Entry, ...]


def mode() -> str:
    """``CABINPLAN_KERNELS`` (``auto`` unless set to ``jit``)."""
    value = os.environ.get("CABINPLAN_KERNELS", "auto").strip().lower() or "auto"
    if value not in MODES:
        log.warning("CABINPLAN_KERNELS=%r is neither of %s; using auto", value, MODES)
        return "auto"
    return value


def target_cpu() -> str:
    """The CPU new builds target: ``CABINPLAN_AOT_CPU`` (``host`` unless set to ``generic``)."""
    value = os.environ.get("CABINPLAN_AOT_CPU", TARGET_CPU).strip().lower() or TARGET_CPU
    if value not in CPU_TARGETS:
        log.warning("CABINPLAN_AOT_CPU=%r is neither of %s; using %s", value, CPU_TARGETS, TARGET_CPU)
        return TARGET_CPU
    return value


def _cpu_identity() -> str:
    """This machine's CPU: model and feature flags (Linux), else what ``platform`` reports."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            lines = [ln for ln in f.read().split("\n\n", 1)[0].splitlines()]
        keep = ("vendor_id", "cpu family", "model", "model name", "flags", "Features", "CPU part")
        return "\n".join(ln for ln in lines if ln.split(":", 1)[0].strip() in keep)
    except OSError:
        return f"{platform.machine()} {platform.processor()}"


def _version_file(package: str) -> str:
    """The ``_version.py`` of a compiler package (numba, llvmlite), read without importing it.

    Empty when the package is not installed. llvmlite's is read too: numba accepts a range of llvmlite
    releases, and a new one may generate other machine code.
    """
    spec = importlib.util.find_spec(package)
    if spec is None or spec.origin is None:
        return ""
    try:
        return (Path(spec.origin).parent / "_version.py").read_text(encoding="utf-8")
    except OSError:
        return spec.origin


def key(ext: Extension, cpu: str | None = None) -> str:
    """The hash of everything the build for ``cpu`` (default :func:`target_cpu`) depends on (24 hex digits).

    A ``host`` build's key holds this machine's CPU model and feature flags; a ``generic`` one's only the
    architecture (``platform.machine()``), so it is the same on every machine of that architecture
    (:func:`planner.core.builds.digest`).
    """
    cpu = target_cpu() if cpu is None else cpu
    files = (path.name.encode() + b"\0" + path.read_bytes() for path in (*ext.sources, Path(__file__)))
    return builds.digest(  # this module's build steps are part of the build
        (
            *files,
            repr(ext.entries),
            _version_file("numba"),
            _version_file("llvmlite"),
            np.__version__,
            sys.version,
            sysconfig.get_platform(),
            _suffix(),
            cpu,
            _cpu_identity() if cpu == "host" else platform.machine(),
        )
    )


def _suffix() -> str:
    return importlib.machinery.EXTENSION_SUFFIXES[0]


def folder() -> Path | None:
    """The folder of the builds (``cache_dir()/native``), or None without a cache folder."""
    return builds.folder()


def native_build(ext: Extension, cpu: str | None = None) -> NativeBuild | None:
    """The place of the build of ``ext`` for ``cpu`` (default :func:`target_cpu`; None without a cache)."""
    return NativeBuild.of(ext.name, key(ext, cpu), _suffix())


def path(ext: Extension, cpu: str | None = None) -> Path | None:
    """Where the build of ``ext`` for ``cpu`` (default :func:`target_cpu`) lives (None without a cache)."""
    build = native_build(ext, cpu)
    return None if build is None else build.path


def load(ext: Extension, cpu: str | None = None) -> ModuleType | None:
    """The extension built for ``cpu`` (default :func:`target_cpu`), loaded, or None when it is not there."""
    lib = path(ext, cpu)
    if lib is None or not lib.is_file():
        return None
    module = _LOADED.get(str(lib))
    if module is not None:
        return module
    spec = importlib.util.spec_from_file_location(ext.name, lib)
    if spec is None or spec.loader is None:
        return None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    _LOADED[str(lib)] = module  # not in sys.modules: builds of other keys may be loaded beside it
    touch(lib)
    return module


_LOADED: dict[str, ModuleType] = {}


def jit_kernels(ext: Extension) -> ModuleType:
    """The module of numba's JIT dispatchers of the entries (imports numba)."""
    return ext.kernels_module()


_WARNED: set[str] = set()


def kernels(ext: Extension) -> Any:
    """The entries of ``ext``: the ahead-of-time build (built now if missing), or numba's JIT.

    Call it before a plan's clock starts: a missing build takes about 15 s of compilation.
    """
    if mode() == "jit" or folder() is None:
        return jit_kernels(ext)
    try:
        module = None
        for cpu in dict.fromkeys((target_cpu(), "generic")):  # this machine's own build, else a portable one
            try:
                module = load(ext, cpu)
            except ImportError as exc:  # a damaged file: set it aside and build again, once
                place = native_build(ext, cpu)
                assert place is not None
                log.warning("kernels %s: %s does not load (%s); building it again", ext.name, place.path, exc)
                place.set_aside()
            if module is not None:
                break
        if module is None:
            module = _build_in_subprocess(ext)
        if module is not None:
            return module
    except (OSError, ImportError, subprocess.SubprocessError) as exc:
        _warn(ext, f"{type(exc).__name__}: {exc}")
    return jit_kernels(ext)


def _warn(ext: Extension, reason: str) -> None:
    if ext.name not in _WARNED:
        _WARNED.add(ext.name)
        log.warning("kernels %s: no ahead-of-time build (%s); using numba's JIT", ext.name, reason)


def _build_in_subprocess(ext: Extension) -> ModuleType | None:
    """Build ``ext`` in a child process under the cache policy (:func:`planner.core.builds.build_once`).

    A build that exits with an error leaves a ``.failed`` marker with its output: later processes use the
    JIT without trying again for :data:`FAILED_RETRY_S`. A build killed by a signal or past
    :data:`BUILD_TIMEOUT_S` leaves none (the next plan tries again).
    """
    place = native_build(ext)
    assert place is not None

    def make() -> None:
        log.info("kernels %s: building the ahead-of-time extension (once per install)", ext.name)
        started = time.perf_counter()
        root = str(Path(__file__).resolve().parents[2])  # the folder holding the planner package
        paths = [root, *(p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p)]
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(paths), LOCK_HELD_ENV: "1"}
        run = subprocess.run(
            [sys.executable, "-m", ext.builder_module],
            env=env,
            capture_output=True,
            text=True,
            timeout=BUILD_TIMEOUT_S,
        )
        if run.returncode != 0 or not place.path.is_file():
            last = (run.stderr or run.stdout).strip().splitlines()[-1:] or ["no output"]
            reason = f"exit code {run.returncode}: {last[0]}"
            if run.returncode > 0:  # an error, not a signal: the next build would fail the same way
                raise BuildFailed(
                    reason, builds.failure_report(run.returncode, run.stderr[-20000:] + run.stdout[-5000:])
                )
            raise BuildInterrupted(reason)
        log.info("kernels %s: built in %.0f s", ext.name, time.perf_counter() - started)

    if not builds.build_once(place, make, lambda reason: _warn(ext, reason)):
        return None
    return load(ext)


def build(ext: Extension) -> Path:
    """Compile the entries of ``ext`` with ``numba.pycc`` into the cache folder (imports numba).

    The build is written in a temporary folder beside its place and renamed into it: a reader sees the
    whole extension or none. Earlier builds of the same extension count against the cache's size bound.

    Raises:
        OSError: no cache folder, or the build could not be written.
        Exception: whatever numba or the C compiler raise when the build fails.
    """
    place = native_build(ext)
    if place is None:
        raise OSError("no cache folder (CABINPLAN_CACHE_DIR is empty)")
    lib = place.path
    from numba.pycc import CC  # noqa: PLC0415 - numba only to build

    kernels_module = ext.kernels_module()
    lib.parent.mkdir(parents=True, exist_ok=True)
    with (
        tempfile.TemporaryDirectory(dir=lib.parent, prefix=f"{ext.name}-build-") as tmp,
        _arrays_boxed_with_a_cached_type(),
    ):
        cc = CC(ext.name)
        cc.output_dir = tmp
        cc.target_cpu = target_cpu()
        cc.verbose = False
        for entry in ext.entries:
            dispatcher = getattr(kernels_module, entry.name)
            cc.export(entry.name, signature(entry))(_trampoline(dispatcher, len(entry.args)))
        cc.compile()
        built = next(Path(tmp).glob(f"{ext.name}*{_suffix()}"))
        os.replace(built, lib)
    place.clear_failure()
    prune(lib.parent, (f"{ext.name}-*{_suffix()}",))
    return lib


def _trampoline(dispatcher: Any, n_args: int) -> Any:
    """A plain function of ``n_args`` arguments that only calls the ``@njit`` ``dispatcher``.

    ``numba.pycc`` compiles an exported function with its default options, not the dispatcher's: exported
    directly, an entry's own body would run under Python's error model (a division by zero raises) where
    the JIT kernel has ``error_model="numpy"`` (inf or NaN). Exporting this call instead compiles the
    kernel with its own options, as the JIT does (``tests/core/test_aot.py`` compares edge inputs).
    """
    names = ", ".join(f"a{i}" for i in range(n_args))
    namespace: dict[str, Any] = {"kernel": dispatcher}
    exec(f"def entry({names}):\n    return kernel({names})\n", namespace)  # noqa: S102 - fixed template
    return namespace["entry"]


@contextlib.contextmanager
def _arrays_boxed_with_a_cached_type() -> Iterator[None]:
    """Box returned arrays with the array type read from the module's constants, not unpickled per call.

    numba boxes a returned array with its Python type (``numpy.ndarray``) embedded as a pickle; under the
    JIT the unpickled object is cached, but an extension built by ``numba.pycc`` runs ``pickle.loads`` on
    every array it returns (measured: +0.35 us an array, +1 us on a state check returning three). This
    boxes them as numba does, with the type added to the environment's constants like the dtype already
    is (unpickled once, when the extension is imported). Only the boxing of results differs: the compiled
    arithmetic is the same (``tests/core/test_aot.py`` compares the bits).
    """
    from llvmlite import ir  # type: ignore[import-untyped]  # noqa: PLC0415 - numba only to build
    from numba.core import boxing, cgutils, types  # noqa: PLC0415
    from numba.core.pythonapi import _boxers  # noqa: PLC0415
    from numba.np import numpy_support  # noqa: PLC0415

    original = boxing.box_array
    assert _boxers.functions[types.Array] is original

    def box_array(typ: Any, val: Any, c: Any) -> Any:
        if not c.context.enable_nrt:
            return original(typ, val, c)
        dtype = c.env_manager.read_const(c.env_manager.add_const(numpy_support.as_dtype(typ.dtype)))
        pytype = c.env_manager.read_const(c.env_manager.add_const(typ.box_type))
        api, i32 = c.pyapi, ir.IntType(32)
        fnty = ir.FunctionType(api.pyobj, [api.voidptr, api.pyobj, i32, i32, api.pyobj])
        fn = api._get_function(fnty, name="NRT_adapt_ndarray_to_python_acqref")
        fn.args[0].add_attribute("captures(none)")
        ndim = c.context.get_constant(types.int32, typ.ndim)
        writable = c.context.get_constant(types.int32, int(typ.mutable))
        ptr = cgutils.alloca_once_value(c.builder, val)
        out = c.builder.call(fn, [c.builder.bitcast(ptr, api.voidptr), pytype, ndim, writable, dtype])
        c.context.nrt.decref(c.builder, typ, val)  # the new array holds the reference
        return out

    _boxers.functions[types.Array] = box_array
    try:
        yield
    finally:
        _boxers.functions[types.Array] = original


def signature(entry: Entry) -> Any:
    """The numba signature of an entry (imports numba)."""
    return _type(entry.returns)(*(_type(a) for a in entry.args))


def _type(code: str) -> Any:
    """A numba type from the small type language of :class:`Entry`."""
    from numba import types  # noqa: PLC0415 - numba only to build

    code = code.strip()
    if code == "none":
        return types.none
    if code.startswith("("):
        return types.Tuple([_type(part) for part in code[1:-1].split(",")])
    scalars = {"f8": types.float64, "i8": types.int64, "b1": types.boolean}
    if "[" not in code:
        return scalars[code]
    base, rest = code.split("[", 1)
    ndim, flags = rest.split("]")
    return types.Array(scalars[base], int(ndim), "C", readonly=flags != "w")


#: The dtypes of the entry types, for :func:`check_array`.
F8, I8, B1 = _DTYPES["f8"], _DTYPES["i8"], _DTYPES["b1"]


def check_array(
    value: object,
    name: str,
    dtype: np.dtype[Any],
    ndim: int,
    out: bool = False,
    shape: tuple[int | None, ...] | None = None,
) -> np.ndarray:
    """``value`` if it is a C-contiguous ``ndim``-D array of ``dtype`` of the entry's shape.

    ``out``: it must also be writable. ``shape``: the sizes it must have (None leaves a dimension free).

    Raises:
        TypeError: naming ``name``, when it is not: an extension entry would read it wrongly.
        ValueError: naming ``name``, when its shape is not ``shape``: an entry would read or write past it.
    """
    if (
        isinstance(value, np.ndarray)
        and value.dtype == dtype
        and value.ndim == ndim
        and value.flags.c_contiguous
        and (not out or value.flags.writeable)
    ):
        if shape is None or value.shape == shape:  # the hot path: one tuple comparison
            return value
        if None in shape and all(w is None or h == w for h, w in zip(value.shape, shape, strict=True)):
            return value
        wanted = "(" + ", ".join("*" if w is None else str(w) for w in shape) + ")"
        raise ValueError(f"{name}: shape {wanted} expected, got {value.shape}")
    got = (
        f"{value.dtype} array of shape {value.shape} (C-contiguous {value.flags.c_contiguous}, "
        f"writable {value.flags.writeable})"
        if isinstance(value, np.ndarray)
        else type(value).__name__
    )
    what = "a writable" if out else "a"
    raise TypeError(f"{name}: {what} C-contiguous {ndim}-D {dtype} array expected, got {got}")


def main(ext: Extension, argv: list[str] | None = None) -> None:
    """``python -m <builder module> [--reuse]``: build ``ext`` into the cache folder and print where.

    ``--reuse`` (what ``make`` passes): a build of the same key already in the cache that loads is kept
    (the key covers the kernel sources, the compiler, numpy, Python and the CPU: a new build would be the
    same), and its path printed. Under the build lock of :func:`_build_in_subprocess` (which a plan's
    first-use build already holds for its child, saying so in ``$CABINPLAN_AOT_LOCK_HELD``), so a build by
    hand and one at first use never write at once.
    """
    args = sys.argv[1:] if argv is None else argv
    unknown = [a for a in args if a != "--reuse"]
    if unknown:
        raise SystemExit(f"usage: python -m <builder module> [--reuse] (unknown argument {unknown[0]!r})")
    place = native_build(ext)
    if "--reuse" in args and place is not None:
        try:
            if load(ext) is not None:
                sys.stdout.write(f"{place.path} (reused: built before with the same key)\n")
                return
        except ImportError as exc:  # a damaged file: built again below (the build replaces it)
            log.warning("kernels %s: %s does not load (%s); building it again", ext.name, place.path, exc)
    if place is None or os.environ.get(LOCK_HELD_ENV) == "1":
        sys.stdout.write(f"{build(ext)}\n")
        return
    with place.locked():
        place.remove_stale_build_folders()
        sys.stdout.write(f"{build(ext)}\n")
