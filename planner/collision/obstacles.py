"""Obstacles added to a cabin: installed units, transport fixtures, a unit waiting on its dock.

An obstacle is a rigid body at a fixed pose in the base frame -- a box, or a triangle mesh -- with its own
FCL object. A world compares every robot body (and the payload) with every obstacle by clearance, exactly as
with the cabin, but the cabin's mesh-derived caches (its BVH, clearance grid and carriage table) are not
touched: adding an installed unit to a world costs one small FCL object and a few arrays, not a rebuild
of the cabin's caches (which stay shared by every world on the cabin).

Certification follows the cabin's rules (:mod:`planner.collision.world`):

* **States**: a conservative prune first -- every body is covered by spheres (its fine cover), and a sphere
  whose distance to the obstacle's bounding box exceeds its radius plus the clearance cannot touch the
  obstacle; what the prune cannot prove clear goes to an FCL *collision* query of the body grown by the
  clearance against the obstacle.
* **Motions** q(t) = q_a + t (q_b - q_a): no point of body b moves more than D_b = rho_b . |q_b - q_a| over
  the segment (the world's reach bounds). At a checked t the pair (body, obstacle) is proven to have a
  distance d >= clearance + margin (its sphere lower bound, else the exact FCL distance), so every t' with
  |t' - t| D_b <= d - clearance keeps the clearance, and the walk steps on by (d - clearance) / D_b.
  A state that cannot prove the margin refuses the motion there (it may be a real contact).
* **Distances**: exact FCL distances on the un-grown shapes (the obstacle always first, as a mesh: FCL's
  box-box distance is wrong in face-parallel cases and its shape-vs-mesh witnesses come swapped).

**Allowed pairs** ``(body, obstacle)`` are left out of every check and distance of the world that allows
them: a planner builds such a world only for the short straight motions where the pair must come close
(a gripper closing on the unit it grasps); every other world keeps the clearance for that pair.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from functools import cache

import fcl
import numpy as np

from planner.collision.bodies import BodySet
from planner.collision.kernels.buffers import cover
from planner.collision.probes import GrownShapes
from planner.collision.reports import Contact
from planner.core.exceptions import InvalidInput
from planner.core.types import Array, IntArray

__all__ = ["Obstacle", "ObstacleSet", "obstacle_contact"]


@cache
def _box_mesh(size: tuple[float, float, float]) -> fcl.BVHModel:
    """An FCL triangle mesh of a box centred on its frame (for exact distances, see the module doc)."""
    import trimesh

    m = trimesh.creation.box(extents=size)
    return _bvh(np.asarray(m.vertices, dtype=float), np.asarray(m.faces, dtype=np.int64))


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
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
        return (signs * h) @ T[:3, :3].T + T[:3, 3]

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


def _rows_times(local: Array, M: Array) -> Array:
    """Local (S, 3) times each M (n, 3, 3): (n, S, 3), written out (no threaded BLAS call for 3 x 3)."""
    return (
        local[None, :, 0, None] * M[:, None, 0, :]
        + local[None, :, 1, None] * M[:, None, 1, :]
        + local[None, :, 2, None] * M[:, None, 2, :]
    )


def obstacle_contact(body: str, obstacle: str, margin: float) -> Contact:
    """The contact of a body with an obstacle within ``margin`` [m] (kind ``"obstacle"``)."""
    return Contact("obstacle", (body, obstacle), f"{body} within {margin:.4g} m of {obstacle}")


class ObstacleSet:
    """The obstacles of one world, its bodies' sphere covers against them, and the FCL queries.

    Args:
        obstacles: The obstacles (names unique).
        bodies: The world's bodies.
        allowed: ``(body name, obstacle name)`` pairs left out of every check and distance.
    """

    def __init__(
        self,
        obstacles: tuple[Obstacle, ...],
        bodies: BodySet,
        allowed: frozenset[tuple[str, str]] = frozenset(),
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
        self._R_bound = np.array([T[:3, :3] for T, _ in bounds]).reshape(n_o, 3, 3)
        self._p_bound = np.array([T[:3, 3] for T, _ in bounds]).reshape(n_o, 3)
        self._half = np.array([h for _, h in bounds]).reshape(n_o, 3)
        self._origin_local = np.einsum("oi,oij->oj", self._p_bound, self._R_bound)  # p_o R_o (O, 3)
        self._objects = [o.collision_object() for o in obstacles]
        self._meshes = [fcl.CollisionObject(o.mesh_model(), _tf(o.T_base_obstacle)) for o in obstacles]
        # The bodies' fine sphere covers: box bodies by local centre, capsules by a fraction of the length.
        spheres = cover(bodies.shapes, bodies.sphere_centres, bodies.sphere_radii)
        self._sphere_body, self._local, self._frac = spheres.table
        self._radii = spheres.radii
        self._capsule = np.array([s.kind == "capsule" for s in bodies.shapes])
        self._capsule_r = np.array([s.radius for s in bodies.shapes])
        self._box_r = np.array([0.5 * float(np.linalg.norm(s.size)) for s in bodies.shapes])
        self._grown = GrownShapes(bodies.shapes)
        self._local_state = threading.local()
        self.queries = 0

    def __len__(self) -> int:
        return len(self.obstacles)

    # ---------------------------------------------------------------- bounds
    def _box_distance(self, points: Array) -> Array:
        """Distances (P, O) of points (P, 3) to every obstacle's bounding box (0 inside)."""
        # In each box's axes: (x - p_o) R_o = x R_o - p_o R_o, one batched product for all boxes.
        R = self._R_bound  # written out, not matmul: a threaded BLAS call costs more than these sums
        local = (
            points[None, :, 0, None] * R[:, None, 0, :]
            + points[None, :, 1, None] * R[:, None, 1, :]
            + points[None, :, 2, None] * R[:, None, 2, :]
            - self._origin_local[:, None, :]
        )  # (O, P, 3)
        outside = np.maximum(np.abs(local) - self._half[:, None, :], 0.0)
        return np.sqrt(np.sum(outside * outside, axis=2)).T

    def lower_bounds(self, flat: Array, threshold: float | Array = np.inf) -> Array:
        """Certified lower bounds (B, O) of each body's distance to each obstacle at one state.

        ``flat`` (B, 13) are the body poses (rotation column-major, centre, capsule length). First each
        body's bounding sphere (centre, half-diagonal or half-length + radius): its distance to the
        obstacle's bounding box minus its radius. A pair whose bound is not above ``threshold`` (scalar or
        (B, 1)) is refined with the body's fine sphere cover (the smallest of its spheres' bounds).
        Allowed pairs are +inf.
        """
        out = self.coarse_bounds_batch(flat[None])[0]
        near = np.flatnonzero(np.any(out <= threshold, axis=1))
        for b in near.tolist():  # both bound the distance from below: keep the larger
            fine = self.fine_bounds_batch(flat[b][None], b)[0]
            out[b] = np.where(self.active[b], np.maximum(out[b], fine), np.inf)
        return out

    def coarse_bounds_batch(self, poses: Array, allowed_too: bool = False) -> Array:
        """Certified lower bounds (N, B, O) of each body's distance to each obstacle at N states, coarse.

        ``poses`` (N, B, 13): each body's bounding sphere (centre, half-diagonal or half-length + radius)
        against each obstacle's bounding box, in one vectorised pass. Allowed pairs are +inf unless
        ``allowed_too`` (their bounds, for reports). :meth:`fine_bounds_batch` refines them.
        """
        n, n_b = poses.shape[0], poses.shape[1]
        n_o = len(self.obstacles)
        length = poses[:, :, 12]
        capsule_r = self._capsule_r[None, :] + 0.5 * length
        radius = np.where(self._capsule[None, :], capsule_r, self._box_r[None, :])
        out = self._box_distance(poses[:, :, 9:12].reshape(-1, 3)).reshape(n, n_b, n_o) - radius[:, :, None]
        active = np.ones_like(self.active) if allowed_too else self.active
        return np.where(active[None], out, np.inf)

    def fine_bounds_batch(self, poses_b: Array, b: int) -> Array:
        """Certified lower bounds (n, O) of body b's distance to each obstacle, from its fine sphere cover.

        ``poses_b`` (n, 13) are body b's poses: the smallest of its spheres' distances to the obstacle's
        bounding box minus their radii (every pair, allowed ones too).
        """
        sel = np.flatnonzero(self._sphere_body == b)
        Rt = poses_b[:, :9].reshape(-1, 3, 3)  # R^T (column-major storage), (n, 3, 3)
        centres = (
            poses_b[:, None, 9:12]
            + _rows_times(self._local[sel], Rt)  # (R local)^T = local^T R^T
            + Rt[:, None, 2, :] * (self._frac[sel][None, :] * poses_b[:, 12][:, None])[..., None]
        )  # (n, S_b, 3)
        d = self._box_distance(centres.reshape(-1, 3)).reshape(len(poses_b), len(sel), len(self.obstacles))
        return np.min(d - self._radii[sel][None, :, None], axis=1)

    def mesh_object(self, o: int) -> fcl.CollisionObject:
        """Obstacle o as a posed FCL triangle mesh (the target of exact distances and swept hulls)."""
        return self._meshes[o]

    # ----------------------------------------------------------------- FCL
    def _body(self, flat: Array, b: int, margin: float) -> fcl.CollisionObject:
        R = flat[b, :9].reshape(3, 3).T
        return fcl.CollisionObject(
            self._grown(b, margin, float(flat[b, 12])), fcl.Transform(R, flat[b, 9:12])
        )

    def hit(self, flat: Array, b: int, o: int, margin: float) -> bool:
        """Body b grown by ``margin`` touches obstacle o (one FCL collision query)."""
        self.queries += 1
        return bool(
            fcl.collide(
                self._body(flat, b, margin), self._objects[o], fcl.CollisionRequest(), fcl.CollisionResult()
            )
            > 0
        )

    def distance(self, flat: Array, b: int, o: int) -> tuple[float, Array, Array]:
        """Exact distance of body b to obstacle o on the un-grown shapes: (d, witness on b, on o).

        Penetration gives d <= 0 (FCL's signed distance where it has one).
        """
        self.queries += 1
        req = fcl.DistanceRequest(enable_nearest_points=True, enable_signed_distance=True)
        res = fcl.DistanceResult()
        d = float(fcl.distance(self._meshes[o], self._body(flat, b, 0.0), req, res))
        p_obstacle, p_body = res.nearest_points
        return d, np.array(p_body), np.array(p_obstacle)

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
