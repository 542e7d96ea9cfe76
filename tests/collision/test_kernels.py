"""Compiled hot path against its references: closed-form poses vs CasADi, kernels vs the reference route.

The compiled route (numba poses, packed kernels, the motion walk in compiled code) must give the reference
route's numbers and verdicts -- exactly, report for report -- on hundreds of random cases.
"""

from __future__ import annotations

import fcl
import numpy as np
import pytest

from planner.collision.bodies import PayloadGeometry
from planner.collision.kernels import bounds, codes, state, walk
from planner.collision.kernels.packed import unpack
from planner.collision.oracle import ReferenceWorld
from planner.collision.world import CollisionWorld
from planner.core.exceptions import InvalidInput
from planner.meshes import REFERENCE_DIR
from planner.meshio import load_mesh
from planner.robots.cabin8 import Cabin8
from planner.robots.kernels import body_poses
from tests.conftest import admissible_joints

MESHES = REFERENCE_DIR


@pytest.fixture(scope="module")
def payload() -> PayloadGeometry:
    grasp = np.eye(4)
    grasp[:3, :3] = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # not the identity
    grasp[:3, 3] = [0.02, -0.01, 0.30]
    return PayloadGeometry((0.45, 0.35, 0.50), T_tool_payload=grasp, mass=100.0)


@pytest.fixture(scope="module")
def worlds(robot: Cabin8, payload: PayloadGeometry) -> tuple[CollisionWorld, ReferenceWorld]:
    mesh = load_mesh(MESHES / "cabin-cluttered.stl", units="m")
    return CollisionWorld(robot, mesh, payload), ReferenceWorld(robot, mesh, payload)


def along_rail(robot: Cabin8, n: int, seed: int) -> np.ndarray:
    qs = admissible_joints(robot, n, seed=seed)
    qs[:, 0] = np.random.default_rng(seed).uniform(0.0, 6.0, n)
    return qs


def test_closed_form_poses_equal_the_casadi_model(robot: Cabin8, worlds: tuple[CollisionWorld, ...]) -> None:
    """Body poses and c(q) from the numba kernel equal the CasADi pose function to 1e-12, off-limits too."""
    world = worlds[0]
    qs = along_rail(robot, 200, seed=11)
    wild = qs + np.random.default_rng(12).normal(0.0, 0.3, qs.shape)  # inadmissible, some links unreachable
    u = unpack(world._kernel.fbuf, world._kernel.ibuf)
    for q in np.vstack([qs, wild]):
        ref_poses, ref_c = world._evaluate(q)
        poses, c = np.empty((len(world.names), 13)), np.empty(len(u.c_lo))
        body_poses(u.kernel, q, u.T_tool_box, u.params, u.kinds, poses, c)
        finite = np.isfinite(ref_c[0])
        np.testing.assert_array_equal(np.isfinite(c), finite)  # NaN exactly where a link cannot close
        np.testing.assert_allclose(c[finite], ref_c[0][finite], rtol=0, atol=1e-12)
        if finite.all():
            np.testing.assert_allclose(poses, ref_poses[0], rtol=0, atol=1e-12)


def test_batched_poses_equal_the_casadi_batch(robot: Cabin8, worlds: tuple[CollisionWorld, ...]) -> None:
    """The batched closed-form poses (compiled route) equal CasADi's batch call (reference route)."""
    fast, ref = worlds
    qs = along_rail(robot, 300, seed=13)
    poses, c = fast._evaluate(qs)
    ref_poses, ref_c = ref._evaluate(qs)
    assert poses.shape == ref_poses.shape and c.shape == ref_c.shape
    np.testing.assert_allclose(c, ref_c, rtol=0, atol=1e-12)
    np.testing.assert_allclose(poses, ref_poses, rtol=0, atol=1e-12)
    np.testing.assert_allclose(fast.cover_centres(qs), ref.cover_centres(qs), rtol=0, atol=1e-12)


def test_cover_extents_are_numpys_maxima_of_the_cover_centres_bit_for_bit(
    worlds: tuple[CollisionWorld, ...],
) -> None:
    """The compiled extents (transit's compactness ranking) are numpy's on the centres, NaN included."""
    fast, _ = worlds
    rng = np.random.default_rng(5)
    qs = admissible_joints(fast.robot, 500, seed=5)
    wild = qs + rng.normal(0.0, 0.5, qs.shape)  # off-limits: some stage links cannot close (NaN poses)
    wild[::7] = np.nan
    for q in (qs, wild):
        centres = fast.cover_centres(q)
        r = fast._kernel.fine.radii[None, :]
        lateral = np.max(np.abs(centres[:, :, 0]) + r, axis=1)
        height = np.max(centres[:, :, 1] + r, axis=1)
        got = fast.cover_extents(q)
        assert got[:, 0].tobytes() == lateral.tobytes() and got[:, 1].tobytes() == height.tobytes()
    assert np.isnan(got).any() and np.isfinite(got).any()


