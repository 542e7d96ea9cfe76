"""The cabin's triangle tree and the compiled box probe (:mod:`planner.collision.kernels.mesh`) against FCL.

The walk probes box bodies against the cabin itself; its verdicts must be FCL's collision verdicts on the
same grown boxes, on random boxes anywhere in a cabin and on boxes grazing its surface, and a walk with the
tree must report exactly what a walk with FCL's probes reports.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import fcl
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from planner.collision.bodies import PayloadGeometry
from planner.collision.kernels.buffers import NO_TREE, MeshTree, check_tree
from planner.collision.kernels.entries import DEFAULT
from planner.collision.motion import CertifiedMotion
from planner.collision.oracle import ReferenceWorld
from planner.collision.world import CollisionWorld
from planner.generate import GeneratorOptions, generate_case, write_case
from planner.generate.cabins import cabin_mesh
from planner.meshes import REFERENCE_DIR
from planner.meshio import load_mesh
from planner.robots.cabin8 import Cabin8
from planner.robots.geometry import BOX_CORNER_SIGNS
from planner.scenario import load_scenario
from tests.collision.minimise import hull_distance, qp_distance
from tests.conftest import admissible_joints


def _cabins() -> list[tuple[np.ndarray, np.ndarray]]:
    hatch = load_mesh(REFERENCE_DIR / "cabin-cluttered.stl", units="m")
    ring = cabin_mesh(generate_case(4, 0, GeneratorOptions(family="ring-frame")).layout)
    return [
        (np.ascontiguousarray(m.vertices, dtype=float), np.ascontiguousarray(m.faces, dtype=np.int64))
        for m in (hatch, ring)
    ]


@pytest.fixture(scope="module")
def cabins() -> list[tuple[np.ndarray, np.ndarray, MeshTree, fcl.CollisionObject]]:
    out = []
    for v, f in _cabins():
        model = fcl.BVHModel()
        model.beginModel(len(v), len(f))
        model.addSubModel(v, f.astype(np.int32))
        model.endModel()
        out.append((v, f, DEFAULT.mesh_tree(v, f), fcl.CollisionObject(model, fcl.Transform())))
    return out


#: A box's corners in its own frame, in units of its half extents.
_SIGNS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)


def _pose(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """A body pose (13,) as the kernels store it: R column-major, then p, then a length."""
    return np.concatenate([R.T.reshape(9), p, [0.0]])


def _fcl_touches(R: np.ndarray, p: np.ndarray, half: np.ndarray, cabin: fcl.CollisionObject) -> bool:
    box = fcl.CollisionObject(fcl.Box(*(2.0 * half)), fcl.Transform(R, p))
    return bool(fcl.collide(box, cabin, fcl.CollisionRequest(), fcl.CollisionResult()) > 0)


def _boxes(
    rng: np.random.Generator, v: np.ndarray, f: np.ndarray, n: int, grow: np.ndarray, away: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rotations, half extents, centres) of 2n boxes: n anywhere in the cabin's bounds, then n near it.

    The last n put a corner of the box grown by ``grow`` (2n,) at ``away`` (n, 1) along the normal of a
    random point of a random triangle (the box grazing it, or that far off).
    """
    lo, hi = v.min(axis=0), v.max(axis=0)
    Rs = Rotation.random(2 * n, random_state=rng.integers(1 << 31)).as_matrix()
    halves = rng.uniform(0.01, 0.3, (2 * n, 3))
    tri = v[f[rng.integers(len(f), size=n)]]
    on = np.einsum("nk,nkx->nx", rng.dirichlet(np.ones(3), size=n), tri)
    corner = np.einsum("nij,nj->ni", Rs[n:], np.sign(rng.normal(size=(n, 3))) * (halves[n:] + grow[n:, None]))
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    return Rs, halves, np.vstack([rng.uniform(lo, hi, (n, 3)), on - corner + away * normal])


