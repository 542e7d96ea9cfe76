"""The collision kernels as Python calls: arguments checked, then the ahead-of-time build or numba's JIT.

The kernels (:mod:`.state`, :mod:`.walk`, :mod:`.bounds`, :mod:`.obstacles`, compiled with the robot's
pose kernel of :mod:`planner.robots.kernels`) are exported as one extension module, :data:`EXTENSION`,
built once per install by :mod:`planner.core.aot` (``make`` runs ``python -m
planner.collision.kernels.build``; a plan that finds no build makes it before its clock starts). A plan
served by the build never imports numba; without a build (no cache folder, ``CABINPLAN_KERNELS=jit``, no C
compiler) the same functions run under numba's JIT. Both give the same numbers, bit for bit
(``tests/core/test_aot.py``).

The build's entries do not check their arguments, so they are reached only through :class:`Kernels`: every
array argument is checked for the dtype, number of dimensions, C order (and, for outputs, writability)
of the entry's signature, every scalar converted; a world's constant arrays are checked once, when its
:class:`~.buffers.KernelData` is built (an obstacle set's, its :class:`~.buffers.ObstacleKernelData`). A
wrong argument raises ``TypeError`` naming it.
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from planner.collision.kernels import codes
from planner.collision.kernels.buffers import Cover, KernelData, MeshTree, ObstacleKernelData, check_tree
from planner.core import aot
from planner.core.aot import B1, F8, I8, Entry, check_array
from planner.core.types import Array, BoolArray, IntArray

_HERE = Path(__file__).resolve().parent
#: How many read-only trees :meth:`Kernels._tree` remembers as checked (a cabin's and its obstacles').
CHECKED_TREES = 256
_ROBOTS = _HERE.parent.parent / "robots"


def _jit_module() -> ModuleType:
    """The ``@njit`` kernels (:mod:`.jit`; importing it imports numba)."""
    from planner.collision.kernels import jit

    return jit


#: Inputs of a world's constant data: packed buffers (floats, ints) and the flat clearance grid.
_DATA = ("f8[1]", "i8[1]")
_GRID = "f8[1]"
#: The cabin's triangle tree (:class:`~.buffers.MeshTree`: triangles, node bounds, node links).
_TREE = ("f8[2]", "f8[2]", "i8[2]")
#: Inputs of an obstacle set's constant data: its packed buffers (floats, ints).
_OBSTACLES = ("f8[1]", "i8[1]")

#: The collision kernels' extension: compiled from every module of this folder and the robots' kernels.
EXTENSION = aot.Extension(
    name="cabinplan_collision_kernels",
    kernels_module=_jit_module,
    builder_module="planner.collision.kernels.build",
    sources=(
        *sorted(_HERE.glob("*.py")),
        _ROBOTS / "kernels.py",
        _ROBOTS / "cabin8_kernels.py",
        _ROBOTS / "kernel_codes.py",
    ),
    entries=(
        Entry("packed_check", ("f8[1]", *_DATA, _GRID, "f8", "f8", "f8"), "(i8,f8[2]w,f8[1]w,f8[1]w)"),
        Entry("packed_state", ("f8[1]", *_DATA, _GRID, "f8"), "(f8[2]w,f8[1]w,f8[1]w,b1)"),
        Entry("packed_valid", ("f8[1]", *_DATA, _GRID, *_TREE, "f8", "f8", "f8"), "(i8,f8[2]w,i8)"),
        Entry("packed_poses", ("f8[2]", *_DATA, "f8[3]w", "f8[2]w"), "none"),
        Entry(
            "axis_sweep",
            ("f8[1]", "i8", "f8[1]", "b1", *_DATA, _GRID, *_TREE, "f8", "f8", "f8"),
            "(i8,i8,i8)",
        ),
        Entry(
            "bounds_at",
            ("i8[1]", "f8[3]", "f8[2]", *_DATA, _GRID, "f8", "f8[2]w", "f8[2]w"),
            "none",
        ),
        Entry(
            "cover_walk",
            (
                "i8[1]w",
                "f8[1]",
                "i8",
                "f8[3]",
                *_DATA,
                _GRID,
                "f8",
                "f8[2]",
                "f8[2]",
                "f8[2]w",
                "i8[2]w",
                "b1[1]w",
            ),
            "i8",
        ),
        Entry("cover_centres_batch", ("f8[3]", "i8[1]", "f8[2]", "f8[1]"), "f8[3]w"),
        Entry("cover_extents", ("f8[3]", "i8[1]", "f8[2]", "f8[1]", "f8[1]"), "f8[2]w"),
        Entry("run_extent", ("f8[2]", "i8", "i8", "f8[1]", "f8"), "(i8,f8)"),
        Entry("first_inadmissible", ("f8[1]", "f8[1]", "i8", *_DATA), "i8"),
        Entry("end_ratio", ("f8[1]", "f8[1]", *_DATA), "f8"),
        Entry(
            "segment_reach",
            ("f8[2]", "b1[1]", "f8", "f8", "i8[1]", "i8[1]", "b1[2]", "f8[1]"),
            "(f8[1]w,f8[1]w)",
        ),
        Entry(
            "motion_walk",
            (
                "i8[1]w",
                "f8[1]w",
                *(["f8[1]"] * 5),
                *_DATA,
                _GRID,
                *_TREE,
                "i8[1]w",
                "f8[3]w",
                "f8[2]w",
                "f8[2]w",
            ),
            "i8",
        ),
        Entry("obstacle_bounds", ("f8[2]", *_OBSTACLES, "f8[1]"), "f8[2]w"),
        Entry("obstacle_coarse_batch", ("f8[3]", *_OBSTACLES, "b1"), "f8[3]w"),
        Entry("obstacle_fine_batch", ("f8[3]", "i8[1]", "i8", *_OBSTACLES), "f8[2]w"),
        Entry("task_offsets", ("f8[3]", "f8[3]", "b1[1]", "f8[1]", "i8[1]", "i8[1]"), "f8[2]w"),
        Entry("hull_deviation", ("f8[3]",), "f8"),
        Entry("path_vertices", ("f8[3]", "i8", "f8[2]", "b1"), "f8[3]w"),
        Entry("pair_vertices", ("f8[3]", "i8", "i8", "f8[2]", "b1"), "f8[3]w"),
        Entry("cumulative_bound", ("f8[2]", "f8[2]"), "f8[2]w"),
        Entry("propagate", ("f8[2]w", "f8[2]", "i8[1]"), "none"),
        Entry("between_bound", ("f8[2]", "f8[2]", "i8[1]"), "(f8,i8)"),
        Entry("grid_marks", ("f8[2]", "i8[2]", "f8[1]", "f8", "f8", "b1[3]w"), "none"),
        Entry("grid_bounds", ("b1[3]", "f8", "f8", "f8[3]w"), "none"),
        Entry("mesh_tree", ("f8[2]", "i8[2]"), "(f8[2]w,f8[2]w,i8[2]w)"),
        Entry("box_touches_mesh", ("f8[1]", "f8[1]", "f8", *_TREE), "b1"),
        Entry("box_mesh_distance", ("f8[1]", "f8[1]", "f8", *_TREE), "f8"),
        Entry("hull_mesh_lower", ("f8[2]", *_TREE), "f8"),
        Entry("hull_shape_lower", ("f8[2]", "f8[1]", "f8"), "f8"),
        Entry("capsule_touches_mesh", ("f8[1]", "f8", "f8", *_TREE), "b1"),
        Entry("capsule_mesh_distance", ("f8[1]", "f8", "f8", *_TREE), "f8"),
        Entry("cabin_witness", ("f8[1]", "f8[1]", "f8", *_TREE), "(f8,f8[1]w,f8[1]w)"),
        Entry("pair_touches", ("f8[2]", "f8[1]", "f8[2]", "i8", "i8", "f8"), "b1"),
        Entry("pair_witness", ("f8[1]", "f8[1]", "f8", "f8[1]", "f8[1]", "f8"), "(f8,f8[1]w,f8[1]w)"),
    ),
)


def _data(d: object) -> KernelData:
    if not isinstance(d, KernelData):
        raise TypeError(f"d: KernelData expected, got {type(d).__name__}")
    return d


def _verdict_inputs(
    d: KernelData, clearance: float, self_clearance: float, upper_slack: float
) -> tuple[Any, ...]:
    """The world's data and the thresholds, as the state verdict entries take them after their own inputs."""
    return (d.fbuf, d.ibuf, d.grid, *d.tree, float(clearance), float(self_clearance), float(upper_slack))


