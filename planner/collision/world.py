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

The rooms of ``planner/collision/``: this module (the state and path API), :mod:`.motion` (the certified
motion walk), :mod:`.probes` (FCL), :mod:`.reports` (the values returned), :mod:`.bodies` (the robot's
bodies plus the payload: sphere covers, reach bounds), :mod:`.clearance_grid` (the cabin's distance lower
bounds), :mod:`.kernels` (the compiled hot path) and :mod:`.reference` (the pure-Python reference route,
kept as the tests' oracle).

No robot is named here: the robot model supplies its bodies, shapes, adjacency, reach bounds, pose
functions and kernel, and its admissibility constraints through its
:class:`~planner.robots.geometry.CollisionModel` (``robot.collision_model()``).
"""

from __future__ import annotations

import hashlib
import logging
import math
import weakref
from collections.abc import Callable
from functools import cache, partial
from typing import Generic, TypeVar

import numpy as np

from planner.collision.along import AlongPath
from planner.collision.bodies import BodySet, PayloadGeometry, robot_bodies, segment_reach_bounds
from planner.collision.clearance_grid import ClearanceGrid, cached_build
from planner.collision.kernels import buffers, codes
from planner.collision.kernels.entries import DEFAULT as KERNELS
from planner.collision.kernels.entries import EXTENSION, Kernels
from planner.collision.motion import CertifiedMotion, Walk
from planner.collision.obstacles import Obstacle, ObstacleSet, obstacle_contact
from planner.collision.probes import Probes, cabin_bvh
from planner.collision.reports import (
    VALID,
    BodyState,
    Distance,
    MotionReport,
    PathReport,
    StateReport,
    body_contact,
    limit_contacts,
)
from planner.core import aot
from planner.core.cache import DATA_PATTERNS, cache_dir, prune, touch, write_atomic
from planner.core.exceptions import InvalidInput
from planner.core.types import Array
from planner.meshio import LoadedMesh
from planner.robots.base import RobotModel

DEFAULT_CLEARANCE_M = 0.01
DEFAULT_MOTION_MARGIN_M = 0.005
DEFAULT_SELF_CLEARANCE_M = 0.005
MIN_MOTION_MARGIN_M = 1e-4

log = logging.getLogger(__name__)

#: The world's robot model type (``world.robot`` keeps it: cabin8's world gives a Cabin8).
RobotT = TypeVar("RobotT", bound=RobotModel)


@cache
def _cabin_grid(sha256: str, vertices_bytes: bytes, faces_bytes: bytes, step: float) -> ClearanceGrid:
    vertices = np.frombuffer(vertices_bytes).reshape(-1, 3)
    faces = np.frombuffer(faces_bytes, dtype=np.int64).reshape(-1, 3)
    # sha256 holds the mesh's content hash and its pose; the vertices are in the base frame already.
    key = hashlib.sha256(sha256.encode() + vertices_bytes + faces_bytes).hexdigest()
    return cached_build(key, vertices, faces, step)


@cache
def _cabin_tree(sha256: str, vertices_bytes: bytes, faces_bytes: bytes) -> buffers.MeshTree:
    """The cabin's triangles in a box tree (the walk's own probes of box bodies), built once per cabin."""
    vertices = np.frombuffer(vertices_bytes).reshape(-1, 3)
    faces = np.frombuffer(faces_bytes, dtype=np.int64).reshape(-1, 3)
    tree = KERNELS.mesh_tree(vertices, faces)
    for arr in tree:  # shared by every world on the cabin: read-only
        arr.setflags(write=False)
    return tree


#: Carriage clearance tables by (cabin, carriage shape, rail travel), built once (``Probes.carriage_table``).
_CARRIAGE_TABLES: dict[tuple[str, str, float, float], tuple[float, float, Array]] = {}
#: Bump when the carriage table's construction or its cache layout changes (the compiled kernels' build key
#: is part of an entry's name too: a changed distance kernel never reads an older kernel's table).
CARRIAGE_TABLE_VERSION = 1


@cache
def _kernels_key() -> str:
    return aot.key(EXTENSION)


def _cached_carriage_table(
    key: tuple[str, str, float, float], compiled: bool, build: Callable[[], tuple[float, float, Array]]
) -> tuple[float, float, Array]:
    """``build()``, cached on disk (``carriage-<hash>.npy``: the rail start, the step, then the distances).

    A carriage table costs 10 ms (600 exact box-mesh distances) for each new cabin in each process: every
    CLI call, a service worker's first job on a cabin. Keyed by the cabin's geometry digest, the carriage's
    shape, the rail, the route (compiled distances or FCL's) and the kernels' build; a missing, unreadable or
    malformed entry is built again, so the cache never changes a figure.
    """
    folder = cache_dir()
    if folder is None:
        return build()
    try:
        kernels = _kernels_key() if compiled else "fcl"
    except OSError as exc:  # the kernels' sources unreadable: no key to trust, so no cache
        log.warning("carriage table not cached: the kernels' build key is unknown (%s)", exc)
        return build()
    name = hashlib.sha256(f"{key!r}|{kernels}|{CARRIAGE_TABLE_VERSION}".encode()).hexdigest()[:32]
    path = folder / f"carriage-{name}.npy"
    try:
        data = np.load(path, allow_pickle=False)
        if data.ndim == 1 and data.dtype == np.float64 and len(data) >= 3 and np.isfinite(data[:2]).all():
            touch(path)
            table = data[2:].copy()
            table.setflags(write=False)
            return float(data[0]), float(data[1]), table
        log.warning("carriage table cache %s malformed; rebuilding", path)
    except FileNotFoundError:
        pass
    except (OSError, ValueError) as exc:
        log.warning("carriage table cache %s unreadable (%s); rebuilding", path, exc)
    lo, step, table = build()
    entry = np.concatenate([[lo, step], table])
    try:
        write_atomic(path, lambda f: np.save(f, entry, allow_pickle=False))
        prune(folder, DATA_PATTERNS)
    except OSError as exc:
        log.warning("carriage table cache not written (%s)", exc)
    return lo, step, table


#: The geometry key and digest of each loaded cabin (the mesh object's arrays are read-only).
_CABIN_KEYS: weakref.WeakKeyDictionary[LoadedMesh, tuple[tuple[str, bytes, bytes], str]] = (
    weakref.WeakKeyDictionary()
)


def cabin_key(cabin: LoadedMesh) -> tuple[str, bytes, bytes]:
    """The cache key of a cabin's geometry: (content hash + pose, vertices, faces) as loaded.

    Computed once per loaded mesh (the bytes of a large cabin cost a copy and a hash each time).
    """
    return _cabin_entry(cabin)[0]


def _cabin_entry(cabin: LoadedMesh) -> tuple[tuple[str, bytes, bytes], str]:
    """(:func:`cabin_key`, the key's one-line digest: content hash and pose, then the arrays' SHA-256)."""
    entry = _CABIN_KEYS.get(cabin)
    if entry is None:
        key = (
            cabin.sha256 + cabin.T_base_mesh.tobytes().hex(),
            cabin.vertices.tobytes(),
            cabin.faces.astype(np.int64).tobytes(),
        )
        entry = _CABIN_KEYS[cabin] = (key, key[0] + hashlib.sha256(key[1] + key[2]).hexdigest())
    return entry


class CollisionWorld(Generic[RobotT]):
    """Robot (+ payload) and cabin, with exact, certified state and motion checks.

    Args:
        robot: The robot model (it supplies its collision geometry: ``robot.collision_model()``).
        cabin: The cabin mesh in the base frame (``None``: free space, self-collision only).
        payload: The carried payload (``None``: none).
        grid_step_m: Node spacing of the clearance lower-bound grid [m].
        self_clearance: Distance [m] non-adjacent bodies keep from each other.
        obstacles: Fixed bodies added to the cabin (installed units, fixtures: :mod:`.obstacles`), each
            compared by clearance like the cabin; reports name them.
        allowed: ``(body name, obstacle name)`` pairs this world leaves out of its checks and distances
            (a gripper closing on the unit it grasps, along that straight motion only).

    Geometry that depends only on the cabin (FCL BVH, clearance grid) is cached per mesh content and pose,
    so several worlds on one cabin share it; obstacles never touch those caches.
    """

    #: Motion walks: probe for more than the bounds prove only where they prove nothing (states cost
    #: ~2 us, an FCL probe 10-50 us); the reference route keeps the original always-probe policy.
    probe_when_proven: bool = False
    #: The compiled tests (:mod:`.kernels.mesh`: FCL's verdicts, exact distances where FCL's GJK stops above
    #: them) outside the walk too (state checks, the gate, reports): a body's probes and exact distances
    #: against the cabin's and each obstacle's triangle tree, and the exact distance of a pair of bodies;
    #: the reference route uses FCL's.
    compiled_tests: bool = True

    def __init__(
        self,
        robot: RobotT,
        cabin: LoadedMesh | None = None,
        payload: PayloadGeometry | None = None,
        grid_step_m: float = 0.03,
        self_clearance: float = DEFAULT_SELF_CLEARANCE_M,
        obstacles: tuple[Obstacle, ...] = (),
        allowed: frozenset[tuple[str, str]] = frozenset(),
    ) -> None:
        _check_clearance(self_clearance)
        self.self_clearance = float(self_clearance)
        self.robot = robot
        self.cabin = cabin
        self.payload = payload
        self.model = robot.collision_model()
        self.bodies: BodySet = robot_bodies(self.model, payload)
        self.names = self.bodies.names
        self._pose_fn, self._pose_fast = self.model.pose_functions(self.bodies.names)
        self._T_tool_box = payload.T_tool_box if payload is not None else np.eye(4)
        self._n_bodies = len(self.names)
        self._grid: ClearanceGrid | None = None
        self._carriage_table: tuple[float, float, Array] | None = None
        entry = _cabin_entry(cabin) if cabin is not None else None
        tree = _cabin_tree(*entry[0]) if entry is not None else buffers.NO_TREE
        self._probes = Probes(
            self.bodies,
            partial(cabin_bvh, *entry[0]) if entry is not None else None,  # built if ever used
            tree if self.compiled_tests else None,
            compiled_pairs=self.compiled_tests,
        )
        if entry is not None:
            self._grid = _cabin_grid(*entry[0], grid_step_m)
            if self.model.rail_body is not None:
                self._carriage_table = self._carriage_table_of(entry[1])
        self._kernel = buffers.build(
            self.model,
            self.bodies,
            self._T_tool_box,
            self._grid,
            self._carriage_table,
            tree,
        )
        #: The compiled kernels' entries (the ahead-of-time build or numba's JIT, :mod:`.kernels.entries`).
        self.kernels: Kernels = KERNELS
        self._motion = CertifiedMotion(self.model, self.bodies, self._kernel, self._probes, self.kernels)
        #: Fine-cover sphere radii (S,), grouped by body (the spheres of :meth:`cover_centres`).
        self._fine_r = self._kernel.fine.radii
        self._cover_digest: str | None = None
        #: Per joint: it moves both bodies of every pair as one (the rail), so pair bounds do not change
        #: along it (:meth:`first_invalid_on_axis`).
        self._pairs_fixed: tuple[bool, ...] = tuple(np.all(self._kernel.pair_rigid, axis=0).tolist())
        #: The obstacles added to the cabin, with the pairs this world allows (None: no obstacles).
        self.obstacles: ObstacleSet | None = (
            ObstacleSet(tuple(obstacles), self.bodies, frozenset(allowed), self.kernels, self.compiled_tests)
            if obstacles
            else None
        )
        if allowed and not obstacles:
            raise InvalidInput("allowed: pairs given without obstacles", field="allowed")

    def _carriage_table_of(self, cabin_digest: str) -> tuple[float, float, Array]:
        """The rail body's clearance table along the rail, built once per cabin, body shape and rail.

        The rail body (cabin8: the carriage) moves with joint 0 alone. Its table depends on the cabin's
        geometry (the vertices as loaded, in the base frame: the file hash alone would not tell units
        apart), the body's shape and the rail.
        """
        assert self.model.rail_body is not None
        carriage = self.names.index(self.model.rail_body)
        lo, hi = self.model.rail_range
        table_key = (
            cabin_digest,
            repr(self.bodies.shapes[carriage]),
            lo,
            hi,
        )
        table = _CARRIAGE_TABLES.get(table_key)
        if table is None:
            if len(_CARRIAGE_TABLES) >= 64:
                _CARRIAGE_TABLES.clear()
            table = _CARRIAGE_TABLES[table_key] = _cached_carriage_table(
                table_key,
                self._probes.tree is not None,
                partial(self._probes.carriage_table, carriage, lo, hi),
            )
        return table

    # ------------------------------------------------------------------ poses
    def _evaluate(self, q: Array) -> tuple[Array, Array]:
        """Flat body poses (N, B, 13) and admissibility values c(q) (N, m) for (N, n) or (n,) joints."""
        q2 = np.atleast_2d(np.asarray(q, dtype=float))
        n = q2.shape[0]
        if n == 1:
            flat, c = (x[None, :] for x in self._pose_fast(q2[0], self._T_tool_box))
            return np.ascontiguousarray(flat.reshape(n, self._n_bodies, 13)), c
        # The closed-form kernel, ~100x faster than CasADi's batch call.
        poses, c = np.empty((n, self._n_bodies, 13)), np.empty((n, len(self._kernel.c_lo)))
        self.kernels.packed_poses(np.ascontiguousarray(q2), self._kernel, poses, c)
        return poses, c

    def cover_centres(self, q: Array, coarse: bool = False) -> Array:
        """World centres (N, S, 3) of the fine (cabin) or coarse (self) sphere cover, grouped by body."""
        flat, _ = self._evaluate(q)
        cover = self._kernel.coarse if coarse else self._kernel.fine
        return self.kernels.cover_centres_batch(flat, cover)

    def cover_extents(self, q: Array) -> Array:
        """(N, 2): how far the fine sphere cover reaches sideways (max |x| + r) and up (max y + r) [m].

        Compiled (:func:`.kernels.bounds.cover_extents`): the numbers numpy gives on :meth:`cover_centres`
        (bit for bit), without the (N, S, 3) centres.
        """
        flat, _ = self._evaluate(q)
        return self.kernels.cover_extents(flat, self._kernel.fine)

    def cover_digest(self) -> str:
        """Digest of what :meth:`cover_extents` depends on besides the robot (the cabin plays no part).

        The world's route (a reference world evaluates poses its own way), the bodies, the tool-to-payload
        transform and the fine sphere cover: worlds of one robot with equal digests give equal extents
        (transit's pool ranking is shared by them, :func:`planner.plan.transit.ranked_pool`).
        """
        if self._cover_digest is None:
            cover = self._kernel.fine
            h = hashlib.sha256(f"{type(self).__qualname__}|{self.names!r}".encode())  # the route, the bodies
            for part in (self._T_tool_box, cover.body, cover.local, cover.frac, cover.radii, cover.start):
                h.update(np.ascontiguousarray(part).tobytes())
            self._cover_digest = h.hexdigest()
        return self._cover_digest

    def poses(self, q: Array) -> tuple[Array, Array, Array]:
        """(R (N, B, 3, 3), p (N, B, 3), lengths (N, B)) of every body for (N, 8) or (8,) joints.

        Each body frame is centred on the body; a capsule's axis is its frame's z axis.
        """
        flat = self._evaluate(q)[0]
        n = flat.shape[0]
        R = flat[:, :, :9].reshape(n, self._n_bodies, 3, 3).transpose(0, 1, 3, 2)
        return R, flat[:, :, 9:12], flat[:, :, 12]

    # --------------------------------------------------------------- checks
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
        q = _joints(q, self.model.n_joints)
        rep = self._check_state_cabin(q, clearance, all_contacts)
        if self.obstacles is None or not (rep.valid or all_contacts):
            return rep
        if any(c.kind == "limit" for c in rep.contacts) and not np.all(np.isfinite(q)):
            return rep
        more = self.obstacles.state_contacts(self.flat_poses(q), self.names, clearance, all_contacts)
        if not more:
            return rep
        return StateReport(False, (*rep.contacts, *more))

    def _check_state_cabin(self, q: Array, clearance: float, all_contacts: bool) -> StateReport:
        """:meth:`check_state` without the obstacles: limits, the cabin and self-collision."""
        screened = self._screen(q, clearance)
        if isinstance(screened, StateReport):
            return screened
        contacts = [] if screened.admissible else limit_contacts(self.model.admissibility, q)
        if contacts and not all_contacts:
            return StateReport(False, tuple(contacts))
        own = self.self_clearance
        for is_cabin, bound, margin in ((True, screened.cabin_lb, clearance), (False, screened.pair_lb, own)):
            for idx in np.flatnonzero(bound <= margin).tolist():
                if self._probes.hit(screened, is_cabin, idx, margin):
                    contacts.append(body_contact(self.names, self.bodies.pairs, is_cabin, idx, margin))
                    if not all_contacts:  # the first contact found (cabin before self) is the report
                        return StateReport(False, tuple(contacts))
        return StateReport(not contacts, tuple(contacts))

    def flat_poses(self, q: Array) -> Array:
        """Body poses (B, 13) at one configuration (8,): rotation column-major, centre, capsule length.

        By the closed-form kernel (~3 us; CasADi's pose function costs ~15 us a call), as every state check
        of the world computes them: the obstacles are checked at the poses the cabin is.
        """
        q2 = np.ascontiguousarray(np.asarray(q, dtype=float).reshape(1, -1))
        poses, c = np.empty((1, self._n_bodies, 13)), np.empty((1, len(self._kernel.c_lo)))
        self.kernels.packed_poses(q2, self._kernel, poses, c)
        return poses[0]

    def _screen(self, q: Array, clearance: float) -> StateReport | BodyState:
        """The compiled part of :meth:`check_state`: a final report, or the state for the FCL probes."""
        d = self._kernel
        code, flat, cabin, pairs = self.kernels.packed_check(q, d, clearance, self.self_clearance, -1.0)
        if code == codes.CLEAR:  # the bounds prove everything: no FCL query
            return VALID
        if code == codes.NOT_FINITE:
            return StateReport(False, tuple(limit_contacts(self.model.admissibility, q)))
        return BodyState(flat, cabin, pairs, code != codes.INADMISSIBLE)

    def is_valid(self, q: Array, clearance: float = DEFAULT_CLEARANCE_M) -> bool:
        """True when limits, margins, cabin clearance and self-clearance all hold at q.

        The verdict of :meth:`check_state`, without building a report: one kernel call, then FCL queries
        only for what the bounds cannot prove clear (the obstacles at the poses that call computed). With
        the compiled tests, the bounds' probes are in that call (:func:`.kernels.state.packed_valid`).
        """
        _check_clearance(clearance)
        q = _joints(q, self.model.n_joints)
        own = self.self_clearance
        d = self._kernel
        if self.compiled_tests:  # the bounds and the probes in one compiled call (the same verdict)
            verdict, flat, probes = self.kernels.packed_valid(q, d, clearance, own, d.upper_slack)
            self._probes.queries += probes
            if verdict == codes.STATE_INVALID:
                return False
            if verdict == codes.STATE_VALID:
                return self.obstacles is None or self.obstacles.clear(flat, clearance)
        code, flat, cabin, pairs = self.kernels.packed_check(q, d, clearance, own, d.upper_slack)
        if code != codes.UNDECIDED:
            if code != codes.CLEAR:
                return False  # a certain contact is as invalid as an FCL-found one
            return self.obstacles is None or self.obstacles.clear(flat, clearance)
        st = BodyState(flat, cabin, pairs, True)
        for b, lb in enumerate(cabin.tolist()):
            if lb <= clearance and self._probes.cabin_hit(st, b, clearance):
                return False
        for k, lb in enumerate(pairs.tolist()):
            if lb <= own and self._probes.pair_hit(st, k, own):
                return False
        return self.obstacles is None or self.obstacles.clear(flat, clearance)

    def first_invalid_on_axis(
        self, q: Array, axis: int, values: Array, clearance: float = DEFAULT_CLEARANCE_M
    ) -> tuple[int, int]:
        """The first of ``values`` where q with joint ``axis`` set to it is not :meth:`is_valid`.

        The states are checked in the order given and the sweep stops at the first one that fails: the
        same verdicts, in the same order, and the same probes counted as :meth:`is_valid` on each copy of
        q, in one compiled call where the world allows it (its compiled tests, a triangle tree, no extra
        obstacles: those are checked in Python state by state). A transit posture swept along the rail is
        the use: 3.8 us a state instead of 8 (the pairs' bounds, which the rail does not change, are
        computed once a posture is clear).

        Returns:
            (index into ``values`` of the first state not valid, or -1; states checked).
        """
        _check_clearance(clearance)
        q = _joints(q, self.model.n_joints)
        values = np.ascontiguousarray(values, dtype=float)
        if values.ndim != 1:
            raise InvalidInput(f"values: a vector expected, got shape {values.shape}", field="values")
        if not 0 <= axis < q.shape[0]:
            raise InvalidInput(f"axis: a joint index below {q.shape[0]} expected, got {axis}", field="axis")
        start = 0
        d = self._kernel
        if self.compiled_tests and self.obstacles is None:
            verdict, start, probes = self.kernels.axis_sweep(
                q, axis, values, self._pairs_fixed[axis], d, clearance, self.self_clearance, d.upper_slack
            )
            self._probes.queries += probes
            if verdict == codes.STATE_VALID:
                return -1, len(values)
            if verdict == codes.STATE_INVALID:
                return start, start + 1
            # STATE_UNDECIDED: a cabin probe without a tree; that state and the rest as is_valid does
        s = q.copy()
        for i in range(start, len(values)):
            s[axis] = values[i]
            if not self.is_valid(s, clearance):
                return i, i + 1
        return -1, len(values)

    def _state(self, q: Array, threshold: float = DEFAULT_CLEARANCE_M) -> BodyState:
        """Poses and certified bounds at one configuration (8,), contiguous float64: one kernel call.

        ``threshold``: pairs whose bound is not above it get their exact distance where one is known.
        """
        d = self._kernel
        flat, cabin, pairs, ok = self.kernels.packed_state(q, d, threshold)
        return BodyState(flat, cabin, pairs, ok)

    def check_motion(
        self,
        q_a: Array,
        q_b: Array,
        clearance: float = DEFAULT_CLEARANCE_M,
        motion_margin: float = DEFAULT_MOTION_MARGIN_M,
        self_clearance: float | None = None,
        reach_ratio: float | None = None,
        min_margin: float | None = None,
    ) -> MotionReport:
        """Certify that the straight joint-space motion q_a -> q_b keeps ``clearance`` everywhere.

        Each body (and each checked pair) is advanced separately along t in [0, 1]. At a checked t the body
        is proven clear by a margin E beyond ``clearance`` -- for free when its sphere lower bound allows,
        else by an FCL query on the body grown by ``clearance + E`` for E in a few levels down to
        ``motion_margin``. With D the body's displacement bound for the whole segment, every t' with
        |t' - t| <= E / D is then clear, so the next check is at ``t + (E + motion_margin) / D`` and must
        prove at least ``motion_margin``. A check that cannot prove ``motion_margin`` is refused (it may be
        a real contact). Where the bound proves nothing, the first probe asks for twice the margin proven
        last time (longer steps), then for that margin again and its halves down to ``motion_margin``
        (the spare clearance changes little from state to state; no level at or above one that hit is
        asked, as a larger grown body hits too); with ``probe_when_proven`` (the reference route's setting)
        the first probe also where the bound proves a margin -- by default not, as a state costs a few
        microseconds and an FCL probe tens. Limits and
        margins (smooth functions of q) are checked at every joint step of at most ``LIMIT_STEP``
        (5 mm / 5 mrad) along the segment. The walk itself is :mod:`planner.collision.motion`.

        **Adaptive margin** (``min_margin`` below ``motion_margin``). A state that cannot prove the step's
        margin is not a refusal while the margin can shrink: the margin is halved (not below
        ``min_margin``) and the walk steps again from the last state it proved, by that state's spare
        clearance and the new margin, so the new state lies closer (or the first state is asked again);
        where a state proves twice the margin, the margin doubles back towards ``motion_margin``. Only a
        state that cannot prove ``min_margin`` is refused. The schedule is that of ``min_margin`` (no step
        ever exceeds what a state proved). So one walk certifies a motion that keeps ``clearance +
        min_margin`` with small steps only where it is tight, where a walk retried with a smaller margin
        walked all of it again (:func:`planner.plan.motion.certify_motion`). None: ``motion_margin``
        throughout, the walk described above.

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
        if min_margin is not None and not (np.isfinite(min_margin) and MIN_MOTION_MARGIN_M <= min_margin):
            raise InvalidInput(
                f"min_margin: must be at least {MIN_MOTION_MARGIN_M} m, got {min_margin}", field="min_margin"
            )
        floor = None if min_margin is None else min(float(min_margin), float(motion_margin))
        n = self.model.n_joints
        spec = Walk(clearance, motion_margin, own, reach_ratio, floor)
        return self._walk(_joints(q_a, n), _joints(q_b, n), spec)

    def _walk(self, q_a: Array, q_b: Array, spec: Walk) -> MotionReport:
        """The motion walk of :meth:`check_motion` on validated arguments (the obstacles' walk after it)."""
        rep = self._motion.check(q_a, q_b, spec, self.probe_when_proven)
        if not rep.valid or self.obstacles is None:
            return rep
        # Each obstacle state steps by its exact spare clearance: the margin only sets what it must prove.
        return self._obstacle_walk(q_a, q_b, spec.clearance, spec.floor, rep)

    def _obstacle_walk(
        self, q_a: Array, q_b: Array, clearance: float, margin: float, rep: MotionReport
    ) -> MotionReport:
        """Certify the segment against the obstacles (see :mod:`.obstacles`).

        each pair advanced by its proven spare clearance over the body's displacement bound D_b = rho_b .
        |q_b - q_a|.
        """
        obs = self.obstacles
        assert obs is not None
        dq = q_b - q_a
        D = self.bodies.rho @ np.abs(dq)  # (B,) displacement bound of any point of each body
        queries0 = obs.queries
        states = rep.states_checked + 1
        lb_mid = obs.lower_bounds(self.flat_poses(q_a + 0.5 * dq), clearance + 0.5 * D[:, None])
        # Pairs the midpoint's bound proves clear over the whole segment need nothing more.
        todo = np.argwhere(lb_mid - 0.5 * D[:, None] <= clearance)
        for b, o in todo.tolist():
            t = 0.0
            while True:
                q = q_a + t * dq
                flat = self.flat_poses(q)
                states += 1
                d = obs.distance(flat, b, o)[0]  # exact: the longest certified step
                if d < clearance + margin:
                    contact = obstacle_contact(self.names[b], obs.names[o], clearance + margin)
                    queries = rep.fcl_queries + obs.queries - queries0
                    return MotionReport(False, states, queries, t, (contact,), rep.smallest_margin_m)
                if D[b] <= 0.0:
                    break
                t += (d - clearance) / float(D[b])
                if t >= 1.0:
                    break
        queries = rep.fcl_queries + obs.queries - queries0
        return MotionReport(True, states, queries, smallest_margin_m=rep.smallest_margin_m)

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
        ratios = self.model.admissibility.constraint_values_batch(qs)[:, list(self.model.ratio_rows)]
        ratio = _largest_ratio(ratios)
        rho_all = segment_reach_bounds(self.model, self.bodies, min(ratio + 0.02, 0.999))[0]
        rho_joint = np.max(rho_all, axis=0)  # per joint, the largest reach of any body
        qs = np.ascontiguousarray(qs)
        rho_joint = np.ascontiguousarray(rho_joint, dtype=float)
        i, checks, cap = 0, 0, max_run
        while i < n - 1:
            # Both bodies of a self pair may move: the kernel doubles the reach-weighted deviation.
            j, extra = self.kernels.run_extent(qs, i, min(n - 1, i + cap), rho_joint, float(max_extra_m))
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

    def along(self, qs: Array) -> AlongPath:
        """The batched pass over a sampled path (N, n), N >= 2: bounds at every sample in one kernel call.

        The result certifies the polyline (:meth:`AlongPath.certify`, as strict as :meth:`check_path`, the
        obstacles included) and finds its smallest distance (:meth:`AlongPath.clearance`: the cabin, the
        robot's pairs and the obstacles; the allowed pairs apart, :meth:`AlongPath.allowed_clearance`); see
        :mod:`planner.collision.along`.
        """
        qs = np.ascontiguousarray(np.asarray(qs, dtype=float))
        if qs.ndim != 2 or qs.shape[0] < 2 or qs.shape[1] != self.model.n_joints:
            raise InvalidInput(
                f"qs: (N >= 2, {self.model.n_joints}) joint samples expected, got shape {qs.shape}",
                field="qs",
            )
        if not np.all(np.isfinite(qs)):
            raise InvalidInput("qs: joint samples must be finite", field="qs")
        poses, c = np.empty((len(qs), self._n_bodies, 13)), np.empty((len(qs), len(self._kernel.c_lo)))
        self.kernels.packed_poses(qs, self._kernel, poses, c)
        ratio_floor = min(_largest_ratio(c[:, list(self.model.ratio_rows)]) + 0.02, 0.999)
        threshold = self.self_clearance + 0.06  # exact capsule-pair distances below (as the motion walk)

        def walk(k: int, clearance: float, own: float, margin: float) -> MotionReport:
            return self._walk(qs[k], qs[k + 1], Walk(clearance, margin, own, ratio=ratio_floor))

        has_cabin = self._probes.has_cabin
        kernels = (self.kernels, self._kernel, threshold)
        return AlongPath(
            qs, poses, c, has_cabin, self.model, self.bodies, self._probes, kernels, walk, self.obstacles
        )

    # ------------------------------------------------------------- distances
    def min_distance(self, q: Array, include_self: bool = True, include_cabin: bool = True) -> Distance:
        """Smallest distance from any body to the cabin (and between non-adjacent bodies), with witnesses.

        Distances are exact on the un-grown shapes (the compiled tests, :attr:`compiled_tests`; FCL's on the
        reference route); candidates whose certified lower bound already exceeds the best distance found are
        skipped (branch and bound). Penetration gives <= 0.
        ``include_self=False``: the cabin only; ``include_cabin=False``: the robot's body pairs only (an
        infinite distance when there is nothing to measure).
        """
        st = self._state(_joints(q, self.model.n_joints))
        candidates: list[tuple[float, bool, int]] = []
        if include_cabin and self._probes.has_cabin:
            candidates += [(float(lb), True, b) for b, lb in enumerate(st.cabin_lb)]
        if include_self:
            candidates += [(float(lb), False, k) for k, lb in enumerate(st.pair_lb)]
        best = Distance(np.inf, ("", ""), np.full(3, np.nan), np.full(3, np.nan))
        for lb, is_cabin, idx in sorted(candidates, key=lambda x: x[0]):
            if lb >= best.distance_m:
                break
            d, a, other, p_body, p_other = self._probes.distance(st, is_cabin, idx)
            if d < best.distance_m:
                best = Distance(
                    d, (self.names[a], "cabin" if other < 0 else self.names[other]), p_body, p_other
                )
        if include_cabin and self.obstacles is not None:
            found = self.obstacle_distance(st.flat, bound=best.distance_m)
            if found.distance_m < best.distance_m:
                best = found
        return best

    def obstacle_distance(
        self, flat: Array, obstacle: str | None = None, body: str | None = None, bound: float = np.inf
    ) -> Distance:
        """Smallest exact distance of a body to an obstacle at the body poses ``flat`` (B, 13).

        ``obstacle`` / ``body``: only that obstacle / body (an allowed pair too: its distance is what a
        report of the allowed pair shows). Pairs this world allows are left out otherwise. Branch and bound
        on the sphere lower bounds, as :meth:`min_distance`; pairs certainly farther than ``bound`` [m] are
        not measured (+inf when none is nearer, or without a pair to measure).
        """
        obs = self.obstacles
        best = Distance(np.inf, ("", ""), np.full(3, np.nan), np.full(3, np.nan))
        if obs is None:
            return best
        lb = obs.lower_bounds(flat, bound)
        if obstacle is not None or body is not None:
            keep = np.ones_like(obs.active)
            if obstacle is not None:
                keep[:, [i for i, n in enumerate(obs.names) if n != obstacle]] = False
            if body is not None:
                keep[[i for i, n in enumerate(self.names) if n != body], :] = False
            allowed_lb = np.where(obs.active, lb, 0.0)  # allowed pairs: no bound, measure them
            lb = np.where(keep, allowed_lb, np.inf)
        for k in np.argsort(lb, axis=None).tolist():
            b, o = divmod(k, lb.shape[1])
            if not np.isfinite(lb[b, o]) or lb[b, o] >= min(best.distance_m, bound):
                break
            d, p_body, p_obstacle = obs.distance(flat, b, o)
            if d < best.distance_m:
                best = Distance(d, (self.names[b], obs.names[o]), p_body, p_obstacle)
        return best

    def is_environment(self, name: str) -> bool:
        """True when ``name`` (a :class:`Distance`'s second body) is the cabin or an obstacle.

        Their distances are held to the clearance, a robot pair's to the self-clearance.
        """
        return name == "cabin" or (self.obstacles is not None and name in self.obstacles.names)

    def clearance_profile(self, qs: Array, include_self: bool = True) -> Array:
        """Minimum distance [m] at each configuration of a path, shape (N,)."""
        return np.array([self.min_distance(q, include_self).distance_m for q in np.atleast_2d(qs)])


def _largest_ratio(ratios: Array) -> float:
    """The largest slope ratio of a path's samples (N, rows): 1 where one is not finite, 0 without rows."""
    if ratios.shape[1] == 0:
        return 0.0
    return float(np.nanmax(ratios)) if np.all(np.isfinite(ratios)) else 1.0


def _joints(q: Array, n: int) -> Array:
    """A joint vector as the kernels need it: contiguous, writeable float64 of shape (n,).

    (A read-only array would be another type to the compiled kernels: a new compilation, not a new result.)
    """
    q = np.ascontiguousarray(q, dtype=float)
    if not q.flags.writeable:
        q = q.copy()
    if q.shape != (n,):
        raise InvalidInput(f"q: a joint vector of {n} values expected, got shape {q.shape}", field="q")
    return q


def _check_clearance(clearance: float) -> None:
    if not (math.isfinite(clearance) and 0.0 <= clearance <= 0.5):
        raise InvalidInput(
            f"clearance: must be a finite distance in [0, 0.5] m, got {clearance}", field="clearance"
        )
