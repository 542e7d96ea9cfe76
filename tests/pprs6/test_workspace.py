"""pprs6 workspace by boundary search: extents stable under refinement, the boundary is the boundary."""

from __future__ import annotations

import numpy as np
import pytest

from planner.core.exceptions import InvalidInput
from planner.kinematics.workspace import boundary_search
from planner.robots import load_robot
from planner.tools.pprs6 import workspace_document


@pytest.fixture(scope="module")
def documents() -> dict[float, dict]:
    return {step: workspace_document(None, step_m=step, png=False)[0] for step in (0.01, 0.005)}


def test_extents_and_volume_stable_under_grid_refinement(documents: dict[float, dict]) -> None:
    coarse, fine = documents[0.01], documents[0.005]
    for axis in "xyz":
        assert np.allclose(coarse["extents_m"][axis], fine["extents_m"][axis], atol=1e-3), axis
    assert abs(coarse["volume_m3"] - fine["volume_m3"]) < 0.06 * fine["volume_m3"]


def test_level_workspace_figures(documents: dict[float, dict]) -> None:
    """At zero orientation: X is exactly the w1 stroke (C1 . u1 = x + r), Y is longer than X."""
    ws = documents[0.005]
    assert ws["extents_m"]["x"] == pytest.approx([0.08 - 0.16, 0.18 - 0.16], abs=1e-9)
    assert ws["size_m"]["y"] > ws["size_m"]["x"]
    # Z: below s_max + l (chain 1's link vertical at its top stroke)
    assert ws["extents_m"]["z"][1] <= 0.1375 + 0.100 + 1e-9
    assert 0.0006 < ws["volume_m3"] < 0.0008


def test_boundary_points_are_on_the_boundary() -> None:
    robot = load_robot("pprs6")

    def admissible(p: np.ndarray) -> np.ndarray:
        x = np.zeros((len(p), 6))
        x[:, :3] = p
        return robot.admissible(x)  # type: ignore[attr-defined,no-any-return]

    ws = boundary_search(admissible, np.array([[-0.1, 0.04], [-0.12, 0.06], [0.1, 0.26]]), 0.01)
    rng = np.random.default_rng(0)
    pts = ws.boundary[rng.choice(len(ws.boundary), 200, replace=False)]
    for e in np.eye(3):
        inside = admissible(pts - 1e-6 * e) | admissible(pts + 1e-6 * e)
        outside = ~admissible(pts - 1e-6 * e) | ~admissible(pts + 1e-6 * e)
        assert np.all(inside | outside)
    # each point has admissible and inadmissible neighbours within 1e-6 m along some axis
    near = np.zeros(len(pts), dtype=bool)
    for e in np.eye(3):
        a, b = admissible(pts - 1e-6 * e), admissible(pts + 1e-6 * e)
        near |= a != b
    assert near.all()


def test_search_box_must_contain_the_workspace() -> None:
    robot = load_robot("pprs6")

    def admissible(p: np.ndarray) -> np.ndarray:
        x = np.zeros((len(p), 6))
        x[:, :3] = p
        return robot.admissible(x)  # type: ignore[attr-defined,no-any-return]

    with pytest.raises(InvalidInput):
        boundary_search(admissible, np.array([[-0.05, 0.0], [-0.12, 0.06], [0.1, 0.26]]), 0.01)
    with pytest.raises(InvalidInput) as exc:
        workspace_document({"phi": "a"})
    assert exc.value.details["field"] == "orientation.phi"


def test_png_is_an_image() -> None:
    doc, png = workspace_document({"phi": 0.1}, step_m=0.01)
    assert png.startswith(b"\x89PNG") and doc["orientation"]["phi"] == 0.1
