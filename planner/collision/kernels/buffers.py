"""A world's constant kernel data: built once (:func:`build`), packed into two flat buffers, read as views.

A Python call into a compiled function costs ~0.1 us per argument, so the kernels take four arguments
(``fbuf``, ``ibuf``, the flat clearance grid, the query) instead of thirty-odd. :func:`pack` lays a
:class:`Packed` value out in the two buffers (float64, int64); the compiled :func:`unpack` takes views of
them (no copies) back into a :class:`Packed`, whose fields the kernels read by name (``u.fine_local``).

What the buffers hold, per body b (B bodies), sphere s and checked pair k:

* the payload box frame ``T_tool_box``, the robot's pose-kernel code and parameters (the robot model's
  :class:`~planner.robots.geometry.CollisionModel`: ``kernel``, ``kernel_params``, its body kind codes);
* the fine sphere cover (cabin bounds on the grid) and the coarse one (self bounds): sphere body, local
  centre, capsule-length fraction, radius, and the first sphere of each body;
* pairs (a_k, b_k), capsule radii and box half sizes (exact capsule-capsule / capsule-box distances);
* the rail body's exact clearance table along the rail (cabin8: the carriage; empty: no cabin or none);
* the admissibility bounds c_lo, c_hi (already widened by 1e-9) and the rows of c(q) whose largest value
  bounds the slope of slope-dependent bodies (``ratio_rows``).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from planner.collision.bodies import BodySet, Shape
from planner.core.aot import B1, F8, I8, check_array
from planner.core.types import Array, BoolArray, IntArray
from planner.robots.geometry import CollisionModel

if TYPE_CHECKING:  # the grid is built with these kernels (:mod:`..clearance_grid` imports them)
    from planner.collision.clearance_grid import ClearanceGrid

#: Integers before the int64 arrays: counts (bodies, fine spheres, coarse spheres, pairs, table length),
#: has_grid, carriage, grid shape (3), then kernel code, counts (kernel parameters, constraints, ratio rows).
HEADER = 14


class Packed(NamedTuple):
    """A world's kernel data by name (arrays as views of the packed buffers inside the kernels)."""

    T_tool_box: Array  # (4, 4) payload box frame in the tool frame
    kernel: int  # the robot's pose-kernel code (planner.robots.kernels)
    params: Array  # the robot's kernel parameters
    kinds: IntArray  # (B,) body kind codes of the robot's pose kernel
    fine_body: IntArray  # (S,) body of each fine sphere
    fine_local: Array  # (S, 3) centre in the body frame (boxes)
    fine_frac: Array  # (S,) fraction of the capsule length along the body z axis (capsules)
    fine_r: Array  # (S,)
    fine_bounds: IntArray  # (B + 1,) first sphere of each body, then S
    origin: Array  # (3,) grid origin
    inv_step: float  # 1 / grid step
    shape: IntArray  # (3,) grid shape
    has_grid: bool
    coarse_body: IntArray  # the coarse cover, as the fine one
    coarse_local: Array
    coarse_frac: Array
    coarse_r: Array
    coarse_bounds: IntArray
    pair_a: IntArray  # (P,)
    pair_b: IntArray  # (P,)
    radius: Array  # (B,) capsule radius (0 for boxes)
    capsule_pair: IntArray  # (P,) 1: both bodies are capsules
    half: Array  # (B, 3) box half sizes (zeros for capsules)
    capsule_box: IntArray  # (P,) 0 none, 1 a is the capsule, 2 b is the capsule
    carriage: int  # index of the rail body (cabin8: the carriage; -1: none)
    table: Array  # exact rail-body clearance along the rail (empty: none)
    table_z0: float
    table_dz: float
    c_lo: Array  # (m,) admissibility bounds
    c_hi: Array
    ratio_rows: IntArray  # rows of c(q) bounding the slope of slope-dependent bodies


