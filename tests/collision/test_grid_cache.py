"""The on-disk cache of clearance grids: a hit returns the same grid, a bad file is rebuilt, never trusted."""

from __future__ import annotations

import json
import logging
import os
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

from planner.collision.clearance_grid import ClearanceGrid, cached_build
from planner.core.cache import prune


@pytest.fixture
def box_mesh() -> tuple[np.ndarray, np.ndarray]:
    m = trimesh.creation.box(extents=(1.0, 0.6, 0.4))
    return np.asarray(m.vertices, dtype=float), np.asarray(m.faces, dtype=np.int64)


def test_cache_hit_returns_the_grid_that_was_built(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, box_mesh
) -> None:
    monkeypatch.setenv("CABINPLAN_CACHE_DIR", str(tmp_path))
    v, f = box_mesh
    built = cached_build("box", v, f, 0.05)
    assert len(list(tmp_path.glob("grid-*.npy"))) == len(list(tmp_path.glob("grid-*.json"))) == 1
    loaded = cached_build("box", v, f, 0.05)
    assert isinstance(loaded.lower_bound, np.memmap)  # mapped, not read
    fresh = ClearanceGrid.build(v, f, step=0.05)
    for g in (built, loaded):
        assert g.step == fresh.step
        assert np.array_equal(g.origin, fresh.origin)
        assert np.array_equal(g.lower_bound, fresh.lower_bound)
    # Another step is another grid, another file.
    cached_build("box", v, f, 0.1)
    assert len(list(tmp_path.glob("grid-*.npy"))) == 2


def test_corrupt_cache_file_is_rebuilt(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, box_mesh, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setenv("CABINPLAN_CACHE_DIR", str(tmp_path))
    v, f = box_mesh
    cached_build("box", v, f, 0.05)
    (path,) = tmp_path.glob("grid-*.npy")
    path.write_bytes(b"not an npy file")
    with caplog.at_level(logging.WARNING):
        grid = cached_build("box", v, f, 0.05)
    assert "rebuilding" in caplog.text
    assert np.array_equal(grid.lower_bound, ClearanceGrid.build(v, f, step=0.05).lower_bound)


def test_empty_cache_dir_disables_the_cache(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, box_mesh
) -> None:
    monkeypatch.setenv("CABINPLAN_CACHE_DIR", "")
    monkeypatch.chdir(tmp_path)
    v, f = box_mesh
    cached_build("box", v, f, 0.05)
    assert not list(tmp_path.rglob("*.np[yz]"))


def test_a_description_that_does_not_match_its_bounds_is_rebuilt(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, box_mesh
) -> None:
    monkeypatch.setenv("CABINPLAN_CACHE_DIR", str(tmp_path))
    v, f = box_mesh
    cached_build("box", v, f, 0.05)
    (meta,) = tmp_path.glob("grid-*.json")
    doc = json.loads(meta.read_text())
    meta.write_text(json.dumps({**doc, "shape": [1, 2, 3]}))
    grid = cached_build("box", v, f, 0.05)
    assert np.array_equal(grid.lower_bound, ClearanceGrid.build(v, f, step=0.05).lower_bound)
    assert json.loads(meta.read_text())["shape"] == doc["shape"]  # rewritten whole


def test_the_cache_keeps_the_most_recently_used_entries_within_its_bound(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, box_mesh
) -> None:
    monkeypatch.setenv("CABINPLAN_CACHE_DIR", str(tmp_path))
    v, f = box_mesh
    cached_build("box", v, f, 0.05)
    one_entry = sum(p.stat().st_size for p in tmp_path.glob("grid-*"))
    monkeypatch.setenv("CABINPLAN_CACHE_MAX_BYTES", str(int(2.5 * one_entry)))
    old = time.time() - 3600
    for p in tmp_path.glob("grid-*"):
        os.utime(p, (old, old))
    cached_build("box2", v, f, 0.05)
    cached_build("box", v, f, 0.05)  # a hit: "box" is now the most recently used
    cached_build("box3", v, f, 0.05)  # over the bound: the least recently used entry ("box2") goes
    assert len(list(tmp_path.glob("grid-*.npy"))) == 2
    assert prune(tmp_path, ("grid-*",), limit=0) > 0 and not list(tmp_path.glob("grid-*"))


def test_a_failed_write_leaves_nothing_and_a_dead_writers_file_is_pruned(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, box_mesh
) -> None:
    monkeypatch.setenv("CABINPLAN_CACHE_DIR", str(tmp_path))
    v, f = box_mesh

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(np, "save", full_disk)
    grid = cached_build("box", v, f, 0.05)  # built, served, not cached
    assert np.array_equal(grid.lower_bound, ClearanceGrid.build(v, f, step=0.05).lower_bound)
    assert not list(tmp_path.iterdir())
    monkeypatch.undo()
    dead = tmp_path / "tmpdead.tmp"  # what a writer killed mid-write leaves
    dead.write_bytes(b"x" * 1000)
    fresh = tmp_path / "tmpalive.tmp"  # a writer at work now
    fresh.write_bytes(b"y")
    old = time.time() - 3600
    os.utime(dead, (old, old))
    assert prune(tmp_path, ("grid-*",), limit=10**9) == 1000
    assert not dead.exists() and fresh.exists()


def test_a_built_and_a_mapped_grid_reach_the_kernels_as_one_type(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, box_mesh, robot
) -> None:
    """A freshly built grid and a memory-mapped one reach the kernels as one type.

    numba compiles one specialisation per argument type: a built (writable) grid and a cached (read-only,
    memory-mapped) one of different types made the plan after a grid build compile every kernel again
    (10 s in a fresh process).
    """
    import numba

    from planner.collision.bodies import robot_bodies
    from planner.collision.kernels import buffers

    monkeypatch.setenv("CABINPLAN_CACHE_DIR", str(tmp_path))
    v, f = box_mesh
    built = cached_build("box", v, f, 0.05)
    mapped = cached_build("box", v, f, 0.05)
    assert not isinstance(built.lower_bound, np.memmap) and isinstance(mapped.lower_bound, np.memmap)
    model = robot.collision_model()
    bodies = robot_bodies(model, None)
    data = [buffers.build(model, bodies, np.eye(4), g, None) for g in (built, mapped, None)]
    assert len({numba.typeof(d.grid) for d in data}) == 1
    assert len({(numba.typeof(d.fbuf), numba.typeof(d.ibuf)) for d in data}) == 1
    np.testing.assert_array_equal(data[0].grid, data[1].grid)