def test_the_tree_holds_every_triangle_once_inside_its_nodes(cabins: list) -> None:
    for v, f, tree, _ in cabins:
        check_tree(tree)
        tris, bounds, links = tree
        assert np.array_equal(np.sort(tris.reshape(-1, 9), axis=0), np.sort(v[f].reshape(-1, 9), axis=0)), (
            "the tree's triangles are the mesh's, each once"
        )
        for k in range(len(bounds)):
            lo, hi = bounds[k, :3], bounds[k, 3:]
            if links[k, 1] > 0:
                first, count = links[k]
                pts = tris[first : first + count].reshape(-1, 3)
                assert 1 <= count <= 4 and np.all(pts >= lo) and np.all(pts <= hi)
            else:
                for child in (links[k, 0], -links[k, 1] - 1):
                    assert child > k and np.all(bounds[child, :3] >= lo) and np.all(bounds[child, 3:] <= hi)


def test_box_probes_agree_with_fcl_anywhere_and_grazing(cabins: list) -> None:
    """Random boxes in the cabin, and boxes within 1 mm of touching a triangle: FCL's verdicts, every one."""
    rng = np.random.default_rng(7)
    for v, f, tree, cabin in cabins:
        n = 3000
        grows = rng.uniform(0.0, 0.05, 2 * n)
        # Grazing: the grown box's corner within +-1 mm of a point on a random triangle.
        Rs, halves, centres = _boxes(rng, v, f, n, grows, rng.uniform(-1e-3, 1e-3, (n, 1)))
        touched = 0
        for i in range(2 * n):
            ours = DEFAULT.box_touches_mesh(_pose(Rs[i], centres[i]), halves[i], float(grows[i]), tree)
            theirs = _fcl_touches(Rs[i], centres[i], halves[i] + grows[i], cabin)
            assert ours == theirs, f"box {i}: ours {ours}, FCL {theirs}"
            touched += ours
        assert 0.2 * n < touched < 1.8 * n, "both verdicts are exercised"


def test_box_distances_are_fcls_exact_distances(cabins: list) -> None:
    """Boxes near the surface (a corner within 0-20 cm of a triangle) and anywhere: FCL's distance, capped.

    To 1e-5 m (FCL's own tolerance), or below FCL's by at most 2e-4 m where FCL's iteration stops short.
    """
    rng = np.random.default_rng(9)
    for v, f, tree, cabin in cabins:
        n = 600
        away = rng.uniform(0.0, 0.2, (n, 1)) * np.sign(rng.normal(size=(n, 1)))
        Rs, halves, centres = _boxes(rng, v, f, n, np.zeros(2 * n), away)
        near = checked = 0
        for i in range(2 * n):
            ours = DEFAULT.box_mesh_distance(_pose(Rs[i], centres[i]), halves[i], 0.25, tree)
            box = fcl.CollisionObject(fcl.Box(*(2.0 * halves[i])), fcl.Transform(Rs[i], centres[i]))
            req = fcl.DistanceRequest(enable_signed_distance=True)
            theirs = max(0.0, float(fcl.distance(cabin, box, req, fcl.DistanceResult())))
            if theirs >= 0.25:
                assert ours >= 0.25 - 1e-9
                continue
            near += 0.0 < theirs
            assert theirs - 2e-4 <= ours <= theirs + 1e-5, f"box {i}: ours {ours}, FCL {theirs}"
            if ours < theirs - 1e-6 and checked < 5:  # FCL stopped short: an independent minimisation
                corners = centres[i] + (_SIGNS * halves[i]) @ Rs[i].T
                assert abs(ours - qp_distance(corners, v, f, theirs)) < 1e-8, f"box {i}"
                checked += 1
        assert near > 0.3 * n