def pack(data: Packed) -> tuple[Array, IntArray]:
    """(fbuf, ibuf) of a world's kernel data, in the layout :func:`unpack` reads."""
    d = data
    counts = [len(d.kinds), len(d.fine_r), len(d.coarse_r), len(d.pair_a), len(d.table)]
    header = [*counts, int(d.has_grid), int(d.carriage), *(int(x) for x in d.shape)]
    header += [int(d.kernel), len(d.params), len(d.c_lo), len(d.ratio_rows)]
    ints = [np.array(header + [0] * (HEADER - len(header)))]
    ints += [d.kinds, d.fine_body, d.fine_bounds, d.coarse_body, d.coarse_bounds, d.pair_a, d.pair_b]
    ints += [d.capsule_pair, d.capsule_box, d.ratio_rows]
    floats = [d.T_tool_box, d.params, d.fine_local, d.fine_frac, d.fine_r, d.origin, [d.inv_step]]
    floats += [d.coarse_local, d.coarse_frac, d.coarse_r, d.radius, d.half, d.table]
    floats += [[d.table_z0, d.table_dz], d.c_lo, d.c_hi]
    fbuf = np.ascontiguousarray(np.concatenate([np.asarray(f, dtype=np.float64).ravel() for f in floats]))
    ibuf = np.ascontiguousarray(np.concatenate([np.asarray(i, dtype=np.int64).ravel() for i in ints]))
    return fbuf, ibuf


@dataclass(frozen=True, eq=False)
class Cover:
    """A sphere cover flattened for the kernels: every sphere's body, local centre, length fraction, radius.

    ``start[b]`` is the first sphere of body b (a body may have none).
    """

    body: IntArray  # (S,)
    local: Array  # (S, 3)
    frac: Array  # (S,)
    radii: Array  # (S,)
    start: IntArray  # (B,)

    def __post_init__(self) -> None:
        """The arrays the kernels read have their entry types and shapes, and are frozen (read-only).

        Checked once here (:func:`planner.core.aot.check_array`), so the entries need not check them on
        every call; read-only, so nothing can change them after the check.
        """
        s = len(self.radii)
        check_array(self.body, "cover.body", I8, 1, shape=(s,))
        check_array(self.local, "cover.local", F8, 2, shape=(s, 3))
        check_array(self.frac, "cover.frac", F8, 1, shape=(s,))
        for arr in (self.body, self.local, self.frac, self.radii, self.start):
            arr.setflags(write=False)

    @property
    def table(self) -> tuple[IntArray, Array, Array]:
        """(body, local, frac): the arguments of ``cover_centres``."""
        return self.body, self.local, self.frac

    @property
    def bounds(self) -> IntArray:
        """(B + 1,) first sphere of each body, then S."""
        return np.concatenate([self.start, [len(self.radii)]]).astype(np.int64)


def cover(shapes: tuple[Shape, ...], centres: tuple[Array, ...], radii: tuple[Array, ...]) -> Cover:
    """The flat :class:`Cover` of per-body sphere centres (capsules: along z, as length fractions)."""
    body, local, frac = [], [], []
    for b, (shape, c) in enumerate(zip(shapes, centres, strict=True)):
        body.append(np.full(len(c), b, dtype=np.int64))
        if shape.kind == "capsule":
            local.append(np.zeros_like(c))
            frac.append(c[:, 2])
        else:
            local.append(c)
            frac.append(np.zeros(len(c)))
    counts = [len(r) for r in radii]
    return Cover(
        np.concatenate(body).astype(np.int64),
        np.ascontiguousarray(np.concatenate(local), dtype=np.float64),
        np.ascontiguousarray(np.concatenate(frac), dtype=np.float64),
        np.concatenate(radii),
        np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(int),
    )


class MeshTree(NamedTuple):
    """The cabin's triangles in a bounding-box tree (:func:`.mesh.mesh_tree`); empty arrays: no cabin."""

    tris: Array  # (T, 9) the triangles' vertices, in the tree's order
    bounds: Array  # (N, 6) each node's bounding box: lo, then hi
    links: IntArray  # (N, 2) a leaf: (first triangle, count > 0); an inner node: (left, -right - 1)


def check_tree(tree: MeshTree) -> MeshTree:
    """``tree`` if its arrays have their entry types and its links stay inside it (else ValueError).

    The compiled walk follows the links without checking them: a link out of range would read past the
    arrays.
    """
    tris = check_array(tree.tris, "tree tris", F8, 2, shape=(None, 9))
    bounds = check_array(tree.bounds, "tree bounds", F8, 2, shape=(None, 6))
    links = check_array(tree.links, "tree links", I8, 2, shape=(len(bounds), 2))
    n, t = len(bounds), len(tris)
    leaf = links[:, 1] > 0
    first, count = links[leaf, 0], links[leaf, 1]
    inner = links[~leaf]
    if (t == 0) != (n == 0) or (
        n
        and not (
            np.all(first >= 0)
            and np.all(first + count <= t)
            and np.all((inner[:, 0] > 0) & (inner[:, 0] < n))
            and np.all((-inner[:, 1] - 1 > 0) & (-inner[:, 1] - 1 < n))
        )
    ):
        raise ValueError("tree: links outside the tree's nodes or triangles")
    return tree


