"""Controller and tool exports read back and compared number by number with the profile they came from.

The profiles are synthetic and exact (each drive a smooth rest-to-rest motion whose position, velocity
and acceleration are known in closed form, within the cabin8 drive limits), so the tests need no planner:
a plan document and a cycle document shaped by the shared cycle contract (``kind``, ``leg``, ``legs``,
``events``). Every export is read back -- JSON and YAML with their parsers, the bag with rosbags' reader
-- and every position compared to 1e-12, every time to the nanosecond; thinning is checked by an
independent quintic (a 6x6 solve per segment and drive) at every original sample.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from planner.cli import app
from planner.core.exceptions import InvalidInput
from planner.documents import exports
from planner.gate.requirements import GOAL_ANGLE_TOL_RAD, GOAL_POSITION_TOL_M, LIMIT_TOLERANCE
from planner.robots import load_robot

ROBOT = load_robot("cabin8")
DRIVES = list(ROBOT.drive_names)
UNITS = list(ROBOT.drive_units)
PERIOD = 0.004
#: libyaml's safe loader where PyYAML has it (the pure-Python one takes 10 s on 1800 points).
LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
LEGS = ["pre_grasp", "grasp_line", "grasp", "lift_off", "transit", "insertion", "release", "retract", "park"]


def _motion(t: np.ndarray, duration: float, amplitude: np.ndarray) -> tuple[np.ndarray, ...]:
    """P = A (s - sin(2 pi s) / (2 pi)), s = t / T: rest to rest, jerk bounded; (p, v, a, jerk) (N, D)."""
    s = (t / duration)[:, None]
    w = 2 * np.pi
    p = amplitude * (s - np.sin(w * s) / w)
    v = amplitude * (1 - np.cos(w * s)) / duration
    a = amplitude * w * np.sin(w * s) / duration**2
    j = amplitude * w * w * np.cos(w * s) / duration**3
    return p, v, a, j


def plan_document(duration: float = 3.0, scale: float = 0.8) -> dict[str, Any]:
    """A succeeded plan document whose drives use up to ``scale`` of their velocity limit."""
    n = round(duration / PERIOD) + 1
    t = np.arange(n) * PERIOD
    lim = ROBOT.limits
    # peak velocity 2 A / T = scale v_max; the peak acceleration 2 pi A / T^2 stays below a_max here
    amplitude = scale * lim.v_max * duration / 2
    start = (lim.lower + lim.upper) / 2 - amplitude / 2
    p, v, a, j = _motion(t, duration, amplitude)
    assert (np.abs(a) <= lim.a_max).all() and (np.abs(j) <= lim.j_max).all()
    position = start + p
    names = list(zip(DRIVES, UNITS, strict=True))
    return {
        "kind": "plan",
        "robot": "cabin8",
        "scenario": {"name": "synthetic", "sha256": "0" * 64},
        "status": "succeeded",
        "drives": DRIVES,
        "units": {"t": "s", "position": dict(names), "velocity": {d: f"{u}/s" for d, u in names}},
        "sample_period_s": PERIOD,
        "t": t.tolist(),
        "position": position.tolist(),
        "velocity": v.tolist(),
        "acceleration": a.tolist(),
        "jerk": j.tolist(),
        "effort": (np.sin(t)[:, None] * np.arange(1, 9)).tolist(),
        "joints": {"names": DRIVES, "position": position.tolist()},
        "duration_s": float(t[-1]),
        "min_clearance_m": 0.0123,
        "report": {},
        "provenance": {},
    }


def cycle_document() -> dict[str, Any]:
    """A cycle document of the shared contract: nine legs over the samples, an attach and a detach."""
    doc = plan_document(duration=3.6)
    n = len(doc["t"])
    bounds = np.linspace(0, n, len(LEGS) + 1).round().astype(int)
    t = np.asarray(doc["t"])
    legs, leg = [], np.zeros(n, dtype=int)
    for i, name in enumerate(LEGS):
        a, b = int(bounds[i]), int(bounds[i + 1])
        leg[a:b] = i
        kind = "dwell" if name in ("grasp", "release") else "motion"
        payload = "unit-7" if name in ("lift_off", "transit", "insertion") else None
        legs.append(
            {
                "name": name,
                "kind": kind,
                "payload": payload,
                "t_start_s": float(t[a]),
                "t_end_s": float(t[b - 1]),
                "sample_start": a,
                "sample_end": b,
            }
        )
    doc.update(
        kind="cycle",
        cycle={"name": "bay-3", "sha256": "1" * 64},
        leg=leg.tolist(),
        legs=legs,
        events=[
            {"kind": "attach", "t_s": legs[2]["t_end_s"], "unit": "unit-7", "leg": 2, "springback_m": 0.0},
            {"kind": "detach", "t_s": legs[6]["t_end_s"], "unit": "unit-7", "leg": 6, "springback_m": 0.0004},
        ],
    )
    del doc["scenario"]
    return doc


@pytest.fixture(scope="module", params=["plan", "cycle"])
def doc(request: pytest.FixtureRequest) -> dict[str, Any]:
    return plan_document() if request.param == "plan" else cycle_document()


def _ns(duration: dict[str, int]) -> int:
    assert set(duration) == {"sec", "nanosec"} and 0 <= duration["nanosec"] < 1_000_000_000
    return duration["sec"] * 1_000_000_000 + duration["nanosec"]


def _check_goal(goal: dict[str, Any], doc: dict[str, Any], every_sample: bool) -> np.ndarray:
    """Every number of a goal read back equals the document's; returns the points' sample indices."""
    traj = goal["trajectory"]
    assert traj["joint_names"] == doc["drives"]
    t = np.asarray(doc["t"])
    points = traj["points"]
    times = np.array([_ns(p["time_from_start"]) for p in points])
    # each point's time is a sample's time to the nanosecond
    idx = np.rint(times * 1e-9 / PERIOD).astype(int)
    assert np.all(np.abs(times - t[idx] * 1e9) <= 0.5)
    if every_sample:
        np.testing.assert_array_equal(idx, np.arange(len(t)))
    assert idx[0] == 0 and idx[-1] == len(t) - 1 and (np.diff(idx) > 0).all()
    for key, field in (
        ("positions", "position"),
        ("velocities", "velocity"),
        ("accelerations", "acceleration"),
        ("effort", "effort"),
    ):
        got = np.array([p[key] for p in points])
        np.testing.assert_allclose(got, np.asarray(doc[field])[idx], rtol=0, atol=1e-12)
    for tol_list in (goal["path_tolerance"], goal["goal_tolerance"]):
        assert [x["name"] for x in tol_list] == doc["drives"]
        for x, unit in zip(tol_list, UNITS, strict=True):
            assert x["position"] == (GOAL_ANGLE_TOL_RAD if unit == "rad" else GOAL_POSITION_TOL_M)
    assert _ns(goal["goal_time_tolerance"]) == round(PERIOD * 1e9)
    return idx


def test_goal_json_and_yaml_read_back_equal_the_profile(doc: dict[str, Any]) -> None:
    goal = exports.follow_joint_trajectory_goal(doc)
    _check_goal(json.loads(exports.goal_json(goal)), doc, every_sample=True)
    _check_goal(yaml.load(exports.goal_yaml(goal), Loader=LOADER), doc, every_sample=True)


def _independent_quintic(t0, t1, x0, x1, t):
    """Position, velocity, acceleration, jerk of the quintic through (p, v, a) at t0 and t1 (a 6x6 solve)."""

    def rows(tt):
        return np.array(
            [
                [1, tt, tt**2, tt**3, tt**4, tt**5],
                [0, 1, 2 * tt, 3 * tt**2, 4 * tt**3, 5 * tt**4],
                [0, 0, 2, 6 * tt, 12 * tt**2, 20 * tt**3],
            ]
        )

    M = np.vstack([rows(0.0), rows(t1 - t0)])
    c = np.linalg.solve(M, np.concatenate([x0, x1]))
    tau = np.asarray(t) - t0
    p = sum(c[k] * tau**k for k in range(6))
    v = sum(k * c[k] * tau ** (k - 1) for k in range(1, 6))
    a = sum(k * (k - 1) * c[k] * tau ** (k - 2) for k in range(2, 6))
    j = sum(k * (k - 1) * (k - 2) * c[k] * tau ** (k - 3) for k in range(3, 6))
    return p, v, a, j


def _interpolate_like_the_controller(goal: dict[str, Any], t: np.ndarray) -> tuple[np.ndarray, ...]:
    """The goal's points interpolated by quintics at times t (K,): (p, v, a, j), (K, D) each."""
    pts = goal["trajectory"]["points"]
    tp = np.array([_ns(p["time_from_start"]) for p in pts]) * 1e-9
    seg = np.clip(np.searchsorted(tp, t, side="right") - 1, 0, len(tp) - 2)
    out = [np.zeros((len(t), len(DRIVES))) for _ in range(4)]
    for s in np.unique(seg):
        at = seg == s
        for d in range(len(DRIVES)):
            x0 = [pts[s]["positions"][d], pts[s]["velocities"][d], pts[s]["accelerations"][d]]
            x1 = [pts[s + 1]["positions"][d], pts[s + 1]["velocities"][d], pts[s + 1]["accelerations"][d]]
            for o, val in zip(out, _independent_quintic(tp[s], tp[s + 1], x0, x1, t[at]), strict=True):
                o[at, d] = val
    return tuple(out)


