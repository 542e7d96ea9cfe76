"""Reference cabin meshes and the script that generates them (see README.md).

The package folder holds the four reference cabins (binary STL in metres, robot base frame) and their
machine-readable manifest ``cabins.json``. Scenarios may name a reference cabin instead of a file path;
:func:`reference_cabin_path` maps such a name to its packaged file. Nothing is read at import time.
"""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path
from typing import Any

#: The package folder: the reference meshes and ``cabins.json`` live here.
REFERENCE_DIR: Path = Path(__file__).resolve().parent

_MANIFEST = "cabins.json"


@cache
def reference_manifest() -> dict[str, Any]:
    """The parsed ``cabins.json`` manifest (read once, then cached).

    Callers must not mutate the returned mapping: it is shared by every caller.

    Returns:
        The manifest: ``format_version``, ``units``, ``frame``, ``cabins`` (a list of per-cabin records
        with ``name``, ``files``, ``sha256``, ``bounds_m``, bays, ...).
    """
    with (REFERENCE_DIR / _MANIFEST).open(encoding="utf-8") as fh:
        manifest: dict[str, Any] = json.load(fh)
    return manifest


def reference_cabins() -> tuple[str, ...]:
    """Names of the reference cabins, in manifest order (e.g. ``("cabin-aisle", ...)``)."""
    return tuple(str(c["name"]) for c in reference_manifest()["cabins"])


def reference_cabin_path(name: str) -> Path | None:
    """The packaged STL of a reference cabin, or ``None`` if ``name`` is not a reference cabin.

    Args:
        name: A reference cabin name with or without the ``.stl`` extension (``"cabin-aisle"`` or
            ``"cabin-aisle.stl"``). Anything else, including paths with folders, returns ``None``.

    Returns:
        Absolute path of the cabin's STL file (units: metres), or ``None``.
    """
    stem = name[: -len(".stl")] if name.lower().endswith(".stl") else name
    for cabin in reference_manifest()["cabins"]:
        if cabin["name"] == stem:
            files = cabin.get("files", {})
            return REFERENCE_DIR / str(files.get("stl", f"{stem}.stl"))
    return None


__all__ = ["REFERENCE_DIR", "reference_cabin_path", "reference_cabins", "reference_manifest"]