def test_hull_bounds_are_certified_and_meet_fcls_hull_distances(cabins: list) -> None:
    """Two poses of a box or a capsule axis (a swept hull's points): FCL's distance from the qhull hull.

    Never above it; within 1e-9 m of it, or, where FCL's iteration stops short (up to 1e-5 m above the
    true distance, measured), equal to an independent minimisation over the nearby triangles; 0 exactly
    where FCL finds a touch.
    """
    from scipy.spatial import ConvexHull

    rng = np.random.default_rng(5)
    signs = _SIGNS
    for v, f, tree, cabin in cabins:
        lo, hi = v.min(axis=0), v.max(axis=0)
        touching = apart = short = 0
        for i in range(400):
            R = Rotation.random(random_state=int(rng.integers(1 << 31))).as_matrix()
            centre = rng.uniform(lo, hi)
            if i % 4 == 3:  # a capsule's axis at two poses, thickened a little so that qhull has a volume
                ends = centre + np.array([[0, 0, -0.2], [0, 0, 0.2]]) @ R.T
                one = (ends[:, None, :] + 1e-4 * signs[None]).reshape(-1, 3)
            else:
                one = centre + (signs * rng.uniform(0.02, 0.25, 3)) @ R.T
            pts = np.ascontiguousarray(np.vstack([one, one + rng.normal(0.0, 0.1, 3)]))
            ours = DEFAULT.hull_mesh_lower(pts, tree)
            hull = ConvexHull(pts)
            faces = np.hstack([np.full((len(hull.simplices), 1), 3), hull.simplices]).ravel().astype(np.int32)
            obj = fcl.CollisionObject(fcl.Convex(hull.points, len(hull.simplices), faces), fcl.Transform())
            theirs = float(fcl.distance(obj, cabin, fcl.DistanceRequest(), fcl.DistanceResult()))
            if theirs <= 0.0:
                assert ours == 0.0
                touching += 1
                continue
            apart += 1
            assert theirs - 2e-5 <= ours <= theirs + 1e-12, f"hull {i}: ours {ours}, FCL {theirs}"
            if ours < theirs - 1e-9:
                assert abs(ours - qp_distance(pts, v, f, theirs)) < 1e-9, f"hull {i}"
                short += 1
        assert touching > 20 and apart > 100 and short < 0.05 * apart


def test_capsule_probes_and_distances_agree_with_fcl_and_an_independent_minimisation(cabins: list) -> None:
    """Capsules anywhere in the cabin and grazing it: FCL's collision verdicts on the grown capsule.

    Every verdict FCL's; distances never above FCL's (its GJK stops up to 0.2 mm above the truth, measured),
    and where they differ by more than 1e-9 m, equal to an independent minimisation over nearby triangles.
    """
    rng = np.random.default_rng(13)
    for v, f, tree, cabin in cabins:
        lo, hi = v.min(axis=0), v.max(axis=0)
        n = 1500
        Rs = Rotation.random(n, random_state=int(rng.integers(1 << 31))).as_matrix()
        radii, lengths, grows = (
            rng.uniform(0.02, 0.1, n),
            rng.uniform(0.05, 0.8, n),
            rng.uniform(0.0, 0.05, n),
        )
        centres = rng.uniform(lo, hi, (n, 3))
        tri = v[f[rng.integers(len(f), size=n)]]
        on = np.einsum("nk,nkx->nx", rng.dirichlet(np.ones(3), size=n), tri)
        end = Rs[:, :, 2] * (0.5 * lengths)[:, None]  # an end of the axis grazing a triangle
        half = n // 2
        centres[half:] = (
            on[half:]
            - end[half:]
            - (radii[half:] + grows[half:] + rng.uniform(-1e-3, 1e-3, n - half))[:, None] * Rs[half:, :, 0]
        )
        touched = checked = 0
        for i in range(n):
            pose = np.concatenate([Rs[i].T.reshape(9), centres[i], [lengths[i]]])
            ours = DEFAULT.capsule_touches_mesh(pose, float(radii[i]), float(grows[i]), tree)
            grown = fcl.CollisionObject(
                fcl.Capsule(radii[i] + grows[i], lengths[i]), fcl.Transform(Rs[i], centres[i])
            )
            theirs = fcl.collide(grown, cabin, fcl.CollisionRequest(), fcl.CollisionResult()) > 0
            assert ours == theirs, f"capsule {i}: ours {ours}, FCL {theirs}"
            touched += ours
            d = DEFAULT.capsule_mesh_distance(pose, float(radii[i]), 0.2, tree)
            body = fcl.CollisionObject(fcl.Capsule(radii[i], lengths[i]), fcl.Transform(Rs[i], centres[i]))
            req = fcl.DistanceRequest(enable_signed_distance=True)
            fd = float(fcl.distance(cabin, body, req, fcl.DistanceResult()))
            if not 0.0 < fd < 0.2:
                continue
            assert fd - 2e-4 <= d <= fd + 1e-9, f"capsule {i}: ours {d}, FCL {fd}"
            if d < fd - 1e-9 and checked < 10:
                axis = centres[i] + np.outer([-0.5, 0.5], lengths[i]) * Rs[i][:, 2]
                assert abs(d + radii[i] - qp_distance(np.ascontiguousarray(axis), v, f, fd + radii[i])) < 1e-8
                checked += 1
        assert 0.2 * n < touched < 0.9 * n and checked > 0


