"""The STEP worker: one STEP file read and tessellated by OpenCASCADE (cascadio) in a process of its own.

Run by :mod:`planner.meshio.step` as ``python -I step_worker.py TOL_MM MAX_FACES MEMORY_BYTES`` with the
file's bytes on standard input. It imports the standard library and cascadio's OpenCASCADE extension only
(never the planner, nor trimesh), caps
its own address space (``RLIMIT_AS``), checks the text before OpenCASCADE sees it, and writes one JSON line
to standard output, followed on success by the binary glTF (GLB) of the tessellation::

    {"ok": true, "file_units": [...], "n_entities": N, "n_triangles": T, "glb_bytes": B}<newline><GLB bytes>
    {"ok": false, "check": "...", "why": "...", ...evidence}<newline>

The checks before OpenCASCADE (each a refusal naming the reason):

* the ISO 10303-21 header and the ``END-ISO-10303-21;`` terminator (a truncated file has none);
* a ``DATA`` section with at least one entity instance;
* no entity instance referring to itself, directly or through a cycle of references: OpenCASCADE follows
  references recursively and overflows its stack on a cycle (measured: SIGSEGV on ``#35=ORIENTED_EDGE
  ('',*,*,#35,.T.)``). STEP instance graphs are acyclic (every reference points to an instance that
  exists independently of the referrer).

A crash, a time-out or the memory cap of this process is the caller's to report: the parent never runs
OpenCASCADE itself.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import json
import os
import re
import resource
import struct
import sys
from pathlib import Path
from typing import Any, NoReturn

#: SI prefixes of a length unit -> the unit's name in reports.
_SI_PREFIX = {
    "$": "m",
    ".MILLI.": "mm",
    ".CENTI.": "cm",
    ".DECI.": "dm",
    ".MICRO.": "um",
    ".KILO.": "km",
}
_STRING = re.compile(rb"'(?:[^']|'')*'")
_COMMENT = re.compile(rb"/\*.*?\*/", re.S)
_INSTANCE = re.compile(rb"^\s*#(\d+)\s*=(.*)$", re.S)
_REF = re.compile(rb"#(\d+)")


#: The answer's channel: standard output as it was at start. OpenCASCADE prints its messages to file
#: descriptor 1, so :func:`main` points that at standard error before reading the file.
_ANSWER: Any = None


def _answer(payload: bytes) -> None:
    _ANSWER.write(payload)
    _ANSWER.flush()


def _refuse(check: str, why: str, **evidence: Any) -> NoReturn:
    _answer(json.dumps({"ok": False, "check": check, "why": why, **evidence}).encode() + b"\n")
    raise SystemExit(0)


def _instances(data: bytes) -> dict[int, bytes]:
    """Entity instance number -> its right-hand side (strings blanked), of the DATA section."""
    head = data.lstrip(b"\xef\xbb\xbf \t\r\n")
    if not head.startswith(b"ISO-10303-21;"):
        first = head[:40].decode("utf-8", errors="replace").splitlines()[0] if head else ""
        _refuse("content", f"not a STEP file: it must start with 'ISO-10303-21;', starts with {first!r}")
    if not data.rstrip().endswith(b"END-ISO-10303-21;"):
        _refuse("truncated", "the file ends before its 'END-ISO-10303-21;' terminator (truncated)")
    text = _COMMENT.sub(b" ", _STRING.sub(b"''", data))  # strings first: a string may hold "/*"
    start = re.search(rb"\bDATA\s*(\([^;]*\))?\s*;", text)
    if start is None:
        _refuse("content", "the file has no DATA section")
    end = text.rfind(b"ENDSEC;")
    body = text[start.end() : end if end > start.end() else len(text)]
    out: dict[int, bytes] = {}
    for statement in body.split(b";"):
        found = _INSTANCE.match(statement)
        if found is not None:
            out[int(found.group(1))] = found.group(2)
    if not out:
        _refuse("empty", "the DATA section holds no entity instances (an empty shape)")
    return out


def _check_acyclic(instances: dict[int, bytes]) -> None:
    """Refuse an instance that refers to itself or a cycle of references (iterative depth-first search)."""
    refs = {k: [int(r) for r in _REF.findall(v)] for k, v in instances.items()}
    for k, targets in refs.items():
        if k in targets:
            _refuse("self_reference", f"entity #{k} refers to itself", entity=k)
    state: dict[int, int] = {}  # 1: on the current path, 2: done
    for root in refs:
        if state.get(root):
            continue
        stack = [(root, iter(refs[root]))]
        path = [root]
        state[root] = 1
        while stack:
            node, it = stack[-1]
            for nxt in it:
                if nxt not in refs:
                    continue  # a dangling reference: OpenCASCADE reports it as a read error
                mark = state.get(nxt, 0)
                if mark == 1:
                    cycle = path[path.index(nxt) :] + [nxt]
                    shown = " -> ".join(f"#{c}" for c in cycle[:8]) + (" -> ..." if len(cycle) > 8 else "")
                    _refuse(
                        "self_reference",
                        f"entities refer to each other in a cycle ({shown})",
                        cycle=cycle[:50],
                    )
                if mark == 0:
                    state[nxt] = 1
                    stack.append((nxt, iter(refs[nxt])))
                    path.append(nxt)
                    break
            else:
                state[node] = 2
                stack.pop()
                path.pop()


def _file_units(instances: dict[int, bytes], raw_units: dict[int, bytes]) -> list[str]:
    """The length units the file's representation contexts assign (sorted, unique).

    ``raw_units`` are the length-unit instances with their strings intact (a conversion-based unit's name,
    e.g. ``'INCH'``, is a string).
    """
    units: set[str] = set()
    for rhs in instances.values():
        ctx = re.search(rb"GLOBAL_UNIT_ASSIGNED_CONTEXT\s*\(\s*\(([^)]*)\)", rhs)
        if ctx is None:
            continue
        for ref in _REF.findall(ctx.group(1)):
            unit = instances.get(int(ref), b"")
            if b"LENGTH_UNIT" not in unit:
                continue
            named = re.search(rb"CONVERSION_BASED_UNIT\s*\(\s*'([^']*)'", raw_units.get(int(ref), b""))
            si = re.search(rb"SI_UNIT\s*\(\s*([^,]*),\s*\.METRE\.\s*\)", unit)
            if named is not None:
                units.add(named.group(1).decode("utf-8", errors="replace").lower() or "conversion-based")
            elif si is not None:
                units.add(_SI_PREFIX.get(si.group(1).strip().decode(), si.group(1).strip().decode()))
    return sorted(units)


def _glb_triangles(glb: bytes) -> int:
    """Triangles of a GLB's mesh primitives (index count / 3, or vertex count / 3 when not indexed)."""
    (json_len,) = struct.unpack_from("<I", glb, 12)
    doc = json.loads(glb[20 : 20 + json_len])
    accessors = doc.get("accessors", [])
    total = 0
    for mesh in doc.get("meshes", []):
        for prim in mesh.get("primitives", []):
            if prim.get("mode", 4) != 4:
                continue
            acc = prim.get("indices", prim.get("attributes", {}).get("POSITION"))
            if acc is not None:
                total += int(accessors[acc]["count"]) // 3
    return total


