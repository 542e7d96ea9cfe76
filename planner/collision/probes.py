"""FCL probes of one collision world: collision queries on grown bodies, exact distances, the carriage table.

Bodies are FCL boxes and capsules grown by a margin (:meth:`Probes.object`: reused per thread and only
moved, since building one costs more than the query); the cabin is one BVH mesh, cached per mesh content
and pose so that several worlds on one cabin share it, and built at its first use (:attr:`Probes.cabin_obj`):
with the cabin's triangle tree the compiled tests answer every probe and distance, so a plan on the
compiled route never builds it (25 ms for a generated cabin of 5 000-12 000 triangles, once per cabin and
process: a CLI call, a service worker's first job on the cabin). *Collision* queries (microseconds)
decide; distance queries (milliseconds) only where a number is needed (reports, the carriage's clearance
table).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from functools import cache
from typing import Any

import fcl
import numpy as np

from planner.collision.bodies import BodySet, Shape
from planner.collision.kernels.buffers import MeshTree
from planner.collision.kernels.entries import DEFAULT as KERNELS
from planner.collision.kernels.entries import Kernels
from planner.collision.reports import BodyState
from planner.core.types import Array, IntArray
from planner.robots.geometry import BOX_CORNER_SIGNS

#: The distance FCL's signed distance query gives a mesh and a shape in contact (it measures no depth).
PENETRATION_M = -1.0
#: The half extents passed for a capsule (unused).
_NO_HALF = np.zeros(3)


def _bvh(vertices: Array, faces: IntArray) -> fcl.BVHModel:
    model = fcl.BVHModel()
    model.beginModel(len(vertices), len(faces))
    model.addSubModel(vertices, faces.astype(np.int32))
    model.endModel()
    return model


@cache
def cabin_bvh(sha256: str, vertices_bytes: bytes, faces_bytes: bytes) -> fcl.BVHModel:
    """The cabin's FCL mesh, cached by (content hash and pose, vertices, faces) -- see ``world.cabin_key``."""
    vertices = np.frombuffer(vertices_bytes).reshape(-1, 3)
    faces = np.frombuffer(faces_bytes, dtype=np.int64).reshape(-1, 3)
    return _bvh(vertices, faces)


#: A box's 12 triangles over its corners (:data:`~planner.robots.geometry.BOX_CORNER_SIGNS`), outward
#: (counter-clockwise seen from outside): the mesh ``trimesh.creation.box`` makes, vertex for vertex
#: (``tests/collision/test_probes.py``), without importing trimesh (0.1 s of a plan's start-up) for it.
_BOX_FACES = np.array(
    [[1, 3, 0], [4, 1, 0], [0, 3, 2], [2, 4, 0], [1, 7, 3], [5, 1, 4]]
    + [[5, 7, 1], [3, 7, 2], [6, 4, 2], [2, 7, 6], [6, 5, 4], [7, 5, 6]],
    dtype=np.int64,
)


def box_mesh(size: tuple[float, float, float]) -> tuple[Array, IntArray]:
    """(vertices (8, 3), faces (12, 3)) of a box of edge lengths ``size`` centred on its frame."""
    return BOX_CORNER_SIGNS * (0.5 * np.asarray(size, dtype=float)), _BOX_FACES.copy()


@cache
def _box_bvh(size: tuple[float, float, float]) -> fcl.BVHModel:
    return _bvh(*box_mesh(size))


class GrownShapes:
    """FCL shapes of a world's bodies grown by a margin, cached per (body, margin, capsule length).

    A box body grown by ``margin`` is a larger box; a capsule body a capsule of radius ``r + margin`` and
    its posed ``length`` (rounded to 1 nm in the key). The cache is cleared past 4096 shapes.

    Args:
        shapes: The bodies' shapes, indexed by body.
    """

    def __init__(self, shapes: tuple[Shape, ...]) -> None:
        self._shapes = shapes
        self._geoms: dict[tuple[int, float, float], Any] = {}

    def __call__(self, b: int, margin: float, length: float) -> Any:
        """FCL shape of body b grown by ``margin`` (a capsule with its posed ``length`` [m])."""
        shape = self._shapes[b]
        key = (b, margin, round(length, 9) if shape.kind == "capsule" else 0.0)
        geom = self._geoms.get(key)
        if geom is None:
            if len(self._geoms) > 4096:
                self._geoms.clear()
            grown = shape.inflated(margin)
            geom = fcl.Box(*grown.size) if grown.kind == "box" else fcl.Capsule(grown.radius, length)
            self._geoms[key] = geom
        return geom


