"""The ahead-of-time build of the kernels: the same numbers as numba's JIT, wrong arguments refused, no numba.

The build (:mod:`planner.core.aot`) and the JIT run the same functions; these tests run both on the same
inputs (states and motions in suite cabins, tight and clear; the timing reference on a real stage's rows)
and require equal results bit for bit. The build's entries read whatever they are given as the declared
type, so the wrappers must refuse every other argument.
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planner.collision.kernels import codes, entries
from planner.collision.kernels.entries import EXTENSION, Kernels
from planner.collision.obstacles import Obstacle
from planner.collision.sweep import body_vertices
from planner.collision.world import CollisionWorld
from planner.core import aot
from planner.robots.cabin8 import Cabin8
from planner.robots.geometry import BOX_CORNER_SIGNS
from planner.scenario import load_scenario
from planner.timing import acc_reference
from planner.timing.jerk import JerkLimitedStage
from planner.timing.path import JointPath, LinePiece, segment_time_length
from tests.conftest import admissible_joints, plan_in_a_fresh_process

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = ROOT / "tests" / "scenarios"


def _built(ext: aot.Extension) -> Any:
    module = aot.load(ext)
    if module is None:
        pytest.skip(f"no ahead-of-time build of {ext.name} (CABINPLAN_CACHE_DIR empty or the build failed)")
    return module


@pytest.fixture(scope="module")
def both() -> tuple[Kernels, Kernels]:
    """(the build's entries, the JIT's entries)."""
    return Kernels(_built(EXTENSION)), Kernels(aot.jit_kernels(EXTENSION))


def _same(a: Any, b: Any, what: str) -> None:
    """Equal bit for bit: arrays by their bytes (NaN payloads and signed zeros too), tuples elementwise."""
    if isinstance(a, tuple):
        assert isinstance(b, tuple) and len(a) == len(b), what
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, f"{what}[{i}]")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape, what
        assert a.tobytes() == b.tobytes(), what
    else:
        assert type(a) is type(b) or {type(a), type(b)} <= {int, np.int64, bool, np.bool_}, what
        assert np.asarray(a).tobytes() == np.asarray(b).tobytes(), f"{what}: {a!r} != {b!r}"


def _states(sc: Any, robot: Cabin8, n: int, seed: int) -> np.ndarray:
    """States of a scenario: near its start (close to the cabin), between start and random ones, random."""
    rng = np.random.default_rng(seed)
    far = admissible_joints(robot, n, seed=seed)
    far[:, 0] = rng.uniform(robot.limits.lower[0], robot.limits.upper[0], n)
    near = sc.start_q + rng.normal(0.0, 0.02, (n, 8))
    between = sc.start_q + rng.uniform(0.0, 1.0, (n, 1)) * (far - sc.start_q)
    wild = far + rng.normal(0.0, 0.3, far.shape)  # off-limits, some stage links cannot close
    return np.ascontiguousarray(np.vstack([near, between, far, wild, [np.full(8, np.nan)]]))


@pytest.mark.parametrize("name", ["tightbay-insert", "aisle-transfer", "hatch-pass"])
def test_build_and_jit_give_the_same_bits_in_suite_cabins(name: str, both: tuple[Kernels, Kernels]) -> None:
    """Every entry, and whole state / motion / path checks, equal on the build and on the JIT."""
    sc = load_scenario(SCENARIOS / f"{name}.yaml")
    robot = sc.robot
    world = CollisionWorld(robot, sc.cabin, sc.payload)
    d = world._kernel
    qs = _states(sc, robot, 40, seed=7)
    built, jit = both
    seen: set[int] = set()
    seen_valid: set[int] = set()
    for q in qs:
        q = np.array(q)
        for clearance in (0.0, 0.01, 0.05):
            for slack in (-1.0, d.upper_slack):
                got = built.packed_check(q, d, clearance, 0.01, slack)
                _same(got, jit.packed_check(q, d, clearance, 0.01, slack), "packed_check")
                seen.add(int(got[0]))
        _same(built.packed_state(q, d, 0.07), jit.packed_state(q, d, 0.07), "packed_state")
        for clearance in (0.0, 0.01, 0.05):
            got_v = built.packed_valid(q, d, clearance, 0.01, d.upper_slack)
            _same(got_v, jit.packed_valid(q, d, clearance, 0.01, d.upper_slack), "packed_valid")
            seen_valid.add(got_v[0])
            values = np.linspace(q[0] - 1.0, q[0] + 1.0, 9)
            for fixed in (True, False):
                got_s = built.axis_sweep(q, 0, values, fixed, d, clearance, 0.01, d.upper_slack)
                _same(got_s, jit.axis_sweep(q, 0, values, fixed, d, clearance, 0.01, d.upper_slack), "sweep")
    assert {codes.CLEAR, codes.INADMISSIBLE, codes.UNDECIDED, codes.NOT_FINITE, codes.CONTACT} <= seen, seen
    assert {codes.STATE_VALID, codes.STATE_INVALID} <= seen_valid, seen_valid
    n_b, m = len(world.names), len(d.c_lo)
    out = [(np.empty((len(qs), n_b, 13)), np.empty((len(qs), m))) for _ in range(2)]
    built.packed_poses(qs, d, *out[0])
    jit.packed_poses(qs, d, *out[1])
    _same(out[0], out[1], "packed_poses")
    for cover in (d.fine, d.coarse):
        poses = out[0][0]
        _same(built.cover_centres_batch(poses, cover), jit.cover_centres_batch(poses, cover), "covers")
        _same(built.cover_extents(poses, cover), jit.cover_extents(poses, cover), "cover_extents")
    poses = out[0][0]
    box = np.array([s.kind == "box" for s in world.bodies.shapes])
    half = np.array([0.5 * float(np.linalg.norm(s.size)) for s in world.bodies.shapes])
    step_a, step_b = np.ascontiguousarray(poses[:-1]), np.ascontiguousarray(poses[1:])
    nb = len(box)
    col_a = np.array([*range(nb), *range(nb - 1)], dtype=np.int64)
    col_b = np.array([-1] * nb + [*range(1, nb)], dtype=np.int64)
    tasks = (step_a, step_b, box, half, col_a, col_b)
    _same(built.task_offsets(*tasks), jit.task_offsets(*tasks), "task_offsets")
    finite = np.ascontiguousarray(poses[:-1])  # the NaN state left out
    for b, shape in enumerate(world.bodies.shapes):
        local = BOX_CORNER_SIGNS * (0.5 * np.asarray(shape.size, dtype=float))
        kind = shape.kind == "box"
        _same(built.path_vertices(finite, b, local, kind), jit.path_vertices(finite, b, local, kind), "verts")
        a = (b + 1) % len(world.bodies.shapes)
        pair = (finite, b, a, local, kind)
        _same(built.pair_vertices(*pair), jit.pair_vertices(*pair), "pair")
        verts = np.ascontiguousarray(body_vertices(poses[:-1, b], shape))
        _same(built.hull_deviation(verts), jit.hull_deviation(verts), "hull_deviation")
        _same(built.hull_deviation(verts[:1]), jit.hull_deviation(verts[:1]), "hull_deviation, one sample")
    rng = np.random.default_rng(3)
    for a, b in zip(qs[:-1], qs[1:], strict=True):
        dq = b - a
        for n_fine in (1, 7, 100):
            bad = built.first_inadmissible(a, dq, n_fine, d)
            _same(bad, jit.first_inadmissible(a, dq, n_fine, d), "limits")
        _same(built.end_ratio(a, b, d), jit.end_ratio(a, b, d), "end_ratio")
        k = float(rng.uniform(0.0, 3.0))
        _same(built.segment_reach(d, k, 0.2, np.abs(dq)), jit.segment_reach(d, k, 0.2, np.abs(dq)), "reach")
    path = np.ascontiguousarray(sc.start_q + np.cumsum(rng.normal(0.0, 0.01, (40, 8)), axis=0))
    rho = np.ascontiguousarray(np.max(d.rho, axis=0))
    reach = np.ascontiguousarray(np.abs(np.diff(path, axis=0)) @ np.abs(rng.normal(0.0, 0.5, (5, 8))).T)
    steps = np.abs(rng.normal(0.0, 0.01, (39, 5)))
    _same(built.cumulative_bound(reach, steps), jit.cumulative_bound(reach, steps), "cumulative_bound")
    lower = rng.normal(0.0, 0.01, (40, 5))
    lower[rng.random(lower.shape) < 0.5] = -np.inf
    cum = np.ascontiguousarray(np.vstack([np.zeros((1, 5)), np.cumsum(steps, axis=0)]))
    spread = [lower.copy(), lower.copy()]
    built.propagate(spread[0], cum, np.array([0, 2, 4]))
    jit.propagate(spread[1], cum, np.array([0, 2, 4]))
    _same(spread[0], spread[1], "propagate")
    _same(
        built.between_bound(lower, steps, np.array([0, 3])),
        jit.between_bound(lower, steps, np.array([0, 3])),
        "between",
    )
    for i in range(0, 39, 3):
        run = built.run_extent(path, i, 39, rho, 0.002)
        _same(run, jit.run_extent(path, i, 39, rho, 0.002), "run_extent")
    # Whole checks (the motion walk with its FCL probes in between), on one world switched between both.
    reports: list[list[Any]] = []
    for kernels in both:
        world.kernels = world._motion.kernels = kernels
        got: list[Any] = []
        for a, b in zip(qs[:-1], qs[1:], strict=True):
            for clearance in (0.0, 0.01):
                got.append(world.is_valid(a, clearance))
                got.append(world.check_state(a, clearance, all_contacts=True))
                got.append(world.check_motion(a, a + 0.3 * (b - a), clearance))
        got.append(world.check_path(path, 0.01))
        got.append(world.cover_centres(path[:5]).tobytes())
        reports.append(got)
    world.kernels = world._motion.kernels = entries.DEFAULT
    assert reports[0] == reports[1]
    motions = [r for r in reports[0] if hasattr(r, "t_fail")]
    assert any(r.valid for r in motions) and not all(r.valid for r in motions)


def _obstacle_world(name: str) -> tuple[Any, CollisionWorld]:
    """A suite scenario's world with obstacles about its start: rotated boxes and a mesh, a pair allowed."""
    sc = load_scenario(SCENARIOS / f"{name}.yaml")
    rng = np.random.default_rng(17)
    T_tool = sc.robot.fk(sc.start_q)
    obstacles = []
    for i in range(4):
        T = np.eye(4)
        T[:3, :3] = np.linalg.qr(rng.normal(size=(3, 3)))[0] * [1.0, 1.0, -1.0]
        T[:3, :3] *= np.sign(np.linalg.det(T[:3, :3]))
        T[:3, 3] = T_tool[:3, 3] + rng.normal(0.0, 0.3, 3)
        if i < 3:
            obstacles.append(Obstacle.box(f"unit {i}", tuple(rng.uniform(0.05, 0.4, 3)), T))
        else:
            v = np.array([[0, 0, 0], [0.3, 0, 0], [0, 0.2, 0], [0, 0, 0.25]], dtype=float)
            f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], dtype=np.int64)
            obstacles.append(Obstacle("fixture", T, vertices=v, faces=f))
    allowed = frozenset({("payload", "unit 0")})
    return sc, CollisionWorld(sc.robot, sc.cabin, sc.payload, obstacles=tuple(obstacles), allowed=allowed)


