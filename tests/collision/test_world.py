"""Collision world: known answers, pruning never changes a verdict, certified motion beats sampling."""

from __future__ import annotations

import io
import json
from pathlib import Path

import fcl
import numpy as np
import pytest
import trimesh

from planner.collision.bodies import PayloadGeometry
from planner.collision.clearance_grid import ClearanceGrid, surface_samples
from planner.collision.oracle import ReferenceWorld
from planner.collision.world import CollisionWorld
from planner.core.exceptions import InvalidInput
from planner.meshes import REFERENCE_DIR
from planner.meshio import LoadedMesh, load_mesh
from planner.redundancy.ik import IKOptions, family_candidates
from planner.robots.cabin8 import Cabin8
from planner.robots.cabin8_geometry import ADJACENT
from tests.conftest import admissible_joints

MESHES = REFERENCE_DIR


def mesh_of(*parts: trimesh.Trimesh) -> LoadedMesh:
    data = trimesh.util.concatenate(parts).export(file_type="stl")
    return load_mesh(io.BytesIO(data).getvalue(), units="m", name="test.stl")


def box_at(extents: tuple[float, float, float], centre: tuple[float, float, float]) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=extents, transform=trimesh.transformations.translation_matrix(centre))


@pytest.fixture(scope="module")
def payload() -> PayloadGeometry:
    grasp = np.eye(4)
    grasp[2, 3] = 0.30
    return PayloadGeometry((0.45, 0.35, 0.50), T_tool_payload=grasp, mass=100.0)


@pytest.fixture(scope="module")
def aisle(robot: Cabin8, payload: PayloadGeometry) -> CollisionWorld:
    return CollisionWorld(robot, load_mesh(MESHES / "cabin-aisle.stl", units="m"), payload)


def home(robot: Cabin8, **changes: float) -> np.ndarray:
    q = robot.joints_from_drives(robot.home_drives)
    names = list(robot.joint_names)
    for k, v in changes.items():
        q[names.index(k)] = v
    return q


def test_box_vs_plane_known_distance(robot: Cabin8) -> None:
    """The carriage's underside is at y = -0.12: a floor plate at y = -0.50 is 0.38 m away."""
    floor = box_at((4.0, 0.01, 8.0), (0.0, -0.505, 3.0))
    world = CollisionWorld(robot, mesh_of(floor))
    q = home(robot, d1=3.0)
    d = world.min_distance(q, include_self=False)
    assert d.bodies == ("carriage", "cabin")
    assert d.distance_m == pytest.approx(0.38, abs=1e-6)
    assert d.point_a[1] == pytest.approx(-0.12, abs=1e-6) and d.point_b[1] == pytest.approx(-0.50, abs=1e-6)
    assert world.is_valid(q, clearance=0.37) and not world.is_valid(q, clearance=0.39)


def test_capsule_vs_box_known_distance(robot: Cabin8) -> None:
    """A block 5 cm beside the column capsule (r 0.07) along the rail: nearest body, distance, witnesses."""
    q = home(robot, d1=3.0, theta3=0.0)
    T2 = robot.frames(q[None, :])[0, 2]
    x, y = T2[0, 3], T2[1, 3]
    # Block face at z = d1 + 0.12; above the platform's top face (y + 0.04) by 0.06, below the arm.
    block = box_at((0.10, 0.08, 0.10), (x, y + 0.14, 3.0 + 0.12 + 0.05))
    world = CollisionWorld(robot, mesh_of(block))
    d = world.min_distance(q, include_self=False)
    assert d.bodies == ("column", "cabin")
    assert d.distance_m == pytest.approx(0.05, abs=1e-5)
    assert d.point_b[2] == pytest.approx(3.12, abs=1e-5)
    assert d.point_a[2] == pytest.approx(3.07, abs=1e-4)
    assert world.is_valid(q, 0.045) and not world.is_valid(q, 0.055)


def test_pruning_never_changes_a_verdict(robot: Cabin8, aisle: CollisionWorld) -> None:
    """is_valid agrees with brute force (every body and pair through FCL, grown, no bounds)."""
    qs = admissible_joints(robot, 150, seed=31)
    qs[:, 0] = np.random.default_rng(3).uniform(0.0, 6.0, len(qs))
    verdicts = []
    for q in qs:
        for clearance in (0.0, 0.01, 0.05):
            verdicts.append(aisle.is_valid(q, clearance) == brute_force_valid(aisle, q, clearance))
    assert all(verdicts)


