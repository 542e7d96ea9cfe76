"""The collision world: robot + payload against a cabin mesh and themselves, exact and certified.

Every decision that something is *clear* is certified; nothing is sampled at a fixed resolution:

* **State check** (:meth:`CollisionWorld.check_state`): limits and singularity margins, then each body
  against the cabin and each non-adjacent pair of bodies. Bodies are grown by the clearance and tested with
  FCL *collision* queries (microseconds), never distance queries (milliseconds). Before that, a
  conservative prune: every body is covered by spheres, and a sphere whose certified distance lower bound
  (:class:`~planner.collision.clearance_grid.ClearanceGrid`) exceeds its radius plus the clearance cannot
  touch the cabin; two bodies whose sphere covers are apart by more than the clearance cannot touch each
  other. Only what the prune cannot prove clear goes to FCL.
* **Motion check** (:meth:`CollisionWorld.check_motion`): along the straight joint-space segment
  q(t) = q_a + t (q_b - q_a), no point of body b moves more than D_b = rho_b . |q_b - q_a| (reach bounds,
  :mod:`planner.collision.bodies`); a pair's relative displacement is bounded likewise, without the joints
  that move both bodies rigidly together. Each body and pair is advanced along t with certified steps
  (its proven spare clearance over its displacement bound), so every body keeps ``clearance`` everywhere
  along the segment, not just at the checked states.
* **Distances** (:meth:`CollisionWorld.min_distance`, :meth:`clearance_profile`): FCL distance queries,
  where a number is needed (reports), pruned by the same lower bounds (branch and bound).
"""

from __future__ import annotations

import hashlib
import math
import threading
import weakref
from dataclasses import dataclass, field
from functools import cache
from typing import Any

import casadi as ca
import fcl
import numpy as np
from numpy.typing import NDArray

from planner.collision import kernels
from planner.collision.bodies import (
    BodySet,
    PayloadGeometry,
    Shape,
    cabin8_bodies,
    link_slope_bound,
    segment_reach_bounds,
)
from planner.collision.clearance_grid import ClearanceGrid, cached_build
from planner.core.exceptions import InvalidInput
from planner.kinematics import chain, parallel
from planner.kinematics.compiled import FastFunction, dense_function
from planner.meshio.load import LoadedMesh
from planner.robots.cabin8 import Cabin8, Cabin8Kinematics

Array = NDArray[np.float64]

DEFAULT_CLEARANCE_M = 0.01
DEFAULT_MOTION_MARGIN_M = 0.005
DEFAULT_SELF_CLEARANCE_M = 0.005
#: Joint-space spacing [m or rad] at which limits and singularity margins are checked along a motion.
LIMIT_STEP = 0.005
MIN_MOTION_MARGIN_M = 1e-4


@dataclass(frozen=True)
class Contact:
    """Why a state is invalid: a limit, a body against the cabin, or a pair of bodies."""

    kind: str  # "limit" | "cabin" | "self"
    bodies: tuple[str, ...]
    detail: str

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {"kind": self.kind, "bodies": list(self.bodies), "detail": self.detail}


@dataclass(frozen=True)
class StateReport:
    """Result of a state check: ``valid`` and, when not, every contact found."""

    valid: bool
    contacts: tuple[Contact, ...] = ()


@dataclass(frozen=True)
class MotionReport:
    """Result of a certified motion check."""

    valid: bool
    states_checked: int
    fcl_queries: int
    t_fail: float | None = None
    contacts: tuple[Contact, ...] = ()


@dataclass(frozen=True)
class PathReport:
    """Result of :meth:`CollisionWorld.check_path`.

    ``first_bad`` is the index of the sample starting the first piece that failed (None if valid).
    """

    valid: bool
    motion_checks: int
    last_checked: int
    first_bad: int | None
    contacts: tuple[Contact, ...] = ()


@dataclass(frozen=True)
class _State:
    """Body poses (flat: R column-major, p, length per body) and certified bounds at one configuration."""

    flat: Array
    cabin_lb: Array
    pair_lb: Array
    admissible: bool = True

    def R(self, b: int) -> Array:
        """Rotation of body b."""
        return self.flat[b, :9].reshape(3, 3).T

    def p(self, b: int) -> Array:
        """Centre of body b."""
        return self.flat[b, 9:12]

    def length(self, b: int) -> float:
        """Capsule length of body b (0 for boxes)."""
        return float(self.flat[b, 12])


_VALID = StateReport(True)


@dataclass(frozen=True)
class Distance:
    """Minimum distance between the robot (with payload) and the cabin or itself, with witnesses."""

    distance_m: float
    bodies: tuple[str, str]
    point_a: Array = field(repr=False)
    point_b: Array = field(repr=False)


def _pose_function(kin: Cabin8Kinematics, names: tuple[str, ...]) -> ca.Function:
    """Compiled (q, T_tool_box) -> body poses and the admissibility vector c(q) of the named bodies.

    Body poses: R column-major, p, capsule length -- 13 values per body.
    """
    q = kin.q_sx
    T_tb = ca.SX.sym("T_tool_box", 4, 4)
    frames = kin.frames_sx
    pts = parallel.stage_points(kin.geometry, q[chain.X], q[chain.Y], q[chain.GAMMA], xp=ca)

    def p3(pt: tuple[ca.SX, ca.SX]) -> ca.SX:
        return ca.vertcat(pt[0], pt[1], q[chain.D1])

    def seg(a: ca.SX, b: ca.SX) -> tuple[ca.SX, ca.SX, ca.SX]:
        d = b - a
        length = ca.norm_2(d)
        z = d / length
        # Any unit vector normal to z completes the frame (a capsule is symmetric about its axis).
        helper = ca.if_else(ca.fabs(z[0]) < 0.9, ca.DM([1, 0, 0]), ca.DM([0, 1, 0]))
        x = ca.cross(helper, z)
        x = x / ca.norm_2(x)
        y = ca.cross(z, x)
        return ca.horzcat(x, y, z), 0.5 * (a + b), length

    outs: list[ca.SX] = []
    for name in names:
        if name == "carriage":
            R, p, length = ca.SX.eye(3), ca.vertcat(0, -0.06, q[chain.D1]), ca.SX(0)
        elif name == "platform":
            R, p, length = frames[2][0:3, 0:3], frames[2][0:3, 3], ca.SX(0)
        elif name == "payload":
            T = ca.mtimes(frames[6], T_tb)
            R, p, length = T[0:3, 0:3], T[0:3, 3], ca.SX(0)
        else:
            a, b = {
                "link_ab": (p3(pts.A), p3(pts.B)),
                "link_cd": (p3(pts.C), p3(pts.D)),
                "link_ef": (p3(pts.E), p3(pts.F)),
                "column": (frames[2][0:3, 3], frames[3][0:3, 3]),
                "arm": (frames[3][0:3, 3], frames[4][0:3, 3]),
                "slide": (frames[4][0:3, 3], frames[6][0:3, 3]),
            }[name]
            R, p, length = seg(a, b)
        outs.append(ca.vertcat(ca.vec(R), p, length))
    return dense_function(
        "body_poses",
        [q, T_tb],
        [ca.vertcat(*outs), kin.constraints_sx(q)],
        {"cse": True},
    )


