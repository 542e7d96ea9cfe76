"""Obstacles added to a cabin: installed units, transport fixtures, a unit waiting on its dock.

An obstacle is a rigid body at a fixed pose in the base frame -- a box, or a triangle mesh -- with its own
FCL object. A world compares every robot body (and the payload) with every obstacle by clearance, exactly as
with the cabin, but the cabin's mesh-derived caches (its BVH, clearance grid and carriage table) are not
touched: adding an installed unit to a world costs one small FCL object and a few arrays, not a rebuild
of the cabin's caches (which stay shared by every world on the cabin).

Certification follows the cabin's rules (:mod:`planner.collision.world`):

* **States**: a conservative prune first -- every body is covered by spheres (its fine cover), and a sphere
  whose distance to the obstacle's bounding box exceeds its radius plus the clearance cannot touch the
  obstacle; what the prune cannot prove clear goes to a *collision* probe of the body grown by the
  clearance against the obstacle.
* **Motions** q(t) = q_a + t (q_b - q_a): no point of body b moves more than D_b = rho_b . |q_b - q_a| over
  the segment (the world's reach bounds). At a checked t the pair (body, obstacle) is proven to have a
  distance d >= clearance + margin (its sphere lower bound, else the exact distance), so every t' with
  |t' - t| D_b <= d - clearance keeps the clearance, and the walk steps on by (d - clearance) / D_b.
  A state that cannot prove the margin refuses the motion there (it may be a real contact).
* **Distances**: exact distances on the un-grown shapes.

The probes, the exact distances and the swept-hull bounds are the compiled tests on each obstacle's
triangles (:meth:`Obstacle.tree`, :mod:`planner.collision.kernels.mesh`), as for the cabin: FCL's GJK
stops up to 0.2 mm above a body's true distance to a mesh (``tests/collision/test_mesh_tree.py``), which a
walk stepping by that distance would turn into an uncertified step. The reference route
(:class:`planner.collision.oracle.ReferenceObstacles`) keeps FCL's queries (the obstacle always first, as a
mesh: FCL's box-box distance is wrong in face-parallel cases and its shape-vs-mesh witnesses come swapped).
Triangles alone cannot tell a body wholly *inside* an obstacle from one outside it, so a box obstacle (a
solid) also tests whether the body's centre is inside it: a body there touches it (distance
:data:`~planner.collision.probes.PENETRATION_M`). A mesh obstacle is its surface, as FCL's mesh is.

The sphere bounds are compiled (:mod:`planner.collision.kernels.obstacles`, from the set's constant arrays
packed once, :attr:`ObstacleSet.kernel_data`); their numpy route is the tests' reference
(:class:`planner.collision.oracle.ReferenceObstacles`).

**Allowed pairs** ``(body, obstacle)`` are left out of every check and distance of the world that allows
them: a planner builds such a world only for the short straight motions where the pair must come close
(a gripper closing on the unit it grasps); every other world keeps the clearance for that pair.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cache

import fcl
import numpy as np

from planner.collision.bodies import BodySet, Shape
from planner.collision.kernels.buffers import MeshTree, cover, obstacle_data
from planner.collision.kernels.codes import ROUND_M
from planner.collision.kernels.entries import DEFAULT as DEFAULT_KERNELS
from planner.collision.kernels.entries import Kernels
from planner.collision.probes import PENETRATION_M, Probes, box_mesh
from planner.collision.reports import Contact
from planner.collision.sweep import run_bound, swept_bound
from planner.core.exceptions import InvalidInput
from planner.core.types import Array, IntArray
from planner.robots.geometry import BOX_CORNER_SIGNS

#: The half extents passed for a capsule body (unused).
_NO_HALF = np.zeros(3)

__all__ = ["Obstacle", "ObstacleSet", "obstacle_contact"]


@cache
def _box_mesh(size: tuple[float, float, float]) -> fcl.BVHModel:
    """An FCL triangle mesh of a box centred on its frame (for exact distances, see the module doc)."""
    return _bvh(*box_mesh(size))


def _bvh(vertices: Array, faces: IntArray) -> fcl.BVHModel:
    model = fcl.BVHModel()
    model.beginModel(len(vertices), len(faces))
    model.addSubModel(
        np.ascontiguousarray(vertices, dtype=float), np.ascontiguousarray(faces, dtype=np.int32)
    )
    model.endModel()
    return model


@dataclass(frozen=True, eq=False)
class Obstacle:
    """A fixed rigid body in the base frame: a box or a triangle mesh.

    Attributes:
        name: How reports name it (``"unit B3"``, ``"fixture of A1"``).
        T_base_obstacle: The obstacle frame in the base frame (4x4); a box is centred on it.
        size: Box size (x, y, z) [m] in the obstacle frame, or None for a mesh.
        vertices: Mesh vertices (V, 3) in the obstacle frame [m], or None for a box.
        faces: Mesh triangles (F, 3), or None for a box.
    """

    name: str
    T_base_obstacle: Array = field(repr=False)
    size: tuple[float, float, float] | None = None
    vertices: Array | None = field(default=None, repr=False)
    faces: IntArray | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        T = np.array(self.T_base_obstacle, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise InvalidInput(f"{self.name}: the pose must be a finite 4x4 transform", field=self.name)
        T.setflags(write=False)
        object.__setattr__(self, "T_base_obstacle", T)
        if (self.size is None) == (self.vertices is None):
            raise InvalidInput(f"{self.name}: exactly one of a box size or a mesh", field=self.name)
        if self.size is not None:
            size = tuple(float(s) for s in self.size)
            if len(size) != 3 or not all(np.isfinite(s) and s > 0 for s in size):
                raise InvalidInput(f"{self.name}: three positive box sizes [m] expected", field=self.name)
            object.__setattr__(self, "size", size)
        else:
            v = np.array(self.vertices, dtype=float)
            f = np.array(self.faces, dtype=np.int64)
            if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4 or f.ndim != 2 or f.shape[1] != 3 or len(f) < 1:
                raise InvalidInput(
                    f"{self.name}: a mesh of vertices (V, 3) and faces (F, 3)", field=self.name
                )
            v.setflags(write=False)
            f.setflags(write=False)
            object.__setattr__(self, "vertices", v)
            object.__setattr__(self, "faces", f)

    @classmethod
    def box(cls, name: str, size: tuple[float, float, float], T_base_obstacle: Array) -> Obstacle:
        """A box of ``size`` [m] centred on ``T_base_obstacle``."""
        return cls(name, T_base_obstacle, size=size)

    @property
    def bound(self) -> tuple[Array, Array]:
        """(T_base_bound (4, 4), half extents (3,)).

        a box containing the obstacle (its own, or the mesh's bounding box in the obstacle frame).
        """
        if self.size is not None:
            return self.T_base_obstacle, 0.5 * np.array(self.size)
        assert self.vertices is not None
        lo, hi = self.vertices.min(axis=0), self.vertices.max(axis=0)
        T = np.eye(4)
        T[:3, 3] = 0.5 * (lo + hi)
        return self.T_base_obstacle @ T, 0.5 * (hi - lo)

    def corners(self) -> Array:
        """The 8 corners (8, 3) of :attr:`bound` in the base frame."""
        T, h = self.bound
        return (BOX_CORNER_SIGNS * h) @ T[:3, :3].T + T[:3, 3]

    def collision_object(self) -> fcl.CollisionObject:
        """The obstacle's FCL object for collision queries (a box primitive, or the mesh's BVH)."""
        tf = fcl.Transform(self.T_base_obstacle[:3, :3], self.T_base_obstacle[:3, 3])
        if self.size is not None:
            return fcl.CollisionObject(fcl.Box(*self.size), tf)
        return fcl.CollisionObject(self.mesh_model(), tf)

    def mesh_model(self) -> fcl.BVHModel:
        """The obstacle as an FCL triangle mesh (exact distances)."""
        if self.size is not None:
            return _box_mesh(self.size)
        assert self.vertices is not None and self.faces is not None
        return _bvh(self.vertices, self.faces)

    def tree(self) -> MeshTree:
        """The obstacle's triangles in the base frame, in a box tree (the compiled tests), built once.

        A box's are its 12 (:func:`~planner.collision.probes.box_mesh`); the arrays are read-only.
        """
        cached: MeshTree | None = self.__dict__.get("_tree")
        if cached is None:
            if self.size is not None:
                vertices, faces = box_mesh(self.size)
            else:
                assert self.vertices is not None and self.faces is not None
                vertices, faces = self.vertices, self.faces
            T = self.T_base_obstacle
            base = np.ascontiguousarray(vertices @ T[:3, :3].T + T[:3, 3])
            cached = DEFAULT_KERNELS.mesh_tree(base, np.ascontiguousarray(faces, dtype=np.int64))
            for arr in cached:
                arr.setflags(write=False)
            object.__setattr__(self, "_tree", cached)  # frozen: set once, as a cache
        return cached

    def contains(self, points: Array) -> bool:
        """True when a point of ``points`` (n, 3) [m, base frame] is strictly inside a box obstacle.

        A mesh obstacle contains nothing (it is its surface, as FCL's mesh).
        """
        if self.size is None:
            return False
        T = self.T_base_obstacle
        local = (np.asarray(points, dtype=float).reshape(-1, 3) - T[:3, 3]) @ T[:3, :3]
        return bool(np.any(np.all(np.abs(local) < 0.5 * np.asarray(self.size), axis=1)))

    def distance_to(self, other: Obstacle) -> float:
        """Exact distance [m] to another obstacle (<= 0 when they overlap or touch)."""
        a = fcl.CollisionObject(self.mesh_model(), _tf(self.T_base_obstacle))
        b = other.collision_object()
        if fcl.collide(a, b, fcl.CollisionRequest(), fcl.CollisionResult()) > 0:
            return 0.0 if not _overlap_depth_known(self, other) else -_overlap_depth(self, other)
        b = fcl.CollisionObject(other.mesh_model(), _tf(other.T_base_obstacle))
        return float(fcl.distance(a, b, fcl.DistanceRequest(), fcl.DistanceResult()))


def _tf(T: Array) -> fcl.Transform:
    return fcl.Transform(np.asarray(T[:3, :3]), np.asarray(T[:3, 3]))


def _overlap_depth_known(a: Obstacle, b: Obstacle) -> bool:
    return a.size is not None and b.size is not None


def _overlap_depth(a: Obstacle, b: Obstacle) -> float:
    """A penetration figure of two overlapping boxes [m]: the smallest separating-axis overlap (> 0)."""
    Ta, ha = a.bound
    Tb, hb = b.bound
    Ra, Rb = Ta[:3, :3], Tb[:3, :3]
    d = Tb[:3, 3] - Ta[:3, 3]
    axes = [Ra[:, i] for i in range(3)] + [Rb[:, i] for i in range(3)]
    for i in range(3):
        for j in range(3):
            c = np.cross(Ra[:, i], Rb[:, j])
            if np.linalg.norm(c) > 1e-9:
                axes.append(c / np.linalg.norm(c))
    overlaps = []
    for axis in axes:
        ra = float(np.sum(ha * np.abs(Ra.T @ axis)))
        rb = float(np.sum(hb * np.abs(Rb.T @ axis)))
        overlaps.append(ra + rb - abs(float(d @ axis)))
    return max(0.0, float(min(overlaps)))


def obstacle_contact(body: str, obstacle: str, margin: float) -> Contact:
    """The contact of a body with an obstacle within ``margin`` [m] (kind ``"obstacle"``)."""
    return Contact("obstacle", (body, obstacle), f"{body} within {margin:.4g} m of {obstacle}")


class ObstacleSet:
    """The obstacles of one world, its bodies' sphere covers against them, and the probes and distances.

    Args:
        obstacles: The obstacles (names unique).
        bodies: The world's bodies.
        allowed: ``(body name, obstacle name)`` pairs left out of every check and distance.
        kernels: The compiled kernels' entries (the world's).
        compiled: Probes, distances and swept hulls by the compiled tests on each obstacle's triangles
            (see the module doc); False: by FCL (the reference route).
    """

    def __init__(
        self,
        obstacles: tuple[Obstacle, ...],
        bodies: BodySet,
        allowed: frozenset[tuple[str, str]] = frozenset(),
        kernels: Kernels = DEFAULT_KERNELS,
        compiled: bool = True,
    ) -> None:
        names = [o.name for o in obstacles]
        if len(set(names)) != len(names):
            raise InvalidInput(f"obstacles: names must be unique, got {names}", field="obstacles")
        unknown = [p for p in allowed if p[0] not in bodies.names or p[1] not in names]
        if unknown:
            raise InvalidInput(
                f"allowed pairs name unknown bodies or obstacles: {sorted(unknown)}", field="allowed"
            )
        self.obstacles = obstacles
        self.names = tuple(names)
        self.bodies = bodies
        self.allowed = allowed
        n_b, n_o = len(bodies.names), len(obstacles)
        #: (B, O) True where the pair is checked.
        self.active = np.ones((n_b, n_o), dtype=bool)
        for b_name, o_name in allowed:
            self.active[bodies.names.index(b_name), names.index(o_name)] = False
        bounds = [o.bound for o in obstacles]
        T_bound = np.array([T for T, _ in bounds], dtype=float).reshape(n_o, 4, 4)
        half = np.array([h for _, h in bounds], dtype=float).reshape(n_o, 3)
        # The bodies' fine sphere covers: box bodies by local centre, capsules by a fraction of the length.
        self._cover = cover(bodies.shapes, bodies.sphere_centres, bodies.sphere_radii)
        #: The packed constant data of the compiled bounds (:mod:`.kernels.obstacles`), built once.
        self.kernel_data = obstacle_data(T_bound, half, bodies.shapes, self._cover, self.active)
        #: The compiled kernels' entries (the world's: the ahead-of-time build or numba's JIT).
        self.kernels = kernels
        #: Whether probes, distances and swept hulls use the compiled tests (else FCL's).
        self.compiled = compiled
        self._trees = [o.tree() for o in obstacles] if compiled else []
        self._body_half = [
            np.array(s.size, dtype=float) / 2 if s.kind == "box" else None for s in bodies.shapes
        ]
        self._body_radius = [float(s.radius) if s.kind == "capsule" else 0.0 for s in bodies.shapes]
        self._boxes = [o.size is not None for o in obstacles]
        if not compiled:
            self._objects = [o.collision_object() for o in obstacles]
            self._meshes = [fcl.CollisionObject(o.mesh_model(), _tf(o.T_base_obstacle)) for o in obstacles]
        # The bodies' FCL objects: grown shapes cached, objects reused per thread and only moved.
        self._probes = Probes(bodies, None)
        self.queries = 0

    def __len__(self) -> int:
        return len(self.obstacles)

    # ---------------------------------------------------------------- bounds
    def lower_bounds(self, flat: Array, threshold: float | Array = np.inf) -> Array:
        """Certified lower bounds (B, O) of each body's distance to each obstacle at one state.

        ``flat`` (B, 13) are the body poses (rotation column-major, centre, capsule length). First each
        body's bounding sphere (centre, half-diagonal or half-length + radius): its distance to the
        obstacle's bounding box minus its radius. A body with a pair whose bound is not above ``threshold``
        (scalar, (B,) or (B, 1)) has its pairs refined with its fine sphere cover (the smallest of its
        spheres' bounds; the larger of the two bounds counts). Allowed pairs are +inf. One compiled call
        (:func:`.kernels.obstacles.obstacle_bounds`).
        """
        n_b = self.kernel_data.n_bodies
        if isinstance(threshold, float | int):
            th = np.full(n_b, float(threshold))
        else:
            th = np.ascontiguousarray(np.asarray(threshold, dtype=float).reshape(n_b))
        return self.kernels.obstacle_bounds(flat, self.kernel_data, th)

    def coarse_bounds_batch(self, poses: Array, allowed_too: bool = False) -> Array:
        """Certified lower bounds (N, B, O) of each body's distance to each obstacle at N states, coarse.

        ``poses`` (N, B, 13): each body's bounding sphere (centre, half-diagonal or half-length + radius)
        against each obstacle's bounding box. Allowed pairs are +inf unless ``allowed_too`` (their bounds,
        for reports). :meth:`fine_bounds_batch` refines them.
        """
        return self.kernels.obstacle_coarse_batch(poses, self.kernel_data, allowed_too)

    def fine_bounds_batch(self, poses: Array, rows: IntArray, b: int) -> Array:
        """Certified lower bounds (n, O) of body b's distance to each obstacle, from its fine sphere cover.

        ``poses`` (N, B, 13), ``rows`` (n,) the states to evaluate: the smallest of body b's spheres'
        distances to the obstacle's bounding box minus their radii (every pair, allowed ones too).
        """
        return self.kernels.obstacle_fine_batch(poses, rows, b, self.kernel_data)

    def swept_bound(self, verts: Array, shape: Shape, o: int) -> float:
        """Certified lower bound of a body's distance to obstacle o over a run (:mod:`.sweep`).

        ``verts`` (n, V, 3): the body's vertices at the run's samples. ``-inf`` when a vertex at the run's
        ends is inside a box obstacle (the hull may then lie wholly inside it, touching no triangle).
        """
        if self._boxes[o] and self.obstacles[o].contains(np.vstack([verts[0], verts[-1]])):
            return -np.inf
        if not self.compiled:
            return swept_bound(verts, shape, self._meshes[o])
        points = np.ascontiguousarray(np.vstack([verts[0], verts[-1]]))
        return run_bound(self.kernels.hull_mesh_lower(points, self._trees[o]), verts, shape, ROUND_M)

    # ----------------------------------------------------------------- probes and distances
    def _body(self, flat: Array, b: int, margin: float) -> fcl.CollisionObject:
        """Body b grown by ``margin`` at the poses ``flat`` (a reused object of the thread, moved there)."""
        R = flat[b, :9].reshape(3, 3).T
        return self._probes.object(b, R, flat[b, 9:12], float(flat[b, 12]), margin)

    def _inside(self, flat: Array, b: int, o: int) -> bool:
        """Body b's centre is inside box obstacle o (the body then touches it: see the module doc)."""
        return self._boxes[o] and self.obstacles[o].contains(flat[b, 9:12])

    def hit(self, flat: Array, b: int, o: int, margin: float) -> bool:
        """Body b grown by ``margin`` touches obstacle o (one probe)."""
        self.queries += 1
        if self._inside(flat, b, o):
            return True
        if not self.compiled:
            return self._probes.collide(self._body(flat, b, margin), self._objects[o])
        half = self._body_half[b]
        if half is not None:
            return self.kernels.box_touches_mesh(flat[b], half, margin, self._trees[o])
        return self.kernels.capsule_touches_mesh(flat[b], self._body_radius[b], margin, self._trees[o])

    def distance(self, flat: Array, b: int, o: int) -> tuple[float, Array, Array]:
        """Exact distance of body b to obstacle o on the un-grown shapes: (d, witness on b, on o).

        A touch or a penetration gives :data:`~planner.collision.probes.PENETRATION_M` (-1, FCL's figure
        for a contact it does not measure; witnesses: the body's centre when it is inside a box obstacle).
        """
        self.queries += 1
        if self._inside(flat, b, o):
            centre = np.array(flat[b, 9:12])
            return PENETRATION_M, centre, centre.copy()
        if not self.compiled:
            req = fcl.DistanceRequest(enable_nearest_points=True, enable_signed_distance=True)
            res = fcl.DistanceResult()
            d = float(fcl.distance(self._meshes[o], self._body(flat, b, 0.0), req, res))
            p_obstacle, p_body = res.nearest_points
            return (d if d > 0.0 else PENETRATION_M), np.array(p_body), np.array(p_obstacle)
        half = self._body_half[b]
        d, p_body, p_obstacle = self.kernels.cabin_witness(
            flat[b], _NO_HALF if half is None else half, self._body_radius[b], self._trees[o]
        )
        return (d if d > 0.0 else PENETRATION_M), p_body, p_obstacle

    # ---------------------------------------------------------------- checks
    def state_contacts(
        self, flat: Array, names: tuple[str, ...], clearance: float, all_contacts: bool
    ) -> list[Contact]:
        """The obstacle contacts at one state: every checked pair within ``clearance`` (or the first)."""
        lb = self.lower_bounds(flat, clearance)
        out: list[Contact] = []
        for b, o in zip(*np.nonzero(lb <= clearance), strict=True):
            if self.hit(flat, int(b), int(o), clearance):
                out.append(obstacle_contact(names[b], self.names[o], clearance))
                if not all_contacts:
                    break
        return out

    def clear(self, flat: Array, clearance: float) -> bool:
        """True when every checked pair keeps ``clearance`` at the state."""
        lb = self.lower_bounds(flat, clearance)
        return not any(
            self.hit(flat, int(b), int(o), clearance)
            for b, o in zip(*np.nonzero(lb <= clearance), strict=True)
        )