def test_packed_states_equal_the_reference_route(robot: Cabin8, worlds: tuple[CollisionWorld, ...]) -> None:
    fast, ref = worlds
    for threshold in (0.005, 0.065):
        for q in along_rail(robot, 150, seed=21):
            a, b = fast._state(q, threshold), ref._state(q, threshold)
            np.testing.assert_allclose(a.flat, b.flat, rtol=0, atol=1e-12)
            np.testing.assert_allclose(a.cabin_lb, b.cabin_lb, rtol=0, atol=1e-12)
            np.testing.assert_allclose(a.pair_lb, b.pair_lb, rtol=0, atol=1e-12)
            assert a.admissible == b.admissible


def test_one_call_state_verdicts_are_the_python_probes_verdicts(worlds: tuple[CollisionWorld, ...]) -> None:
    """packed_valid (is_valid's one compiled call) = packed_check and then the world's probes, in Python.

    On the states the bounds leave undecided (the ones the call probes itself): the same verdict, and as
    many probes counted (the world's query figure).
    """
    from planner.collision.kernels import codes
    from planner.collision.reports import BodyState

    fast, _ = worlds
    d, probes = fast._kernel, fast._probes
    rng = np.random.default_rng(11)
    qs = admissible_joints(fast.robot, 3000, seed=11)
    qs[:, 0] = rng.uniform(fast.robot.limits.lower[0], fast.robot.limits.upper[0], len(qs))
    undecided = verdicts = 0
    for q in qs:
        for clearance in (0.005, 0.03):
            own = fast.self_clearance
            code, flat, cabin, pairs = fast.kernels.packed_check(q, d, clearance, own, d.upper_slack)
            if code != codes.UNDECIDED:
                continue
            undecided += 1
            before = probes.queries
            st = BodyState(flat, cabin, pairs, True)
            expected = not any(
                lb <= clearance and probes.cabin_hit(st, b, clearance) for b, lb in enumerate(cabin.tolist())
            ) and not any(lb <= own and probes.pair_hit(st, k, own) for k, lb in enumerate(pairs.tolist()))
            asked = probes.queries - before
            verdict, poses, n = fast.kernels.packed_valid(q, d, clearance, own, d.upper_slack)
            assert verdict == (codes.STATE_VALID if expected else codes.STATE_INVALID)
            assert n == asked and poses.tobytes() == flat.tobytes()
            verdicts += expected
    assert undecided > 100 and 0 < verdicts < undecided, (undecided, verdicts)


def test_state_verdicts_equal_the_reference_route(robot: Cabin8, worlds: tuple[CollisionWorld, ...]) -> None:
    """is_valid (bool fast path) and check_state agree with the reference on valid and colliding states."""
    fast, ref = worlds
    qs = along_rail(robot, 200, seed=31)
    qs[::7, 6] += 0.8  # some beyond the d5 limit
    verdicts = []
    for q in qs:
        for clearance in (0.0, 0.01, 0.05):
            expected = ref.check_state(q, clearance, all_contacts=True)
            assert fast.check_state(q, clearance, all_contacts=True) == expected
            assert fast.is_valid(q, clearance) == expected.valid
            verdicts.append(expected.valid)
    assert 0.2 < np.mean(verdicts) < 0.9  # both outcomes are well represented
    assert not fast.is_valid(np.full(8, np.nan)) and not fast.check_state(np.full(8, np.inf)).valid
    with pytest.raises(InvalidInput):
        fast.is_valid(np.zeros(7))
    frozen = qs[:2].copy()
    frozen.flags.writeable = False  # read-only inputs (e.g. from buffers) work like any other
    assert fast.is_valid(frozen[0]) == ref.is_valid(frozen[0])
    assert fast.check_motion(frozen[0], frozen[1]).valid == ref.check_motion(frozen[0], frozen[1]).valid