def test_witness_points_lie_on_the_body_and_the_cabin_at_the_distance(cabins: list) -> None:
    """The exact distance's nearest points: |p_body - p_cabin| = d, both on their surfaces.

    p_cabin on the cabin (FCL finds it there), p_body on the box's surface or at the capsule's radius from its
    axis; the distance FCL's within FCL's own tolerance.
    """
    rng = np.random.default_rng(21)
    v, _, tree, cabin = cabins[0]
    lo, hi = v.min(axis=0), v.max(axis=0)
    done = 0
    for i in range(400):
        R = Rotation.random(random_state=int(rng.integers(1 << 31))).as_matrix()
        c = rng.uniform(lo, hi)
        capsule = i % 2 == 1
        half, radius, length = (
            rng.uniform(0.02, 0.2, 3),
            float(rng.uniform(0.02, 0.08)),
            float(rng.uniform(0.1, 0.6)),
        )
        pose = np.concatenate([R.T.reshape(9), c, [length if capsule else 0.0]])
        d, pa, pb = DEFAULT.cabin_witness(
            pose, np.zeros(3) if capsule else half, radius if capsule else 0.0, tree
        )
        if not 1e-4 < d < 0.3:
            continue
        done += 1
        assert abs(np.linalg.norm(pa - pb) - d) < 1e-9
        local = R.T @ (pa - c)
        if capsule:
            axis = np.clip(local[2], -length / 2, length / 2)
            assert abs(np.linalg.norm(local - [0.0, 0.0, axis]) - radius) < 1e-9
            shape = fcl.Capsule(radius, length)
        else:
            assert np.all(np.abs(local) <= half + 1e-9) and np.max(np.abs(local) - half) > -1e-9
            shape = fcl.Box(*(2 * half))
        req = fcl.DistanceRequest(enable_nearest_points=True, enable_signed_distance=True)
        res = fcl.DistanceResult()
        fd = fcl.distance(cabin, fcl.CollisionObject(shape, fcl.Transform(R, c)), req, res)
        assert fd - 2e-4 <= d <= fd + 1e-9
        # the cabin's point is on the cabin: FCL finds it at distance 0 from the mesh
        probe = fcl.CollisionObject(fcl.Sphere(1e-7), fcl.Transform(pb))
        assert fcl.distance(cabin, probe, fcl.DistanceRequest(), fcl.DistanceResult()) < 1e-6
    assert done > 100


