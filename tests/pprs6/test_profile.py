"""pprs6 drive profiles along the paper's closed path: every sample within limits, the path followed."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from planner.core.exceptions import InvalidInput, OutsideWorkspace, ValidationFailed
from planner.gate.pprs6 import validate
from planner.plan.pose_path import PAPER_PATH, build_profile, pose_path_from_spec
from planner.robots import load_robot
from planner.robots.pprs6 import Pprs6
from planner.tools.pprs6 import profile_document, profile_png


@pytest.fixture(scope="module")
def robot() -> Pprs6:
    model = load_robot("pprs6")
    assert isinstance(model, Pprs6)
    return model


@pytest.fixture(scope="module")
def document() -> dict:
    return profile_document(None)


def test_every_sample_within_limits(robot: Pprs6, document: dict) -> None:
    pos = np.array(document["position"])
    vel = np.array(document["velocity"])
    acc = np.array(document["acceleration"])
    t = np.array(document["t"])
    lim = robot.limits
    assert np.all(pos >= lim.lower) and np.all(pos <= lim.upper)
    assert np.all(np.abs(vel) <= 1.01 * lim.v_max)
    assert np.all(np.abs(acc) <= 1.01 * lim.a_max)
    assert np.all(np.abs(np.diff(vel, axis=0)) / np.diff(t)[:, None] <= 1.01 * lim.a_max)
    # The shared jerk-limited stage: the change of the sampled acceleration within the jerk limits.
    assert lim.j_max is not None
    assert np.all(np.abs(np.diff(acc, axis=0)) / np.diff(t)[:, None] <= 1.01 * lim.j_max)
    np.testing.assert_allclose(np.array(document["jerk"])[:-1], np.diff(acc, axis=0) / np.diff(t)[:, None])
    assert np.allclose(np.diff(t), document["sample_period_s"], atol=1e-12) and t[0] == 0
    # time-optimal under the limits: some drive reaches its velocity limit
    assert np.max(np.abs(vel) / lim.v_max) > 0.95


def test_rest_at_ends_and_at_every_corner(robot: Pprs6, document: dict) -> None:
    vel = np.array(document["velocity"])
    leg = np.array(document["leg"])
    assert np.abs(vel[0]).max() < 1e-12 and np.abs(vel[-1]).max() < 1e-12
    for k in range(1, 4):  # the first sample of each leg after the first is its corner, at rest
        corner = np.flatnonzero(leg == k)[0]
        assert np.abs(vel[corner]).max() < 1e-9
        assert corner - 1 == np.flatnonzero(leg == k - 1)[-1]


def test_pose_path_followed_and_closed(robot: Pprs6, document: dict) -> None:
    """FK of the sampled drives stays on the polyline E-F-G-H-E and returns to E."""
    pose = np.array(document["pose"])
    wps = np.array(
        [[w[n] for n in ("x", "y", "z", "phi", "theta", "psi")] for w in document["path"]["waypoints"]]
    )
    # The poses are the FK (Newton, converged when the drives are reproduced within 1e-12 m) of the sampled
    # drives: within 1e-11 of the waypoints (measured 1.1e-12 at the end of the jerk-limited law).
    assert np.allclose(pose[0], wps[0], atol=1e-11) and np.allclose(pose[-1], wps[0], atol=1e-11)
    pos = np.array(document["position"])
    assert np.allclose(robot.ik(pose), pos, atol=1e-12)
    leg = np.array(document["leg"])
    for k in range(4):
        a, b = wps[k], wps[k + 1]
        p = pose[leg == k]
        t = (p - a) @ (b - a) / ((b - a) @ (b - a))
        assert np.max(np.abs(p - a - t[:, None] * (b - a))) < 1e-9
        assert t.min() > -1e-9 and t.max() < 1 + 1e-9


def test_gate_refuses_a_corrupted_profile(robot: Pprs6) -> None:
    path = pose_path_from_spec(PAPER_PATH)
    prof = build_profile(robot, path, period_s=0.01)
    assert prof.gate.passed and prof.profile.effort is None
    fast = dataclasses.replace(prof.profile, velocity=1.5 * prof.profile.velocity)
    report, _ = validate(robot, path, fast, prof.leg, 0.01)
    assert {"velocity", "consistency"} <= {c.name for c in report.failures}
    # Off the path: drives of a pose 1 mm beside the leg at one sample.
    position = prof.profile.position.copy()
    i = len(position) // 3
    position[i] = robot.ik(prof.poses[i] + np.array([0.0, 0.0, 1e-3, 0.0, 0.0, 0.0]))
    off = dataclasses.replace(prof.profile, position=position)
    report, _ = validate(robot, path, off, prof.leg, 0.01)
    assert "pose_path_followed" in {c.name for c in report.failures}


def test_refusals_are_typed(robot: Pprs6) -> None:
    spec = {"waypoints": [dict(PAPER_PATH["waypoints"][0]), {**PAPER_PATH["waypoints"][1], "z": 0.30}]}
    with pytest.raises(OutsideWorkspace) as exc:
        profile_document(spec)
    assert exc.value.details["leg"] == "E->F"
    level = {"waypoints": [{**w, "phi": 0.0} for w in PAPER_PATH["waypoints"]], "closed": True}
    with pytest.raises(OutsideWorkspace) as exc:
        profile_document(level)
    assert exc.value.details["condition"] == "singularity"
    with pytest.raises(InvalidInput) as exc2:
        profile_document({"waypoints": [{"x": 0}]})
    assert exc2.value.details["field"] == "waypoints"
    with pytest.raises(InvalidInput) as exc2:
        profile_document(
            {"waypoints": [PAPER_PATH["waypoints"][0], {**PAPER_PATH["waypoints"][1], "z": None}]}
        )
    assert exc2.value.details["field"] == "waypoints.1.z"
    assert issubclass(ValidationFailed, Exception)


def test_profile_png(document: dict) -> None:
    assert profile_png(document).startswith(b"\x89PNG")