#: Compiled pose functions by kinematic model and body list (building one takes ~10 ms).
_POSE_FUNCTIONS: weakref.WeakKeyDictionary[
    Cabin8Kinematics, dict[tuple[str, ...], tuple[ca.Function, FastFunction]]
]
_POSE_FUNCTIONS = weakref.WeakKeyDictionary()


def _pose_functions(kin: Cabin8Kinematics, names: tuple[str, ...]) -> tuple[ca.Function, FastFunction]:
    """The pose function of :func:`_pose_function` and its buffered wrapper, built once per model."""
    by_names = _POSE_FUNCTIONS.setdefault(kin, {})
    key = tuple(names)
    entry = by_names.get(key)
    if entry is None:
        fn = _pose_function(kin, key)
        entry = by_names[key] = (fn, FastFunction(fn))
    return entry


@cache
def _cabin_bvh(sha256: str, vertices_bytes: bytes, faces_bytes: bytes) -> fcl.BVHModel:
    vertices = np.frombuffer(vertices_bytes).reshape(-1, 3)
    faces = np.frombuffer(faces_bytes, dtype=np.int64).reshape(-1, 3)
    model = fcl.BVHModel()
    model.beginModel(len(vertices), len(faces))
    model.addSubModel(vertices, faces.astype(np.int32))
    model.endModel()
    return model


@cache
def _cabin_grid(sha256: str, vertices_bytes: bytes, faces_bytes: bytes, step: float) -> ClearanceGrid:
    vertices = np.frombuffer(vertices_bytes).reshape(-1, 3)
    faces = np.frombuffer(faces_bytes, dtype=np.int64).reshape(-1, 3)
    # sha256 holds the mesh's content hash and its pose; the vertices are in the base frame already.
    key = hashlib.sha256(sha256.encode() + vertices_bytes + faces_bytes).hexdigest()
    return cached_build(key, vertices, faces, step)


#: Carriage clearance tables by (cabin, carriage shape, rail travel): CollisionWorld._build_carriage_table.
_CARRIAGE_TABLES: dict[tuple[str, str, float, float], tuple[float, float, Array]] = {}


@cache
def _box_bvh(size: tuple[float, float, float]) -> fcl.BVHModel:
    import trimesh

    m = trimesh.creation.box(extents=size)
    model = fcl.BVHModel()
    model.beginModel(len(m.vertices), len(m.faces))
    model.addSubModel(np.asarray(m.vertices), np.asarray(m.faces, dtype=np.int32))
    model.endModel()
    return model


def _fcl_geometry(shape: Shape, margin: float, length: float) -> Any:
    grown = shape.inflated(margin)
    if grown.kind == "box":
        return fcl.Box(*grown.size)
    return fcl.Capsule(grown.radius, length)