def test_build_and_jit_give_the_same_obstacle_bounds(both: tuple[Kernels, Kernels]) -> None:
    """The obstacle entries, and whole checks of a world with obstacles, equal on the build and the JIT."""
    sc, world = _obstacle_world("tightbay-insert")
    obs = world.obstacles
    assert obs is not None
    d = obs.kernel_data
    qs = _states(sc, sc.robot, 30, seed=19)
    n_b, m = len(world.names), len(world._kernel.c_lo)
    poses, c = np.empty((len(qs), n_b, 13)), np.empty((len(qs), m))
    world.kernels.packed_poses(qs, world._kernel, poses, c)
    assert np.isnan(poses).any()  # the wild states: NaN where a link cannot close
    built, jit = both
    rng = np.random.default_rng(5)
    refined = 0
    for flat in poses:
        for th in (np.full(n_b, -1.0), np.full(n_b, 0.05), np.full(n_b, np.inf), rng.uniform(0.0, 0.5, n_b)):
            got = built.obstacle_bounds(flat, d, th)
            _same(got, jit.obstacle_bounds(flat, d, th), "obstacle_bounds")
            refined += int(np.any(got != built.obstacle_bounds(flat, d, np.full(n_b, -1.0))))
    assert refined > 0  # the fine covers were used
    for allowed_too in (False, True):
        got = built.obstacle_coarse_batch(poses, d, allowed_too)
        _same(got, jit.obstacle_coarse_batch(poses, d, allowed_too), "obstacle_coarse_batch")
    rows = np.array([3, 0, 3, len(qs) - 1], dtype=np.int64)
    for b in range(n_b):
        _same(
            built.obstacle_fine_batch(poses, rows, b, d), jit.obstacle_fine_batch(poses, rows, b, d), "fine"
        )
    reports: list[list[Any]] = []
    for kernels in both:
        world.kernels = world._motion.kernels = obs.kernels = kernels
        got: list[Any] = []
        for a, b in zip(qs[:-1], qs[1:], strict=True):
            got.append(world.is_valid(a, 0.01))
            got.append(world.check_state(a, 0.01, all_contacts=True))
            got.append(world.check_motion(a, a + 0.2 * (b - a), 0.01))
        reports.append(got)
    world.kernels = world._motion.kernels = obs.kernels = entries.DEFAULT
    assert reports[0] == reports[1]
    assert any(c.kind == "obstacle" for r in reports[0] if hasattr(r, "contacts") for c in r.contacts)