def brute_force_valid(world: CollisionWorld, q: np.ndarray, clearance: float) -> bool:
    R, p, lengths = world.poses(q)
    req = fcl.CollisionRequest()
    for b in range(len(world.names)):
        o = world._probes.object(b, R[0, b], p[0, b], lengths[0, b], clearance)
        if world._probes.cabin_obj is not None and fcl.collide(
            o, world._probes.cabin_obj, req, fcl.CollisionResult()
        ):
            return False
    for a, b in world.bodies.pairs:
        oa = world._probes.object(a, R[0, a], p[0, a], lengths[0, a], world.self_clearance / 2)
        ob = world._probes.object(b, R[0, b], p[0, b], lengths[0, b], world.self_clearance / 2)
        if fcl.collide(oa, ob, req, fcl.CollisionResult()):
            return False
    return True


def test_self_collision_pairs_are_non_adjacent_and_found(robot: Cabin8, payload: PayloadGeometry) -> None:
    world = CollisionWorld(robot, None, payload)
    for a, b in world.bodies.pairs:
        assert frozenset((world.names[a], world.names[b])) not in ADJACENT
    assert ("slide", "payload") not in [(world.names[a], world.names[b]) for a, b in world.bodies.pairs]
    # Fold the payload back onto the platform: a self contact, reported with the pair.
    folded = home(robot, theta4=-1.45, d5=-0.5, theta3=0.0)
    report = world.check_state(folded, 0.01, all_contacts=True)
    assert not report.valid
    pairs = {c.bodies for c in report.contacts if c.kind == "self"}
    assert pairs and all(len(p) == 2 for p in pairs)
    assert world.is_valid(home(robot))


def test_limits_are_part_of_validity(robot: Cabin8, aisle: CollisionWorld) -> None:
    q = home(robot, d1=3.0)
    q[2] = 0.40  # platform above its range
    report = aisle.check_state(q)
    assert not report.valid and report.contacts[0].kind == "limit"
    with pytest.raises(InvalidInput):
        aisle.check_state(home(robot), clearance=-0.1)


def test_clearance_grid_is_a_lower_bound(aisle: CollisionWorld) -> None:
    grid = aisle._grid
    assert grid is not None and aisle._probes.cabin_obj is not None
    rng = np.random.default_rng(1)
    lo = aisle.cabin.vertices.min(axis=0) - 0.3  # type: ignore[union-attr]
    hi = aisle.cabin.vertices.max(axis=0) + 0.3  # type: ignore[union-attr]
    pts = rng.uniform(lo, hi, (400, 3))
    req = fcl.DistanceRequest()
    exact = np.array(
        [
            fcl.distance(
                fcl.CollisionObject(fcl.Sphere(1e-9), fcl.Transform(p)),
                aisle._probes.cabin_obj,
                req,
                fcl.DistanceResult(),
            )
            for p in pts
        ]
    )
    bound = grid.query(pts)
    assert np.all(bound <= exact + 1e-9)
    assert np.median(exact - bound) < 0.12, "the bound is useful, not just valid"


def test_surface_samples_cover_the_surface() -> None:
    mesh = trimesh.creation.icosphere(subdivisions=1, radius=1.0)
    sliver = trimesh.Trimesh([[0, 0, 0], [6, 0, 0], [0, 0.05, 0]], [[0, 1, 2]])
    for m in (mesh, sliver):
        s = surface_samples(np.asarray(m.vertices), np.asarray(m.faces, dtype=np.int64), 0.05)
        pts, _ = trimesh.sample.sample_surface(m, 3000, seed=0)
        gap = (
            np.min(np.linalg.norm(pts[:, None, :] - s[None, ::1, :], axis=2), axis=1)
            if len(s) < 5000
            else None
        )
        if gap is not None:
            assert gap.max() <= 2 * 0.05