class Probes:
    """FCL objects of a world's bodies and its cabin, and the queries on them (counted in ``queries``).

    A body against the cabin is probed by the compiled tests on the cabin's triangle tree when there is one
    (:mod:`planner.collision.kernels.mesh`: FCL's verdicts, a box in about 2 us instead of 10).

    A pair of bodies' probe and exact distance are compiled too where ``compiled_pairs``
    (:func:`.kernels.distances.pair_touches`, :func:`.kernels.mesh.pair_witness`: FCL's signed query runs
    up to 1.1 mm above two capsules' distance, its collision query misses their contact by up to 1 um).

    Args:
        bodies: The world's bodies (shapes, checked pairs).
        cabin: The cabin's FCL mesh, or what builds it at its first use (``None``: free space).
        tree: The same cabin's triangle tree (``None``: every probe through FCL).
        kernels: The compiled kernels' entries.
        compiled_pairs: Pairs' probes and exact distances by the compiled tests (False: FCL's).
    """

    def __init__(
        self,
        bodies: BodySet,
        cabin: fcl.BVHModel | Callable[[], fcl.BVHModel] | None,
        tree: MeshTree | None = None,
        kernels: Kernels = KERNELS,
        compiled_pairs: bool = False,
    ) -> None:
        self.bodies = bodies
        #: Whether the world has a cabin (its FCL object, :attr:`cabin_obj`, is built when first asked for).
        self.has_cabin = cabin is not None
        self._cabin_source = cabin
        self._cabin_obj: fcl.CollisionObject | None = None
        #: The cabin's triangle tree for the compiled tests (None: FCL only).
        self.tree = tree if tree is not None and len(tree.tris) and cabin is not None else None
        self._kernels = kernels
        self._half = [np.array(s.size, dtype=float) / 2 if s.kind == "box" else None for s in bodies.shapes]
        self._radius = [float(s.radius) if s.kind == "capsule" else 0.0 for s in bodies.shapes]
        self.queries = 0
        self.compiled_pairs = compiled_pairs
        # The pairs' compiled tests read every body's radius and half extents (0 where it has none).
        self._radii = np.array(self._radius, dtype=float)
        self._halves = np.array([np.zeros(3) if h is None else h for h in self._half], dtype=float).reshape(
            -1, 3
        )
        self._radii.setflags(write=False)
        self._halves.setflags(write=False)
        self._capsule = [s.kind == "capsule" for s in bodies.shapes]
        self._grown = GrownShapes(bodies.shapes)
        self._local = threading.local()
        self._req = fcl.CollisionRequest()

    @property
    def cabin_obj(self) -> fcl.CollisionObject | None:
        """The cabin as an FCL object (``None``: free space), its BVH built at the first use."""
        if self._cabin_obj is None and self._cabin_source is not None:
            source = self._cabin_source
            model = source if isinstance(source, fcl.BVHModel) else source()
            self._cabin_obj = fcl.CollisionObject(model, fcl.Transform())
        return self._cabin_obj

    def geometry(self, b: int, margin: float, length: float) -> Any:
        """FCL shape of body b grown by ``margin`` (a capsule with its posed ``length``), cached."""
        return self._grown(b, margin, length)

    def object(self, b: int, R: Array, p: Array, length: float, margin: float) -> fcl.CollisionObject:
        """A posed FCL object of body b grown by ``margin``; objects are reused (per thread), only moved."""
        key = (b, margin, round(length, 9) if self._capsule[b] else 0.0)
        try:
            objects: dict[tuple[int, float, float], fcl.CollisionObject] = self._local.objects
        except AttributeError:
            objects = self._local.objects = {}
        obj = objects.get(key)
        if obj is None:
            if len(objects) > 4096:
                objects.clear()
            obj = objects[key] = fcl.CollisionObject(self.geometry(b, margin, length), fcl.Transform(R, p))
        else:
            obj.setRotation(R)
            obj.setTranslation(p)
        return obj

    def posed(self, st: BodyState, b: int, margin: float) -> fcl.CollisionObject:
        """:meth:`object` of body b at the state ``st``."""
        return self.object(b, st.R(b), st.p(b), st.length(b), margin)

    def collide(self, o1: fcl.CollisionObject, o2: fcl.CollisionObject) -> bool:
        """One FCL collision query (counted)."""
        self.queries += 1
        try:  # one result object per thread, emptied for each query (a new one costs more than the query)
            res: fcl.CollisionResult = self._local.result
        except AttributeError:
            res = self._local.result = fcl.CollisionResult()
        res.is_collision = False
        res.contacts.clear()
        res.cost_sources.clear()
        return bool(fcl.collide(o1, o2, self._req, res) > 0)

    def cabin_hit(self, st: BodyState, b: int, margin: float) -> bool:
        """Body b grown by ``margin`` touches the cabin."""
        assert self.has_cabin
        if self.tree is not None:
            self.queries += 1
            half = self._half[b]
            if half is not None:
                return self._kernels.box_touches_mesh(st.flat[b], half, margin, self.tree)
            return self._kernels.capsule_touches_mesh(st.flat[b], self._radius[b], margin, self.tree)
        return self.collide(self.posed(st, b, margin), self.cabin_obj)

    def pair_hit(self, st: BodyState, k: int, margin: float) -> bool:
        """The bodies of checked pair k, each grown by ``margin / 2``, touch (compiled: compiled_pairs)."""
        a, b = self.bodies.pairs[k]
        if self.compiled_pairs:
            self.queries += 1
            return self._kernels.pair_touches(st.flat, self._radii, self._halves, a, b, margin)
        return self.collide(self.posed(st, a, margin / 2), self.posed(st, b, margin / 2))

    def hit(self, st: BodyState, is_cabin: bool, idx: int, margin: float) -> bool:
        """:meth:`cabin_hit` of body ``idx`` or :meth:`pair_hit` of pair ``idx``."""
        return self.cabin_hit(st, idx, margin) if is_cabin else self.pair_hit(st, idx, margin)

    def carriage_table(
        self, carriage: int, lo: float, hi: float, step: float = 0.01
    ) -> tuple[float, float, Array]:
        """Exact carriage-to-cabin distance every ``step`` along the rail [lo, hi]: (lo, step, distances).

        The carriage moves with d1 only; between samples the distance changes by at most the rail
        displacement (it is 1-Lipschitz in d1), which the lookup subtracts. Penetration gives -inf. A box
        carriage against the cabin's tree: the compiled exact distance (FCL's GJK ran up to 28 nm above it
        on 84 generated cabins); else FCL's.
        """
        assert self.has_cabin
        z = np.arange(lo, hi + step, step)
        half = self._half[carriage]
        if self.tree is not None and half is not None:
            pose = np.zeros(13)
            pose[[0, 4, 8]] = 1.0  # the carriage's frame is the base frame's, moved along the rail
            pose[10] = -0.06
            table = np.empty(len(z))
            for k, zk in enumerate(z):
                pose[11] = zk
                table[k] = self._kernels.box_mesh_distance(pose, half, np.inf, self.tree)
            return lo, step, np.where(table < 0, -np.inf, table)
        geom = self.geometry(carriage, 0.0, 0.0)
        req = fcl.DistanceRequest()
        table = np.array(
            [
                fcl.distance(
                    fcl.CollisionObject(geom, fcl.Transform(np.array([0.0, -0.06, zi]))),
                    self.cabin_obj,
                    req,
                    fcl.DistanceResult(),
                )
                for zi in z
            ]
        )
        return lo, step, np.where(table < 0, -np.inf, table)

    def distance(self, st: BodyState, is_cabin: bool, idx: int) -> tuple[float, int, int, Array, Array]:
        """Exact distance of body ``idx`` to the cabin (or of pair ``idx``) on the un-grown shapes.

        Returns (distance, body a, other body (-1: the cabin), witness on a, witness on the other).
        FCL returns the witness points of a shape-vs-mesh query in swapped order, and its box-box distance
        is wrong in degenerate (face-parallel) cases: so the first object is always a mesh (the cabin, or
        the first box of a box pair as a triangle mesh), whose point comes first.
        """
        shapes = self.bodies.shapes
        if is_cabin and self.tree is not None:  # compiled: exact, where FCL's GJK stops up to 0.2 mm above
            half = self._half[idx]
            d, p_body, p_cabin = self._kernels.cabin_witness(
                st.flat[idx], _NO_HALF if half is None else half, self._radius[idx], self.tree
            )
            # A touch or a penetration: -1, as FCL reports one it does not measure (so that every distance
            # of a report, the obstacles' included, follows one convention).
            return (d if d > 0.0 else PENETRATION_M), idx, -1, p_body, p_cabin
        if not is_cabin and self.compiled_pairs:  # compiled: exact, where FCL's GJK stops above
            a, other = self.bodies.pairs[idx]
            half_a, half_b = self._half[a], self._half[other]
            d, p_a, p_other = self._kernels.pair_witness(
                st.flat[a],
                _NO_HALF if half_a is None else half_a,
                self._radius[a],
                st.flat[other],
                _NO_HALF if half_b is None else half_b,
                self._radius[other],
            )
            return d, a, other, p_a, p_other
        if is_cabin:
            a, other = idx, -1
            first = self.cabin_obj
        else:
            a, other = self.bodies.pairs[idx]
            if shapes[a].kind == "box" and shapes[other].kind == "box":
                first = fcl.CollisionObject(
                    _box_bvh(shapes[other].size), fcl.Transform(st.R(other), st.p(other))
                )
            else:
                first = self.posed(st, other, 0.0)
        second = self.posed(st, a, 0.0)
        req = fcl.DistanceRequest(enable_nearest_points=True, enable_signed_distance=True)
        res = fcl.DistanceResult()
        d = float(fcl.distance(first, second, req, res))
        p_other, p_body = res.nearest_points
        return d, a, other, np.array(p_body), np.array(p_other)
