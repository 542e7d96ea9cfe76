"""What a container image carries in its cache folder, checked where it is built (``Dockerfile``).

The image's build stage builds the ahead-of-time kernels for the baseline CPU (``CABINPLAN_AOT_CPU=generic``)
and plans the warm-up scenario (:mod:`api.warmup`), which makes the native CasADi builds of the dynamics.
:func:`check` fails that stage when one is missing, so that an image never ships without them and falls
back, silently and 5-7x slower, to numba's JIT and CasADi's virtual machine in production.

    python -c "from api.prebuilt import check; check()"
"""

from __future__ import annotations

import sys

from planner.collision.kernels.entries import EXTENSION as COLLISION_KERNELS
from planner.core import aot
from planner.core.cache import cache_dir
from planner.timing.acc_reference import EXTENSION as TIMING_KERNELS

#: The native CasADi libraries a plan of the reference robot loads (``planner.kinematics.native``).
NATIVE_PREFIXES = ("cabin8_dynamics", "cabin8_drive_path")


def missing() -> list[str]:
    """What the cache folder lacks of the portable builds (empty when it has everything)."""
    root = cache_dir()
    if root is None:
        return ["a cache folder (CABINPLAN_CACHE_DIR is empty)"]
    out = []
    for ext in (COLLISION_KERNELS, TIMING_KERNELS):
        lib = aot.path(ext, "generic")
        if lib is None or not lib.is_file():
            out.append(f"the portable build of {ext.name} ({lib})")
    native = root / "native"
    for prefix in NATIVE_PREFIXES:
        if not any(native.glob(f"{prefix}*.so")):
            out.append(f"a native CasADi build {prefix}*.so in {native}")
    return out


def check() -> None:
    """Exit with status 1 and say what is missing when the cache folder lacks a portable build."""
    gaps = missing()
    if gaps:
        sys.stderr.write("the image's cache folder lacks " + "; ".join(gaps) + "\n")
        raise SystemExit(1)
    sys.stdout.write(f"cache folder {cache_dir()}: portable kernels and native builds present\n")


__all__ = ["NATIVE_PREFIXES", "check", "missing"]
