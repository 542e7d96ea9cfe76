"""The files of a generated case: the cabin mesh, the scenario's YAML text, the folder's manifest.

The mesh is STL, OBJ, PLY or GLB, in m or mm, authored in its own frame.

Everything here returns bytes, text or dicts, except :func:`write_generated` (:func:`write_case`) and
:func:`write_manifest` at the edge. A scenario is an ordinary one (``cabinplan plan``): the mesh path is
relative to the scenario file, the cabin's ``pose`` maps the file's frame to the base frame, lengths in
metres.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import trimesh
import yaml

from planner.core.schemas import Pose
from planner.core.types import Array
from planner.generate.cabins import CabinLayout, cabin_parts, merge
from planner.generate.options import Generated, GeneratedCase, MeshFormat
from planner.meshes.generate import Part, binary_stl_bytes, glb_bytes
from planner.meshio.load import LoadedMesh, load_mesh


def mesh_bytes(
    layout: CabinLayout, fmt: MeshFormat, units: Literal["m", "mm"], T_base_cabin: Array, name: str
) -> bytes:
    """The cabin's file: vertices expressed in the file frame (``inv(T_base_cabin)``), in ``units``."""
    scale = 1000.0 if units == "mm" else 1.0
    T_cabin_base = np.linalg.inv(T_base_cabin)
    parts = [
        Part(p.name, scale * (p.vertices @ T_cabin_base[:3, :3].T + T_cabin_base[:3, 3]), p.faces)
        for p in cabin_parts(layout)
    ]
    if fmt == "glb":
        # One node per part; names must be unique (a scene keeps one geometry per name).
        return glb_bytes([Part(f"{i:03d}_{p.name}", p.vertices, p.faces) for i, p in enumerate(parts)])
    whole = merge(name, parts)
    if fmt == "stl":
        return binary_stl_bytes(whole.vertices, whole.faces, f"cabinplan generated cabin {name} [{units}]")
    mesh = trimesh.Trimesh(whole.vertices, whole.faces, process=False)
    if fmt == "obj":
        text = trimesh.exchange.obj.export_obj(mesh, include_normals=False, include_texture=False)
        return str(text).encode("ascii")
    return bytes(trimesh.exchange.ply.export_ply(mesh, encoding="binary"))


def loaded_cabin(layout: CabinLayout) -> LoadedMesh:
    """The cabin as the planner loads it (binary STL in metres, base frame): the generator's checks' mesh."""
    whole = merge("cabin", cabin_parts(layout))
    return load_mesh(binary_stl_bytes(whole.vertices, whole.faces, "generated"), units="m", name="cabin.stl")


def pose_doc(T: Array) -> dict[str, Any]:
    """A transform (4, 4) as a scenario pose (position [m], unit quaternion), rounded for the file."""
    pose = Pose.from_matrix(T)
    q = pose.orientation
    return {
        "position": [float(np.round(v, 9)) + 0.0 for v in pose.position],
        "orientation": {k: float(np.round(getattr(q, k), 12)) + 0.0 for k in ("w", "x", "y", "z")},
    }


def commented_yaml(comment: str, document: dict[str, Any]) -> str:
    """A generated file's text: one comment line (what was drawn), then the document as YAML."""
    return f"# {comment}\n" + yaml.safe_dump(document, sort_keys=False, default_flow_style=None, width=110)


def scenario_yaml(case: GeneratedCase) -> str:
    """The scenario file's text: a comment line describing the case, then the scenario as YAML."""
    m = case.meta
    return commented_yaml(
        f"Generated ({m['goal']}): {json.dumps({k: v for k, v in m.items() if k != 'redraws'})}",
        case.scenario,
    )


def write_generated(case: Generated, text: str, out_dir: Path) -> Path:
    """Write a generated document (``<name>.yaml``: ``text``) and its mesh into ``out_dir``; its path."""
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / case.mesh_name).write_bytes(case.mesh_bytes)
    path = out_dir / f"{case.name}.yaml"
    path.write_text(text, encoding="utf-8")
    return path


def write_case(case: GeneratedCase, out_dir: Path) -> Path:
    """Write the case's scenario (``<name>.yaml``) and mesh file into ``out_dir``; the scenario's path."""
    return write_generated(case, scenario_yaml(case), out_dir)


def write_manifest(cases: Sequence[GeneratedCase], out_dir: Path, seed: int) -> Path:
    """``manifest.json``: the seed and, per case, its scenario file, mesh file and features."""
    doc = {
        "generator": "planner.generate",
        "seed": seed,
        "count": len(cases),
        "cases": [
            {"name": c.name, "scenario": f"{c.name}.yaml", "mesh": c.mesh_name, **c.meta} for c in cases
        ],
    }
    path = out_dir / "manifest.json"
    path.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    return path


__all__ = [
    "commented_yaml",
    "loaded_cabin",
    "mesh_bytes",
    "pose_doc",
    "scenario_yaml",
    "write_case",
    "write_generated",
    "write_manifest",
]
