"""Native (C) builds of compiled CasADi functions, cached on disk; the CasADi virtual machine otherwise.

CasADi evaluates an SX function by interpreting its instruction list (about 8 ns an instruction here): the
inverse dynamics, some 3,400 instructions, costs about 28 us a grid point that way. The same function
generated as C and built with the system's C compiler costs about 5 us a point in a mapped call
(``bench/kinematics.py`` reports both). :func:`native` generates the C source of a set of functions, builds
it once into a shared library keyed by the source's SHA-256 (so a change of the model, the description or
CasADi gives a new build), and loads the library with ``casadi.external``.

Every failure falls back to the original functions, which give the same numbers (tests compare both):
no C compiler and no build in the cache, a failed build, a read-only cache, or ``CABINPLAN_NATIVE=0``.
A build already in the cache is loaded without a compiler: a slim container carries the builds its
image's build stage made (plain ``-O1`` C, no ``-march``: they load on any machine of the architecture).
Builds are written to a temporary file and renamed into place, so concurrent processes never load a
half-written library.
"""

from __future__ import annotations

import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from pathlib import Path

import casadi as ca

from planner.core.cache import cache_dir

log = logging.getLogger(__name__)

#: Compiler flags: -O1 builds in well under a second and runs as fast as -O2 on these functions.
CFLAGS = ("-O1", "-shared", "-fPIC")
#: Longest a build may take [s] before the VM is used instead.
BUILD_TIMEOUT_S = 120.0


def native_enabled() -> bool:
    """Whether native builds are allowed (``CABINPLAN_NATIVE`` not ``0``) and a C compiler is on the PATH."""
    if os.environ.get("CABINPLAN_NATIVE", "1") == "0":
        return False
    return _compiler() is not None


def _compiler() -> str | None:
    return os.environ.get("CC") or shutil.which("gcc") or shutil.which("cc")


def _cache_dir() -> Path | None:
    folder = cache_dir()
    return None if folder is None else folder / "native"


def native(functions: Sequence[ca.Function], name: str) -> list[ca.Function]:
    """C builds of ``functions`` (same names, inputs and outputs), or the functions themselves.

    Args:
        functions: CasADi functions (SX or mapped) to build into one library.
        name: A file-name stem for the library (``[A-Za-z0-9_]``), e.g. ``"cabin8_dynamics"``.

    Returns:
        One function per input, in order: ``casadi.external`` loads of the native build when it is
        available, the given functions otherwise.
    """
    cc = _compiler()
    folder = _cache_dir()
    if os.environ.get("CABINPLAN_NATIVE", "1") == "0" or folder is None:
        return list(functions)
    if cc is None and not any(folder.glob(f"{name}-*.so")):  # nothing to load, nothing to build with
        return list(functions)
    try:
        gen = ca.CodeGenerator(f"{name}.c")
        for fn in functions:
            gen.add(fn)
        source = gen.dump()
        digest = hashlib.sha256(f"{source}|{CFLAGS}|{ca.CasadiMeta.version()}".encode()).hexdigest()[:24]
        lib = folder / f"{name}-{digest}.so"
        if not lib.is_file():
            if cc is None:  # builds of other sources only (another version): no compiler to build this one
                return list(functions)
            _build(cc, source, lib)
        return [ca.external(fn.name(), str(lib)) for fn in functions]
    except (OSError, RuntimeError, subprocess.SubprocessError) as exc:
        log.warning("native build of %s unavailable (%s); using the CasADi virtual machine", name, exc)
        return list(functions)


def _build(cc: str, source: str, lib: Path) -> None:
    lib.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=lib.parent) as tmp:
        c_file = Path(tmp) / "src.c"
        c_file.write_text(source, encoding="utf-8")
        out = Path(tmp) / "lib.so"
        subprocess.run(
            [cc, *CFLAGS, "-o", str(out), str(c_file), "-lm"],
            check=True,
            capture_output=True,
            timeout=BUILD_TIMEOUT_S,
        )
        os.replace(out, lib)
    log.info("built %s", lib)
