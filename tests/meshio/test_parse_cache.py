"""The on-disk parse cache: a file parsed before is read back, equal to a fresh parse, never trusted blindly.

Every later step (units, validation, pose) runs as on a fresh parse, so the loaded meshes must be equal to
the bit; an unreadable entry is parsed again; a stricter cap gets an entry of its own and so its own
refusal; and a plan's command line never imports trimesh or matplotlib once its cabin was parsed.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from planner.core.exceptions import InvalidMesh
from planner.meshio import MeshLimits, load_mesh
from planner.meshio import load as mesh_load
from tests.conftest import plan_in_a_fresh_process, share_compiled_kernels
from tests.meshio.test_load import box_mesh, export

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    root = tmp_path / "cache"
    monkeypatch.setenv("CABINPLAN_CACHE_DIR", str(root))
    mesh_load.clear_mesh_cache()
    yield root
    mesh_load.clear_mesh_cache()


def _entries(root: Path) -> list[Path]:
    return sorted((root / "meshes").glob("*.npz"))


def _fresh_and_cached(data: bytes, name: str, **kw):
    first = load_mesh(data, units="m", name=name, **kw)
    mesh_load.clear_mesh_cache()  # the in-memory cache would hide the disk one
    second = load_mesh(data, units="m", name=name, **kw)
    return first, second


@pytest.mark.parametrize("fmt", ["stl", "ply", "glb", "obj"])
def test_cached_parse_equals_fresh_parse(cache: Path, fmt: str, monkeypatch: pytest.MonkeyPatch) -> None:
    data = export(box_mesh(), fmt)
    pose = np.eye(4)
    pose[:3, 3] = (1.0, -2.0, 0.5)
    first = load_mesh(data, units="m", name=f"b.{fmt}", pose=pose)
    assert len(_entries(cache)) == 1
    mesh_load.clear_mesh_cache()

    def no_parse(*args, **kwargs):
        raise AssertionError("parsed again although the parse cache holds the file")

    monkeypatch.setattr(mesh_load, "parse_with_trimesh", no_parse)
    monkeypatch.setattr(mesh_load, "parse_obj", no_parse)
    second = load_mesh(data, units="m", name=f"b.{fmt}", pose=pose)
    assert np.array_equal(first.vertices, second.vertices)
    assert np.array_equal(first.faces, second.faces)
    assert first.report == second.report


def test_unreadable_entry_is_parsed_again(cache: Path) -> None:
    data = export(box_mesh(), "stl")
    load_mesh(data, units="m", name="b.stl")
    (entry,) = _entries(cache)
    entry.write_bytes(b"not an npz file")
    first, second = _fresh_and_cached(data, "b.stl")
    assert np.array_equal(first.vertices, second.vertices)
    with np.load(entry, allow_pickle=False) as npz:  # rewritten whole by the parse
        assert int(npz["n_parts"]) == 1


def test_stricter_cap_is_not_served_from_a_looser_parse(cache: Path) -> None:
    data = export(box_mesh(), "glb")  # 12 triangles, counted by the parser (a GLB header has no count)
    load_mesh(data, units="m", name="b.glb")
    mesh_load.clear_mesh_cache()
    with pytest.raises(InvalidMesh) as err:
        load_mesh(data, units="m", name="b.glb", limits=MeshLimits(max_faces=10))
    assert err.value.details["check"] == "face_count"
    assert len(_entries(cache)) == 1  # a refused parse writes nothing


def test_no_cache_folder_means_no_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CABINPLAN_CACHE_DIR", "")
    mesh_load.clear_mesh_cache()
    first, second = _fresh_and_cached(export(box_mesh(), "stl"), "b.stl")
    assert np.array_equal(first.vertices, second.vertices)
    assert not list(tmp_path.rglob("*.npz"))


def test_plan_command_imports_neither_trimesh_nor_matplotlib(cache: Path, tmp_path: Path) -> None:
    """Start-up: a warm ``cabinplan plan`` imports no module it does not need (issue 13, item 5)."""
    scenario = ROOT / "tests" / "scenarios" / "aisle-transfer.yaml"
    unused = ("trimesh", "matplotlib", "PIL", "fastapi", "sqlalchemy", "qpsolvers", "jinja2")
    env = {**os.environ, "CABINPLAN_CACHE_DIR": str(cache)}
    share_compiled_kernels(cache)
    _, first = plan_in_a_fresh_process(scenario, tmp_path / "out.json", unused, env)
    _, second = plan_in_a_fresh_process(scenario, tmp_path / "out.json", unused, env)
    assert json.loads((tmp_path / "out.json").read_text())["status"] == "succeeded"
    assert "trimesh" in first  # the first call parses the cabin
    assert second == []  # the second reads the parse back


def test_a_change_to_our_parsing_code_invalidates_the_cached_parses(
    cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    data = export(box_mesh(), "obj")
    load_mesh(data, units="m", name="b.obj")
    mesh_load.clear_mesh_cache()
    monkeypatch.setattr(mesh_load, "_parser_source", lambda: "a-fixed-parser")
    load_mesh(data, units="m", name="b.obj")
    assert len(_entries(cache)) == 2  # parsed again under the new code's key