@pytest.mark.parametrize("probe_when_proven", [False, True])
def test_motion_reports_equal_the_reference_walk(
    robot: Cabin8, worlds: tuple[CollisionWorld, ...], probe_when_proven: bool
) -> None:
    """Compiled and Python walks, either probe policy: the same report, field for field."""
    fast, ref = worlds
    rng = np.random.default_rng(41)
    starts = [q for q in along_rail(robot, 120, seed=41) if ref.is_valid(q)]
    reports = []
    saved = (fast.probe_when_proven, ref.probe_when_proven)
    fast.probe_when_proven = ref.probe_when_proven = probe_when_proven
    try:
        for k, q in enumerate(starts):
            step = rng.normal(size=8)
            step *= (0.15 if k % 3 else 0.8) / np.linalg.norm(step)  # typical edges and long ones
            for clearance, margin in ((0.01, 0.005), (0.03, 0.002)):
                expected = ref.check_motion(q, q + step, clearance, margin)
                assert fast.check_motion(q, q + step, clearance, margin) == expected
                reports.append(expected)
    finally:
        fast.probe_when_proven, ref.probe_when_proven = saved
    assert len(reports) > 80
    assert {r.valid for r in reports} == {True, False}
    assert any(r.contacts and r.contacts[0].kind == "limit" for r in reports)
    assert any(r.contacts and r.contacts[0].kind in ("cabin", "self") for r in reports)
    assert max(r.states_checked for r in reports) > 32  # the state store had to grow


@pytest.mark.parametrize("probe_when_proven", [False, True])
def test_adaptive_motion_reports_equal_the_reference_walk(
    robot: Cabin8, worlds: tuple[CollisionWorld, ...], probe_when_proven: bool
) -> None:
    """With a smaller ``min_margin`` (halved near tight states): the same report, field for field."""
    fast, ref = worlds
    rng = np.random.default_rng(47)
    starts = [q for q in along_rail(robot, 120, seed=47) if ref.is_valid(q, 0.03)]
    adapted = 0
    saved = (fast.probe_when_proven, ref.probe_when_proven)
    fast.probe_when_proven = ref.probe_when_proven = probe_when_proven
    try:
        for k, q in enumerate(starts):
            step = rng.normal(size=8)
            step *= (0.15 if k % 3 else 0.8) / np.linalg.norm(step)
            for clearance, margin in ((0.01, 0.005), (0.03, 0.008)):
                expected = ref.check_motion(q, q + step, clearance, margin, min_margin=0.0005)
                assert fast.check_motion(q, q + step, clearance, margin, min_margin=0.0005) == expected
                adapted += expected.valid and not fast.check_motion(q, q + step, clearance, margin).valid
    finally:
        fast.probe_when_proven, ref.probe_when_proven = saved
    assert adapted > 0  # some motions only the adaptive walk certifies


def test_an_adaptive_walk_certifies_only_what_keeps_the_clearance(
    robot: Cabin8, worlds: tuple[CollisionWorld, ...]
) -> None:
    """Motions only the adaptive walk certifies keep the clearance at 400 states each (exact distances)."""
    fast = worlds[0]
    rng = np.random.default_rng(53)
    clearance, checked = 0.03, 0
    for q in [q for q in along_rail(robot, 1500, seed=53) if fast.is_valid(q, clearance)]:
        step = rng.normal(size=8)
        step *= 0.3 / np.linalg.norm(step)
        rep = fast.check_motion(q, q + step, clearance, 0.008, min_margin=0.0005)
        if not rep.valid or fast.check_motion(q, q + step, clearance, 0.008).valid:
            continue
        for t in np.linspace(0.0, 1.0, 400):
            assert fast.min_distance(q + t * step, include_self=False).distance_m >= clearance - 1e-9
            closest = fast.min_distance(q + t * step, include_self=True)  # a pair's, or the cabin's again
            need = clearance if fast.is_environment(closest.bodies[1]) else fast.self_clearance
            assert closest.distance_m >= need - 1e-9
        checked += 1
        if checked == 4:
            break
    assert checked == 4, "too few motions needed the adaptive margin"


def test_default_probe_policy_certifies_as_much_with_fewer_queries(
    robot: Cabin8, worlds: tuple[CollisionWorld, ...]
) -> None:
    """Probing only where the bounds prove nothing: the same verdicts here, fewer FCL queries."""
    fast, ref = worlds
    assert not fast.probe_when_proven and ref.probe_when_proven
    rng = np.random.default_rng(43)
    queries = [0, 0]
    for q in [q for q in along_rail(robot, 120, seed=43) if ref.is_valid(q)]:
        step = rng.normal(size=8)
        step *= 0.15 / np.linalg.norm(step)
        a, b = fast.check_motion(q, q + step), ref.check_motion(q, q + step)
        assert a.valid == b.valid
        queries[0] += a.fcl_queries
        queries[1] += b.fcl_queries
    assert queries[0] < 0.75 * queries[1]


