"""STEP (ISO 10303-21) files: exact CAD geometry tessellated by OpenCASCADE in a worker process with limits.

A STEP file describes exact surfaces (planes, cylinders, B-splines) in the units its representation
contexts declare, often as an assembly of parts placed by transforms. :func:`tessellate_step` hands the
bytes to :mod:`planner.meshio.step_worker` -- a fresh interpreter that imports only cascadio (trimesh's
OpenCASCADE binding), caps its own address space and checks the text first -- and gets back a binary glTF
in metres with every assembly instance placed (OpenCASCADE's XCAF reader converts the file's units and
flattens the assembly tree; the glTF writer converts to metres). The parent never runs OpenCASCADE: a
crash, a run past ``MeshLimits.step_timeout_s`` or past ``MeshLimits.step_memory_bytes`` ends the worker,
and comes back as one :class:`~planner.core.exceptions.InvalidMesh` naming the file and the reason.

**Tessellation and clearance.** OpenCASCADE's linear deflection bounds the distance between each
triangle and the exact surface: with tolerance ``d`` the tessellated surface may lie up to ``d`` *inside*
the true one on a convex part (a chord of a cylinder cuts inside it by ``r (1 - cos(dtheta/2)) <= d``),
so a clearance measured against the triangles can overstate the true clearance by up to ``d``. The
vertices are stored as float32 in the glTF, which adds at most ``|x|_max 2^-24``. Their sum is the mesh's
``surface_deviation_m``; the scenario resolution adds it to the requested clearance
(:func:`planner.scenario.resolve.resolve_scenario`), and the plan's report says so.

The tolerance is given in metres and passed to OpenCASCADE in its working unit, millimetres (its STEP
reader converts every file to millimetres before meshing; measured: the same 0.1 m cylinder tessellates
alike from a file in mm and one in m).
"""

from __future__ import annotations

import json
import logging
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from planner.meshio.types import (
    MAX_TESSELLATION_TOLERANCE_M,
    MIN_TESSELLATION_TOLERANCE_M,
    MeshLimits,
    error,
    fail,
)

_LOG = logging.getLogger(__name__)

#: OpenCASCADE's STEP reader works in millimetres: metres -> its unit.
_OCC_UNIT_PER_M = 1e3
#: Angular deflection of the tessellation [rad] (OpenCASCADE's default 0.5); the linear tolerance is the
#: bound that matters for clearance, the angle only refines small curved features further.
ANGULAR_DEFLECTION_RAD = 0.5
_WORKER = Path(__file__).with_name("step_worker.py")


@dataclass(frozen=True)
class StepTessellation:
    """A STEP file tessellated by the worker.

    Attributes:
        glb: The binary glTF of the tessellation (metres, every assembly instance placed).
        file_units: The length units the file's contexts declare (e.g. ``("mm",)``).
        n_entities: Entity instances in the file's DATA section.
        n_triangles: Triangles of the tessellation (before instancing).
        tolerance_m: The chordal tolerance used [m].
        elapsed_s: Wall-clock time of the worker [s] (interpreter start, checks, read, tessellation).
    """

    glb: bytes
    file_units: tuple[str, ...]
    n_entities: int
    n_triangles: int
    tolerance_m: float
    elapsed_s: float


def check_tolerance(label: str, tolerance_m: float) -> float:
    """The tessellation tolerance as a float within its bounds, or ``InvalidMesh`` (check ``tolerance``)."""
    try:
        value = float(tolerance_m)
    except (TypeError, ValueError):
        fail(label, "tolerance", f"tessellation_tolerance_m must be a number, got {tolerance_m!r}")
    if not MIN_TESSELLATION_TOLERANCE_M <= value <= MAX_TESSELLATION_TOLERANCE_M:
        fail(
            label,
            "tolerance",
            f"tessellation_tolerance_m {value!r} is outside [{MIN_TESSELLATION_TOLERANCE_M}, "
            f"{MAX_TESSELLATION_TOLERANCE_M}] m",
            tessellation_tolerance_m=value,
        )
    return value