class CollisionWorld:
    """Robot (+ payload) and cabin, with exact, certified state and motion checks.

    Args:
        robot: The cabin8 model.
        cabin: The cabin mesh in the base frame (``None``: free space, self-collision only).
        payload: The carried payload (``None``: none).
        grid_step_m: Node spacing of the clearance lower-bound grid [m].
        self_clearance: Distance [m] non-adjacent bodies keep from each other.
        reference: Use the reference routes (CasADi poses, the motion walk in Python) instead of the
            compiled kernels; same verdicts, slower (tests and the benchmark compare the two).

    Geometry that depends only on the cabin (FCL BVH, clearance grid) is cached per mesh content and pose,
    so several worlds on one cabin share it.
    """

    def __init__(
        self,
        robot: Cabin8,
        cabin: LoadedMesh | None = None,
        payload: PayloadGeometry | None = None,
        grid_step_m: float = 0.03,
        self_clearance: float = DEFAULT_SELF_CLEARANCE_M,
        reference: bool = False,
    ) -> None:
        _check_clearance(self_clearance)
        self.self_clearance = float(self_clearance)
        self.reference = bool(reference)
        self.robot = robot
        self.cabin = cabin
        self.payload = payload
        self.bodies: BodySet = cabin8_bodies(robot, payload)
        self.names = self.bodies.names
        self._pose_fn, self._pose_fast = _pose_functions(robot.kin, self.bodies.names)
        self._T_tool_box = payload.T_tool_box if payload is not None else np.eye(4)
        self._cabin_obj: fcl.CollisionObject | None = None
        self._grid: ClearanceGrid | None = None
        if cabin is not None:
            key = (
                cabin.sha256 + cabin.T_base_mesh.tobytes().hex(),
                cabin.vertices.tobytes(),
                cabin.faces.astype(np.int64).tobytes(),
            )
            self._cabin_obj = fcl.CollisionObject(_cabin_bvh(*key), fcl.Transform())
            self._grid = _cabin_grid(*key, grid_step_m)
        self._geoms: dict[tuple[int, float, float], Any] = {}
        self._local = threading.local()
        self._req = fcl.CollisionRequest()
        self._n_bodies = len(self.names)
        self._capsule = [s.kind == "capsule" for s in self.bodies.shapes]
        self._link_mask = np.array([n in ("link_ab", "link_cd", "link_ef") for n in self.names])
        self._fcl_queries = 0
        # Fine cover (cabin bounds): radii and the first sphere of each body, for per-body minima. With a
        # cabin the carriage's bound comes from its exact clearance table, so it needs no spheres.
        self._carriage = self.names.index("carriage")
        fine_centres = list(self.bodies.sphere_centres)
        fine_radii = list(self.bodies.sphere_radii)
        if cabin is not None:
            fine_centres[self._carriage] = np.zeros((0, 3))
            fine_radii[self._carriage] = np.zeros(0)
        fine_counts = [len(r) for r in fine_radii]
        self._fine_r = np.concatenate(fine_radii)
        self._fine_start = np.concatenate([[0], np.cumsum(fine_counts)[:-1]]).astype(int)
        self._fine_empty = np.array([n == 0 for n in fine_counts])
        # Coarse cover (self bounds): every sphere pair of every checked body pair, grouped by body pair.
        counts = [len(r) for r in self.bodies.coarse_radii]
        self._sph_r = np.concatenate(self.bodies.coarse_radii)
        self._sph_start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(int)
        self._pair_a = np.array([a for a, _ in self.bodies.pairs], dtype=int)
        self._pair_b = np.array([b for _, b in self.bodies.pairs], dtype=int)
        ia, ib = [], []
        for a, b in self.bodies.pairs:
            ga, gb = np.meshgrid(
                np.arange(self._sph_start[a], self._sph_start[a] + counts[a]),
                np.arange(self._sph_start[b], self._sph_start[b] + counts[b]),
                indexing="ij",
            )
            ia.append(ga.ravel())
            ib.append(gb.ravel())
        sizes = [len(x) for x in ia]
        bounds = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
        self._pair_ia = np.concatenate(ia) if ia else np.zeros(0, dtype=int)
        self._pair_ib = np.concatenate(ib) if ib else np.zeros(0, dtype=int)
        self._pair_rsum = self._sph_r[self._pair_ia] + self._sph_r[self._pair_ib]
        self._pair_sph = [np.arange(bounds[k], bounds[k + 1]) for k in range(len(self.bodies.pairs))]
        self._carriage_table: tuple[float, float, Array] | None = None
        if self._cabin_obj is not None:
            # The table depends on the cabin's geometry (the vertices as loaded, in the base frame: the file
            # hash alone would not tell units apart), the carriage's shape and the rail: built once.
            table_key = (
                key[0] + hashlib.sha256(key[1] + key[2]).hexdigest(),
                repr(self.bodies.shapes[self._carriage]),
                robot.limits.lower[0],
                robot.limits.upper[0],
            )
            table = _CARRIAGE_TABLES.get(table_key)
            if table is None:
                if len(_CARRIAGE_TABLES) >= 64:
                    _CARRIAGE_TABLES.clear()
                table = _CARRIAGE_TABLES[table_key] = self._build_carriage_table()
            self._carriage_table = table
        # Flat views and bounds for the compiled kernels.
        self._fine_bounds = np.concatenate([self._fine_start, [len(self._fine_r)]]).astype(np.int64)
        self._coarse_bounds = np.concatenate([self._sph_start, [len(self._sph_r)]]).astype(np.int64)
        self._grid_flat = self._grid.lower_bound.reshape(-1) if self._grid is not None else np.zeros(1)
        self._grid_shape = np.array(self._grid.lower_bound.shape if self._grid is not None else (1, 1, 1))
        self._fine_cover = _cover_table(self.bodies.shapes, tuple(fine_centres))
        self._coarse_cover = _cover_table(self.bodies.shapes, self.bodies.coarse_centres)
        self._radius = np.array([s.radius for s in self.bodies.shapes])
        self._capsule_pair = np.array(
            [
                self.bodies.shapes[a].kind == "capsule" and self.bodies.shapes[b].kind == "capsule"
                for a, b in self.bodies.pairs
            ],
            dtype=np.bool_,
        )
        shapes = self.bodies.shapes
        self._half = np.array([np.array(s.size) / 2 if s.kind == "box" else np.zeros(3) for s in shapes])
        self._capsule_box = np.array(
            [
                1
                if shapes[a].kind == "capsule" and shapes[b].kind == "box"
                else 2
                if shapes[a].kind == "box" and shapes[b].kind == "capsule"
                else 0
                for a, b in self.bodies.pairs
            ],
            dtype=np.int64,
        )
        self._exact_pair = self._capsule_pair | (self._capsule_box > 0)
        self._c_lo = robot.c_lower - 1e-9
        self._c_hi = robot.c_upper + 1e-9
        g = self._grid
        self._kernel_args = (
            *self._fine_cover,
            self._fine_r,
            self._fine_bounds,
            self._grid_flat,
            g.origin if g is not None else np.zeros(3),
            1.0 / g.step if g is not None else 1.0,
            self._grid_shape,
            g is not None,
            *self._coarse_cover,
            self._sph_r,
            self._coarse_bounds,
            self._pair_a,
            self._pair_b,
            self._radius,
            self._capsule_pair,
            self._half,
            self._capsule_box,
            self._carriage,
            *(
                (self._carriage_table[2], self._carriage_table[0], self._carriage_table[1])
                if self._carriage_table is not None
                else (np.zeros(0), 0.0, 1.0)
            ),
        )
        # Closed-form poses in the kernel (the CasADi pose function stays the reference, :meth:`poses`).
        if len(robot.c_lower) != kernels.N_CONSTRAINTS:
            raise InvalidInput(
                f"robot: {len(robot.c_lower)} admissibility values, the collision kernels expect "
                f"{kernels.N_CONSTRAINTS}",
                field="robot",
            )
        links = robot.desc.serial_chain
        mdh = np.array(
            [
                [link.alpha, link.a, link.theta, link.d, float(j), 1.0 if revolute else 0.0]
                for link, (j, revolute) in zip(links, chain.LINK_VARIABLES, strict=True)
            ]
        )
        geo = robot.geometry
        table = self._carriage_table
        self._fbuf, self._ibuf = kernels.pack(
            np.ascontiguousarray(self._T_tool_box, dtype=float),
            mdh,
            np.array([geo.L1, geo.L2, geo.L3, geo.L4]),
            np.array([kernels.KIND_CODES[n] for n in self.names], dtype=np.int64),
            (*self._fine_cover, self._fine_r, self._fine_bounds),
            g.origin if g is not None else np.zeros(3),
            1.0 / g.step if g is not None else 1.0,
            self._grid_shape,
            g is not None,
            (*self._coarse_cover, self._sph_r, self._coarse_bounds),
            self._pair_a,
            self._pair_b,
            self._radius,
            self._capsule_pair,
            self._half,
            self._capsule_box,
            self._carriage,
            table[2] if table is not None else np.zeros(0),
            table[0] if table is not None else 0.0,
            table[1] if table is not None else 1.0,
            self._c_lo,
            self._c_hi,
        )
        self._grid_flat = np.ascontiguousarray(self._grid_flat, dtype=float)
        self._upper_slack = g.upper_slack if g is not None else -1.0
        # Motion walks: probe for more than the bounds prove only where they prove nothing (states cost
        # ~2 us, an FCL probe 10-50 us); the reference route keeps the original always-probe policy.
        self.probe_when_proven = self.reference

    # ------------------------------------------------------------------ poses
    def _evaluate(self, q: Array) -> tuple[Array, Array]:
        """Flat body poses (N, B, 13) and admissibility values c(q) (N, m) for (N, 8) or (8,) joints."""
        q2 = np.atleast_2d(np.asarray(q, dtype=float))
        n = q2.shape[0]
        if n == 1:
            flat, c = (x[None, :] for x in self._pose_fast(q2[0], self._T_tool_box))
        elif not self.reference:  # the closed-form kernel, ~100x faster than CasADi's batch call
            poses, c = np.empty((n, self._n_bodies, 13)), np.empty((n, kernels.N_CONSTRAINTS))
            kernels.packed_poses(np.ascontiguousarray(q2), self._fbuf, self._ibuf, poses, c)
            return poses, c
        else:
            # CasADi evaluates a function column-wise when given N stacked columns.
            outs = self._pose_fn(ca.DM(q2.T), ca.DM(self._T_tool_box))
            flat, c = (np.asarray(o.full(), dtype=float).T for o in outs)
        return np.ascontiguousarray(flat.reshape(n, self._n_bodies, 13)), c

    def _split(self, flat: Array) -> tuple[Array, Array, Array]:
        n = flat.shape[0]
        R = flat[:, :, :9].reshape(n, self._n_bodies, 3, 3).transpose(0, 1, 3, 2)
        return R, flat[:, :, 9:12], flat[:, :, 12]

    def cover_centres(self, q: Array, coarse: bool = False) -> Array:
        """World centres (N, S, 3) of the fine (cabin) or coarse (self) sphere cover, grouped by body."""
        flat, _ = self._evaluate(q)
        cover = self._coarse_cover if coarse else self._fine_cover
        return kernels.cover_centres_batch(flat, *cover)

    def poses(self, q: Array) -> tuple[Array, Array, Array]:
        """(R (N, B, 3, 3), p (N, B, 3), lengths (N, B)) of every body for (N, 8) or (8,) joints.

        Each body frame is centred on the body; a capsule's axis is its frame's z axis.
        """
        return self._split(self._evaluate(q)[0])

    def cabin_lower_bounds(self, fine_centres: Array, d1: Array) -> Array:
        """(N, B) certified lower bound of each body's distance to the cabin (inf without a cabin).

        From the fine sphere cover and the clearance grid; for the carriage, which moves with d1 only, also
        from its exact clearance table along the rail (whichever bound is larger).
        """
        n = fine_centres.shape[0]
        if self._grid is None:
            return np.full((n, self._n_bodies), np.inf)
        lb = self._grid.query(fine_centres) - self._fine_r[None, :]
        out = np.minimum.reduceat(lb, np.minimum(self._fine_start, lb.shape[1] - 1), axis=1)
        out[:, self._fine_empty] = np.inf  # reduceat returns an element for an empty group
        if self._carriage_table is not None:
            z0, dz, table = self._carriage_table
            k = np.clip(np.rint((d1 - z0) / dz).astype(int), 0, len(table) - 1)
            exact = table[k] - np.abs(d1 - (z0 + k * dz))
            current = out[:, self._carriage]
            out[:, self._carriage] = np.where(np.isinf(current), exact, np.maximum(current, exact))
        return out

    def pair_lower_bounds(self, centres: Array, threshold: float) -> Array:
        """(N, P) certified lower bound of the distance between the bodies of each checked pair.

        First the separation of the bodies' boxes (from their coarse sphere covers) along the axes; where
        that is not above ``threshold`` for some state, also the sphere-cover gap (the larger bound counts).
        """
        n = centres.shape[0]
        if len(self._pair_a) == 0:
            return np.full((n, 0), np.inf)
        r = self._sph_r[None, :, None]
        lo = np.minimum.reduceat(centres - r, self._sph_start, axis=1)
        hi = np.maximum.reduceat(centres + r, self._sph_start, axis=1)
        sep = np.maximum(lo[:, self._pair_b] - hi[:, self._pair_a], lo[:, self._pair_a] - hi[:, self._pair_b])
        out = np.max(sep, axis=2)
        close = np.flatnonzero(np.any(out <= threshold, axis=0))
        if close.size:
            idx = np.concatenate([self._pair_sph[k] for k in close])
            starts = np.concatenate([[0], np.cumsum([len(self._pair_sph[k]) for k in close])[:-1]])
            ia, ib = self._pair_ia[idx], self._pair_ib[idx]
            gap = np.linalg.norm(centres[:, ia] - centres[:, ib], axis=2) - self._pair_rsum[idx][None, :]
            out[:, close] = np.maximum(out[:, close], np.minimum.reduceat(gap, starts, axis=1))
        return out

    # ------------------------------------------------------------------- FCL
    def _geometry(self, b: int, margin: float, length: float) -> Any:
        shape = self.bodies.shapes[b]
        key = (b, margin, round(length, 9) if shape.kind == "capsule" else 0.0)
        geom = self._geoms.get(key)
        if geom is None:
            if len(self._geoms) > 4096:
                self._geoms.clear()
            geom = _fcl_geometry(shape, margin, length)
            self._geoms[key] = geom
        return geom

    def _object(self, b: int, R: Array, p: Array, length: float, margin: float) -> fcl.CollisionObject:
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
            obj = objects[key] = fcl.CollisionObject(self._geometry(b, margin, length), fcl.Transform(R, p))
        else:
            obj.setRotation(R)
            obj.setTranslation(p)
        return obj

    def _collide(self, o1: fcl.CollisionObject, o2: fcl.CollisionObject) -> bool:
        self._fcl_queries += 1
        try:  # one result object per thread, emptied for each query (a new one costs more than the query)
            res: fcl.CollisionResult = self._local.result
        except AttributeError:
            res = self._local.result = fcl.CollisionResult()
        res.is_collision = False
        res.contacts.clear()
        res.cost_sources.clear()
        return bool(fcl.collide(o1, o2, self._req, res) > 0)

    # --------------------------------------------------------------- checks
    def _limit_contacts(self, q: Array) -> list[Contact]:
        return [
            Contact(
                "limit",
                (v["name"],),
                f"{v['name']}={v['value']:.6g} outside [{v['lower']:.6g}, {v['upper']:.6g}]"
                if isinstance(v["value"], float)
                else "non-finite configuration",
            )
            for v in self.robot.violations(q)
        ]

    def check_state(
        self, q: Array, clearance: float = DEFAULT_CLEARANCE_M, all_contacts: bool = False
    ) -> StateReport:
        """Check one configuration: limits and margins, cabin clearance, self-collision.

        Args:
            q: Joint vector (8,).
            clearance: Minimum distance [m] every body keeps from the cabin. Non-adjacent bodies keep the
                world's ``self_clearance`` from each other.
            all_contacts: Collect every contact instead of stopping at the first.
        """
        _check_clearance(clearance)
        q = _joints(q)
        if self.reference:
            if not np.all(np.isfinite(q)):
                return StateReport(False, tuple(self._limit_contacts(q)))
            state = self._state(q, self.self_clearance)
        else:
            code, flat, cabin, pairs = kernels.packed_check(
                q, self._fbuf, self._ibuf, self._grid_flat, clearance, self.self_clearance, -1.0
            )
            if code == kernels.CLEAR:  # the bounds prove everything: no FCL query
                return _VALID
            if code == kernels.NOT_FINITE:
                return StateReport(False, tuple(self._limit_contacts(q)))
            state = _State(flat, cabin, pairs, code != kernels.INADMISSIBLE)
        contacts = [] if state.admissible else self._limit_contacts(q)
        if contacts and not all_contacts:
            return StateReport(False, tuple(contacts))
        for b in np.flatnonzero(state.cabin_lb <= clearance).tolist():
            if self._cabin_hit(state, b, clearance):
                contacts.append(self._cabin_contact(b, clearance))
                if not all_contacts:
                    break
        else:
            for k in np.flatnonzero(state.pair_lb <= self.self_clearance).tolist():
                if self._pair_hit(state, k, self.self_clearance):
                    contacts.append(self._pair_contact(k, self.self_clearance))
                    if not all_contacts:
                        break
        return StateReport(not contacts, tuple(contacts))

    def is_valid(self, q: Array, clearance: float = DEFAULT_CLEARANCE_M) -> bool:
        """True when limits, margins, cabin clearance and self-clearance all hold at q.

        The verdict of :meth:`check_state`, without building a report: one kernel call, then FCL queries
        only for what the bounds cannot prove clear.
        """
        if self.reference:
            return self.check_state(q, clearance).valid
        _check_clearance(clearance)
        q = _joints(q)
        own = self.self_clearance
        code, flat, cabin, pairs = kernels.packed_check(
            q, self._fbuf, self._ibuf, self._grid_flat, clearance, own, self._upper_slack
        )
        if code != kernels.UNDECIDED:
            return code == kernels.CLEAR  # a certain contact is as invalid as an FCL-found one
        st = _State(flat, cabin, pairs, True)
        for b, lb in enumerate(cabin.tolist()):
            if lb <= clearance and self._cabin_hit(st, b, clearance):
                return False
        for k, lb in enumerate(pairs.tolist()):
            if lb <= own and self._pair_hit(st, k, own):
                return False
        return True

    def _states(self, qs: Array, threshold: float) -> list[_State]:
        """Poses and certified bounds for (N, 8) configurations."""
        qs = np.array(np.atleast_2d(qs), dtype=float)  # a writeable, contiguous copy
        return [self._state(q, threshold) for q in qs]

    def _state(self, q: Array, threshold: float = DEFAULT_CLEARANCE_M) -> _State:
        """Poses and certified bounds at one configuration (8,), contiguous float64: one kernel call.

        ``threshold``: pairs whose bound is not above it get their exact distance where one is known.
        """
        if self.reference:
            return self._state_reference(q, threshold)
        flat, cabin, pairs, ok = kernels.packed_state(q, self._fbuf, self._ibuf, self._grid_flat, threshold)
        return _State(flat, cabin, pairs, ok)

    def _state_reference(self, q: Array, threshold: float) -> _State:
        """:meth:`_state` by the reference route: CasADi pose function, then the bound kernel."""
        slot = self._pose_fast._slot()  # shared by every world of this model: the payload box each time
        slot.args[1][:] = self._T_tool_box.ravel(order="F")
        slot.args[0][:] = q
        slot.trigger()
        flat = slot.res[0].reshape(self._n_bodies, 13).copy()
        cabin, pairs, ok = kernels.state_bounds(
            flat, *self._kernel_args, slot.res[1].copy(), self._c_lo, self._c_hi, threshold
        )
        return _State(flat, cabin, pairs, ok)

    def _carriage_clearance(self, d1_a: float, d1_b: float) -> float:
        """Certified carriage-to-cabin clearance for every d1 between d1_a and d1_b (table minimum)."""
        assert self._carriage_table is not None
        z0, dz, table = self._carriage_table
        lo, hi = sorted((d1_a, d1_b))
        k0 = int(np.clip(np.floor((lo - z0) / dz), 0, len(table) - 1))
        k1 = int(np.clip(np.ceil((hi - z0) / dz), 0, len(table) - 1))
        if lo < z0 or hi > z0 + dz * (len(table) - 1):
            return -np.inf
        # Every d1 in [lo, hi] is within dz/2 of a sample in k0..k1; the distance is 1-Lipschitz in d1.
        return float(table[k0 : k1 + 1].min()) - 0.5 * dz

    def _build_carriage_table(self, step: float = 0.01) -> tuple[float, float, Array]:
        """Exact carriage-to-cabin distance every ``step`` along the rail (the carriage moves with d1 only).

        Between samples the distance changes by at most the rail displacement (it is 1-Lipschitz in d1),
        which the lookup subtracts.
        """
        assert self._cabin_obj is not None
        lo, hi = float(self.robot.limits.lower[0]), float(self.robot.limits.upper[0])
        z = np.arange(lo, hi + step, step)
        b = self._carriage
        geom = self._geometry(b, 0.0, 0.0)
        req = fcl.DistanceRequest()
        table = np.array(
            [
                fcl.distance(
                    fcl.CollisionObject(geom, fcl.Transform(np.array([0.0, -0.06, zi]))),
                    self._cabin_obj,
                    req,
                    fcl.DistanceResult(),
                )
                for zi in z
            ]
        )
        return lo, step, np.where(table < 0, -np.inf, table)

    def _cabin_hit(self, st: _State, b: int, margin: float) -> bool:
        assert self._cabin_obj is not None
        return self._collide(self._object(b, st.R(b), st.p(b), st.length(b), margin), self._cabin_obj)

    def _pair_hit(self, st: _State, k: int, margin: float) -> bool:
        a, b = self.bodies.pairs[k]
        oa = self._object(a, st.R(a), st.p(a), st.length(a), margin / 2)
        ob = self._object(b, st.R(b), st.p(b), st.length(b), margin / 2)
        return self._collide(oa, ob)

    def _exact_spare(self, st: _State, kind_cabin: bool, idx: int, base: float) -> float:
        """Exact distance beyond ``base`` of body ``idx`` to the cabin (or of pair ``idx``), by FCL distance.

        A grown box is a larger box: near its edges and corners it overstates the clearance it tests by up
        to (sqrt 3 - 1) times the growth, so a state whose grown bodies all hit may still be clear by the
        margin. The certified walk asks this exact query (milliseconds against a mesh) only there.
        """
        req = fcl.DistanceRequest()
        res = fcl.DistanceResult()
        self._fcl_queries += 1
        if kind_cabin:
            assert self._cabin_obj is not None
            body = self._object(idx, st.R(idx), st.p(idx), st.length(idx), 0.0)
            return float(fcl.distance(self._cabin_obj, body, req, res)) - base
        a, b = self.bodies.pairs[idx]
        if self.bodies.shapes[a].kind == "box" and self.bodies.shapes[b].kind == "box":
            first = fcl.CollisionObject(_box_bvh(self.bodies.shapes[b].size), fcl.Transform(st.R(b), st.p(b)))
        else:
            first = self._object(b, st.R(b), st.p(b), st.length(b), 0.0)
        second = self._object(a, st.R(a), st.p(a), st.length(a), 0.0)
        return float(fcl.distance(first, second, req, res)) - base

    def _cabin_contact(self, b: int, margin: float) -> Contact:
        return Contact("cabin", (self.names[b],), f"{self.names[b]} within {margin:.4g} m of the cabin")

    def _pair_contact(self, k: int, margin: float) -> Contact:
        a, b = self.bodies.pairs[k]
        return Contact(
            "self",
            (self.names[a], self.names[b]),
            f"{self.names[a]} within {margin:.4g} m of {self.names[b]}",
        )

    def check_motion(
        self,
        q_a: Array,
        q_b: Array,
        clearance: float = DEFAULT_CLEARANCE_M,
        motion_margin: float = DEFAULT_MOTION_MARGIN_M,
        self_clearance: float | None = None,
        reach_ratio: float | None = None,
    ) -> MotionReport:
        """Certify that the straight joint-space motion q_a -> q_b keeps ``clearance`` everywhere.

        Each body (and each checked pair) is advanced separately along t in [0, 1]. At a checked t the body
        is proven clear by a margin E beyond ``clearance`` -- for free when its sphere lower bound allows,
        else by an FCL query on the body grown by ``clearance + E`` for E in a few levels down to
        ``motion_margin``. With D the body's displacement bound for the whole segment, every t' with
        |t' - t| <= E / D is then clear, so the next check is at ``t + (E + motion_margin) / D`` and must
        prove at least ``motion_margin``. A check that cannot prove ``motion_margin`` is refused (it may be
        a real contact). Where the bound proves nothing, the first probe asks for twice the margin proven
        last time (longer steps); with ``probe_when_proven`` (the reference route's setting) also where
        it does -- by default not, as a state costs a few microseconds and an FCL probe tens. Limits and
        margins (smooth functions of q) are checked at every joint step of at most ``LIMIT_STEP``
        (5 mm / 5 mrad) along the segment.

        ``self_clearance`` overrides the world's self-clearance for this check and ``reach_ratio`` raises
        the link-height ratio the reach bounds assume (both used by :meth:`check_path`).
        """
        _check_clearance(clearance)
        own = self.self_clearance if self_clearance is None else float(self_clearance)
        if not (np.isfinite(motion_margin) and MIN_MOTION_MARGIN_M <= motion_margin <= 0.1):
            raise InvalidInput(
                f"motion_margin: must be in [{MIN_MOTION_MARGIN_M}, 0.1] m, got {motion_margin}",
                field="motion_margin",
            )
        q_a, q_b = _joints(q_a), _joints(q_b)
        dq = q_b - q_a
        if not self.reference:
            return self._check_motion_compiled(q_a, q_b, dq, clearance, motion_margin, own, reach_ratio)
        rho, pair_rho = self._segment_reach(q_a, q_b, reach_ratio)
        reach = rho @ np.abs(dq)
        n_fine = int(min(10_000, max(1, np.ceil(float(np.abs(dq).max()) / LIMIT_STEP))))
        t_fine = np.linspace(0.0, 1.0, n_fine + 1)
        qs = q_a[None, :] + t_fine[:, None] * dq[None, :]
        bad = ~self.robot.admissible_batch(qs)
        if bad.any():
            i = int(np.argmax(bad))
            return MotionReport(False, n_fine + 1, 0, float(t_fine[i]), tuple(self._limit_contacts(qs[i])))
        before = self._fcl_queries
        levels = (4 * motion_margin, 2 * motion_margin, motion_margin)
        tasks: list[tuple[str, int, float]] = []
        if self._cabin_obj is not None:
            tasks += [("cabin", b, float(reach[b])) for b in range(self._n_bodies)]
        pair_reach = pair_rho @ np.abs(dq)
        tasks += [("self", k, float(pair_reach[k])) for k in range(len(self.bodies.pairs))]
        # One schedule for all: spacing such that no body or pair moves more than motion_margin between
        # neighbouring states; each task's next check is snapped down onto it (a shorter step stays
        # certified).
        d_max = max((d for _, _, d in tasks), default=0.0)
        # Not capped: one schedule step must never exceed a proven step (at least 2 motion_margin of motion).
        n = int(max(1, np.ceil(d_max / motion_margin)))

        def t_of(i: int) -> float:
            return i / n

        cache: dict[int, _State] = {}

        def state(i: int) -> _State:  # evaluated lazily: the walks visit few of the n + 1 states
            st = cache.get(i)
            if st is None:
                # Exact pair distances where they are small (beyond, the bounds allow long steps anyway).
                st = cache[i] = self._state(q_a + t_of(i) * dq, own + 0.06)
            return st

        # Both end states: a task whose spare clearance at the two ends covers the segment from both sides
        # (free_0 / D + free_1 / D >= 1) needs nothing in between.
        s0, s1 = state(0), state(n)
        for kind, idx, D in tasks:
            base = clearance if kind == "cabin" else own
            f0 = (s0.cabin_lb[idx] if kind == "cabin" else s0.pair_lb[idx]) - base
            f1 = (s1.cabin_lb[idx] if kind == "cabin" else s1.pair_lb[idx]) - base
            if f0 >= motion_margin and f1 >= motion_margin and f0 + f1 >= D:
                continue
            if kind == "cabin" and idx == self._carriage and self._carriage_table is not None:
                # The carriage moves with d1 only: its exact clearance table covers the whole segment.
                if self._carriage_clearance(q_a[chain.D1], q_b[chain.D1]) > clearance:
                    continue
            t_stop = 1.0 - f1 / D if f1 >= motion_margin and D > 0.0 else 1.0
            i, last = 0, motion_margin
            while True:
                st = state(i)
                free = (st.cabin_lb[idx] if kind == "cabin" else st.pair_lb[idx]) - base
                E = free if free >= motion_margin else 0.0
                # Probe for more spare clearance than the bound proves (twice what held last time), then fall
                # back level by level; where the bound proves a margin, only with ``probe_when_proven``.
                exact = kind == "self" and bool(self._exact_pair[idx])  # E is the exact spare clearance
                optimistic = D > 0.0 and not exact and (E == 0.0 or self.probe_when_proven)
                probes = [min(0.3, max(2.0 * last, 2.0 * E, 4.0 * motion_margin))] if optimistic else []
                probes += [lv for lv in levels if E == 0.0 and not exact]
                for level in probes:
                    if level <= E:
                        continue
                    hit = (
                        self._cabin_hit(st, idx, base + level)
                        if kind == "cabin"
                        else self._pair_hit(st, idx, base + level)
                    )
                    if not hit:
                        E = level
                        break
                if E == 0.0 and not exact:  # every grown body hit: the exact distance decides
                    spare = self._exact_spare(st, kind == "cabin", idx, base)
                    E = spare if spare >= motion_margin else 0.0
                last = max(E, motion_margin)
                if E == 0.0:
                    contact = (
                        self._cabin_contact(idx, base + motion_margin)
                        if kind == "cabin"
                        else self._pair_contact(idx, base + motion_margin)
                    )
                    return MotionReport(False, len(cache), self._fcl_queries - before, t_of(i), (contact,))
                # Done when the proven interval reaches the end state's own certified interval.
                if i == n or D <= 0.0 or t_of(i) + E / D >= t_stop:
                    break
                i = min(n, max(i + 1, int(np.floor((t_of(i) + (E + motion_margin) / D) * n + 1e-9))))
        return MotionReport(True, len(cache), self._fcl_queries - before)

    def _check_motion_compiled(
        self,
        q_a: Array,
        q_b: Array,
        dq: Array,
        clearance: float,
        motion_margin: float,
        own: float,
        ratio: float | None,
    ) -> MotionReport:
        """:meth:`check_motion` through the compiled kernels: the same samples, bounds and walk.

        Limits at the same samples, the same reach bounds (:meth:`_segment_reach`), then
        :func:`~planner.collision.kernels.motion_walk`, which evaluates states lazily in compiled code and
        returns here only when a task needs FCL probes on a grown body.
        """
        adq = np.abs(dq)
        n_fine = int(min(10_000, max(1, np.ceil(float(adq.max()) / LIMIT_STEP))))
        bad = kernels.first_inadmissible(q_a, dq, n_fine, self._fbuf, self._ibuf)
        if bad >= 0:
            t = bad * (1.0 / n_fine) if bad < n_fine else 1.0  # numpy.linspace's samples
            return MotionReport(False, n_fine + 1, 0, t, tuple(self._limit_contacts(q_a + t * dq)))
        g = self.robot.geometry
        end = kernels.end_ratio(q_a, q_b, self._fbuf)
        dev = 0.5 * g.L2 * (q_b[chain.GAMMA] - q_a[chain.GAMMA]) ** 2 / 8.0 / min(g.L1, g.L3, 2.0 * g.L4)
        if ratio is not None:
            end = max(end, ratio)
        reach, pair_reach = kernels.segment_reach(
            self.bodies.rho,
            self._link_mask,
            link_slope_bound(end + dev),
            0.5 * g.L2,
            self._pair_a,
            self._pair_b,
            self.bodies.pair_rigid,
            adq,
        )
        has_cabin = self._cabin_obj is not None
        d_max = max([*(reach.tolist() if has_cabin else []), *pair_reach.tolist()], default=0.0)
        n = int(max(1, np.ceil(d_max / motion_margin)))
        cap = min(n + 1, 32)
        slot_of = np.full(n + 1, -1, dtype=np.int64)
        poses = np.empty((cap, self._n_bodies, 13))
        cabin = np.empty((cap, self._n_bodies))
        pairs = np.empty((cap, len(self._pair_a)))
        ci = np.zeros(kernels.CI_SIZE, dtype=np.int64)
        cf = np.zeros(kernels.CF_SIZE)
        ci[kernels.CI_N], ci[kernels.CI_CABIN] = n, has_cabin
        cf[kernels.CF_CLEARANCE], cf[kernels.CF_OWN], cf[kernels.CF_MARGIN] = clearance, own, motion_margin
        # Exact pair distances where they are small (beyond, the bounds allow long steps anyway).
        cf[kernels.CF_THRESHOLD] = own + 0.06
        cf[kernels.CF_PROBE_PROVEN] = self.probe_when_proven
        n_cabin = self._n_bodies if has_cabin else 0
        before = self._fcl_queries
        while True:
            code = kernels.motion_walk(
                ci, cf, q_a, q_b, dq, reach, pair_reach, self._fbuf, self._ibuf, self._grid_flat,
                slot_of, poses, cabin, pairs,
            )  # fmt: skip
            task = int(ci[kernels.CI_TASK])
            is_cabin = task < n_cabin
            idx = task if is_cabin else task - n_cabin
            base = clearance if is_cabin else own
            if code == kernels.WALK_DONE:
                return MotionReport(True, int(ci[kernels.CI_COUNT]), self._fcl_queries - before)
            if code == kernels.WALK_GROW:
                grow = poses.shape[0]
                poses = np.concatenate([poses, np.empty_like(poses[:grow])])
                cabin = np.concatenate([cabin, np.empty_like(cabin[:grow])])
                pairs = np.concatenate([pairs, np.empty_like(pairs[:grow])])
            elif code == kernels.WALK_FAIL:
                contact = (
                    self._cabin_contact(idx, base + motion_margin)
                    if is_cabin
                    else self._pair_contact(idx, base + motion_margin)
                )
                states = int(ci[kernels.CI_COUNT])
                t_fail = float(cf[kernels.CF_TFAIL])
                return MotionReport(False, states, self._fcl_queries - before, t_fail, (contact,))
            else:  # WALK_PROBE: the first level at which the grown body is clear becomes the spare clearance
                slot = int(ci[kernels.CI_SLOT])
                st = _State(poses[slot], cabin[slot], pairs[slot])
                first = kernels.CF_LEVEL0
                levels = cf[first : first + int(ci[kernels.CI_LEVELS])].tolist()
                for level in levels:
                    hit = (
                        self._cabin_hit(st, idx, base + level)
                        if is_cabin
                        else self._pair_hit(st, idx, base + level)
                    )
                    if not hit:
                        cf[kernels.CF_E] = level
                        break
                else:
                    if levels and min(levels) <= motion_margin + 1e-12:  # the last resort: every level hit
                        spare = self._exact_spare(st, is_cabin, idx, base)
                        if spare >= motion_margin:
                            cf[kernels.CF_E] = spare

    def _segment_reach(self, q_a: Array, q_b: Array, ratio: float | None = None) -> tuple[Array, Array]:
        """Reach bounds valid along the straight segment q_a -> q_b.

        The link-height ratios y_B/L1, y_C/L3, y_E/L4 are affine in y and in sin(gamma); along the segment
        they exceed the larger endpoint value by at most (L2/2) dgamma^2 / 8 over the shortest length
        (the sine's deviation from its chord), which bounds the links' slopes.
        """
        c = self.robot.constraint_values_batch(np.stack([q_a, q_b]))
        g = self.robot.geometry
        end = float(np.nanmax(c[:, -3:])) if np.all(np.isfinite(c[:, -3:])) else 1.0
        dev = 0.5 * g.L2 * (q_b[chain.GAMMA] - q_a[chain.GAMMA]) ** 2 / 8.0 / min(g.L1, g.L3, 2.0 * g.L4)
        if ratio is not None:
            end = max(end, ratio)
        return segment_reach_bounds(self.robot, self.bodies, end + dev)

    def check_path(
        self,
        qs: Array,
        clearance: float = DEFAULT_CLEARANCE_M,
        motion_margin: float = DEFAULT_MOTION_MARGIN_M,
        max_run: int = 32,
        max_extra_m: float = 0.002,
    ) -> PathReport:
        """Certify the polyline through (N, 8) configurations: every straight piece keeps ``clearance``.

        Consecutive samples of a trajectory are close, so runs of them are certified together: for a run
        q_i..q_j and its chord q_i -> q_j (parameterised alike), the polyline deviates from the chord by at
        most e (componentwise, attained at the samples, since both are piecewise linear in the parameter).
        Any body point of a polyline configuration is then within rho . e of the same point at the chord
        configuration (rho the per-joint reach bounds), so the chord certified with ``clearance + rho . e``
        (and self-clearance grown alike) certifies the whole run. Runs shrink until that extra is at most
        ``max_extra_m``; a single piece is checked as it is. A run that fails is halved before anything is
        refused (its extra, not the path, may be what failed): only a single piece that fails refuses the
        path, and ``first_bad`` is the sample that starts it.
        """
        _check_clearance(clearance)
        qs = np.atleast_2d(np.asarray(qs, dtype=float))
        n = len(qs)
        if n == 1:
            rep = self.check_state(qs[0], clearance)
            return PathReport(rep.valid, 0, 0, None if rep.valid else 0, rep.contacts)
        ratios = self.robot.constraint_values_batch(qs)[:, -3:]
        ratio = float(np.nanmax(ratios)) if np.all(np.isfinite(ratios)) else 1.0
        rho_all = segment_reach_bounds(self.robot, self.bodies, min(ratio + 0.02, 0.999))[0]
        rho_joint = np.max(rho_all, axis=0)  # per joint, the largest reach of any body
        qs = np.ascontiguousarray(qs)
        rho_joint = np.ascontiguousarray(rho_joint, dtype=float)
        i, checks, cap = 0, 0, max_run
        while i < n - 1:
            # Both bodies of a self pair may move: the kernel doubles the reach-weighted deviation.
            j, extra = kernels.run_extent(qs, i, min(n - 1, i + cap), rho_joint, float(max_extra_m))
            motion = self.check_motion(
                qs[i],
                qs[j],
                clearance + extra,
                motion_margin,
                self.self_clearance + extra,
                min(ratio + 0.02, 0.999),
            )
            checks += 1
            if motion.valid:
                i, cap = j, min(max_run, 2 * cap)
            elif j == i + 1:
                return PathReport(False, checks, i, i, motion.contacts)
            else:
                cap = max(1, (j - i) // 2)  # the run again in halves
        return PathReport(True, checks, n - 1, None, ())

    def motion_valid(self, q_a: Array, q_b: Array, clearance: float = DEFAULT_CLEARANCE_M) -> bool:
        """True when the straight motion q_a -> q_b is certified clear (see :meth:`check_motion`)."""
        return self.check_motion(q_a, q_b, clearance).valid

    # ------------------------------------------------------------- distances
    def min_distance(self, q: Array, include_self: bool = True) -> Distance:
        """Smallest distance from any body to the cabin (and between non-adjacent bodies), with witnesses.

        Distances are exact FCL queries on the un-grown shapes; candidates whose certified lower bound
        already exceeds the best distance found are skipped (branch and bound). Penetration gives <= 0.
        """
        st = self._state(_joints(q))
        candidates: list[tuple[float, str, int]] = []
        if self._cabin_obj is not None:
            candidates += [(float(lb), "cabin", b) for b, lb in enumerate(st.cabin_lb)]
        if include_self:
            candidates += [(float(lb), "self", k) for k, lb in enumerate(st.pair_lb)]
        best = Distance(np.inf, ("", ""), np.full(3, np.nan), np.full(3, np.nan))
        req = fcl.DistanceRequest(enable_nearest_points=True, enable_signed_distance=True)
        for lb, kind, idx in sorted(candidates, key=lambda x: x[0]):
            if lb >= best.distance_m:
                break
            # FCL returns the witness points of a shape-vs-mesh query in swapped order, and its box-box
            # distance is wrong in degenerate (face-parallel) cases: so the first object is always a mesh
            # (the cabin, or the first box of a box pair as a triangle mesh), whose point comes first.
            if kind == "cabin":
                a, other = idx, "cabin"
                first = self._cabin_obj
                second = self._object(a, st.R(a), st.p(a), st.length(a), 0.0)
            else:
                a, b = self.bodies.pairs[idx]
                other = self.names[b]
                if self.bodies.shapes[a].kind == "box" and self.bodies.shapes[b].kind == "box":
                    first = fcl.CollisionObject(
                        _box_bvh(self.bodies.shapes[b].size), fcl.Transform(st.R(b), st.p(b))
                    )
                    second = self._object(a, st.R(a), st.p(a), st.length(a), 0.0)
                else:
                    first = self._object(b, st.R(b), st.p(b), st.length(b), 0.0)
                    second = self._object(a, st.R(a), st.p(a), st.length(a), 0.0)
            res = fcl.DistanceResult()
            d = float(fcl.distance(first, second, req, res))
            if d < best.distance_m:
                p_other, p_body = res.nearest_points
                best = Distance(d, (self.names[a], other), np.array(p_body), np.array(p_other))
        return best

    def clearance_profile(self, qs: Array, include_self: bool = True) -> Array:
        """Minimum distance [m] at each configuration of a path, shape (N,)."""
        return np.array([self.min_distance(q, include_self).distance_m for q in np.atleast_2d(qs)])


def _cover_table(shapes: tuple[Shape, ...], centres: tuple[Array, ...]) -> tuple[Array, Array, Array]:
    """(body index, local centre, capsule-length fraction) of every sphere of a cover, for the kernels."""
    body, local, frac = [], [], []
    for b, (shape, c) in enumerate(zip(shapes, centres, strict=True)):
        body.append(np.full(len(c), b, dtype=np.int64))
        if shape.kind == "capsule":
            local.append(np.zeros_like(c))
            frac.append(c[:, 2])
        else:
            local.append(c)
            frac.append(np.zeros(len(c)))
    return np.concatenate(body), np.ascontiguousarray(np.concatenate(local)), np.concatenate(frac)


def _joints(q: Array) -> Array:
    """A joint vector as the kernels need it: contiguous, writeable float64 of shape (8,).

    (A read-only array would be another type to the compiled kernels: a new compilation, not a new result.)
    """
    q = np.ascontiguousarray(q, dtype=float)
    if not q.flags.writeable:
        q = q.copy()
    if q.shape != (8,):
        raise InvalidInput(f"q: a joint vector of 8 values expected, got shape {q.shape}", field="q")
    return q


def _check_clearance(clearance: float) -> None:
    if not (math.isfinite(clearance) and 0.0 <= clearance <= 0.5):
        raise InvalidInput(
            f"clearance: must be a finite distance in [0, 0.5] m, got {clearance}", field="clearance"
        )