def test_self_only_world_motion_equals_the_reference(robot: Cabin8, payload: PayloadGeometry) -> None:
    fast, ref = CollisionWorld(robot, None, payload), ReferenceWorld(robot, None, payload)
    fast.probe_when_proven = True  # the reference walk's policy (pairs: the bounds decide the probes)
    rng = np.random.default_rng(51)
    for q in admissible_joints(robot, 40, seed=51):
        step = rng.normal(size=8) * 0.4
        assert fast.check_motion(q, q + step) == ref.check_motion(q, q + step)


def test_clearance_grid_upper_bound(worlds: tuple[CollisionWorld, ...]) -> None:
    """Inside the grid, distance <= LB + upper_slack (exact point distances by FCL)."""
    world = worlds[0]
    grid, cabin = world._grid, world._probes.cabin_obj
    assert grid is not None and cabin is not None and world.cabin is not None
    rng = np.random.default_rng(2)
    pts = rng.uniform(
        world.cabin.vertices.min(axis=0) - 0.2, world.cabin.vertices.max(axis=0) + 0.2, (400, 3)
    )
    req = fcl.DistanceRequest()
    exact = np.array(
        [fcl.distance(fcl.CollisionObject(fcl.Sphere(1e-9), fcl.Transform(p)), cabin, req) for p in pts]
    )
    lb = grid.query(pts)
    inside = np.isfinite(lb)
    assert inside.mean() > 0.9
    assert np.all(lb[inside] <= exact[inside] + 1e-9)
    assert np.all(exact[inside] <= lb[inside] + grid.upper_slack + 1e-9)


def test_certain_contacts_are_real(robot: Cabin8, worlds: tuple[CollisionWorld, ...]) -> None:
    """Every body the kernel calls certainly in contact collides in FCL (grown by the clearance)."""
    world = worlds[0]
    cabin = world._probes.cabin_obj
    assert cabin is not None
    data = world._kernel
    found = 0
    for q in along_rail(robot, 200, seed=61):
        for clearance in (0.0, 0.01, 0.05):
            code, flat, _, _ = state.packed_check(
                q, data.fbuf, data.ibuf, data.grid, clearance, world.self_clearance, data.upper_slack
            )
            R, p, lengths = world.poses(q)
            for b in range(len(world.names)):
                if bounds.certain_cabin_contact(
                    b, flat, clearance, data.fbuf, data.ibuf, data.grid, data.upper_slack
                ):
                    found += 1
                    o = world._probes.object(b, R[0, b], p[0, b], lengths[0, b], clearance)
                    assert fcl.collide(o, cabin, fcl.CollisionRequest(), fcl.CollisionResult()) > 0
            if code == state.CONTACT:
                assert not worlds[1].is_valid(q, clearance)
    assert found > 20  # the test recognises a good share of the contacts


def test_worlds_of_one_model_share_its_pose_function_but_not_their_payloads(robot: Cabin8) -> None:
    """Two payloads on one robot model: one compiled pose function, each world its own payload's poses."""
    small = PayloadGeometry((0.2, 0.2, 0.2), T_tool_payload=np.eye(4), mass=10.0)
    grasp = np.eye(4)
    grasp[:3, 3] = [0.0, 0.0, 0.4]
    large = PayloadGeometry((0.5, 0.4, 0.6), T_tool_payload=grasp, mass=80.0)
    a_ref, b_ref = (ReferenceWorld(robot, None, p) for p in (small, large))
    a, b = (CollisionWorld(robot, None, p) for p in (small, large))
    assert a_ref._pose_fn is b_ref._pose_fn is a._pose_fn
    for q in along_rail(robot, 20, seed=41):  # interleaved: the shared buffers must not carry a payload over
        for ref, fast in ((a_ref, a), (b_ref, b)):
            np.testing.assert_allclose(
                ref._state(q, 0.06).flat, fast._state(q, 0.06).flat, rtol=0, atol=1e-12
            )