def _obstacles(d: object) -> ObstacleKernelData:
    if not isinstance(d, ObstacleKernelData):
        raise TypeError(f"d: ObstacleKernelData expected, got {type(d).__name__}")
    return d


class Kernels:
    """The entries of the collision kernels on one implementation, with checked arguments.

    ``module``: the ahead-of-time build or the JIT dispatchers (:mod:`.jit`); None (the default) takes
    :func:`planner.core.aot.kernels` on the first call.
    """

    def __init__(self, module: Any = None) -> None:
        self._module = module
        #: Read-only trees already checked, by identity (held here, so an id is never reused): the cabin's
        #: and each obstacle's (:meth:`_tree`); bounded, the oldest dropped first.
        self._checked: dict[int, MeshTree] = {}

    @property
    def module(self) -> Any:
        """The implementation (resolved on first use)."""
        if self._module is None:
            self._module = aot.kernels(EXTENSION)
        return self._module

    def packed_check(
        self, q: Array, d: KernelData, clearance: float, self_clearance: float, upper_slack: float
    ) -> tuple[int, Array, Array, Array]:
        """:func:`.state.packed_check` on a world's data: (code, poses (B, 13), cabin (B,), pairs (P,))."""
        d = _data(d)
        return self.module.packed_check(
            check_array(q, "q", F8, 1, shape=d.joint_shape),
            d.fbuf,
            d.ibuf,
            d.grid,
            float(clearance),
            float(self_clearance),
            float(upper_slack),
        )

    def packed_valid(
        self, q: Array, d: KernelData, clearance: float, self_clearance: float, upper_slack: float
    ) -> tuple[int, Array, int]:
        """:func:`.state.packed_valid` on a world's data: (``STATE_*`` verdict, poses (B, 13), probes)."""
        d = _data(d)
        q = check_array(q, "q", F8, 1, shape=d.joint_shape)
        verdict, poses, probes = self.module.packed_valid(
            q, *_verdict_inputs(d, clearance, self_clearance, upper_slack)
        )
        return int(verdict), poses, int(probes)

    def axis_sweep(
        self,
        q: Array,
        axis: int,
        values: Array,
        pairs_fixed: bool,
        d: KernelData,
        clearance: float,
        self_clearance: float,
        upper_slack: float,
    ) -> tuple[int, int, int]:
        """:func:`.state.axis_sweep` on a world's data: (``STATE_*`` verdict, its state's index, probes)."""
        d = _data(d)
        q = check_array(q, "q", F8, 1, shape=d.joint_shape)
        values = check_array(values, "values", F8, 1)
        verdict, index, probes = self.module.axis_sweep(
            q,
            int(axis),
            values,
            bool(pairs_fixed),
            *_verdict_inputs(d, clearance, self_clearance, upper_slack),
        )
        return int(verdict), int(index), int(probes)

    def packed_state(self, q: Array, d: KernelData, threshold: float) -> tuple[Array, Array, Array, bool]:
        """:func:`.state.packed_state`: (poses (B, 13), cabin bounds (B,), pair bounds (P,), admissible)."""
        d = _data(d)
        q = check_array(q, "q", F8, 1, shape=d.joint_shape)
        return self.module.packed_state(q, d.fbuf, d.ibuf, d.grid, float(threshold))

    def packed_poses(self, qs: Array, d: KernelData, poses: Array, c: Array) -> None:
        """:func:`.state.packed_poses`: poses (N, B, 13) and c(q) (N, m) of (N, n) joints, in place."""
        d = _data(d)
        qs = check_array(qs, "qs", F8, 2, shape=(None, d.n_joints))
        n = qs.shape[0]
        self.module.packed_poses(
            qs,
            d.fbuf,
            d.ibuf,
            check_array(poses, "poses", F8, 3, out=True, shape=(n, d.n_bodies, 13)),
            check_array(c, "c", F8, 2, out=True, shape=(n, d.n_constraints)),
        )

    def bounds_at(
        self, idx: IntArray, poses: Array, c: Array, d: KernelData, threshold: float
    ) -> tuple[Array, Array]:
        """:func:`.along.bounds_at`: cabin bounds (K, B) and pair bounds (K, P) at samples ``idx`` (K,).

        ``poses`` (N, B, 13) and ``c`` (N, m) are the samples' poses and admissibility values
        (:meth:`packed_poses`); every index must be a row of them.
        """
        d = _data(d)
        poses = check_array(poses, "poses", F8, 3, shape=(None, d.n_bodies, 13))
        n = poses.shape[0]
        c = check_array(c, "c", F8, 2, shape=(n, d.n_constraints))
        idx = check_array(idx, "idx", I8, 1)
        if len(idx) and not (0 <= int(idx.min()) and int(idx.max()) < n):
            raise ValueError(f"bounds_at: sample indices in [0, {n}) expected")
        cabin = np.empty((len(idx), d.n_bodies))
        pairs = np.empty((len(idx), len(d.pair_a)))
        self.module.bounds_at(idx, poses, c, d.fbuf, d.ibuf, d.grid, float(threshold), cabin, pairs)
        return cabin, pairs

    def cover_walk(
        self,
        ci: IntArray,
        need: Array,
        n_cabin: int,
        poses: Array,
        d: KernelData,
        threshold: float,
        cum: Array,
        reach: Array,
        lower: Array,
        state: IntArray,
        left: BoolArray,
    ) -> int:
        """:func:`.along.cover_walk` (resumable; ``lower``, ``state``, ``left`` in place)."""
        d = _data(d)
        poses = check_array(poses, "poses", F8, 3, shape=(None, d.n_bodies, 13))
        n = poses.shape[0]
        n_t = (d.n_bodies if n_cabin else 0) + len(d.pair_a)
        if n_cabin not in (0, d.n_bodies) or n < 2:
            raise ValueError(f"cover_walk: n_cabin 0 or {d.n_bodies} and N >= 2 expected")
        ci = check_array(ci, "ci", I8, 1, out=True, shape=(codes.CW_SIZE,))
        task, pos, k = (int(ci[i]) for i in (codes.CW_TASK, codes.CW_POS, codes.CW_K))
        if not (0 <= task <= n_t and 0 <= pos < n and 0 <= k < n):
            raise ValueError("cover_walk: inconsistent walk state")
        return self.module.cover_walk(
            ci,
            check_array(need, "need", F8, 1, shape=(n_t,)),
            int(n_cabin),
            poses,
            d.fbuf,
            d.ibuf,
            d.grid,
            float(threshold),
            check_array(cum, "cum", F8, 2, shape=(n, n_t)),
            check_array(reach, "reach", F8, 2, shape=(n - 1, n_t)),
            check_array(lower, "lower", F8, 2, out=True, shape=(n, n_t)),
            check_array(state, "state", I8, 2, out=True, shape=(n, n_t)),
            check_array(left, "left", B1, 1, out=True, shape=(n - 1,)),
        )

    def cover_centres_batch(self, poses: Array, cover: Cover) -> Array:
        """:func:`.bounds.cover_centres_batch`: world centres (N, S, 3) of a cover for poses (N, B, 13)."""
        if not isinstance(cover, Cover):
            raise TypeError(f"cover: Cover expected, got {type(cover).__name__}")
        bodies = len(cover.start)  # the cover's bodies index the poses' second axis
        poses = check_array(poses, "poses", F8, 3, shape=(None, bodies, 13))
        return self.module.cover_centres_batch(poses, cover.body, cover.local, cover.frac)

    def cover_extents(self, poses: Array, cover: Cover) -> Array:
        """:func:`.bounds.cover_extents`: (N, 2) max |x| + r and max y + r of a cover for poses (N, B, 13)."""
        if not isinstance(cover, Cover):
            raise TypeError(f"cover: Cover expected, got {type(cover).__name__}")
        poses = check_array(poses, "poses", F8, 3, shape=(None, len(cover.start), 13))
        return self.module.cover_extents(poses, cover.body, cover.local, cover.frac, cover.radii)

    def run_extent(self, qs: Array, i: int, j: int, rho: Array, max_extra: float) -> tuple[int, float]:
        """:func:`.walk.run_extent`: (last sample, extra clearance) of the run from sample i to at most j."""
        qs = check_array(qs, "qs", F8, 2)
        rho = check_array(rho, "rho", F8, 1, shape=(qs.shape[1],))
        i, j = int(i), int(j)
        if not 0 <= i <= j < qs.shape[0]:
            raise ValueError(f"run_extent: samples 0 <= i <= j < {qs.shape[0]} expected, got i={i}, j={j}")
        return self.module.run_extent(qs, i, j, rho, float(max_extra))

    def first_inadmissible(self, q_a: Array, dq: Array, n_fine: int, d: KernelData) -> int:
        """:func:`.walk.first_inadmissible`: the first failing limit sample, -1: none."""
        d = _data(d)
        n_fine = int(n_fine)
        if n_fine < 1:
            raise ValueError(f"first_inadmissible: n_fine >= 1 expected, got {n_fine}")
        return self.module.first_inadmissible(
            check_array(q_a, "q_a", F8, 1, shape=d.joint_shape),
            check_array(dq, "dq", F8, 1, shape=d.joint_shape),
            n_fine,
            d.fbuf,
            d.ibuf,
        )

    def end_ratio(self, q_a: Array, q_b: Array, d: KernelData) -> float:
        """:func:`.walk.end_ratio`: the largest slope ratio at the two ends."""
        d = _data(d)
        return self.module.end_ratio(
            check_array(q_a, "q_a", F8, 1, shape=d.joint_shape),
            check_array(q_b, "q_b", F8, 1, shape=d.joint_shape),
            d.fbuf,
            d.ibuf,
        )

    def segment_reach(self, d: KernelData, k: float, h: float, adq: Array) -> tuple[Array, Array]:
        """:func:`.walk.segment_reach` of a world's bodies: displacement bounds of bodies (B,), pairs (P,)."""
        d = _data(d)
        return self.module.segment_reach(
            d.rho,
            d.link_mask,
            float(k),
            float(h),
            d.pair_a,
            d.pair_b,
            d.pair_rigid,
            check_array(adq, "adq", F8, 1, shape=d.joint_shape),
        )

    def motion_walk(
        self,
        ci: IntArray,
        cf: Array,
        q_a: Array,
        q_b: Array,
        dq: Array,
        reach: Array,
        pair_reach: Array,
        d: KernelData,
        slot_of: IntArray,
        poses: Array,
        cabin: Array,
        pairs: Array,
        resumed: bool = False,
    ) -> int:
        """:func:`.walk.motion_walk` on a world's data (resumable; the state store is written in place).

        Besides the types and shapes, the walk's own bookkeeping is checked before it resumes: ``slot_of``
        has a slot for each of the n + 1 states (n = ``ci[CI_N]`` >= 1), the store holds the states used
        so far, and every recorded slot lies inside the store.

        ``resumed``: the call resumes on the arrays the last call accepted, unchecked -- for the walk's own
        loop only (:class:`planner.collision.motion.CertifiedMotion`), where between the calls the kernel
        alone writes the walk's state and the caller only writes probe results into ``cf`` and replaces a
        full store by a larger one of the same kind (``WALK_GROW``). The checks cost about as much as a
        resumed call (tens of thousands a plan set).
        """
        if resumed:
            t = d.tree
            return self.module.motion_walk(
                ci,
                cf,
                q_a,
                q_b,
                dq,
                reach,
                pair_reach,
                d.fbuf,
                d.ibuf,
                d.grid,
                *t,
                slot_of,
                poses,
                cabin,
                pairs,
            )
        d = _data(d)
        b, p, n_j = d.n_bodies, len(d.pair_a), d.n_joints
        ci = check_array(ci, "ci", I8, 1, out=True, shape=(codes.CI_SIZE,))
        poses = check_array(poses, "poses", F8, 3, out=True, shape=(None, b, 13))
        cap = poses.shape[0]
        n = int(ci[codes.CI_N])
        slot_of = check_array(slot_of, "slot_of", I8, 1, out=True, shape=(n + 1,))
        if n < 1 or not 0 <= int(ci[codes.CI_COUNT]) <= cap or int(slot_of.max()) >= int(ci[codes.CI_COUNT]):
            raise ValueError(
                f"motion_walk: inconsistent walk state (n={n}, count={int(ci[codes.CI_COUNT])}, store {cap})"
            )
        return self.module.motion_walk(
            ci,
            check_array(cf, "cf", F8, 1, out=True, shape=(codes.CF_SIZE,)),
            check_array(q_a, "q_a", F8, 1, shape=(n_j,)),
            check_array(q_b, "q_b", F8, 1, shape=(n_j,)),
            check_array(dq, "dq", F8, 1, shape=(n_j,)),
            check_array(reach, "reach", F8, 1, shape=(b,)),
            check_array(pair_reach, "pair_reach", F8, 1, shape=(p,)),
            d.fbuf,
            d.ibuf,
            d.grid,
            *d.tree,
            slot_of,
            poses,
            check_array(cabin, "cabin", F8, 2, out=True, shape=(cap, b)),
            check_array(pairs, "pairs", F8, 2, out=True, shape=(cap, p)),
        )

    def obstacle_bounds(self, poses: Array, d: ObstacleKernelData, threshold: Array) -> Array:
        """:func:`.obstacles.obstacle_bounds`: bounds (B, O) at poses (B, 13), fine up to ``threshold``."""
        d = _obstacles(d)
        b = d.n_bodies
        return self.module.obstacle_bounds(
            check_array(poses, "poses", F8, 2, shape=(b, 13)),
            d.fbuf,
            d.ibuf,
            check_array(threshold, "threshold", F8, 1, shape=(b,)),
        )

    def obstacle_coarse_batch(self, poses: Array, d: ObstacleKernelData, allowed_too: bool) -> Array:
        """:func:`.obstacles.obstacle_coarse_batch`: coarse bounds (N, B, O) at poses (N, B, 13)."""
        d = _obstacles(d)
        poses = check_array(poses, "poses", F8, 3, shape=(None, d.n_bodies, 13))
        return self.module.obstacle_coarse_batch(poses, d.fbuf, d.ibuf, bool(allowed_too))

    def obstacle_fine_batch(self, poses: Array, rows: IntArray, b: int, d: ObstacleKernelData) -> Array:
        """:func:`.obstacles.obstacle_fine_batch`: body b's fine bounds (n, O) at samples ``rows`` (n,)."""
        d = _obstacles(d)
        poses = check_array(poses, "poses", F8, 3, shape=(None, d.n_bodies, 13))
        rows = check_array(rows, "rows", I8, 1)
        n, b = poses.shape[0], int(b)
        if len(rows) and not (0 <= int(rows.min()) and int(rows.max()) < n):
            raise ValueError(f"obstacle_fine_batch: sample indices in [0, {n}) expected")
        if not 0 <= b < d.n_bodies:
            raise ValueError(f"obstacle_fine_batch: a body in [0, {d.n_bodies}) expected, got {b}")
        return self.module.obstacle_fine_batch(poses, rows, b, d.fbuf, d.ibuf)

    def task_offsets(
        self, poses_a: Array, poses_b: Array, box: BoolArray, half: Array, col_a: IntArray, col_b: IntArray
    ) -> Array:
        """:func:`.offsets.task_offsets`: (M, T) bounds of each task's move (body col_a[t] + col_b[t])."""
        poses_a = check_array(poses_a, "poses_a", F8, 3)
        nb = poses_a.shape[1]
        poses_b = check_array(poses_b, "poses_b", F8, 3, shape=(poses_a.shape[0], nb, 13))
        if poses_a.shape[2] != 13:
            raise ValueError(f"poses_a: shape (M, B, 13) expected, got {poses_a.shape}")
        box = check_array(box, "box", B1, 1, shape=(nb,))
        half = check_array(half, "half", F8, 1, shape=(nb,))
        col_a = check_array(col_a, "col_a", I8, 1)
        col_b = check_array(col_b, "col_b", I8, 1, shape=col_a.shape)
        if len(col_a) and not (0 <= int(col_a.min()) and int(col_a.max()) < nb):
            raise ValueError(f"col_a: body indices in [0, {nb}) expected")
        if len(col_b) and not (-1 <= int(col_b.min()) and int(col_b.max()) < nb):
            raise ValueError(f"col_b: body indices in [-1, {nb}) expected (-1: none)")
        return self.module.task_offsets(poses_a, poses_b, box, half, col_a, col_b)

    def hull_deviation(self, verts: Array) -> float:
        """:func:`.offsets.hull_deviation`: how far a run's vertices (n, V, 3) stray from their chords."""
        verts = check_array(verts, "verts", F8, 3)
        if verts.shape[0] < 1 or verts.shape[2] != 3:
            raise ValueError(f"verts: shape (n >= 1, V, 3) expected, got {verts.shape}")
        return float(self.module.hull_deviation(verts))

    def path_vertices(self, poses: Array, b: int, local: Array, box: bool) -> Array:
        """:func:`.offsets.path_vertices`: body b's vertices (N, V, 3) at poses (N, B, 13)."""
        poses = self._poses_of(poses, b)
        local = check_array(local, "local", F8, 2, shape=(8, 3))
        return self.module.path_vertices(poses, int(b), local, bool(box))

    def pair_vertices(self, poses: Array, a: int, b: int, local: Array, box: bool) -> Array:
        """:func:`.offsets.pair_vertices`: body a's vertices (N, V, 3) in body b's frame."""
        poses = self._poses_of(poses, a, b)
        local = check_array(local, "local", F8, 2, shape=(8, 3))
        return self.module.pair_vertices(poses, int(a), int(b), local, bool(box))

    @staticmethod
    def _poses_of(poses: Array, *bodies: int) -> Array:
        poses = check_array(poses, "poses", F8, 3)
        if poses.shape[2] != 13:
            raise ValueError(f"poses: shape (N, B, 13) expected, got {poses.shape}")
        for b in bodies:
            if not 0 <= int(b) < poses.shape[1]:
                raise ValueError(f"body index {b} outside [0, {poses.shape[1]})")
        return poses

    def cumulative_bound(self, reach: Array, steps: Array) -> Array:
        """:func:`.spread.cumulative_bound`: cum (N, T) of the pieces' reach and steps (N - 1, T)."""
        reach = check_array(reach, "reach", F8, 2)
        steps = check_array(steps, "steps", F8, 2, shape=reach.shape)
        return self.module.cumulative_bound(reach, steps)

    def propagate(self, lower: Array, cum: Array, cols: IntArray) -> None:
        """:func:`.spread.propagate`: raise columns ``cols`` of lower (N, T) along cum (N, T), in place."""
        lower = check_array(lower, "lower", F8, 2, out=True)
        cum = check_array(cum, "cum", F8, 2, shape=lower.shape)
        cols = check_array(cols, "cols", I8, 1)
        if len(cols) and not (0 <= int(cols.min()) and int(cols.max()) < lower.shape[1]):
            raise ValueError(f"propagate: columns in [0, {lower.shape[1]}) expected")
        self.module.propagate(lower, cum, cols)

    def between_bound(self, lower: Array, reach: Array, cols: IntArray) -> tuple[float, int]:
        """:func:`.spread.between_bound`: (smallest bound between samples, its piece) over ``cols``."""
        lower = check_array(lower, "lower", F8, 2)
        reach = check_array(reach, "reach", F8, 2, shape=(lower.shape[0] - 1, lower.shape[1]))
        cols = check_array(cols, "cols", I8, 1)
        if not len(cols) or not (0 <= int(cols.min()) and int(cols.max()) < lower.shape[1]):
            raise ValueError(f"between_bound: one or more columns in [0, {lower.shape[1]}) expected")
        value, k = self.module.between_bound(lower, reach, cols)
        return float(value), int(k)

    def grid_marks(
        self, vertices: Array, faces: IntArray, lo: Array, step: float, spacing: float, marked: BoolArray
    ) -> None:
        """:func:`.grid.grid_marks`: mark the nodes of ``marked`` (nx, ny, nz) nearest to surface samples."""
        vertices = check_array(vertices, "vertices", F8, 2, shape=(None, 3))
        faces = check_array(faces, "faces", I8, 2, shape=(None, 3))
        if len(faces) and not (0 <= int(faces.min()) and int(faces.max()) < len(vertices)):
            raise ValueError(f"grid_marks: face indices in [0, {len(vertices)}) expected")
        if not (step > 0.0 and spacing > 0.0):
            raise ValueError(f"grid_marks: step and spacing > 0 expected, got {step}, {spacing}")
        self.module.grid_marks(
            vertices,
            faces,
            check_array(lo, "lo", F8, 1, shape=(3,)),
            float(step),
            float(spacing),
            check_array(marked, "marked", B1, 3, out=True),
        )

    def mesh_tree(self, vertices: Array, faces: IntArray) -> MeshTree:
        """:func:`.mesh.mesh_tree`: the triangles of a mesh (vertices (V, 3), faces (F, 3)) in a box tree."""
        vertices = check_array(vertices, "vertices", F8, 2, shape=(None, 3))
        faces = check_array(faces, "faces", I8, 2, shape=(None, 3))
        if len(faces) and not (0 <= int(faces.min()) and int(faces.max()) < len(vertices)):
            raise ValueError(f"mesh_tree: face indices in [0, {len(vertices)}) expected")
        return MeshTree(*self.module.mesh_tree(vertices, faces))

    def _tree(self, tree: MeshTree) -> MeshTree:
        """``tree``, checked (:func:`~.buffers.check_tree`) unless it was checked before and is read-only.

        A world's tree (:class:`~.buffers.KernelData`) and an obstacle's are read-only: each is checked once.
        """
        if self._checked.get(id(tree)) is tree:
            return tree
        if not isinstance(tree, MeshTree):
            raise TypeError(f"tree: MeshTree expected, got {type(tree).__name__}")
        check_tree(tree)
        if not any(a.flags.writeable for a in tree):
            if len(self._checked) >= CHECKED_TREES:
                del self._checked[next(iter(self._checked))]
            self._checked[id(tree)] = tree
        return tree

    def box_touches_mesh(self, pose: Array, half: Array, grow: float, tree: MeshTree) -> bool:
        """:func:`.mesh.box_touches_mesh`: the box of half extents ``half`` + ``grow`` at ``pose`` (13,)."""
        tree = self._tree(tree)
        return bool(
            self.module.box_touches_mesh(
                check_array(pose, "pose", F8, 1, shape=(13,)),
                check_array(half, "half", F8, 1, shape=(3,)),
                float(grow),
                *tree,
            )
        )

    def box_mesh_distance(self, pose: Array, half: Array, cap: float, tree: MeshTree) -> float:
        """:func:`.mesh.box_mesh_distance`: the box's distance to the tree's triangles, at most ``cap``."""
        tree = self._tree(tree)
        return float(
            self.module.box_mesh_distance(
                check_array(pose, "pose", F8, 1, shape=(13,)),
                check_array(half, "half", F8, 1, shape=(3,)),
                float(cap),
                *tree,
            )
        )

    def capsule_touches_mesh(self, pose: Array, radius: float, grow: float, tree: MeshTree) -> bool:
        """:func:`.mesh.capsule_touches_mesh`: the capsule of radius ``radius`` + ``grow`` at ``pose``."""
        tree = self._tree(tree)
        pose = check_array(pose, "pose", F8, 1, shape=(13,))
        return bool(self.module.capsule_touches_mesh(pose, float(radius), float(grow), *tree))

    def capsule_mesh_distance(self, pose: Array, radius: float, cap: float, tree: MeshTree) -> float:
        """:func:`.mesh.capsule_mesh_distance`: the capsule's distance to the triangles, at most ``cap``."""
        tree = self._tree(tree)
        pose = check_array(pose, "pose", F8, 1, shape=(13,))
        return float(self.module.capsule_mesh_distance(pose, float(radius), float(cap), *tree))

    def cabin_witness(
        self, pose: Array, half: Array, radius: float, tree: MeshTree
    ) -> tuple[float, Array, Array]:
        """:func:`.mesh.cabin_witness`: (distance, body point, cabin point) of a box (radius 0), a capsule."""
        tree = self._tree(tree)
        pose = check_array(pose, "pose", F8, 1, shape=(13,))
        half = check_array(half, "half", F8, 1, shape=(3,))
        d, pa, pb = self.module.cabin_witness(pose, half, float(radius), *tree)
        return float(d), pa, pb

    def pair_touches(self, poses: Array, radius: Array, half: Array, a: int, b: int, grow: float) -> bool:
        """:func:`.distances.pair_touches`: bodies a, b of ``poses`` (B, 13), each grown by ``grow`` / 2."""
        poses = check_array(poses, "poses", F8, 2, shape=(None, 13))
        n = poses.shape[0]
        if not (0 <= a < n and 0 <= b < n):
            raise ValueError(f"pair_touches: bodies {a}, {b} outside [0, {n})")
        return bool(
            self.module.pair_touches(
                poses,
                check_array(radius, "radius", F8, 1, shape=(n,)),
                check_array(half, "half", F8, 2, shape=(n, 3)),
                int(a),
                int(b),
                float(grow),
            )
        )

    def pair_witness(
        self, pose_a: Array, half_a: Array, radius_a: float, pose_b: Array, half_b: Array, radius_b: float
    ) -> tuple[float, Array, Array]:
        """:func:`.mesh.pair_witness`: (distance, a's point, b's point) of two bodies (a box: radius 0)."""
        d, pa, pb = self.module.pair_witness(
            check_array(pose_a, "pose_a", F8, 1, shape=(13,)),
            check_array(half_a, "half_a", F8, 1, shape=(3,)),
            float(radius_a),
            check_array(pose_b, "pose_b", F8, 1, shape=(13,)),
            check_array(half_b, "half_b", F8, 1, shape=(3,)),
            float(radius_b),
        )
        return float(d), pa, pb

    def hull_mesh_lower(self, points: Array, tree: MeshTree) -> float:
        """:func:`.mesh.hull_mesh_lower`: a certified lower bound of conv(points (n, 3))'s distance."""
        tree = self._tree(tree)
        return float(
            self.module.hull_mesh_lower(check_array(points, "points", F8, 2, shape=(None, 3)), *tree)
        )

    def hull_shape_lower(self, points: Array, half: Array, radius: float) -> float:
        """:func:`.mesh.hull_shape_lower`: a certified lower bound of conv(points (n, 3))'s distance.

        The other body is the box [-half, half] (3,) grown by ``radius`` (a capsule: half (0, 0, L / 2)).
        """
        return float(
            self.module.hull_shape_lower(
                check_array(points, "points", F8, 2, shape=(None, 3)),
                check_array(half, "half", F8, 1, shape=(3,)),
                float(radius),
            )
        )

    def grid_bounds(self, marked: BoolArray, step: float, offset: float) -> Array:
        """:func:`.grid.grid_bounds`: step * distance to the nearest marked node - offset, padded by -inf."""
        marked = check_array(marked, "marked", B1, 3)
        out = np.empty(tuple(n + 2 for n in marked.shape))
        self.module.grid_bounds(marked, float(step), float(offset), out)
        return out


#: The kernels every world uses: the ahead-of-time build when there is one, resolved on first use.
DEFAULT = Kernels()