def test_build_and_jit_give_the_same_clearance_grid(both: tuple[Kernels, Kernels]) -> None:
    """The grid's marks and distance transform: the same bits from the build and the JIT, on a suite cabin."""
    built, jit = both
    sc = load_scenario(SCENARIOS / "hatch-pass.yaml")
    assert sc.cabin is not None
    v = np.ascontiguousarray(sc.cabin.vertices, dtype=float)
    f = np.ascontiguousarray(sc.cabin.faces, dtype=np.int64)
    lo = v.min(axis=0) - 0.2
    shape = tuple(int(n) for n in np.ceil((v.max(axis=0) + 0.2 - lo) / 0.06).astype(int) + 1)
    marks = [np.zeros(shape, dtype=bool), np.zeros(shape, dtype=bool)]
    built.grid_marks(v, f, lo, 0.06, 0.03, marks[0])
    jit.grid_marks(v, f, lo, 0.06, 0.03, marks[1])
    _same(marks[0], marks[1], "grid_marks")
    _same(built.grid_bounds(marks[0], 0.06, 0.1), jit.grid_bounds(marks[0], 0.06, 0.1), "grid_bounds")
    trees = built.mesh_tree(v, f), jit.mesh_tree(v, f)
    _same(tuple(trees[0]), tuple(trees[1]), "mesh_tree")
    rng = np.random.default_rng(2)
    for p in rng.uniform(v.min(axis=0), v.max(axis=0), (200, 3)):
        pose = np.concatenate([np.eye(3).reshape(9), p, [0.0]])
        half = rng.uniform(0.01, 0.3, 3)
        pts = np.ascontiguousarray(p + rng.normal(0.0, 0.2, (16, 3)))
        capsule = np.concatenate([pose[:12], [0.4]])
        calls = [
            ("box_touches_mesh", (pose, half, 0.01)),
            ("box_mesh_distance", (pose, half, 0.3)),
            ("hull_mesh_lower", (pts,)),
            ("cabin_witness", (capsule, half, 0.0)),
            ("cabin_witness", (capsule, half, 0.05)),
            ("capsule_touches_mesh", (capsule, 0.05, 0.02)),
            ("capsule_mesh_distance", (capsule, 0.05, 0.02)),
        ]
        for what, args in calls:
            _same(getattr(built, what)(*args, trees[0]), getattr(jit, what)(*args, trees[0]), what)
        for shape_half, radius in ((half, 0.0), (half, 0.02), (np.array([0.0, 0.0, half[2]]), 0.05)):
            a_pts = np.ascontiguousarray(pts - p)  # a pair: the other body at the origin
            for chosen in (a_pts, a_pts[:4], np.ascontiguousarray(np.vstack([a_pts[:2], a_pts[:2]]))):
                _same(
                    built.hull_shape_lower(chosen, shape_half, radius),
                    jit.hull_shape_lower(chosen, shape_half, radius),
                    "hull_shape_lower",
                )
        other = np.concatenate([rng.normal(size=9), p + rng.normal(0.0, 0.3, 3), [0.3]])  # a pair's pose
        pairs = [(pose, half, 0.0, other, half, 0.0), (capsule, half, 0.05, other, half, 0.0)]
        for pair in [*pairs, (capsule, half, 0.05, other, half, 0.03)]:
            _same(built.pair_witness(*pair), jit.pair_witness(*pair), "pair_witness")
            _same(
                built.pair_witness(*pair[3:], *pair[:3]),
                jit.pair_witness(*pair[3:], *pair[:3]),
                "pair_witness",
            )
            poses, radii, halves = (
                np.array([pair[0], pair[3]]),
                np.array([pair[2], pair[5]]),
                np.array([half, half]),
            )
            for g in (0.0, 0.02, 0.2):
                got = (
                    built.pair_touches(poses, radii, halves, 0, 1, g),
                    jit.pair_touches(poses, radii, halves, 0, 1, g),
                )
                _same(got[0], got[1], "pair_touches")