#: The tree of a world without a cabin.
NO_TREE = MeshTree(np.zeros((0, 9)), np.zeros((0, 6)), np.zeros((0, 2), dtype=np.int64))


@dataclass(frozen=True, eq=False)
class KernelData:
    """Everything a world's kernels read, built once per world by :func:`build`.

    ``fbuf``/``ibuf`` are the packed buffers, ``grid`` the flat clearance lower-bound grid (C order; one
    dummy value without a cabin), ``upper_slack`` the grid's upper-bound slack (-1: no grid, which disables
    the certain-contact test). The covers and pair masks stay for the Python side (sphere centres for
    :mod:`planner.plan.transit`, the reference route, the motion walk's reach bounds), with the bodies'
    reach bounds ``rho`` and rigid pair joints ``pair_rigid`` (the motion walk's segment reach).

    Every array a kernel entry reads is checked for its entry type when the data is built, so the entries
    (:mod:`.entries`) need not check them again on every call.
    """

    fbuf: Array
    ibuf: IntArray
    grid: Array
    upper_slack: float
    fine: Cover
    coarse: Cover
    pair_a: IntArray
    pair_b: IntArray
    exact_pair: BoolArray  # (P,) the pair bound is the exact distance (capsule-capsule, capsule-box)
    link_mask: BoolArray  # (B,) slope-dependent bodies (cabin8: the stage links; ``slope_bodies``)
    c_lo: Array
    c_hi: Array
    rho: Array  # (B, n_joints) static reach bounds (``BodySet.rho``)
    pair_rigid: BoolArray  # (P, n_joints) joint j moves both bodies of pair p rigidly
    tree: MeshTree = NO_TREE  # the cabin's triangles, for the walk's own probes of boxes

    def __post_init__(self) -> None:
        """The arrays the kernels read have their entry types and shapes, and are frozen (read-only).

        Checked once here (:func:`planner.core.aot.check_array`), so the entries (:mod:`.entries`) need not
        check them on every call; read-only, so nothing can change them (the counts in ``ibuf`` above all)
        after the check.
        """
        check_array(self.ibuf, "kernel data ibuf", I8, 1)
        b, p = self.n_bodies, len(self.pair_a)
        for name, value, dtype, ndim, shape in (
            ("fbuf", self.fbuf, F8, 1, None),
            ("grid", self.grid, F8, 1, None),
            ("pair_a", self.pair_a, I8, 1, (p,)),
            ("pair_b", self.pair_b, I8, 1, (p,)),
            ("link_mask", self.link_mask, B1, 1, (b,)),
            ("rho", self.rho, F8, 2, (b, None)),
            ("pair_rigid", self.pair_rigid, B1, 2, (p, self.n_joints)),
        ):
            check_array(value, f"kernel data {name}", dtype, ndim, shape=shape)
        check_tree(self.tree)
        if self.ibuf[5]:  # has_grid: the flat grid holds every node of the packed grid shape
            check_array(self.grid, "kernel data grid", F8, 1, shape=(int(np.prod(self.ibuf[7:10])),))
        frozen = (self.fbuf, self.ibuf, self.grid, self.pair_a, self.pair_b, self.exact_pair, self.link_mask)
        for arr in (*frozen, self.c_lo, self.c_hi, self.rho, self.pair_rigid, *self.tree):
            arr.setflags(write=False)

    @cached_property
    def n_bodies(self) -> int:
        """B, the number of bodies (the packed header's first count)."""
        return int(self.ibuf[0])

    @cached_property
    def n_joints(self) -> int:
        """The robot's number of joints (the columns of ``rho``)."""
        return int(self.rho.shape[1])

    @cached_property
    def n_constraints(self) -> int:
        """m, the length of the admissibility vector c(q)."""
        return len(self.c_lo)

    @cached_property
    def joint_shape(self) -> tuple[int]:
        """(n_joints,): the shape of a joint vector (checked on every call of an entry)."""
        return (self.n_joints,)


