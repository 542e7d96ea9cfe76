"""Native (C) builds of compiled CasADi functions, cached on disk; the CasADi virtual machine otherwise.

CasADi evaluates an SX function by interpreting its instruction list (about 8 ns an instruction here): the
inverse dynamics, some 3,400 instructions, costs about 28 us a grid point that way. The same function
generated as C and built with the system's C compiler costs about 5 us a point in a mapped call
(``bench/kinematics.py`` reports both). :func:`native` generates the C source of a set of functions, builds
it once into a shared library keyed by the digest of the source, the compiler, its flags and the CasADi
version (so a change of the model, the description, the compiler or CasADi gives a new build), and loads
the library with ``casadi.external``.

Every failure falls back to the original functions, which give the same numbers (tests compare both):
no C compiler and no build in the cache, a failed build, a read-only cache, or ``CABINPLAN_NATIVE=0``.
A build already in the cache is loaded without a compiler: a slim container carries the builds its image's
build stage made (plain ``-O1`` C, no ``-march``: they load on any machine of the architecture), so the key
holds what the library's code depends on (the source, the flags, CasADi's version), not the compiler's path.
The builds follow the cache policy of every native build (:mod:`planner.core.builds`): keyed by that
digest, built under a file lock (concurrent processes build once), written to a temporary file and renamed
into place (never a half-written library), a compiler that fails leaves a failure marker so that later
processes use the virtual machine at once instead of trying again (for a day), and a library that does not
load is set aside and built again once.
"""

from __future__ import annotations

import logging
import os
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from pathlib import Path

import casadi as ca

from planner.core import builds
from planner.core.builds import BuildFailed, NativeBuild

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


_WARNED: set[str] = set()


def _warn(name: str, reason: str) -> None:
    if name not in _WARNED:
        _WARNED.add(name)
        log.warning("native build of %s unavailable (%s); using the CasADi virtual machine", name, reason)


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
    folder = builds.folder()
    if os.environ.get("CABINPLAN_NATIVE", "1") == "0" or folder is None:
        return list(functions)
    if cc is None and not any(folder.glob(f"{name}-*.so")):  # nothing to load, nothing to build with
        return list(functions)
    try:
        gen = ca.CodeGenerator(f"{name}.c")
        for fn in functions:
            gen.add(fn)
        source = gen.dump()
        key = builds.digest((source, repr(CFLAGS), ca.CasadiMeta.version()))
        place = NativeBuild.of(name, key, ".so")
        if place is None:
            return list(functions)
        for attempt in range(2):
            # A build of another source (another version) only, and no compiler to build this one: the VM.
            if not place.path.is_file() and (cc is None or not _build_once(cc, source, place, name)):
                return list(functions)
            try:
                return [ca.external(fn.name(), str(place.path)) for fn in functions]
            except RuntimeError as exc:  # a damaged library: set it aside and build it again, once
                if attempt:
                    raise
                log.warning("native build %s does not load (%s); building it again", place.path, exc)
                place.set_aside()
    except (OSError, RuntimeError, subprocess.SubprocessError) as exc:
        _warn(name, str(exc))
    return list(functions)


def _build_once(cc: str, source: str, place: NativeBuild, name: str) -> bool:
    """Build ``place`` under the cache policy (:func:`planner.core.builds.build_once`); True if built."""
    return builds.build_once(place, lambda: _build(cc, source, place), lambda reason: _warn(name, reason))


def _build(cc: str, source: str, place: NativeBuild) -> None:
    """Compile ``source`` into the build's file (a temporary folder beside it, one rename).

    Raises:
        BuildFailed: the compiler exits with an error or cannot be run (the same next time).
        subprocess.TimeoutExpired: the build took longer than :data:`BUILD_TIMEOUT_S`.
    """
    lib = place.path
    lib.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=lib.parent, prefix=f"{place.name}-build-") as tmp:
        c_file = Path(tmp) / "src.c"
        c_file.write_text(source, encoding="utf-8")
        out = Path(tmp) / "lib.so"
        try:
            subprocess.run(
                [cc, *CFLAGS, "-o", str(out), str(c_file), "-lm"],
                check=True,
                capture_output=True,
                text=True,
                timeout=BUILD_TIMEOUT_S,
            )
        except subprocess.CalledProcessError as exc:
            output = (exc.stderr or "") + (exc.stdout or "")
            last = output.strip().splitlines()[-1:] or ["no output"]
            raise BuildFailed(
                f"{cc} exit code {exc.returncode}: {last[0]}", builds.failure_report(exc.returncode, output)
            ) from None
        except (FileNotFoundError, PermissionError) as exc:  # no compiler to run
            raise BuildFailed(f"{cc} cannot run: {exc}", builds.failure_report(127, str(exc))) from None
        os.replace(out, lib)
    log.info("built %s", lib)