def test_build_and_jit_give_the_same_reference_speed() -> None:
    """The timing reference (forward-backward pass) on the rows of real jerk-limited stages: equal bits."""
    robot = Cabin8()
    rows: list[tuple[np.ndarray, ...]] = []

    def record(*args: np.ndarray, **kw: Any) -> np.ndarray:
        rows.append(tuple(np.array(a) for a in args))
        return acc_reference.acceleration_limited(*args, **kw)

    home = robot.joints_from_drives(robot.home_drives)
    stage = JerkLimitedStage(robot, None, sample_period_s=0.004)
    mp = pytest.MonkeyPatch()
    with mp.context() as m:
        m.setattr("planner.timing.jerk.acceleration_limited", record)
        for step in ({0: 1.5}, {0: 0.8, 4: 0.4, 6: -0.15}, {5: -0.5, 7: 1.2}):
            q1 = home.copy()
            for j, v in step.items():
                q1[j] += v
            stage.time_path(JointPath((LinePiece(home, q1, segment_time_length(robot, home, q1)),)))
    assert rows
    built, jit = _built(acc_reference.EXTENSION), aot.jit_kernels(acc_reference.EXTENSION)
    for args in rows:
        _same(
            acc_reference.acceleration_limited(*args, implementation=built),
            acc_reference.acceleration_limited(*args, implementation=jit),
            "acceleration_limited",
        )