def tessellate_step(label: str, data: bytes, tolerance_m: float, limits: MeshLimits) -> StepTessellation:
    """Read and tessellate one STEP file in a worker process (see the module docstring).

    Args:
        label: The file's name, for messages.
        data: The file's bytes (already checked against ``limits.max_bytes``).
        tolerance_m: Chordal tolerance [m] (:func:`check_tolerance`).
        limits: ``max_faces`` caps the tessellation; ``step_timeout_s`` and ``step_memory_bytes`` the worker.

    Returns:
        The tessellation as a GLB with what the worker found.

    Raises:
        InvalidMesh: ``check`` is ``content`` (not STEP), ``truncated``, ``empty`` (no entities or no
            triangles), ``self_reference`` (an entity refers to itself or a cycle), ``parse``
            (OpenCASCADE refused the file or crashed), ``face_count``, ``step_timeout`` or
            ``step_memory``.
    """
    tolerance_m = check_tolerance(label, tolerance_m)
    args = [
        sys.executable,
        "-I",  # isolated: the worker imports the standard library and cascadio only
        str(_WORKER),
        repr(tolerance_m * _OCC_UNIT_PER_M),
        str(limits.max_faces),
        str(limits.step_memory_bytes),
    ]
    started = time.perf_counter()
    try:
        done = subprocess.run(
            args, input=data, capture_output=True, timeout=limits.step_timeout_s, check=False
        )
    except subprocess.TimeoutExpired:
        fail(
            label,
            "step_timeout",
            f"reading and tessellating the STEP file took longer than {limits.step_timeout_s:g} s (stopped); "
            "a coarser tessellation_tolerance_m or a simplified model is faster",
            timeout_s=limits.step_timeout_s,
        )
    except OSError as exc:
        raise error(label, "parse", f"the STEP worker could not start: {exc}") from exc
    elapsed = time.perf_counter() - started
    stderr = done.stderr.decode("utf-8", errors="replace")
    if done.returncode != 0:
        _crashed(label, done.returncode, stderr, limits)
    line, _, glb = done.stdout.partition(b"\n")
    try:
        head = json.loads(line)
    except ValueError as exc:
        raise error(label, "parse", f"the STEP worker answered no result ({_last_line(stderr)})") from exc
    if not head.get("ok"):
        check, why = str(head.pop("check")), str(head.pop("why"))
        head.pop("ok", None)
        if check == "parse" and _last_line(stderr):
            why = f"{why}: {_last_line(stderr)}"
        fail(label, check, why, **head)
    if len(glb) != head["glb_bytes"]:
        fail(
            label,
            "parse",
            f"the STEP worker's output is incomplete ({len(glb)} of {head['glb_bytes']} bytes)",
        )
    _LOG.info(
        "STEP %r: %d entities, units %s, %d triangles at %.3g m in %.2f s",
        label,
        head["n_entities"],
        head["file_units"],
        head["n_triangles"],
        tolerance_m,
        elapsed,
    )
    return StepTessellation(
        glb=glb,
        file_units=tuple(head["file_units"]),
        n_entities=int(head["n_entities"]),
        n_triangles=int(head["n_triangles"]),
        tolerance_m=tolerance_m,
        elapsed_s=elapsed,
    )


def _crashed(label: str, returncode: int, stderr: str, limits: MeshLimits) -> None:
    """Refuse for a worker that died: out of memory, a signal, or an uncaught error."""
    memory = any(
        s in stderr
        for s in (
            "MemoryError",
            "bad_alloc",
            "OutOfMemory",
            "Out of memory",
            "Cannot allocate",
            "failed to map",
        )
    )
    if memory or returncode == -signal.SIGKILL:
        fail(
            label,
            "step_memory",
            f"reading and tessellating the STEP file needed more than {limits.step_memory_bytes} bytes of "
            f"memory (the worker's cap; exit {returncode})",
            step_memory_bytes=limits.step_memory_bytes,
            returncode=returncode,
        )
    if returncode < 0:
        name = signal.Signals(-returncode).name if -returncode in signal.valid_signals() else str(-returncode)
        why = f"OpenCASCADE crashed on the file (signal {name})"
    else:
        why = f"the STEP worker failed (exit {returncode}): {_last_line(stderr) or 'no message'}"
    fail(label, "parse", why, returncode=returncode)


def _last_line(text: str) -> str:
    """The last non-empty line of a worker's error output, without terminal colour codes."""
    import re

    lines = [re.sub(r"\x1b\[[0-9;]*m|\*+", "", s).strip() for s in text.splitlines()]
    lines = [s for s in lines if s]
    return lines[-1][:200] if lines else ""
