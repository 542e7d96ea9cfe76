"""The on-disk cache of clearance grids: a hit returns the same grid, a bad file is rebuilt, never trusted."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
import trimesh

from planner.collision.clearance_grid import ClearanceGrid, cached_build


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
    files = list(tmp_path.glob("grid-*.npz"))
    assert len(files) == 1
    loaded = cached_build("box", v, f, 0.05)
    fresh = ClearanceGrid.build(v, f, step=0.05)
    for g in (built, loaded):
        assert g.step == fresh.step
        assert np.array_equal(g.origin, fresh.origin)
        assert np.array_equal(g.lower_bound, fresh.lower_bound)
    # Another step is another grid, another file.
    cached_build("box", v, f, 0.1)
    assert len(list(tmp_path.glob("grid-*.npz"))) == 2


def test_corrupt_cache_file_is_rebuilt(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, box_mesh, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setenv("CABINPLAN_CACHE_DIR", str(tmp_path))
    v, f = box_mesh
    cached_build("box", v, f, 0.05)
    (path,) = tmp_path.glob("grid-*.npz")
    path.write_bytes(b"not a zip file")
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
    assert not list(tmp_path.rglob("*.npz"))