def test_an_empty_or_broken_tree(cabins: list) -> None:
    assert DEFAULT.box_touches_mesh(_pose(np.eye(3), np.zeros(3)), np.ones(3), 0.0, NO_TREE) is False
    empty = DEFAULT.mesh_tree(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    assert all(len(a) == 0 for a in empty)
    tris, bounds, links = cabins[0][2]
    bad = links.copy()
    bad[0, 0] = len(bounds)  # the root's left child past the last node
    with pytest.raises(ValueError, match="tree"):
        DEFAULT.box_touches_mesh(_pose(np.eye(3), np.zeros(3)), np.ones(3), 0.0, MeshTree(tris, bounds, bad))
    with pytest.raises(TypeError, match="tree"):
        DEFAULT.box_touches_mesh(_pose(np.eye(3), np.zeros(3)), np.ones(3), 0.0, (tris, bounds, links))  # type: ignore[arg-type]


def test_the_walk_with_its_own_box_probes_reports_what_fcl_probes_give(robot: Cabin8) -> None:
    """The same motion reports, query counts included, with the tree and without it (FCL's probes)."""
    payload = PayloadGeometry((0.45, 0.35, 0.5), T_tool_payload=np.eye(4), mass=60.0)
    world = CollisionWorld(robot, load_mesh(REFERENCE_DIR / "cabin-cluttered.stl", units="m"), payload)
    own = world._motion
    fcl_only = CertifiedMotion(
        own.model, own.bodies, dataclasses.replace(own.data, tree=NO_TREE), own.probes, own.kernels
    )
    rng = np.random.default_rng(3)
    qs = admissible_joints(robot, 160, seed=11)
    in_kernel = 0
    for q in qs:
        if not world.is_valid(q):
            continue
        step = rng.normal(0.0, 0.15, 8) * np.array([4.0, 1, 1, 1, 1, 1, 0.5, 1])
        for clearance in (0.01, 0.03):
            world._motion = own
            before = own.probes.queries
            ours = world.check_motion(q, q + step, clearance)
            in_kernel += ours.fcl_queries - (own.probes.queries - before)  # the walk's own probes
            world._motion = fcl_only
            theirs = world.check_motion(q, q + step, clearance)
            world._motion = own
            assert ours == theirs
    assert in_kernel > 100, "the walk probed the payload itself"


def _inside(point: np.ndarray, pose: np.ndarray, half: np.ndarray, radius: float) -> float:
    """How far ``point`` lies outside a body at ``pose`` (13,) (<= 0: in it): a box, or a capsule."""
    R, c = pose[:9].reshape(3, 3).T, pose[9:12]
    if radius == 0.0:
        return float(np.max(np.abs(R.T @ (point - c)) - half))
    z = 0.5 * pose[12] * R[:, 2]
    t = np.clip((point - c + z) @ (2 * z) / float((2 * z) @ (2 * z)), 0.0, 1.0)
    return float(np.linalg.norm(point - (c - z + t * 2 * z)) - radius)


def test_pair_distances_are_exact_where_fcls_signed_query_stops_above() -> None:
    """A pair of bodies (box-box, capsule-box, capsule-capsule): the compiled distance and witness points.

    Against the analytic distances (segment-segment, segment-box by golden section) to 1e-12 m, box pairs
    against FCL's (exact there) and an independent minimisation; the witness points lie on their bodies,
    the distance apart. FCL's *signed* query, which the pairs used, stops up to a millimetre above the truth
    for two capsules and 0.3 mm for a capsule and a box (its GJK): measured here, as the case this is for.
    """
    from planner.collision.kernels.distances import segment_box_distance, segment_segment_sq

    rng = np.random.default_rng(17)
    signed = fcl.DistanceRequest(enable_signed_distance=True)
    over = {0: 0.0, 1: 0.0, 2: 0.0}
    checked = {0: 0, 1: 0, 2: 0}
    for i in range(1500):
        Ra, Rb = Rotation.random(2, random_state=i).as_matrix()
        ca, cb = rng.uniform(-0.3, 0.3, (2, 3))
        kind = i % 3  # 0 box-box, 1 capsule-box, 2 capsule-capsule
        ha, hb = rng.uniform(0.02, 0.2, (2, 3))
        ra = 0.0 if kind == 0 else float(rng.uniform(0.02, 0.08))
        rb = float(rng.uniform(0.02, 0.08)) if kind == 2 else 0.0
        la, lb = (
            float(x) if r > 0 else 0.0 for x, r in zip(rng.uniform(0.05, 0.5, 2), (ra, rb), strict=True)
        )
        pa_pose, pb_pose = _pose(Ra, ca), _pose(Rb, cb)
        pa_pose[12], pb_pose[12] = la, lb
        d, wa, wb = DEFAULT.pair_witness(pa_pose, ha, ra, pb_pose, hb, rb)
        za, zb = 0.5 * la * Ra[:, 2], 0.5 * lb * Rb[:, 2]
        if kind == 2:
            truth = float(np.sqrt(segment_segment_sq(ca - za, ca + za, cb - zb, cb + zb))) - ra - rb
        elif kind == 1:
            truth = segment_box_distance(Rb.T @ (ca - za - cb), Rb.T @ (ca + za - cb), hb) - ra
        else:
            box_a, box_b = (c + (BOX_CORNER_SIGNS * h) @ R.T for c, h, R in ((ca, ha, Ra), (cb, hb, Rb)))
            truth = hull_distance(box_a, box_b)
        geom = [
            fcl.Box(*(2 * h)) if r == 0 else fcl.Capsule(r, length)
            for h, r, length in ((ha, ra, la), (hb, rb, lb))
        ]
        objs = [
            fcl.CollisionObject(g, fcl.Transform(R, c))
            for g, R, c in zip(geom, (Ra, Rb), (ca, cb), strict=True)
        ]
        theirs = float(fcl.distance(*objs, signed, fcl.DistanceResult()))
        if truth <= 1e-6:
            assert d <= 0.0, (i, d, truth)
            continue
        checked[kind] += 1
        assert abs(d - truth) < (1e-8 if kind == 0 else 1e-12), (i, kind, d, truth)
        assert abs(float(np.linalg.norm(wa - wb)) - d) < 1e-9, i
        assert _inside(wa, pa_pose, ha, ra) < 1e-9 and _inside(wb, pb_pose, hb, rb) < 1e-9, i
        assert theirs >= d - 1e-9, (i, kind, theirs, d)  # FCL's never below the truth here
        over[kind] = max(over[kind], theirs - d)
    assert min(checked.values()) > 250, checked
    assert over[1] > 1e-5 and over[2] > 1e-4, over  # FCL's signed query above the truth: measured


def test_the_worlds_pair_distances_are_the_compiled_ones_and_never_above_fcls(robot: Cabin8) -> None:
    """The robot's own pairs at admissible states: the compiled distances, never above FCL's.

    The world's closest pair is the compiled distance, which FCL's (the reference route's) is never below;
    the walks certify the same motions.
    """
    payload = PayloadGeometry(size=(0.45, 0.35, 0.5), T_tool_payload=np.eye(4))
    fast = CollisionWorld(robot, None, payload)
    ref = ReferenceWorld(robot, None, payload)
    assert fast._probes.compiled_pairs and not ref._probes.compiled_pairs
    qs = admissible_joints(robot, 300, seed=41)
    near = 0
    for q_a, q_b in zip(qs[:-1], qs[1:], strict=True):
        d, d_ref = fast.min_distance(q_a, include_cabin=False), ref.min_distance(q_a, include_cabin=False)
        if d.distance_m > 0.0:
            assert d_ref.distance_m >= d.distance_m - 1e-9, (d, d_ref)
            near += d.distance_m < 0.05
        if d.distance_m > 0.02:  # well clear: the same verdict on a short motion from it
            q_b = q_a + 0.1 * (q_b - q_a)
            assert fast.check_motion(q_a, q_b, 0.01).valid == ref.check_motion(q_a, q_b, 0.01).valid
    assert near > 20, near


def test_pair_probes_are_fcls_verdicts_on_the_same_grown_bodies() -> None:
    """A pair's probe (each body grown by half the growth: a box as a box, a capsule's radius): FCL's verdict.

    Box-box and capsule-box: FCL's verdict at every growth, grazing ones included (0.1% either side of the
    distance). Two capsules: exactly where their distance is at most the growth; FCL's collision query
    misses such contacts by up to a micrometre (counted, not required).
    """
    rng = np.random.default_rng(23)
    checked = {0: 0, 1: 0, 2: 0}
    fcl_missed = 0
    for i in range(1800):
        Ra, Rb = Rotation.random(2, random_state=900 + i).as_matrix()
        ca, cb = rng.uniform(-0.3, 0.3, (2, 3))
        kind = i % 3
        ha, hb = rng.uniform(0.02, 0.2, (2, 3))
        ra = 0.0 if kind == 0 else float(rng.uniform(0.02, 0.08))
        rb = float(rng.uniform(0.02, 0.08)) if kind == 2 else 0.0
        la = float(rng.uniform(0.05, 0.5)) if ra > 0 else 0.0
        lb = float(rng.uniform(0.05, 0.5)) if rb > 0 else 0.0
        poses = np.array([_pose(Ra, ca), _pose(Rb, cb)])
        poses[:, 12] = la, lb
        radii = np.array([ra, rb])
        halves = np.array([ha if ra == 0 else np.zeros(3), hb if rb == 0 else np.zeros(3)])
        d = DEFAULT.pair_witness(poses[0], halves[0], ra, poses[1], halves[1], rb)[0]
        grows = [0.0, 0.01, 0.03] + ([d * (1 - 1e-3), d * (1 + 1e-3)] if d > 0 else [])
        for g in grows:
            ours = DEFAULT.pair_touches(poses, radii, halves, 0, 1, g)
            shapes = [
                fcl.Box(*(2 * h + g)) if r == 0 else fcl.Capsule(r + g / 2, length)
                for h, r, length in ((ha, ra, la), (hb, rb, lb))
            ]
            objs = [
                fcl.CollisionObject(s, fcl.Transform(R, c))
                for s, R, c in zip(shapes, (Ra, Rb), (ca, cb), strict=True)
            ]
            theirs = fcl.collide(*objs, fcl.CollisionRequest(), fcl.CollisionResult()) > 0
            checked[kind] += 1
            if kind == 2:
                assert ours == (d <= g), (i, g, d)
                fcl_missed += ours and not theirs
            else:
                assert ours == theirs, (i, kind, g, d)
            if d > 0 and g >= d:  # grown by at least the distance: they touch (a box as a box, or more)
                assert ours, (i, kind, g, d)
    assert min(checked.values()) > 2500, checked
    assert DEFAULT.pair_touches(poses, radii, halves, 1, 0, 0.03) == DEFAULT.pair_touches(
        poses, radii, halves, 0, 1, 0.03
    )
    with pytest.raises(ValueError, match="outside"):
        DEFAULT.pair_touches(poses, radii, halves, 0, 2, 0.01)


def test_the_carriage_table_is_the_compiled_exact_distance(robot: Cabin8, tmp_path: Path) -> None:
    """The carriage's clearance table along the rail: the compiled box distance, FCL's to 1e-7 m, never above.

    A suite cabin and a generated cabin rotated about the rail (FCL's GJK ran up to 28 nm above the exact
    distance on such cabins).
    """
    from planner.collision.probes import Probes, cabin_bvh
    from planner.collision.world import cabin_key

    generated = load_scenario(write_case(generate_case(0, 0, GeneratorOptions(family="cluttered")), tmp_path))
    assert generated.cabin is not None
    for mesh in (generated.cabin, load_mesh(REFERENCE_DIR / "cabin-cluttered.stl", units="m")):
        world = CollisionWorld(robot, mesh, None)
        reference = Probes(world.bodies, cabin_bvh(*cabin_key(mesh)), None)  # FCL's distances
        carriage = world.names.index(world.model.rail_body)
        lo, hi = world.model.rail_range
        z0, dz, table = world._probes.carriage_table(carriage, lo, hi)
        _, _, fcl_table = reference.carriage_table(carriage, lo, hi)
        finite = np.isfinite(fcl_table)
        assert np.array_equal(finite, np.isfinite(table)) and finite.any()
        assert np.all(table[finite] <= fcl_table[finite] + 1e-12)
        assert np.max(fcl_table[finite] - table[finite]) < 1e-7
        half = np.array(world.bodies.shapes[carriage].size) / 2
        for k in range(
            0, len(table), 97
        ):  # each entry the exact distance of the carriage at its rail position
            pose = _pose(np.eye(3), np.array([0.0, -0.06, z0 + k * dz]))
            assert table[k] == DEFAULT.box_mesh_distance(pose, half, np.inf, world._probes.tree)