def _cascadio_core() -> Any:
    """Cascadio's OpenCASCADE extension module (``cascadio._core``), loaded without the package.

    The package's ``__init__`` also registers trimesh glTF extensions, which imports trimesh: 2.8 s of
    this process's start-up against 0.4 s for the extension alone (measured under load 7 on 2 cores).
    """
    spec = importlib.util.find_spec("cascadio")  # locates the package without running its __init__
    if spec is None or not spec.submodule_search_locations:
        raise SystemExit("cascadio is not installed")
    folder = Path(next(iter(spec.submodule_search_locations)))
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        path = folder / f"_core{suffix}"
        if path.is_file():
            core_spec = importlib.util.spec_from_file_location("_core", path)
            assert core_spec is not None and core_spec.loader is not None
            module = importlib.util.module_from_spec(core_spec)
            core_spec.loader.exec_module(module)
            return module
    raise SystemExit(f"cascadio's extension module is missing from {folder}")


def main() -> None:
    """Read stdin, check, tessellate, answer on stdout (see the module docstring)."""
    global _ANSWER
    tol_mm, max_faces, memory_bytes = float(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
    _ANSWER = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # whatever OpenCASCADE prints goes to standard error
    resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))
    data = sys.stdin.buffer.read()
    # The units are read from the text as written (strings intact), the graph with strings blanked.
    instances = _instances(data)
    _check_acyclic(instances)
    raw_units = {}
    for statement in data.split(b";"):
        found = _INSTANCE.match(statement)
        if found is not None and b"LENGTH_UNIT" in found.group(2):
            raw_units[int(found.group(1))] = found.group(2)
    file_units = _file_units(instances, raw_units)

    core = _cascadio_core()  # after the checks and the memory cap: OpenCASCADE only sees a checked file
    glb = core.to_glb_bytes(
        data,
        core.FileType.STEP,
        tol_linear=tol_mm,
        tol_angular=0.5,
        tol_relative=False,
        merge_primitives=True,
        use_parallel=False,
        include_brep=False,
        brep_types=set(),
        include_materials=False,
    )
    if not glb:
        _refuse(
            "parse",
            "OpenCASCADE could not read or transfer the file (syntax errors, or no shape to transfer)",
        )
    n_triangles = _glb_triangles(glb)
    if n_triangles == 0:
        _refuse("empty", "the file's shapes tessellate to no triangles (an empty shape)")
    if n_triangles > max_faces:
        _refuse(
            "face_count",
            f"the tessellation has {n_triangles} triangles, cap is {max_faces} (a coarser "
            "tessellation_tolerance_m gives fewer)",
            n_faces=n_triangles,
            max_faces=max_faces,
        )
    head = {
        "ok": True,
        "file_units": file_units,
        "n_entities": len(instances),
        "n_triangles": n_triangles,
        "glb_bytes": len(glb),
    }
    _answer(json.dumps(head).encode() + b"\n" + glb)


if __name__ == "__main__":
    main()
