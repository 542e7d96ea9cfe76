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


def test_a_witness_parameter_settles_a_sample_and_a_wrong_one_falls_back_to_the_search() -> None:
    """Samples at the sampler's parameters: each one's figure is its distance from its witness point.

    A witness that is off (the wrong parameter, or a sample moved off the path) gets the nearest-point
    search, so a sample on the path still passes and one off it is still measured.
    """
    leg = _leg(json.loads((DATA / "short-blend-leg.json").read_text()))
    s = np.linspace(0.0, leg.length, 2_001)
    q = leg.evaluate(s)[0]
    q[7] += 1e-4 * np.eye(8)[4]  # off the path
    leg_of = np.zeros(len(s), dtype=np.int64)
    searched = path_deviation(q, (leg,), leg_of)
    witnessed = path_deviation(q, (leg,), leg_of, s)
    assert witnessed[0] == 0.0 and float(np.delete(witnessed, 7).max()) <= 1e-9
    assert witnessed[7] == searched[7] and 0.5e-4 < witnessed[7] <= 1e-4 + 1e-12
    wrong = s.copy()
    wrong[100:200] = np.clip(wrong[100:200] + 0.05, 0.0, leg.length)  # witnesses 0.05 along the leg
    shifted = path_deviation(q, (leg,), leg_of, wrong)
    assert float(np.delete(shifted, 7).max()) <= 1e-9  # the search finds them on the path
    assert np.array_equal(shifted[100:200], searched[100:200])