def test_wrong_arguments_are_refused_not_computed(both: tuple[Kernels, Kernels]) -> None:
    """A strided view, another dtype, another number of dimensions, a read-only output: TypeError by name."""
    built = both[0]
    robot = Cabin8()
    world = CollisionWorld(robot, None, None)
    d = world._kernel
    q = robot.joints_from_drives(robot.home_drives).astype(float)
    wide = np.repeat(q, 2)
    cases = [
        (lambda: built.packed_check(wide[::2], d, 0.01, 0.01, -1.0), "q"),  # strided: every other value
        (lambda: built.packed_check(q.astype(np.int64), d, 0.01, 0.01, -1.0), "q"),
        (lambda: built.packed_check(q.astype(np.float32), d, 0.01, 0.01, -1.0), "q"),
        (lambda: built.packed_check(q[None, :], d, 0.01, 0.01, -1.0), "q"),
        (lambda: built.packed_check(list(q), d, 0.01, 0.01, -1.0), "q"),
        (lambda: built.packed_check(q, d.fbuf, 0.01, 0.01, -1.0), "d"),
        (lambda: built.packed_state(q, d, 0.07), None),  # the control: accepted
        (lambda: built.end_ratio(q, q.reshape(2, 4), d), "q_b"),
        (lambda: built.run_extent(np.asfortranarray(np.stack([q, q, q])), 0, 2, np.ones(8), 0.1), "qs"),
    ]
    poses, c = np.empty((1, len(world.names), 13)), np.empty((1, len(d.c_lo)))
    poses.setflags(write=False)
    cases.append((lambda: built.packed_poses(q[None, :], d, poses, c), "poses"))
    flat = np.empty((1, len(world.names), 13))
    cases.append((lambda: built.cover_centres_batch(flat, d.fine.body), "cover"))
    _, with_obstacles = _obstacle_world("aisle-transfer")
    assert with_obstacles.obstacles is not None
    od, th = with_obstacles.obstacles.kernel_data, np.zeros(len(with_obstacles.names))
    at = np.zeros((1, len(with_obstacles.names), 13))
    at[0, :, [0, 4, 8]] = 1.0
    one = np.arange(len(at[0]), dtype=np.int64)  # each body its own task column
    none = np.full(len(at[0]), -1, dtype=np.int64)
    yes, half = np.zeros(len(at[0]), bool), np.zeros(len(at[0]))
    pts, tri, grid = np.eye(3), np.array([[0, 1, 2]]), np.zeros((3, 3, 3), dtype=bool)
    cases += [
        (lambda: built.obstacle_bounds(at[0], od, th), None),  # the control: accepted
        (lambda: built.obstacle_bounds(at[0], d, th), "d"),  # a world's data, not an obstacle set's
        (lambda: built.obstacle_bounds(np.asfortranarray(at[0]), od, th), "poses"),
        (lambda: built.obstacle_bounds(at[0], od, th.astype(np.float32)), "threshold"),
        (lambda: built.obstacle_coarse_batch(at[0], od, False), "poses"),
        (lambda: built.obstacle_fine_batch(at, np.zeros(1, dtype=np.int32), 0, od), "rows"),
        (lambda: built.task_offsets(at, at, yes, half, one, none), None),
        (lambda: built.task_offsets(at, at, half, half, one, none), "box"),
        (lambda: built.task_offsets(at, at[:, :, :12], yes, np.zeros(1), one, none), "poses_b"),
        (lambda: built.task_offsets(at, at, yes, half, one.astype(np.int32), none), "col_a"),
        (lambda: built.hull_deviation(np.asfortranarray(at[:, :, :3])), "verts"),
        (lambda: built.grid_bounds(np.zeros((2, 2, 2), dtype=bool), 0.1, 0.0), None),
        (lambda: built.grid_bounds(np.zeros((2, 2, 2), dtype=np.int8), 0.1, 0.0), "marked"),
        (lambda: built.grid_bounds(np.zeros((2, 2), dtype=bool), 0.1, 0.0), "marked"),
        (lambda: built.grid_marks(pts, tri, np.zeros(3), 0.1, 0.1, grid), None),
        (lambda: built.grid_marks(at[0, :, 9:12], tri, np.zeros(3), 0.1, 0.1, grid), "vertices"),
        (lambda: built.grid_marks(pts, tri.astype(np.int32), np.zeros(3), 0.1, 0.1, grid), "faces"),
        (lambda: built.grid_marks(pts, tri, np.zeros(3), 0.1, 0.1, grid.astype(np.int8)), "marked"),
        (lambda: built.mesh_tree(pts, tri), None),
        (lambda: built.mesh_tree(pts, tri.astype(np.int32)), "faces"),
        (lambda: built.box_touches_mesh(at[0, 0], np.ones(3), 0.0, built.mesh_tree(pts, tri)), None),
        (
            lambda: built.box_touches_mesh(np.zeros(26)[::2], np.ones(3), 0.0, built.mesh_tree(pts, tri)),
            "pose",
        ),
    ]
    for call, name in cases:
        if name is None:
            call()
            continue
        with pytest.raises(TypeError, match=f"^{name}: "):
            call()
    ds, x = np.full(4, 0.1), np.ones((5, 2))
    with pytest.raises(TypeError, match="^cx: "):
        acc_reference.acceleration_limited(ds, x[:, 0], x, x, np.ones(5))
    with pytest.raises(ValueError, match="do not fit"):
        acc_reference.acceleration_limited(ds, x, x, x[:4], np.ones(5))