def test_run_extent_is_the_halving_rule_of_check_path() -> None:
    """The compiled run rule equals the numpy one: halve until the reach-weighted chord deviation fits."""
    rng = np.random.default_rng(51)
    rho = rng.uniform(0.2, 2.0, 8)
    for trial in range(200):
        n = int(rng.integers(2, 300))
        qs = np.cumsum(rng.normal(0.0, 10.0 ** rng.uniform(-5, -2), (n, 8)), axis=0)
        i = int(rng.integers(0, n - 1))
        j0 = int(min(n - 1, i + rng.integers(1, 200)))
        max_extra = float(10.0 ** rng.uniform(-4, -1))
        j, extra = j0, 0.0
        while j > i + 1:  # the reference: numpy, as check_path had it
            t = np.linspace(0.0, 1.0, j - i + 1)[:, None]
            e = np.max(np.abs(qs[i : j + 1] - (qs[i] + t * (qs[j] - qs[i]))), axis=0)
            extra = float(rho @ e) * 2.0 + 1e-6
            if extra <= max_extra:
                break
            j, extra = i + max(1, (j - i) // 2), 0.0
        got_j, got_extra = walk.run_extent(qs, i, j0, rho, max_extra)
        assert got_j == j, trial
        assert got_extra == pytest.approx(extra, rel=1e-9, abs=1e-15)


def _first_invalid_state_by_state(world: CollisionWorld, q: np.ndarray, values: np.ndarray, c: float) -> int:
    """The reference: is_valid on each copy of q with its rail position set, in order, to the first fail."""
    for i, x in enumerate(values):
        s = q.copy()
        s[0] = x
        if not world.is_valid(s, c):
            return i
    return -1


def test_a_rail_sweep_in_one_call_is_is_valid_state_by_state(
    robot: Cabin8, payload: PayloadGeometry, worlds: tuple[CollisionWorld, ...]
) -> None:
    """first_invalid_on_axis (transit's sweep along the rail) = is_valid on each state: index, checks, probes.

    In the cluttered cabin (the compiled sweep), with an extra obstacle (checked state by state in Python)
    and on the reference route (no compiled tests); sweeps that pass whole and that fail early and late.
    """
    from planner.collision.obstacles import Obstacle

    fast, ref = worlds
    T = np.eye(4)
    T[:3, 3] = [3.0, 0.6, 0.4]
    mesh = fast.cabin
    boxed = CollisionWorld(robot, mesh, payload, obstacles=(Obstacle.box("unit X", (0.3, 0.3, 0.3), T),))
    rng = np.random.default_rng(17)
    postures = admissible_joints(robot, 120, seed=17)
    outcomes = set()
    for world in (fast, boxed, ref):
        for k, q in enumerate(postures):
            values = np.sort(rng.uniform(0.0, 6.0, 12))[:: 1 if k % 2 else -1]
            for c in (0.005, 0.03):
                before = world._probes.queries
                expected = _first_invalid_state_by_state(world, q, values, c)
                asked = world._probes.queries - before
                before = world._probes.queries
                got = world.first_invalid_on_axis(q, 0, values, c)
                assert got == (expected, len(values) if expected < 0 else expected + 1)
                assert world._probes.queries - before == asked
                outcomes.add("all" if expected < 0 else "first" if expected == 0 else "later")
    assert outcomes == {"all", "first", "later"}
    with pytest.raises(InvalidInput, match="axis"):
        fast.first_invalid_on_axis(postures[0], 8, np.zeros(3))
    with pytest.raises(InvalidInput, match="values"):
        fast.first_invalid_on_axis(postures[0], 0, np.zeros((3, 2)))
    assert fast.first_invalid_on_axis(postures[0], 0, np.zeros(0)) == (-1, 0)


def test_a_sweeps_states_after_the_pairs_are_settled_get_packed_valids_verdicts(
    worlds: tuple[CollisionWorld, ...],
) -> None:
    """The rail sweep's shortcut (cabin part only, once every pair is clear by PAIR_SETTLED_M) = packed_valid.

    On states whose pair bounds are all that far above the self-clearance (the only ones it is used on):
    the same verdict and probe count, valid and invalid, probed and not, both seen.
    """
    fast, _ = worlds
    d = fast._kernel
    u = unpack(d.fbuf, d.ibuf)
    own = fast.self_clearance
    qs = along_rail(fast.robot, 1500, seed=23)
    poses, c = np.empty((len(fast.names), 13)), np.empty(len(u.c_lo))
    seen = set()
    for q in qs:
        for clearance in (0.005, 0.03):
            code, _, _, pairs = state.packed_check(q, d.fbuf, d.ibuf, d.grid, clearance, own, d.upper_slack)
            if code == codes.NOT_FINITE or not np.all(pairs > own + state.PAIR_SETTLED_M):
                continue
            expected, _, probes = state.packed_valid(
                q, d.fbuf, d.ibuf, d.grid, *d.tree, clearance, own, d.upper_slack
            )
            got = state._settled_verdict(
                q, u, d.fbuf, d.ibuf, d.grid, *d.tree, clearance, d.upper_slack, poses, c
            )
            assert got == (expected, probes)
            seen.add((expected, probes > 0))
    assert {(codes.STATE_VALID, False), (codes.STATE_INVALID, False), (codes.STATE_VALID, True)} <= seen, seen