def build(
    model: CollisionModel,
    bodies: BodySet,
    T_tool_box: Array,
    grid: ClearanceGrid | None,
    carriage_table: tuple[float, float, Array] | None,
    tree: MeshTree = NO_TREE,
) -> KernelData:
    """The kernel data of a world: covers, pair tables, closed-form pose data, packed.

    With a cabin (``grid`` given) the rail body's cabin bound comes from its exact clearance table
    ``carriage_table`` = (z0, dz, distances) along the rail, so its fine cover is left empty.
    """
    names, shapes = bodies.names, bodies.shapes
    carriage = names.index(model.rail_body) if model.rail_body is not None else -1
    fine_centres, fine_radii = list(bodies.sphere_centres), list(bodies.sphere_radii)
    if grid is not None and carriage >= 0:
        fine_centres[carriage], fine_radii[carriage] = np.zeros((0, 3)), np.zeros(0)
    fine = cover(shapes, tuple(fine_centres), tuple(fine_radii))
    coarse = cover(shapes, bodies.coarse_centres, bodies.coarse_radii)
    pair_a = np.array([a for a, _ in bodies.pairs], dtype=np.int64)
    pair_b = np.array([b for _, b in bodies.pairs], dtype=np.int64)
    kinds = [(shapes[a].kind, shapes[b].kind) for a, b in bodies.pairs]
    capsule_pair = np.array([k == ("capsule", "capsule") for k in kinds], dtype=np.bool_)
    capsule_box = np.array(
        [1 if k == ("capsule", "box") else 2 if k == ("box", "capsule") else 0 for k in kinds], dtype=np.int64
    )
    z0, dz, table = carriage_table if carriage_table is not None else (0.0, 1.0, np.zeros(0))
    c_lo, c_hi = model.admissibility.c_lower - 1e-9, model.admissibility.c_upper + 1e-9
    fbuf, ibuf = pack(
        Packed(
            T_tool_box=np.ascontiguousarray(T_tool_box, dtype=float),
            kernel=model.kernel,
            params=np.asarray(model.kernel_params, dtype=float),
            kinds=np.array([model.kind_code(n) for n in names], dtype=np.int64),
            fine_body=fine.body,
            fine_local=fine.local,
            fine_frac=fine.frac,
            fine_r=fine.radii,
            fine_bounds=fine.bounds,
            origin=grid.origin if grid is not None else np.zeros(3),
            inv_step=1.0 / grid.step if grid is not None else 1.0,
            shape=np.array(grid.lower_bound.shape if grid is not None else (1, 1, 1)),
            has_grid=grid is not None,
            coarse_body=coarse.body,
            coarse_local=coarse.local,
            coarse_frac=coarse.frac,
            coarse_r=coarse.radii,
            coarse_bounds=coarse.bounds,
            pair_a=pair_a,
            pair_b=pair_b,
            radius=np.array([s.radius for s in shapes]),
            capsule_pair=np.asarray(capsule_pair, dtype=np.int64),
            half=np.array([np.array(s.size) / 2 if s.kind == "box" else np.zeros(3) for s in shapes]),
            capsule_box=capsule_box,
            carriage=carriage,
            table=table,
            table_z0=z0,
            table_dz=dz,
            c_lo=c_lo,
            c_hi=c_hi,
            ratio_rows=np.array(model.ratio_rows, dtype=np.int64),
        )
    )
    # Always a read-only plain array: numba compiles one specialisation per argument type, and a grid read
    # from the cache is a read-only memory map while a freshly built one is writable -- two types, so the
    # plan after a grid build used to compile every kernel a second time (10 s in a fresh process).
    bounds = grid.lower_bound if grid is not None else np.zeros(1)
    flat_grid = np.ascontiguousarray(np.asarray(bounds, dtype=np.float64).reshape(-1)).view(np.ndarray)
    flat_grid.setflags(write=False)
    return KernelData(
        fbuf=fbuf,
        ibuf=ibuf,
        grid=flat_grid,
        upper_slack=grid.upper_slack if grid is not None else -1.0,
        fine=fine,
        coarse=coarse,
        pair_a=pair_a,
        pair_b=pair_b,
        exact_pair=capsule_pair | (capsule_box > 0),
        link_mask=np.array([n in model.slope_bodies for n in names], dtype=bool),
        c_lo=c_lo,
        c_hi=c_hi,
        rho=np.ascontiguousarray(bodies.rho, dtype=np.float64),
        pair_rigid=np.ascontiguousarray(bodies.pair_rigid, dtype=np.bool_),
        tree=tree,
    )


#: Integers before the obstacle data's int64 arrays: counts (bodies, obstacles, fine spheres).
OBSTACLE_HEADER = 3