@pytest.mark.parametrize("spacing_s", [0.05, 0.4])
def test_thinned_goal_keeps_every_sample_within_deviation_and_limits(
    doc: dict[str, Any], spacing_s: float
) -> None:
    goal = json.loads(exports.goal_json(exports.follow_joint_trajectory_goal(doc, spacing_s=spacing_s)))
    idx = _check_goal(goal, doc, every_sample=False)
    assert len(idx) < len(doc["t"]) / 5  # thinned
    t = np.asarray(doc["t"])
    p, v, a, j = _interpolate_like_the_controller(goal, t)
    assert np.abs(p - np.asarray(doc["position"])).max() <= exports.DEFAULT_MAX_DEVIATION
    lim = ROBOT.limits
    scale = 1 + LIMIT_TOLERANCE
    assert (np.abs(v) <= lim.v_max * scale).all()
    assert (np.abs(a) <= lim.a_max * scale).all()
    assert (np.abs(j) <= lim.j_max * scale).all()


def test_thinning_adds_points_where_the_quintic_would_exceed_a_limit() -> None:
    """A point whose acceleration is 40 times the profile's (near the velocity limit).

    The quintics 0.4 s long that start and end there would leave the samples and exceed the limits, so
    points are added around it (and only there), and no sample exceeds a limit.
    """
    doc = plan_document(scale=0.999)
    a = np.asarray(doc["acceleration"])
    wanted = round(0.4 / PERIOD)
    spike = wanted * (len(a) // (3 * wanted))  # a point of the regular thinning
    a[spike] *= 40.0  # an acceleration the quintics ending and starting there must honour
    doc["acceleration"] = a.tolist()
    prof = exports.profile_of(doc)
    idx = exports.thin_points(prof, 0.4, exports.bounds_for("cabin8"))
    regular = set(range(0, len(a), wanted)) | {len(a) - 1}
    assert not set(idx) - regular or len(idx) > len(regular)  # points were added
    added = sorted(set(idx.tolist()) - regular)
    assert added and all(abs(k - spike) < wanted for k in added)
    goal = exports.follow_joint_trajectory_goal(doc, spacing_s=0.4)
    p, v, acc, j = _interpolate_like_the_controller(goal, np.asarray(doc["t"]))
    lim = ROBOT.limits
    assert (np.abs(v) <= lim.v_max * (1 + LIMIT_TOLERANCE)).all()
    assert np.abs(p - np.asarray(doc["position"])).max() <= exports.DEFAULT_MAX_DEVIATION


def _read_bag(folder: Path) -> dict[str, list[tuple[int, Any]]]:
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    meta = yaml.safe_load((folder / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["storage_identifier"] == "mcap" and meta["relative_file_paths"][0].endswith(".mcap")
    out: dict[str, list[tuple[int, Any]]] = {}
    with Reader(folder) as reader:
        for conn, stamp, raw in reader.messages():
            out.setdefault(conn.topic, []).append((stamp, store.deserialize_cdr(raw, conn.msgtype)))
    return out


def test_rosbag_reads_back_equal_to_the_profile(doc: dict[str, Any], tmp_path: Path) -> None:
    clearance = exports.ClearanceSeries(
        t_s=np.asarray(doc["t"])[::100], distance_m=np.linspace(0.05, 0.02, 31)[: len(doc["t"][::100])]
    )
    folder = exports.write_rosbag(
        doc, tmp_path / "bag", spacing_s=0.2, clearance=clearance, start_ns=1_700_000_000_000_000_000
    )
    assert (folder / "metadata.yaml").is_file() and len(list(folder.glob("*.mcap"))) == 1
    topics = _read_bag(folder)
    t = np.asarray(doc["t"])
    start = 1_700_000_000_000_000_000
    states = topics["/joint_states"]
    assert len(states) == len(t)
    stamps = np.array([s for s, _ in states])
    assert np.all(np.abs(stamps - start - t * 1e9) <= 0.5)
    for (stamp, msg), k in zip(states, range(len(t)), strict=True):
        assert list(msg.name) == DRIVES
        assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == stamp
        np.testing.assert_allclose(msg.position, doc["position"][k], rtol=0, atol=1e-12)
        np.testing.assert_allclose(msg.velocity, doc["velocity"][k], rtol=0, atol=1e-12)
        np.testing.assert_allclose(msg.effort, doc["effort"][k], rtol=0, atol=1e-12)
    ((_, traj),) = topics["/joint_trajectory"]
    goal = {
        "trajectory": {
            "joint_names": list(traj.joint_names),
            "points": [
                {
                    "positions": p.positions.tolist(),
                    "velocities": p.velocities.tolist(),
                    "accelerations": p.accelerations.tolist(),
                    "effort": p.effort.tolist(),
                    "time_from_start": {"sec": p.time_from_start.sec, "nanosec": p.time_from_start.nanosec},
                }
                for p in traj.points
            ],
        },
        **{k: v for k, v in exports.follow_joint_trajectory_goal(doc).items() if k != "trajectory"},
    }
    _check_goal(goal, doc, every_sample=False)
    ((_, minimum),) = topics["/cabinplan/min_clearance"]
    assert minimum.data == doc["min_clearance_m"]
    got = topics["/cabinplan/clearance"]
    np.testing.assert_array_equal([m.data for _, m in got], clearance.distance_m)
    assert np.all(np.abs(np.array([s for s, _ in got]) - start - clearance.t_s * 1e9) <= 0.5)
    events = [(s, json.loads(m.data)) for s, m in topics.get("/cabinplan/events", [])]
    expected = exports.timeline_events(doc)
    assert [e for _, e in events] == [json.loads(x) for _, x in expected]
    if doc.get("kind") == "cycle":
        assert [e["name"] for _, e in events if e["kind"] == "leg"] == LEGS
        for stamp, e in events:
            when = e["t_start_s"] if e["kind"] == "leg" else e["t_s"]
            assert abs(stamp - start - when * 1e9) <= 0.5
        assert [e["kind"] for _, e in events if e["kind"] != "leg"] == ["attach", "detach"]
    else:
        assert events == []


def test_refusals_and_bad_documents_are_not_exported() -> None:
    with pytest.raises(InvalidInput, match="only a succeeded"):
        exports.follow_joint_trajectory_goal({"status": "failed", "reason": "no_path_within_budget"})
    bad = plan_document()
    bad["position"][3][2] = float("nan")
    with pytest.raises(InvalidInput, match="position"):
        exports.follow_joint_trajectory_goal(bad)
    with pytest.raises(InvalidInput, match="format"):
        exports.export_bytes(plan_document(), "rosbag1")


def test_cli_export_writes_each_format(tmp_path: Path) -> None:
    doc = cycle_document()
    src = tmp_path / "cycle.json"
    src.write_text(json.dumps(doc))
    runner = CliRunner()
    for fmt, out in (("ros2-json", "g.json"), ("ros2-yaml", "g.yaml"), ("mcap", "bag")):
        r = runner.invoke(
            app, ["export", str(src), "--format", fmt, "--spacing-s", "0.1", "-o", str(tmp_path / out)]
        )
        assert r.exit_code == 0, r.output
    _check_goal(json.loads((tmp_path / "g.json").read_text()), doc, every_sample=False)
    _check_goal(yaml.load((tmp_path / "g.yaml").read_text(), Loader=LOADER), doc, every_sample=False)
    assert len(_read_bag(tmp_path / "bag")["/joint_states"]) == len(doc["t"])
    refused = tmp_path / "refused.json"
    refused.write_text(json.dumps({"status": "failed", "reason": "goal_in_collision"}))
    r = runner.invoke(app, ["export", str(refused), "--format", "ros2-json", "-o", str(tmp_path / "x.json")])
    assert r.exit_code == 2 and "only a succeeded plan" in r.output and not (tmp_path / "x.json").exists()