def test_a_plan_served_by_the_build_never_imports_numba(tmp_path: Path) -> None:
    """A ``cabinplan plan`` with the build in the cache folder imports neither numba nor llvmlite."""
    _built(EXTENSION)
    _built(acc_reference.EXTENSION)
    scenario = SCENARIOS / "aisle-transfer.yaml"
    env = {k: v for k, v in os.environ.items() if k != "CABINPLAN_KERNELS"}
    _, loaded = plan_in_a_fresh_process(scenario, tmp_path / "out.json", ("numba", "llvmlite"), env)
    assert loaded == []
    assert '"succeeded"' in (tmp_path / "out.json").read_text()


def _toy(tmp_path: Path, builder: str) -> aot.Extension:
    """A one-entry extension of the timing kernels, with its own source file and builder module."""
    source = tmp_path / "toy_source.py"
    source.write_text("# toy\n")
    return aot.Extension(
        "cabinplan_toy_kernels",
        acc_reference.EXTENSION.kernels_module,
        builder,
        (source,),
        acc_reference.EXTENSION.entries,
    )


def test_no_cache_folder_or_jit_mode_runs_the_jit(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    ext = _toy(tmp_path, "planner.nowhere")
    jit = aot.jit_kernels(ext)
    monkeypatch.setenv("CABINPLAN_CACHE_DIR", "")
    assert aot.kernels(ext) is jit
    monkeypatch.setenv("CABINPLAN_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("CABINPLAN_KERNELS", "jit")
    assert aot.kernels(ext) is jit
    assert not (tmp_path / "cache").exists()  # nothing built


def test_a_failed_build_falls_back_to_the_jit_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """No build (a builder that does not exist here; no C compiler on a machine): the JIT, one warning.

    A marker keeps later processes from trying again for the same key.
    """
    monkeypatch.setenv("CABINPLAN_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv("CABINPLAN_KERNELS", raising=False)
    monkeypatch.setattr(aot, "_WARNED", set())
    ext = _toy(tmp_path, "planner.nowhere")
    with caplog.at_level(logging.WARNING, logger="planner.core.aot"):
        assert aot.kernels(ext) is aot.jit_kernels(ext)
        assert aot.kernels(ext) is aot.jit_kernels(ext)
    assert len([r for r in caplog.records if "no ahead-of-time build" in r.getMessage()]) == 1
    lib = aot.path(ext)
    assert lib is not None and not lib.exists()
    assert lib.with_name(lib.name + ".failed").is_file()


def test_the_key_follows_the_sources(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CABINPLAN_CACHE_DIR", str(tmp_path))
    ext = _toy(tmp_path, "planner.nowhere")
    before = aot.path(ext)
    ext.sources[0].write_text("# toy, edited\n")
    after = aot.path(ext)
    assert before != after and before is not None and before.parent == tmp_path / "native"


def test_a_missing_build_is_built_at_first_use(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """No build in the cache folder: the first use builds it (a child process, under the lock), loads it."""
    monkeypatch.setenv("CABINPLAN_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv("CABINPLAN_KERNELS", raising=False)
    lib = aot.path(acc_reference.EXTENSION)
    assert lib is not None and not lib.exists()
    module = aot.kernels(acc_reference.EXTENSION)
    assert lib.is_file() and module.__file__ == str(lib)
    rows = np.ones((3, 1)), np.zeros((3, 1)), np.ones((3, 1))
    x = acc_reference.acceleration_limited(np.full(2, 0.5), *rows, np.ones(3), implementation=module)
    jit = acc_reference.acceleration_limited(
        np.full(2, 0.5), *rows, np.ones(3), implementation=aot.jit_kernels(acc_reference.EXTENSION)
    )
    assert x.tobytes() == jit.tobytes() and x[0] == x[-1] == 0.0

    # ``make``'s build step (``--reuse``) keeps that build: same key, same file, nothing compiled.
    mtime = lib.stat().st_mtime_ns
    monkeypatch.setattr(aot, "build", lambda ext: pytest.fail("rebuilt a build of the same key"))
    aot.main(acc_reference.EXTENSION, ["--reuse"])
    assert "reused" in capsys.readouterr().out and lib.stat().st_mtime_ns == mtime
    # A file of that key that does not load is built again; without --reuse the build always runs (this
    # process has the file loaded: the dynamic loader would hand back the same library, so load raises).
    built: list[str] = []
    monkeypatch.setattr(aot, "build", lambda ext: built.append(ext.name) or lib)

    def damaged(ext: aot.Extension, cpu: str | None = None) -> None:
        raise ImportError("invalid ELF header")  # as a new process loading a damaged file would

    monkeypatch.setattr(aot, "load", damaged)
    aot.main(acc_reference.EXTENSION, ["--reuse"])
    aot.main(acc_reference.EXTENSION, [])
    assert built == [acc_reference.EXTENSION.name] * 2
    with pytest.raises(SystemExit, match="unknown argument '--force'"):
        aot.main(acc_reference.EXTENSION, ["--force"])


def test_wrong_shapes_and_walk_states_are_refused_and_the_worlds_data_is_read_only(
    both: tuple[Kernels, Kernels],
) -> None:
    """Shapes the compiled code would read or write past: ValueError by name; the world's data is frozen."""
    built = both[0]
    robot = Cabin8()
    world = CollisionWorld(robot, None, None)
    d = world._kernel
    q = robot.joints_from_drives(robot.home_drives).astype(float)
    b, m = len(world.names), len(d.c_lo)
    cases = [
        (lambda: built.packed_check(q[:7].copy(), d, 0.01, 0.01, -1.0), "q"),  # 7 of 8 joints
        (lambda: built.packed_state(np.append(q, 0.0), d, 0.07), "q"),
        (lambda: built.packed_poses(q[None, :], d, np.empty((1, 2, 13)), np.empty((1, m))), "poses"),
        (lambda: built.packed_poses(q[None, :], d, np.empty((1, b, 13)), np.empty((1, 1))), "c"),
        (lambda: built.cover_centres_batch(np.empty((1, 2, 13)), d.fine), "poses"),
        (lambda: built.segment_reach(d, 1.0, 0.2, np.ones(3)), "adq"),
        (lambda: built.run_extent(np.stack([q, q]), 0, 2, np.ones(8), 0.1), "run_extent"),
        (lambda: built.run_extent(np.stack([q, q]), 0, 1, np.ones(7), 0.1), "rho"),
        (lambda: built.first_inadmissible(q, 0.0 * q, 0, d), "first_inadmissible"),
    ]
    _, with_obstacles = _obstacle_world("aisle-transfer")
    assert with_obstacles.obstacles is not None
    od, n_o = with_obstacles.obstacles.kernel_data, len(with_obstacles.names)
    at = np.zeros((2, n_o, 13))
    one = np.zeros(1, dtype=np.int64)
    cases += [
        (lambda: built.obstacle_bounds(at[0, :-1].copy(), od, np.zeros(n_o)), "poses"),  # a body short
        (lambda: built.obstacle_bounds(at[0], od, np.zeros(n_o + 1)), "threshold"),
        (lambda: built.obstacle_coarse_batch(np.zeros((2, 3, 13)), od, True), "poses"),
        (lambda: built.obstacle_fine_batch(at, one + 2, 0, od), "obstacle_fine_batch"),  # no sample 2
        (lambda: built.obstacle_fine_batch(at, one, n_o, od), "obstacle_fine_batch"),  # no body n_o
    ]
    for arr in (od.fbuf, od.ibuf):
        assert not arr.flags.writeable
    for call, name in cases:
        with pytest.raises(ValueError, match=f"^{name}: "):
            call()
    for arr in (d.fbuf, d.ibuf, d.grid, d.rho, d.pair_a, d.fine.body, d.fine.local):
        assert not arr.flags.writeable
    with pytest.raises(ValueError, match="read-only"):
        d.ibuf[0] = 100  # a count the kernels trust
    # A motion walk whose bookkeeping does not fit its store is refused before it resumes.
    n = 4
    ci, cf = np.zeros(codes.CI_SIZE, dtype=np.int64), np.zeros(codes.CF_SIZE)
    ci[codes.CI_N] = n
    slot_of = np.full(n + 1, -1, dtype=np.int64)
    store = np.empty((2, b, 13)), np.empty((2, b)), np.empty((2, len(d.pair_a)))
    reach, pair_reach = np.zeros(b), np.zeros(len(d.pair_a))
    for bad in ("slots", "count", "slot"):
        c_i, s_o = ci.copy(), slot_of.copy()
        if bad == "slots":
            s_o = np.full(n, -1, dtype=np.int64)
        elif bad == "count":
            c_i[codes.CI_COUNT] = 3  # more states than the store holds
        else:
            s_o[1] = 1  # a slot the walk never filled
        with pytest.raises(ValueError, match="^(slot_of|motion_walk): "):
            built.motion_walk(c_i, cf.copy(), q, q, 0.0 * q, reach, pair_reach, d, s_o, *store)


def test_the_build_is_compiled_with_the_kernels_error_model(both: tuple[Kernels, Kernels]) -> None:
    """An entry's own arithmetic follows its kernel's options (numpy's error model), as the JIT's does.

    Called on the raw entries (the wrapper refuses n_fine = 0): the division by zero in the entry's own
    body gives inf and the same answer on both, where an entry compiled with pycc's defaults raised
    ZeroDivisionError.
    """
    built, jit = (k.module for k in both)
    world = CollisionWorld(Cabin8(), None, None)
    d = world._kernel
    q = world.robot.joints_from_drives(world.robot.home_drives).astype(float)
    got = built.first_inadmissible(q, 0.0 * q, 0, d.fbuf, d.ibuf)
    assert got == jit.first_inadmissible(q, 0.0 * q, 0, d.fbuf, d.ibuf)


def test_a_killed_build_leaves_no_marker_and_an_old_marker_is_retried(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Only a build that exits with an error marks its key; a marker older than a day is tried again."""
    monkeypatch.setenv("CABINPLAN_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv("CABINPLAN_KERNELS", raising=False)
    (tmp_path / "killed_builder.py").write_text("import os, signal\nos.kill(os.getpid(), signal.SIGKILL)\n")
    monkeypatch.setenv("PYTHONPATH", str(tmp_path))
    killed = _toy(tmp_path, "killed_builder")
    assert aot.kernels(killed) is aot.jit_kernels(killed)
    lib = aot.path(killed)
    assert lib is not None and not lib.exists()
    assert not lib.with_name(lib.name + ".failed").exists()  # the next process tries again
    failing = _toy(tmp_path, "planner.nowhere")
    assert aot.kernels(failing) is aot.jit_kernels(failing)
    lib = aot.path(failing)
    assert lib is not None
    marker = lib.with_name(lib.name + ".failed")
    assert marker.read_text().startswith("exit code 1 at ")
    old = time.time() - aot.FAILED_RETRY_S - 60.0
    os.utime(marker, (old, old))
    assert aot.kernels(failing) is aot.jit_kernels(failing)  # tried again, failed again
    assert marker.stat().st_mtime > old + 3600.0


def test_a_build_that_does_not_load_is_set_aside_and_built_again(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("CABINPLAN_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv("CABINPLAN_KERNELS", raising=False)
    lib = aot.path(acc_reference.EXTENSION)
    assert lib is not None
    lib.parent.mkdir(parents=True)
    lib.write_bytes(b"not an extension module")
    stale = lib.parent / f"{acc_reference.EXTENSION.name}-build-left-by-a-killed-build"
    stale.mkdir()
    os.utime(stale, (time.time() - 3600.0, time.time() - 3600.0))
    module = aot.kernels(acc_reference.EXTENSION)
    assert module.__file__ == str(lib)
    assert lib.with_name(lib.name + ".bad").read_bytes() == b"not an extension module"
    assert not stale.exists()