class ObstaclePacked(NamedTuple):
    """An obstacle set's kernel data by name (views of its packed buffers inside the kernels).

    Each obstacle is bounded by a box (its own, or its mesh's bounding box); each body by its bounding
    sphere (box: half-diagonal; capsule: radius + half its length) and by its fine sphere cover.
    """

    R: Array  # (O, 9) each bounding box's rotation in the base frame, row-major: R[o, 3 i + j] = R_ij
    origin_local: Array  # (O, 3) the box centre p_o in its own axes, p_o R_o
    half: Array  # (O, 3) half extents of the bounding boxes
    capsule: IntArray  # (B,) 1: the body is a capsule
    capsule_r: Array  # (B,) capsule radius (0 for boxes)
    box_r: Array  # (B,) half the diagonal of a box body
    active: IntArray  # (B, O) 1: the pair is checked, 0: allowed
    local: Array  # (S, 3) fine cover: centre in the body frame (boxes)
    frac: Array  # (S,) fraction of the capsule length along the body z axis (capsules)
    radii: Array  # (S,)
    start: IntArray  # (B + 1,) first sphere of each body, then S


def pack_obstacles(data: ObstaclePacked) -> tuple[Array, IntArray]:
    """(fbuf, ibuf) of an obstacle set's kernel data, in the layout ``packed.unpack_obstacles`` reads."""
    d = data
    header = [len(d.capsule), len(d.half), len(d.radii)]
    ints = [np.array(header), d.capsule, d.active, d.start]
    floats = [d.R, d.origin_local, d.half, d.capsule_r, d.box_r, d.local, d.frac, d.radii]
    fbuf = np.ascontiguousarray(np.concatenate([np.asarray(f, dtype=np.float64).ravel() for f in floats]))
    ibuf = np.ascontiguousarray(np.concatenate([np.asarray(i, dtype=np.int64).ravel() for i in ints]))
    return fbuf, ibuf


@dataclass(frozen=True, eq=False)
class ObstacleKernelData:
    """The packed constant data of an obstacle set, built once (:func:`obstacle_data`), read-only."""

    fbuf: Array
    ibuf: IntArray

    def __post_init__(self) -> None:
        """Both buffers have their entry types and the sizes their header implies, and are frozen."""
        check_array(self.ibuf, "obstacle data ibuf", I8, 1)
        b, o, s = (int(x) for x in self.ibuf[:OBSTACLE_HEADER])
        check_array(self.ibuf, "obstacle data ibuf", I8, 1, shape=(OBSTACLE_HEADER + b + b * o + b + 1,))
        check_array(self.fbuf, "obstacle data fbuf", F8, 1, shape=(15 * o + 2 * b + 5 * s,))
        for arr in (self.fbuf, self.ibuf):
            arr.setflags(write=False)

    @cached_property
    def n_bodies(self) -> int:
        """B, the number of bodies."""
        return int(self.ibuf[0])

    @cached_property
    def n_obstacles(self) -> int:
        """O, the number of obstacles."""
        return int(self.ibuf[1])


def obstacle_data(
    T_base_bound: Array, half: Array, shapes: tuple[Shape, ...], fine: Cover, active: BoolArray
) -> ObstacleKernelData:
    """The kernel data of obstacles bounded by boxes (T (O, 4, 4), half extents (O, 3)) and of the bodies.

    ``fine``: the bodies' fine sphere cover (every body's spheres contiguous, in body order); ``active``
    (B, O): the checked pairs.
    """
    R = np.ascontiguousarray(T_base_bound[:, :3, :3], dtype=np.float64)
    p = np.ascontiguousarray(T_base_bound[:, :3, 3], dtype=np.float64)
    fbuf, ibuf = pack_obstacles(
        ObstaclePacked(
            R=R.reshape(len(R), 9),
            origin_local=np.einsum("oi,oij->oj", p, R),  # p_o R_o (O, 3)
            half=np.asarray(half, dtype=np.float64).reshape(len(R), 3),
            capsule=np.array([s.kind == "capsule" for s in shapes], dtype=np.int64),
            capsule_r=np.array([s.radius for s in shapes], dtype=np.float64),
            box_r=np.array([0.5 * float(np.linalg.norm(s.size)) for s in shapes], dtype=np.float64),
            active=np.asarray(active, dtype=np.int64),
            local=fine.local,
            frac=fine.frac,
            radii=fine.radii,
            start=fine.bounds,
        )
    )
    return ObstacleKernelData(fbuf, ibuf)