def _reference_grid(vertices: np.ndarray, faces: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """(marked nodes, distance to the nearest one [m]) as numpy and scipy compute them.

    The samples held in memory, then ``scipy.ndimage.distance_transform_edt``: the construction the compiled
    one replaced.
    """
    from scipy import ndimage

    lo = vertices.min(axis=0) - 0.5
    shape = tuple(int(n) for n in np.ceil((vertices.max(axis=0) + 0.5 - lo) / step).astype(int) + 1)
    samples = surface_samples(vertices, faces, 0.015)
    idx = np.clip(np.rint((samples - lo) / step).astype(np.int64), 0, np.array(shape) - 1)
    free = np.ones(shape, dtype=bool)
    free[idx[:, 0], idx[:, 1], idx[:, 2]] = False
    return ~free, ndimage.distance_transform_edt(free, sampling=step)


def test_the_compiled_grid_is_the_sampled_surfaces_exact_distance_transform() -> None:
    """The same nodes marked as numpy's samples mark, the same distances as scipy's transform (to 1e-12 m).

    On a generated ring-frame cabin and a suite cabin at two steps, and on masks with empty lines, one
    marked node and every node marked.
    """
    from scipy import ndimage

    from planner.collision.kernels.entries import DEFAULT
    from planner.generate import GeneratorOptions, generate_case
    from planner.generate.cabins import cabin_mesh

    case = generate_case(3, 0, GeneratorOptions(family="ring-frame"))
    cabins = [cabin_mesh(case.layout), load_mesh(REFERENCE_DIR / "cabin-hatch.stl", units="m")]
    for cabin, step in zip(cabins, (0.05, 0.03), strict=True):
        v = np.ascontiguousarray(cabin.vertices, dtype=float)
        f = np.ascontiguousarray(cabin.faces, dtype=np.int64)
        grid = ClearanceGrid.build(v, f, step=step)
        marked, dist = _reference_grid(v, f, step)
        lo = v.min(axis=0) - 0.5
        ours = np.zeros(marked.shape, dtype=bool)
        DEFAULT.grid_marks(v, f, lo, step, 0.015, ours)
        assert np.array_equal(ours, marked)
        offset = step * np.sqrt(3.0) + 2 * 0.015
        inner = grid.lower_bound[1:-1, 1:-1, 1:-1]
        assert np.max(np.abs(inner - (dist - offset))) < 1e-12
        assert np.all(grid.lower_bound[[0, -1]] == -np.inf) and np.all(
            grid.lower_bound[:, :, [0, -1]] == -np.inf
        )
        assert np.allclose(grid.origin, lo - step, rtol=0.0, atol=1e-15)
    rng = np.random.default_rng(5)
    masks = [rng.random((9, 13, 7)) < p for p in (0.02, 0.3)]
    one = np.zeros((6, 1, 11), dtype=bool)
    one[4, 0, 2] = True
    masks += [one, np.ones((3, 4, 5), dtype=bool)]
    for mask in masks:
        out = DEFAULT.grid_bounds(mask, 0.1, 0.0)[1:-1, 1:-1, 1:-1]
        assert np.max(np.abs(out - ndimage.distance_transform_edt(~mask, sampling=0.1))) < 1e-12


def test_grid_build_and_outside_points() -> None:
    m = box_at((1.0, 1.0, 1.0), (0, 0, 0))
    grid = ClearanceGrid.build(np.asarray(m.vertices), np.asarray(m.faces, dtype=np.int64), step=0.05)
    assert grid.query(np.array([[50.0, 0.0, 0.0]]))[0] == -np.inf
    assert grid.query(np.array([[0.0, 0.0, 0.0]]))[0] > 0.3  # centre of the box: 0.5 m from every face


def test_certified_motion_catches_a_thin_wall_that_sampling_misses(
    robot: Cabin8, payload: PayloadGeometry
) -> None:
    """A 2 mm plate across the path of link AB (6 cm thick) on a 1 m rail move, between samples 10 cm apart.

    Fixed-resolution checking at the samples sees nothing (the grown link stops 9 mm short of the plate on
    either side); the certified check must find the contact in between.
    """
    q_a, q_b = home(robot, d1=2.0), home(robot, d1=3.0)
    assert CollisionWorld(robot, None, payload).check_motion(q_a, q_b).valid
    g = robot.geometry
    with np.errstate(invalid="ignore"):
        from planner.kinematics.parallel import stage_points

        pts = stage_points(g, q_a[1], q_a[2], q_a[3])
    a, b = np.array(pts.A), np.array(pts.B)
    spot = a + 0.75 * (b - a)  # on AB between E (where EF joins) and B (the platform)
    plate = box_at((0.02, 0.02, 0.002), (spot[0], spot[1], 2.55))
    world = CollisionWorld(robot, mesh_of(plate), payload)
    n = 10
    samples = [q_a + (k / n) * (q_b - q_a) for k in range(n + 1)]
    assert all(world.is_valid(q, 0.01) for q in samples), "fixed-resolution checking sees nothing"
    assert not world.is_valid(home(robot, d1=2.55), 0.0), "but the link goes right through the plate"
    report = world.check_motion(q_a, q_b, clearance=0.01)
    assert not report.valid
    assert report.contacts[0].bodies == ("link_ab",)
    assert report.t_fail is not None and 0.45 < report.t_fail < 0.56


def test_certified_motion_keeps_clearance_everywhere(robot: Cabin8, aisle: CollisionWorld) -> None:
    """Where the check passes, dense exact distances along the segment never drop below the clearance."""
    rng = np.random.default_rng(8)
    qs = admissible_joints(robot, 30, seed=12)
    checked = 0
    for q_a in qs:
        q_a = q_a.copy()
        q_a[0] = rng.uniform(0.5, 5.5)
        q_b = q_a + rng.normal(size=8) * np.array([0.2, 0.02, 0.02, 0.03, 0.2, 0.1, 0.05, 0.3])
        if not (aisle.is_valid(q_a) and aisle.is_valid(q_b)):
            continue
        report = aisle.check_motion(q_a, q_b, clearance=0.01)
        if not report.valid:
            continue
        checked += 1
        dense = [q_a + t * (q_b - q_a) for t in np.linspace(0, 1, 60)]
        assert min(aisle.clearance_profile(np.array(dense))) >= 0.01 - 1e-9
        if checked >= 5:
            break
    assert checked >= 3


def test_reference_bays_have_collision_free_ik(robot: Cabin8, payload: PayloadGeometry) -> None:
    """Every bay of every reference cabin: a payload inserted in the bay has a collision-free IK solution."""
    manifest = json.loads((MESHES / "cabins.json").read_text())
    R_tool = np.column_stack([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])  # tool z into the bay (+x)
    for cabin in manifest["cabins"]:
        world = CollisionWorld(robot, load_mesh(MESHES / f"{cabin['name']}.stl", units="m"), payload)
        for bay in cabin["bays"]:
            T = np.eye(4)
            T[:3, :3] = R_tool
            T[:3, 3] = np.array(bay["center_m"]) - 0.30 * R_tool[:, 2]
            good, _ = family_candidates(robot, T, robot.home_drives, 0.5, IKOptions())
            assert any(world.is_valid(c.q, 0.01) for c in good), f"{cabin['name']} bay {bay['id']}"


def test_compiled_bounds_equal_the_numpy_reference(robot: Cabin8, aisle: CollisionWorld) -> None:
    """The numba kernels compute exactly the bounds of the vectorised numpy reference."""
    reference = ReferenceWorld(robot, aisle.cabin, aisle.payload)
    qs = admissible_joints(robot, 40, seed=77)
    qs[:, 0] = np.linspace(0.3, 5.7, len(qs))
    for threshold in (0.005, 0.1):
        states = [aisle._state(q, threshold) for q in qs]
        cabin = reference.cabin_lower_bounds(aisle.cover_centres(qs), qs[:, 0])
        pairs = reference.pair_lower_bounds(aisle.cover_centres(qs, coarse=True), threshold)
        np.testing.assert_allclose(np.array([s.cabin_lb for s in states]), cabin, atol=1e-12)
        got = np.array([s.pair_lb for s in states])
        # Where a pair's box separation exceeds the threshold the kernel may skip the sphere gap (both
        # values then exceed the threshold); elsewhere they are equal.
        caps = aisle._kernel.exact_pair[None, :]
        near = (pairs <= threshold) & ~caps
        np.testing.assert_allclose(got[near], pairs[near], atol=1e-12)
        assert np.all(got[~near & ~caps] > threshold)
        # Capsule pairs near the threshold carry their exact distance, never below the sphere bound.
        exact = np.broadcast_to(caps, got.shape) & (got <= threshold)
        assert np.all(got[exact] >= pairs[exact] - 1e-12)
        assert np.all(got[np.broadcast_to(caps, got.shape) & ~exact] > threshold)


def test_capsule_pairs_use_exact_distances(robot: Cabin8, payload: PayloadGeometry) -> None:
    """The analytic capsule-capsule and capsule-box distances equal FCL's on the posed shapes."""
    world = CollisionWorld(robot, None, payload)
    req = fcl.DistanceRequest()
    for q in admissible_joints(robot, 25, seed=5):
        st = world._state(q, 10.0)  # exact distances for every pair within 10 m
        R, p, lengths = world.poses(q)
        for k, (a, b) in enumerate(world.bodies.pairs):
            if not world._kernel.exact_pair[k]:
                continue
            oa = world._probes.object(a, R[0, a], p[0, a], lengths[0, a], 0.0)
            ob = world._probes.object(b, R[0, b], p[0, b], lengths[0, b], 0.0)
            via_fcl = fcl.distance(oa, ob, req, fcl.DistanceResult())
            if via_fcl <= 0:
                continue
            # Independent route: dense points along the capsule axis (exact point-to-shape distances).
            shapes = world.bodies.shapes
            cap, other = (a, b) if shapes[a].kind == "capsule" else (b, a)
            ts = np.linspace(-0.5, 0.5, 20001)[:, None]
            axis_pts = p[0, cap] + ts * lengths[0, cap] * R[0, cap][:, 2]
            if shapes[other].kind == "box":
                local = (axis_pts - p[0, other]) @ R[0, other]
                gap = np.linalg.norm(
                    np.maximum(np.abs(local) - np.array(shapes[other].size) / 2, 0.0), axis=1
                )
            else:
                z = R[0, other][:, 2]
                s = np.clip((axis_pts - p[0, other]) @ z, -lengths[0, other] / 2, lengths[0, other] / 2)
                gap = np.linalg.norm(axis_pts - (p[0, other] + s[:, None] * z), axis=1) - shapes[other].radius
            dense = float(gap.min()) - shapes[cap].radius
            step = lengths[0, cap] / 20000
            assert dense - step <= st.pair_lb[k] <= dense + 1e-12
            # FCL's GJK stops a little above the true distance (up to ~0.3 mm here), never below.
            assert st.pair_lb[k] <= via_fcl + 1e-9


def test_segment_box_distance_known_answers() -> None:
    from planner.collision.kernels.distances import segment_box_distance, segment_distance

    half = np.array([0.5, 0.25, 0.1])
    cases = [
        ((1.5, 0.0, 0.0), (2.5, 0.0, 0.0), 1.0),  # along x, beyond the face
        ((-1.0, 1.25, 0.0), (1.0, 1.25, 0.0), 1.0),  # parallel to a face, above it
        ((1.0, 1.0, 0.0), (2.0, 2.0, 0.0), float(np.hypot(0.5, 0.75))),  # nearest to an edge
        ((-2.0, 0.0, 0.0), (2.0, 0.0, 0.0), 0.0),  # through the box
        (
            (0.5 + 0.3, 0.25 + 0.4, 0.1 + 1.2),
            (3.0, 3.0, 5.0),
            float(np.linalg.norm([0.3, 0.4, 1.2])),
        ),  # corner
    ]
    for p, q, expected in cases:
        assert segment_box_distance(np.array(p), np.array(q), half) == pytest.approx(expected, abs=1e-12)
    assert (
        segment_distance(np.zeros(3), np.array([1.0, 0, 0]), np.array([0.5, 1.0, 0]), np.array([0.5, 2.0, 0]))
        == 1.0
    )
    assert (
        segment_distance(np.zeros(3), np.array([1.0, 0, 0]), np.array([2.0, 0, 0]), np.array([3.0, 0, 0]))
        == 1.0
    )


def test_motion_margin_is_validated(robot: Cabin8, aisle: CollisionWorld) -> None:
    q = home(robot, d1=1.0)
    for bad in (0.0, 1e-5, float("nan"), 0.5):
        with pytest.raises(InvalidInput):
            aisle.check_motion(q, home(robot, d1=1.1), motion_margin=bad)


def test_long_move_at_fine_margin_has_an_uncapped_schedule(robot: Cabin8, payload: PayloadGeometry) -> None:
    """A 6 m rail move at the finest allowed margin: every proven step is at least one schedule step."""
    world = CollisionWorld(robot, None, payload)
    report = world.check_motion(home(robot, d1=0.0), home(robot, d1=6.0), motion_margin=1e-4)
    assert report.valid


def test_body_lengths_follow_the_description(tmp_path: Path) -> None:
    """Column, arm and slide lengths come from the description's MDH numbers, not the reference ones."""
    import yaml

    from planner.robots.cabin8 import default_description_path

    raw = yaml.safe_load(default_description_path().read_text())
    raw["serial_chain"][0]["a"] = 0.15
    raw["serial_chain"][3]["a"] = 0.20
    path = tmp_path / "custom.yaml"
    path.write_text(yaml.safe_dump(raw))
    custom = Cabin8(path)
    world = CollisionWorld(custom, None, None)
    rng = np.random.default_rng(4)
    for _ in range(50):
        q = custom.joints_from_drives(custom.home_drives)
        q[6] = rng.uniform(custom.limits.lower[6], custom.limits.upper[6])
        f = custom.frames(q[None, :])[0]
        for name, (i, j) in {"column": (2, 3), "arm": (3, 4), "slide": (4, 6)}.items():
            shape = world.bodies.shapes[world.names.index(name)]
            assert np.linalg.norm(f[j, :3, 3] - f[i, :3, 3]) <= shape.length + 1e-12


def test_the_compiled_route_never_builds_the_cabins_fcl_mesh_and_the_reference_route_does() -> None:
    """A whole plan (search, timing, gate, report figures) on the compiled route leaves the FCL BVH unbuilt.

    It is built lazily (25 ms a new cabin in each process); the reference route, which probes with FCL,
    builds it at its first probe, and both routes give the same verdicts.
    """
    from planner.plan.pipeline import Planner
    from planner.scenario import load_scenario

    sc = load_scenario(Path(__file__).parents[1] / "scenarios" / "hatch-bay-insert.yaml")
    planner = Planner(sc)
    result = planner.plan()
    assert result.gate.passed
    probes = planner.world._probes
    assert probes.has_cabin and probes._cabin_obj is None
    d = planner.world.min_distance(sc.start_q)  # the report's exact distances: compiled too
    assert d.distance_m > 0 and probes._cabin_obj is None
    fast, ref = CollisionWorld(sc.robot, sc.cabin, sc.payload), ReferenceWorld(sc.robot, sc.cabin, sc.payload)
    assert ref._probes._cabin_obj is None
    qs = admissible_joints(sc.robot, 60, seed=4)
    qs[:, 0] = sc.start_q[0]
    verdicts = [ref.is_valid(q, 0.01) for q in qs]
    assert verdicts == [fast.is_valid(q, 0.01) for q in qs] and any(verdicts) and not all(verdicts)
    assert ref._probes._cabin_obj is not None and fast._probes._cabin_obj is None


def test_the_carriage_table_is_cached_on_disk_and_read_back_bit_for_bit(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """A new process's world reads the carriage table a first one wrote: the same bits, nothing rebuilt.

    A malformed entry is rebuilt (with a warning) to the same table; the reference route (FCL's distances)
    keeps entries of its own.
    """
    import planner.collision.world as world_module
    from planner.collision.probes import Probes

    monkeypatch.setenv("CABINPLAN_CACHE_DIR", str(tmp_path))
    robot = Cabin8()
    cabin = load_mesh(REFERENCE_DIR / "cabin-hatch.stl", units="m")

    def fresh() -> CollisionWorld:
        world_module._CARRIAGE_TABLES.clear()  # as in a new process
        return CollisionWorld(robot, cabin)

    built = fresh()._carriage_table
    assert built is not None and np.isfinite(built[2]).any()
    entries = sorted(tmp_path.glob("carriage-*.npy"))
    assert len(entries) == 1

    def no_build(*args: object, **kwargs: object) -> None:
        raise AssertionError("the table was built again")

    with monkeypatch.context() as m:
        m.setattr(Probes, "carriage_table", no_build)
        read = fresh()._carriage_table
    assert read is not None and read[:2] == built[:2] and read[2].tobytes() == built[2].tobytes()
    entries[0].write_bytes(b"not a table")
    with caplog.at_level("WARNING"):
        again = fresh()._carriage_table
    assert again is not None and again[2].tobytes() == built[2].tobytes()
    assert "carriage table cache" in caplog.text
    world_module._CARRIAGE_TABLES.clear()
    ReferenceWorld(robot, cabin)
    assert len(list(tmp_path.glob("carriage-*.npy"))) == 2  # FCL's table: an entry of its own

    def unreadable() -> str:
        raise OSError("no sources")

    with monkeypatch.context() as m:  # no build key to trust: built, not cached
        m.setattr(world_module, "_kernels_key", unreadable)
        m.setenv("CABINPLAN_CACHE_DIR", str(tmp_path / "other"))
        (tmp_path / "other").mkdir()
        keyless = fresh()._carriage_table
    assert keyless is not None and keyless[2].tobytes() == built[2].tobytes()
    assert not list((tmp_path / "other").glob("carriage-*"))
