"""The gate's path check measures the distance from the path itself, not from its dense sampling."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from planner.gate.path_check import path_deviation
from planner.timing.path import BlendPiece, JointPath, LinePiece, Piece

DATA = Path(__file__).parent / "data"


def _leg(doc: dict) -> JointPath:
    pieces: list[Piece] = []
    for p in doc["pieces"]:
        if p["kind"] == "LinePiece":
            pieces.append(LinePiece(np.array(p["q0"]), np.array(p["q1"]), p["length"]))
        else:
            pieces.append(BlendPiece(np.array(p["a"]), np.array(p["w"]), np.array(p["b"]), p["length"]))
    return JointPath(tuple(pieces))


def test_a_sample_near_a_short_blend_between_long_lines_is_on_the_path() -> None:
    """A generated cycle's transit leg (7 pieces, a 0.015 blend after a 0.24 line on an 18.5 leg).

    With the dense points spread evenly over the leg the blend got three of them, Newton's method started
    on the wrong piece and the gate refused the plan: "samples off the certified path by at most 0.0019"
    for a sample the path passes within 0.75 um of (a brute-force search over 2 million points).
    """
    doc = json.loads((DATA / "short-blend-leg.json").read_text())
    leg = _leg(doc)
    q = np.array(doc["q"])[None, :]
    assert float(path_deviation(q, (leg,))[0]) < 1e-6
    # Every point of the path, blends included, at the gate's tolerance and far below it.
    s = np.concatenate([np.linspace(0.0, leg.length, 20_001), leg.breaks])
    assert float(path_deviation(leg.evaluate(s)[0], (leg,)).max()) <= 1e-9
    off = leg.evaluate(np.array([0.5 * leg.length]))[0] + 1e-4 * np.eye(8)[4]
    assert 0.5e-4 < float(path_deviation(off, (leg,))[0]) <= 1e-4 + 1e-12  # off the path: measured
