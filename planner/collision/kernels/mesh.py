"""Does a box touch the cabin's triangles? A bounding-volume tree and an exact overlap test, compiled.

The certified motion walk (:func:`.walk.motion_walk`) proves a state's spare clearance by *probes*: the body
grown by a level is tested against the cabin mesh, and the first level that does not touch is the spare.
Through FCL that is a return to Python per probe (about 10 us each: the posed object, the query and its
result), thousands a plan in a tight cabin, nearly all of them on the payload, a box. Here the same test
runs inside the walk:

- :func:`mesh_tree` builds an axis-aligned bounding-box tree over the triangles (median split of the
  longest axis of the centroids, at most :data:`LEAF` triangles a leaf), once per cabin;
- :func:`box_touches_mesh` walks it with the box's axis-aligned bounds and tests each triangle of a leaf
  it reaches by the separating-axis theorem (:func:`box_touches_triangle`: the box's 3 face normals, the
  triangle's normal and the 9 edge-edge cross products; Akenine-Moeller, "Fast 3D triangle-box overlap
  testing", 2001). Touching counts as overlap, as FCL's collision query does.

The test is exact up to rounding; the box is tested with its half extents raised by
:data:`~.codes.ROUND_M`, so that rounding can only make it report a touch that is not there, never miss one
that is. :func:`box_mesh_distance` gives a box's exact distance (the walk's last resort, as FCL's was) and
:func:`hull_mesh_lower` a certified lower bound of a point set's convex hull's distance (the gate's swept
hulls, :mod:`planner.collision.sweep`), both on the same tree.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from planner.collision.kernels.codes import ROUND_M
from planner.collision.kernels.distances import dot3 as _dot3
from planner.collision.kernels.distances import segment_segment_sq

#: Most triangles in a leaf of the tree.
LEAF = 4


@njit(cache=True, fastmath=False)
def mesh_tree(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(triangles (T, 9) in the tree's order, node bounds (N, 6): lo then hi, node links (N, 2)).

    A leaf's links are (first triangle, count > 0); an inner node's (left child, 0), its right child
    following the left one's subtree at ``links[k, 0] + size of the left subtree``: stored as the right
    child's index in ``links[k, 1]`` negated minus one, so that a leaf and an inner node are told apart by the
    sign of ``links[k, 1]``.
    """
    n_t = faces.shape[0]
    if n_t == 0:
        return np.zeros((0, 9)), np.zeros((0, 6)), np.zeros((0, 2), dtype=np.int64)
    cent = np.empty((n_t, 3))
    tri_lo = np.empty((n_t, 3))
    tri_hi = np.empty((n_t, 3))
    for t in range(n_t):
        for x in range(3):
            a, b, c = vertices[faces[t, 0], x], vertices[faces[t, 1], x], vertices[faces[t, 2], x]
            tri_lo[t, x] = min(a, min(b, c))
            tri_hi[t, x] = max(a, max(b, c))
            cent[t, x] = (a + b + c) / 3.0
    order = np.arange(n_t)
    cap = 2 * n_t
    bounds = np.empty((cap, 6))
    links = np.zeros((cap, 2), dtype=np.int64)
    # An explicit stack of (node, first, count); nodes are numbered as they are created.
    stack = np.empty((cap, 3), dtype=np.int64)
    top = 0
    n_nodes = 1
    stack[0, 0], stack[0, 1], stack[0, 2] = 0, 0, n_t
    top = 1
    while top > 0:
        top -= 1
        node, first, count = stack[top, 0], stack[top, 1], stack[top, 2]
        for x in range(3):
            lo, hi = math.inf, -math.inf
            for r in range(first, first + count):
                lo = min(lo, tri_lo[order[r], x])
                hi = max(hi, tri_hi[order[r], x])
            bounds[node, x], bounds[node, 3 + x] = lo, hi
        if count <= LEAF:
            links[node, 0], links[node, 1] = first, count
            continue
        # Split at the median centroid along the centroids' longest extent.
        axis, width = 0, -1.0
        for x in range(3):
            lo, hi = math.inf, -math.inf
            for r in range(first, first + count):
                lo = min(lo, cent[order[r], x])
                hi = max(hi, cent[order[r], x])
            if hi - lo > width:
                axis, width = x, hi - lo
        seg = order[first : first + count]
        keys = np.empty(count)
        for r in range(count):
            keys[r] = cent[seg[r], axis]
        seg[:] = seg[np.argsort(keys, kind="mergesort")]
        half = count // 2
        left, right = n_nodes, n_nodes + 1
        n_nodes += 2
        links[node, 0], links[node, 1] = left, -right - 1
        stack[top, 0], stack[top, 1], stack[top, 2] = left, first, half
        stack[top + 1, 0], stack[top + 1, 1], stack[top + 1, 2] = right, first + half, count - half
        top += 2
    tris = np.empty((n_t, 9))
    for r in range(n_t):
        t = order[r]
        for c in range(3):
            for x in range(3):
                tris[r, 3 * c + x] = vertices[faces[t, c], x]
    return tris, bounds[:n_nodes].copy(), links[:n_nodes].copy()


@njit(cache=True, fastmath=False, inline="always")
def _apart(p0: float, p1: float, p2: float, r: float) -> bool:
    """The projections p0, p1, p2 of the triangle miss the box's projection [-r, r]."""
    return min(p0, min(p1, p2)) > r or max(p0, max(p1, p2)) < -r


@njit(cache=True, fastmath=False)
def box_touches_triangle(v: np.ndarray, e0: float, e1: float, e2: float) -> bool:
    """Whether the box [-e, e] touches the triangle v (3, 3) (rows: vertices in the box's frame)."""
    a0, a1, a2 = v[0, 0], v[0, 1], v[0, 2]
    b0, b1, b2 = v[1, 0], v[1, 1], v[1, 2]
    c0, c1, c2 = v[2, 0], v[2, 1], v[2, 2]
    # The box's face normals: the triangle's bounds against the box.
    if _apart(a0, b0, c0, e0) or _apart(a1, b1, c1, e1) or _apart(a2, b2, c2, e2):
        return False
    # The nine axes e_i x f_j (f: the triangle's edges).
    for k in range(3):
        if k == 0:
            f0, f1, f2 = b0 - a0, b1 - a1, b2 - a2
        elif k == 1:
            f0, f1, f2 = c0 - b0, c1 - b1, c2 - b2
        else:
            f0, f1, f2 = a0 - c0, a1 - c1, a2 - c2
        # x axis cross f = (0, -f2, f1)
        r = e1 * abs(f2) + e2 * abs(f1)
        if _apart(-f2 * a1 + f1 * a2, -f2 * b1 + f1 * b2, -f2 * c1 + f1 * c2, r):
            return False
        # y axis cross f = (f2, 0, -f0)
        r = e0 * abs(f2) + e2 * abs(f0)
        if _apart(f2 * a0 - f0 * a2, f2 * b0 - f0 * b2, f2 * c0 - f0 * c2, r):
            return False
        # z axis cross f = (-f1, f0, 0)
        r = e0 * abs(f1) + e1 * abs(f0)
        if _apart(-f1 * a0 + f0 * a1, -f1 * b0 + f0 * b1, -f1 * c0 + f0 * c1, r):
            return False
    # The triangle's normal.
    u0, u1, u2 = b0 - a0, b1 - a1, b2 - a2
    w0, w1, w2 = c0 - a0, c1 - a1, c2 - a2
    n0, n1, n2 = u1 * w2 - u2 * w1, u2 * w0 - u0 * w2, u0 * w1 - u1 * w0
    r = e0 * abs(n0) + e1 * abs(n1) + e2 * abs(n2)
    s = n0 * a0 + n1 * a1 + n2 * a2
    return not abs(s) > r


@njit(cache=True, fastmath=False)
def box_touches_mesh(
    pose: np.ndarray, half: np.ndarray, grow: float, tris: np.ndarray, bounds: np.ndarray, links: np.ndarray
) -> bool:
    """Whether a triangle of the tree (:func:`mesh_tree`) touches the box at ``pose``.

    ``pose`` (13,): R column-major, then p (a body pose of the kernels); the box's half extents are
    ``half`` + ``grow``.
    """
    if tris.shape[0] == 0:
        return False
    e0, e1, e2 = half[0] + grow + ROUND_M, half[1] + grow + ROUND_M, half[2] + grow + ROUND_M
    # R column-major: R[i, j] = pose[3 j + i]; column j is the box's axis j in the base frame.
    px, py, pz = pose[9], pose[10], pose[11]
    ext = np.empty(3)
    for i in range(3):
        ext[i] = abs(pose[i]) * e0 + abs(pose[3 + i]) * e1 + abs(pose[6 + i]) * e2
    v = np.empty((3, 3))
    stack = np.empty(64, dtype=np.int64)
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        k = stack[top]
        if (
            bounds[k, 0] > px + ext[0]
            or bounds[k, 3] < px - ext[0]
            or bounds[k, 1] > py + ext[1]
            or bounds[k, 4] < py - ext[1]
            or bounds[k, 2] > pz + ext[2]
            or bounds[k, 5] < pz - ext[2]
        ):
            continue
        if links[k, 1] > 0:
            for t in range(links[k, 0], links[k, 0] + links[k, 1]):
                for c in range(3):
                    d0 = tris[t, 3 * c] - px
                    d1 = tris[t, 3 * c + 1] - py
                    d2 = tris[t, 3 * c + 2] - pz
                    for j in range(3):  # R^T d: the vertex in the box's frame
                        v[c, j] = (pose[3 * j] * d0 + pose[3 * j + 1] * d1) + pose[3 * j + 2] * d2
                if box_touches_triangle(v, e0, e1, e2):
                    return True
            continue
        if top + 2 > stack.shape[0]:
            grown = np.empty(2 * stack.shape[0], dtype=np.int64)
            grown[:top] = stack[:top]
            stack = grown
        stack[top] = links[k, 0]
        stack[top + 1] = -links[k, 1] - 1
        top += 2
    return False


@njit(cache=True, fastmath=False)
def point_triangle_sq(p: np.ndarray, v: np.ndarray) -> float:
    """Squared distance from p (3,) to the triangle v (3, 3) (Ericson, Real-Time Collision Detection, 5.1.5).

    The Voronoi regions of the vertices, then of the edges, then the face.
    """
    a0, a1, a2 = v[0, 0], v[0, 1], v[0, 2]
    ab0, ab1, ab2 = v[1, 0] - a0, v[1, 1] - a1, v[1, 2] - a2
    ac0, ac1, ac2 = v[2, 0] - a0, v[2, 1] - a1, v[2, 2] - a2
    ap0, ap1, ap2 = p[0] - a0, p[1] - a1, p[2] - a2
    d1 = _dot3(ab0, ab1, ab2, ap0, ap1, ap2)
    d2 = _dot3(ac0, ac1, ac2, ap0, ap1, ap2)
    if d1 <= 0.0 and d2 <= 0.0:  # vertex a
        return _dot3(ap0, ap1, ap2, ap0, ap1, ap2)
    bp0, bp1, bp2 = p[0] - v[1, 0], p[1] - v[1, 1], p[2] - v[1, 2]
    d3 = _dot3(ab0, ab1, ab2, bp0, bp1, bp2)
    d4 = _dot3(ac0, ac1, ac2, bp0, bp1, bp2)
    if d3 >= 0.0 and d4 <= d3:  # vertex b
        return _dot3(bp0, bp1, bp2, bp0, bp1, bp2)
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:  # edge ab
        s = d1 / (d1 - d3)
        q0, q1, q2 = ap0 - s * ab0, ap1 - s * ab1, ap2 - s * ab2
        return _dot3(q0, q1, q2, q0, q1, q2)
    cp0, cp1, cp2 = p[0] - v[2, 0], p[1] - v[2, 1], p[2] - v[2, 2]
    d5 = _dot3(ab0, ab1, ab2, cp0, cp1, cp2)
    d6 = _dot3(ac0, ac1, ac2, cp0, cp1, cp2)
    if d6 >= 0.0 and d5 <= d6:  # vertex c
        return _dot3(cp0, cp1, cp2, cp0, cp1, cp2)
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:  # edge ac
        s = d2 / (d2 - d6)
        q0, q1, q2 = ap0 - s * ac0, ap1 - s * ac1, ap2 - s * ac2
        return _dot3(q0, q1, q2, q0, q1, q2)
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:  # edge bc
        s = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        bc0, bc1, bc2 = v[2, 0] - v[1, 0], v[2, 1] - v[1, 1], v[2, 2] - v[1, 2]
        q0, q1, q2 = bp0 - s * bc0, bp1 - s * bc1, bp2 - s * bc2
        return _dot3(q0, q1, q2, q0, q1, q2)
    den = 1.0 / (va + vb + vc)  # inside the face
    s, w = vb * den, vc * den
    q0, q1, q2 = ap0 - s * ab0 - w * ac0, ap1 - s * ab1 - w * ac1, ap2 - s * ab2 - w * ac2
    return _dot3(q0, q1, q2, q0, q1, q2)


@njit(cache=True, fastmath=False)
def box_triangle_distance(v: np.ndarray, e0: float, e1: float, e2: float, corners: np.ndarray) -> float:
    """Distance between the box [-e, e] and the triangle v (3, 3) in the box's frame (0 when they touch).

    Disjoint convex polytopes are nearest at a vertex of one and a face of the other, or at two edges:
    the triangle's vertices against the box (clamped), the box's corners (``corners`` (8, 3), scratch)
    against the triangle, and the box's 12 edges against the triangle's 3.
    """
    if box_touches_triangle(v, e0, e1, e2):
        return 0.0
    best = math.inf
    for c in range(3):  # the triangle's vertices against the box
        x0 = max(abs(v[c, 0]) - e0, 0.0)
        x1 = max(abs(v[c, 1]) - e1, 0.0)
        x2 = max(abs(v[c, 2]) - e2, 0.0)
        best = min(best, _dot3(x0, x1, x2, x0, x1, x2))
    for k in range(8):  # the box's corners against the triangle
        corners[k, 0] = e0 if k & 1 else -e0
        corners[k, 1] = e1 if k & 2 else -e1
        corners[k, 2] = e2 if k & 4 else -e2
        best = min(best, point_triangle_sq(corners[k], v))
    for k in range(
        8
    ):  # the box's edges (corner k to the corner one axis bit above it) against the triangle's
        for bit in (1, 2, 4):
            if k & bit:
                continue
            for c in range(3):
                best = min(best, segment_segment_sq(corners[k], corners[k | bit], v[c], v[(c + 1) % 3]))
    return math.sqrt(best)


@njit(cache=True, fastmath=False)
def box_mesh_distance(
    pose: np.ndarray, half: np.ndarray, cap: float, tris: np.ndarray, bounds: np.ndarray, links: np.ndarray
) -> float:
    """The distance from the box of half extents ``half`` at ``pose`` (13,) to the tree's triangles.

    Exact (to rounding) where it is below ``cap``; ``cap`` where no triangle is nearer (only the triangles
    within the box's bounds grown by the best distance so far are visited). 0 where the box touches one.
    """
    return _box_nearest(pose, half, cap, tris, bounds, links)[0]


@njit(cache=True, fastmath=False)
def _box_nearest(
    pose: np.ndarray, half: np.ndarray, cap: float, tris: np.ndarray, bounds: np.ndarray, links: np.ndarray
) -> tuple[float, int]:
    """:func:`box_mesh_distance` and the nearest triangle (-1: none below ``cap``)."""
    best, best_t = cap, -1
    if tris.shape[0] == 0:
        return best, best_t
    e0, e1, e2 = half[0], half[1], half[2]
    px, py, pz = pose[9], pose[10], pose[11]
    ext = np.empty(3)
    for i in range(3):
        ext[i] = abs(pose[i]) * e0 + abs(pose[3 + i]) * e1 + abs(pose[6 + i]) * e2
    lo = np.empty(3)  # the box's bounds
    hi = np.empty(3)
    for i in range(3):
        lo[i], hi[i] = pose[9 + i] - ext[i], pose[9 + i] + ext[i]
    v = np.empty((3, 3))
    corners = np.empty((8, 3))
    stack = np.empty(64, dtype=np.int64)
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        k = stack[top]
        if _box_gap_sq(lo, hi, bounds, k) >= best * best:
            continue
        if links[k, 1] > 0:
            for t in range(links[k, 0], links[k, 0] + links[k, 1]):
                for c in range(3):
                    d0 = tris[t, 3 * c] - px
                    d1 = tris[t, 3 * c + 1] - py
                    d2 = tris[t, 3 * c + 2] - pz
                    for j in range(3):
                        v[c, j] = (pose[3 * j] * d0 + pose[3 * j + 1] * d1) + pose[3 * j + 2] * d2
                # A lower bound first: the triangle's bounds against the box, in the box's frame.
                x0 = max(
                    min(v[0, 0], min(v[1, 0], v[2, 0])) - e0, -e0 - max(v[0, 0], max(v[1, 0], v[2, 0])), 0.0
                )
                x1 = max(
                    min(v[0, 1], min(v[1, 1], v[2, 1])) - e1, -e1 - max(v[0, 1], max(v[1, 1], v[2, 1])), 0.0
                )
                x2 = max(
                    min(v[0, 2], min(v[1, 2], v[2, 2])) - e2, -e2 - max(v[0, 2], max(v[1, 2], v[2, 2])), 0.0
                )
                if _dot3(x0, x1, x2, x0, x1, x2) >= best * best:
                    continue
                d = box_triangle_distance(v, e0, e1, e2, corners)
                if d < best:
                    best, best_t = d, t
                    if best == 0.0:
                        return best, best_t
            continue
        if top + 2 > stack.shape[0]:
            grown = np.empty(2 * stack.shape[0], dtype=np.int64)
            grown[:top] = stack[:top]
            stack = grown
        left, right = links[k, 0], -links[k, 1] - 1
        if _box_gap_sq(lo, hi, bounds, left) < _box_gap_sq(lo, hi, bounds, right):
            left, right = right, left  # the nearer child popped first
        stack[top] = left
        stack[top + 1] = right
        top += 2
    return best, best_t


#: Iterations of :func:`hull_triangle_lower`'s minimum-norm search (it stops earlier at a relative gap of
#: :data:`HULL_GAP`; whatever the iterate, the bound it returns is certified).
HULL_ITERATIONS = 64
HULL_GAP = 1e-12


@njit(cache=True, fastmath=False)
def _affine_min(m: np.ndarray, s: np.ndarray, k: int, a: np.ndarray, g: np.ndarray) -> bool:
    """Weights a[:k] (summing to 1) of the affine minimum-norm point of the points m[s[:k]]; False: singular.

    The system [G 1; 1' 0] [a; mu] = [0; 1] (G the Gram matrix), by Gaussian elimination with pivoting in
    ``g`` ((5, 6) scratch).
    """
    n = k + 1
    for i in range(k):
        for j in range(k):
            g[i, j] = _dot3(m[s[i], 0], m[s[i], 1], m[s[i], 2], m[s[j], 0], m[s[j], 1], m[s[j], 2])
        g[i, k] = 1.0
        g[i, n] = 0.0
    for j in range(k):
        g[k, j] = 1.0
    g[k, k] = 0.0
    g[k, n] = 1.0
    scale = 0.0
    for i in range(k):
        scale = max(scale, abs(g[i, i]))
    tiny = 1e-14 * max(scale, 1.0)
    for c in range(n):
        piv = c
        for r in range(c + 1, n):
            if abs(g[r, c]) > abs(g[piv, c]):
                piv = r
        if abs(g[piv, c]) <= tiny:
            return False
        if piv != c:
            for j in range(n + 1):
                g[c, j], g[piv, j] = g[piv, j], g[c, j]
        for r in range(n):
            if r != c:
                f = g[r, c] / g[c, c]
                if f != 0.0:
                    for j in range(c, n + 1):
                        g[r, j] -= f * g[c, j]
    for i in range(k):
        a[i] = g[i, n] / g[i, i]
    return True


@njit(cache=True, fastmath=False)
def _wolfe(
    m: np.ndarray, nm: int, s: np.ndarray, lam: np.ndarray, a: np.ndarray, g: np.ndarray
) -> tuple[int, float, float, float]:
    """Wolfe's minimum-norm point of conv(m[:nm]): (corral size k, x); the corral in ``s[:k]``, ``lam[:k]``.

    Wolfe, "Finding the nearest point in a polytope", Math. Programming 11, 1976: from the shortest point,
    the corral (at most 4 points) moves towards the origin's nearest point of the hull, until the gap
    x . x - min_k x . m_k is below :data:`HULL_GAP` (relative) or :data:`HULL_ITERATIONS` pass. k = 0: the
    corral collapsed (x is then 0). Scratch: ``s`` (5,) ints, ``lam``, ``a`` (5,), ``g`` (5, 6).
    """
    best, k0 = math.inf, 0
    for i in range(nm):
        v = _dot3(m[i, 0], m[i, 1], m[i, 2], m[i, 0], m[i, 1], m[i, 2])
        if v < best:
            best, k0 = v, i
    k = 1
    s[0], lam[0] = k0, 1.0
    x0, x1, x2 = m[k0, 0], m[k0, 1], m[k0, 2]
    for _ in range(HULL_ITERATIONS):
        xx = _dot3(x0, x1, x2, x0, x1, x2)
        if xx == 0.0:
            break
        jmin, w = 0, math.inf
        for i in range(nm):
            v = _dot3(x0, x1, x2, m[i, 0], m[i, 1], m[i, 2])
            if v < w:
                w, jmin = v, i
        if xx - w <= HULL_GAP * xx or k == 4:
            break
        fresh = True
        for i in range(k):
            fresh = fresh and s[i] != jmin
        if not fresh:
            break
        s[k], lam[k] = jmin, 0.0
        k += 1
        while True:  # minor cycles: the affine minimum of the corral, or the step to its boundary
            if not _affine_min(m, s, k, a, g):
                k -= 1  # the newest point made the corral degenerate: keep the last iterate
                break
            inside = True
            for i in range(k):
                inside = inside and a[i] > 0.0
            if inside:
                for i in range(k):
                    lam[i] = a[i]
                break
            theta = 1.0
            for i in range(k):
                if a[i] <= 0.0 and lam[i] - a[i] > 0.0:
                    theta = min(theta, lam[i] / (lam[i] - a[i]))
            j = 0
            for i in range(k):
                li = lam[i] + theta * (a[i] - lam[i])
                if li > 1e-14:
                    s[j], lam[j] = s[i], li
                    j += 1
            k = j
            if k == 0:
                return 0, 0.0, 0.0, 0.0
        x0, x1, x2 = 0.0, 0.0, 0.0
        for i in range(k):
            x0 += lam[i] * m[s[i], 0]
            x1 += lam[i] * m[s[i], 1]
            x2 += lam[i] * m[s[i], 2]
    return k, x0, x1, x2


@njit(cache=True, fastmath=False)
def hull_triangle_lower(
    m: np.ndarray, nm: int, s: np.ndarray, lam: np.ndarray, a: np.ndarray, g: np.ndarray
) -> float:
    """A certified lower bound of the norm of conv(m[:nm]) (0: it may hold the origin).

    With m the differences of two point sets' points, the distance between their convex hulls. For any x,
    every point p of the hull has x . p >= min_k x . m_k = w, so the hull is at least w / |x| from the
    origin where w > 0: that bound, from :func:`_wolfe`'s minimum-norm point, exact at its convergence.
    """
    _, x0, x1, x2 = _wolfe(m, nm, s, lam, a, g)
    return _certified_norm(m, nm, x0, x1, x2)


@njit(cache=True, fastmath=False)
def _certified_norm(m: np.ndarray, nm: int, x0: float, x1: float, x2: float) -> float:
    """min_k x . m_k / |x| for any x (0 where that is not positive): conv(m[:nm]) is at least that far out."""
    xx = _dot3(x0, x1, x2, x0, x1, x2)
    if xx == 0.0:
        return 0.0
    w = math.inf
    for i in range(nm):
        w = min(w, _dot3(x0, x1, x2, m[i, 0], m[i, 1], m[i, 2]))
    return w / math.sqrt(xx) if w > 0.0 else 0.0


@njit(cache=True, fastmath=False)
def hull_mesh_lower(points: np.ndarray, tris: np.ndarray, bounds: np.ndarray, links: np.ndarray) -> float:
    """A certified lower bound of the distance between the convex hull of ``points`` (n, 3) and the triangles.

    :func:`hull_triangle_lower` per triangle of the tree (0 where they may touch; inf: no triangles). The
    tree is walked nearer child first and pruned by the bounding boxes' distance to the points' box.
    """
    n = points.shape[0]
    best = math.inf
    if tris.shape[0] == 0 or n == 0:
        return best
    lo = np.empty(3)
    hi = np.empty(3)
    for x in range(3):
        lo[x], hi[x] = points[0, x], points[0, x]
        for i in range(1, n):
            lo[x] = min(lo[x], points[i, x])
            hi[x] = max(hi[x], points[i, x])
    m = np.empty((3 * n, 3))
    s = np.empty(5, dtype=np.int64)
    lam = np.empty(5)
    a = np.empty(5)
    g = np.empty((5, 6))
    stack = np.empty(64, dtype=np.int64)
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        k = stack[top]
        if _box_gap_sq(lo, hi, bounds, k) >= best * best:
            continue
        if links[k, 1] > 0:
            for t in range(links[k, 0], links[k, 0] + links[k, 1]):
                gap = 0.0
                for x in range(3):
                    tlo = min(tris[t, x], min(tris[t, 3 + x], tris[t, 6 + x]))
                    thi = max(tris[t, x], max(tris[t, 3 + x], tris[t, 6 + x]))
                    d = max(tlo - hi[x], lo[x] - thi, 0.0)
                    gap += d * d
                if gap >= best * best:
                    continue
                for i in range(n):
                    for c in range(3):
                        for x in range(3):
                            m[3 * i + c, x] = points[i, x] - tris[t, 3 * c + x]
                best = min(best, hull_triangle_lower(m, 3 * n, s, lam, a, g))
                if best == 0.0:
                    return 0.0
            continue
        if top + 2 > stack.shape[0]:
            grown = np.empty(2 * stack.shape[0], dtype=np.int64)
            grown[:top] = stack[:top]
            stack = grown
        left, right = links[k, 0], -links[k, 1] - 1
        if _box_gap_sq(lo, hi, bounds, left) < _box_gap_sq(lo, hi, bounds, right):
            left, right = right, left  # the nearer child popped first
        stack[top] = left
        stack[top + 1] = right
        top += 2
    return best


@njit(cache=True, fastmath=False)
def hull_shape_lower(points: np.ndarray, half: np.ndarray, radius: float) -> float:
    """A certified lower bound of the distance between conv(``points`` (n, 3)) and a shape at the origin.

    The shape: the box [-half, half] (axis-aligned, centred) grown by ``radius``; a capsule along z of
    length L is the box (0, 0, L / 2) grown by its radius. The hulls' distance is the norm of the convex
    hull of every point's difference with the box's corners (2 distinct ones for a segment, 8 for a box),
    bounded from below by :func:`hull_triangle_lower`'s certified norm; less ``radius``, 0 where they may
    touch. Whatever the iterate, the bound holds; where :func:`_wolfe` converges it is the distance to
    rounding (against an independent minimisation, ``tests/collision/test_sweep.py``; FCL's GJK on the same
    flat hulls stopped up to 34 mm above it).
    """
    n = points.shape[0]
    segment = half[0] == 0.0 and half[1] == 0.0
    nc = 2 if segment else 8
    m = np.empty((nc * n, 3))
    nm = 0
    for i in range(n):
        repeated = False  # a point given twice (a run's ends where the body did not move) once only:
        for k in range(i):  # Wolfe's corral cannot take a copy of one of its points (a singular system)
            repeated = repeated or (
                points[k, 0] == points[i, 0] and points[k, 1] == points[i, 1] and points[k, 2] == points[i, 2]
            )
        if repeated:
            continue
        for c in range(nc):
            if segment:
                cz = half[2] if c == 1 else -half[2]
                m[nm, 0] = points[i, 0]
                m[nm, 1] = points[i, 1]
                m[nm, 2] = points[i, 2] - cz
            else:
                m[nm, 0] = points[i, 0] - (half[0] if c & 1 else -half[0])
                m[nm, 1] = points[i, 1] - (half[1] if c & 2 else -half[1])
                m[nm, 2] = points[i, 2] - (half[2] if c & 4 else -half[2])
            nm += 1
    s = np.empty(5, dtype=np.int64)
    lam = np.empty(5)
    a = np.empty(5)
    g = np.empty((5, 6))
    d = hull_triangle_lower(m, nm, s, lam, a, g) - radius
    return d if d > 0.0 else 0.0


@njit(cache=True, fastmath=False, inline="always")
def _box_gap_sq(lo: np.ndarray, hi: np.ndarray, bounds: np.ndarray, k: int) -> float:
    """The squared distance between the box [lo, hi] and node k's box."""
    gap = 0.0
    for x in range(3):
        d = max(bounds[k, x] - hi[x], lo[x] - bounds[k, 3 + x], 0.0)
        gap += d * d
    return gap


@njit(cache=True, fastmath=False)
def segment_triangle_sq(a: np.ndarray, b: np.ndarray, v: np.ndarray, x: np.ndarray) -> float:
    """Squared distance between the segment [a, b] and the triangle v (3, 3) (``x`` (3,): scratch).

    Where the segment crosses the triangle's plane, the crossing's distance to the triangle (0 inside it);
    then the end points against the triangle and the segment against its 3 edges, where the nearest points
    of a segment and a triangle that do not meet lie.
    """
    n0 = (v[1, 1] - v[0, 1]) * (v[2, 2] - v[0, 2]) - (v[1, 2] - v[0, 2]) * (v[2, 1] - v[0, 1])
    n1 = (v[1, 2] - v[0, 2]) * (v[2, 0] - v[0, 0]) - (v[1, 0] - v[0, 0]) * (v[2, 2] - v[0, 2])
    n2 = (v[1, 0] - v[0, 0]) * (v[2, 1] - v[0, 1]) - (v[1, 1] - v[0, 1]) * (v[2, 0] - v[0, 0])
    da = _dot3(n0, n1, n2, a[0] - v[0, 0], a[1] - v[0, 1], a[2] - v[0, 2])
    db = _dot3(n0, n1, n2, b[0] - v[0, 0], b[1] - v[0, 1], b[2] - v[0, 2])
    best = math.inf
    if (da <= 0.0 <= db or db <= 0.0 <= da) and da != db:
        t = da / (da - db)
        for j in range(3):
            x[j] = a[j] + t * (b[j] - a[j])
        best = point_triangle_sq(x, v)
        if best == 0.0:
            return 0.0
    best = min(best, point_triangle_sq(a, v))
    best = min(best, point_triangle_sq(b, v))
    for c in range(3):
        best = min(best, segment_segment_sq(a, b, v[c], v[(c + 1) % 3]))
    return best


@njit(cache=True, fastmath=False)
def capsule_mesh_distance(
    pose: np.ndarray, radius: float, cap: float, tris: np.ndarray, bounds: np.ndarray, links: np.ndarray
) -> float:
    """The distance from the capsule at ``pose`` to the tree's triangles.

    The capsule: radius ``radius``, axis length ``pose[12]`` along its z axis (as FCL's capsule). Exact (to
    rounding) below ``cap``, else ``cap``; negative (the axis's distance less the radius) where the capsule
    reaches into a triangle.
    """
    return _capsule_nearest(pose, radius, cap, tris, bounds, links)[0]


@njit(cache=True, fastmath=False)
def _capsule_nearest(
    pose: np.ndarray, radius: float, cap: float, tris: np.ndarray, bounds: np.ndarray, links: np.ndarray
) -> tuple[float, int]:
    """:func:`capsule_mesh_distance` and the nearest triangle (-1: none below ``cap``)."""
    best, best_t = cap + radius, -1  # on the axis
    if tris.shape[0] == 0:
        return cap, best_t
    h = 0.5 * pose[12]
    a = np.empty(3)
    b = np.empty(3)
    for j in range(3):
        a[j] = pose[9 + j] - h * pose[6 + j]
        b[j] = pose[9 + j] + h * pose[6 + j]
    lo = np.empty(3)
    hi = np.empty(3)
    for j in range(3):
        lo[j], hi[j] = min(a[j], b[j]), max(a[j], b[j])
    v = np.empty((3, 3))
    x = np.empty(3)
    stack = np.empty(64, dtype=np.int64)
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        k = stack[top]
        if _box_gap_sq(lo, hi, bounds, k) >= best * best:
            continue
        if links[k, 1] > 0:
            for t in range(links[k, 0], links[k, 0] + links[k, 1]):
                for c in range(3):
                    for j in range(3):
                        v[c, j] = tris[t, 3 * c + j]
                d = math.sqrt(segment_triangle_sq(a, b, v, x))
                if d < best:
                    best, best_t = d, t
            continue
        if top + 2 > stack.shape[0]:
            grown = np.empty(2 * stack.shape[0], dtype=np.int64)
            grown[:top] = stack[:top]
            stack = grown
        left, right = links[k, 0], -links[k, 1] - 1
        if _box_gap_sq(lo, hi, bounds, left) < _box_gap_sq(lo, hi, bounds, right):
            left, right = right, left
        stack[top] = left
        stack[top + 1] = right
        top += 2
    return min(best - radius, cap), best_t


@njit(cache=True, fastmath=False)
def capsule_touches_mesh(
    pose: np.ndarray, radius: float, grow: float, tris: np.ndarray, bounds: np.ndarray, links: np.ndarray
) -> bool:
    """Whether the capsule of radius ``radius`` + ``grow`` at ``pose`` touches a triangle of the tree."""
    return capsule_mesh_distance(pose, radius + grow + ROUND_M, ROUND_M, tris, bounds, links) <= 0.0


@njit(cache=True, fastmath=False)
def _body_points(pose: np.ndarray, half: np.ndarray, radius: float) -> np.ndarray:
    """A body's points at ``pose`` (13,): a capsule's (``radius`` > 0) 2 axis end points, a box's 8 corners.

    The body is their convex hull (a capsule: grown by its radius); corner k is at +half[j] along axis j
    where bit j of k is set, else at -half[j].
    """
    n = 2 if radius > 0.0 else 8
    pts = np.empty((n, 3))
    for k in range(n):
        for j in range(3):
            if radius > 0.0:
                pts[k, j] = pose[9 + j] + (k - 0.5) * pose[12] * pose[6 + j]
            else:
                c = pose[9 + j]
                c += (half[0] if k & 1 else -half[0]) * pose[j]
                c += (half[1] if k & 2 else -half[1]) * pose[3 + j]
                c += (half[2] if k & 4 else -half[2]) * pose[6 + j]
                pts[k, j] = c
    return pts


@njit(cache=True, fastmath=False)
def pair_witness(
    pose_a: np.ndarray,
    half_a: np.ndarray,
    radius_a: float,
    pose_b: np.ndarray,
    half_b: np.ndarray,
    radius_b: float,
) -> tuple[float, np.ndarray, np.ndarray]:
    """(distance, a's nearest point, b's nearest point) of two bodies, each a box or a capsule.

    A box is the hull of its 8 corners (``radius`` 0, half extents ``half``), a capsule that of its 2 axis
    end points grown by ``radius``: the distance is the norm of the minimum-norm point of the hull of the
    points' differences (Wolfe's, :func:`_wolfe`; certified from below as in :func:`hull_triangle_lower`,
    exact to rounding at convergence) less both radii. Where the hulls may touch: -1 (FCL's figure for a
    contact it does not measure). Two capsules whose axes keep apart but whose radii overlap give their
    true signed distance (negative), as FCL's does. The points come from the corral's weights, moved out
    from an axis by its radius.
    """
    pa = np.full(3, np.nan)
    pb = np.full(3, np.nan)
    ra = _body_points(pose_a, half_a, radius_a)
    rb = _body_points(pose_b, half_b, radius_b)
    na, nb = ra.shape[0], rb.shape[0]
    m = np.empty((na * nb, 3))
    for i in range(na):
        for j in range(nb):
            for c in range(3):
                m[nb * i + j, c] = ra[i, c] - rb[j, c]
    s = np.empty(5, dtype=np.int64)
    lam = np.empty(5)
    k, x0, x1, x2 = _wolfe(m, na * nb, s, lam, np.empty(5), np.empty((5, 6)))
    lower = _certified_norm(m, na * nb, x0, x1, x2)
    if k == 0 or not lower > 0.0:
        return -1.0, pa, pb
    pa[:] = 0.0
    pb[:] = 0.0
    for i in range(k):
        for c in range(3):
            pa[c] += lam[i] * ra[s[i] // nb, c]
            pb[c] += lam[i] * rb[s[i] % nb, c]
    g0, g1, g2 = pb[0] - pa[0], pb[1] - pa[1], pb[2] - pa[2]
    gap = math.sqrt(_dot3(g0, g1, g2, g0, g1, g2))
    if gap > 0.0:  # from the axes to the capsules' surfaces (a box: radius 0)
        pa[0] += radius_a * g0 / gap
        pa[1] += radius_a * g1 / gap
        pa[2] += radius_a * g2 / gap
        pb[0] -= radius_b * g0 / gap
        pb[1] -= radius_b * g1 / gap
        pb[2] -= radius_b * g2 / gap
    d = lower - radius_a - radius_b
    if d <= 0.0 and (radius_a == 0.0 or radius_b == 0.0):
        return -1.0, pa, pb  # a box in contact: no depth measured (FCL's convention)
    return d, pa, pb


@njit(cache=True, fastmath=False)
def cabin_witness(
    pose: np.ndarray, half: np.ndarray, radius: float, tris: np.ndarray, bounds: np.ndarray, links: np.ndarray
) -> tuple[float, np.ndarray, np.ndarray]:
    """(distance, the body's nearest point, the cabin's nearest point) of a body against the triangles.

    A box (``radius`` 0, half extents ``half``) or a capsule (``radius`` > 0) at ``pose``. The distance is
    :func:`box_mesh_distance`'s / :func:`capsule_mesh_distance`'s (exact; inf and NaN points without
    triangles); the points come from :func:`_wolfe` on the differences of the nearest triangle's vertices
    and the body's corners (a capsule: its axis end points, the body's point then moved out by the radius).
    """
    pa = np.full(3, np.nan)
    pb = np.full(3, np.nan)
    if radius > 0.0:
        d, t = _capsule_nearest(pose, radius, math.inf, tris, bounds, links)
        n = 2
    else:
        d, t = _box_nearest(pose, half, math.inf, tris, bounds, links)
        n = 8
    if t < 0:
        return d, pa, pb
    pts = _body_points(pose, half, radius)
    m = np.empty((3 * n, 3))
    for i in range(n):
        for c in range(3):
            for j in range(3):
                m[3 * i + c, j] = pts[i, j] - tris[t, 3 * c + j]
    s = np.empty(5, dtype=np.int64)
    lam = np.empty(5)
    k, _, _, _ = _wolfe(m, 3 * n, s, lam, np.empty(5), np.empty((5, 6)))
    if k == 0:  # a collapsed corral (a touch): the first corner and the triangle's first vertex
        s[0], lam[0], k = 0, 1.0, 1
    pa[:] = 0.0
    pb[:] = 0.0
    for i in range(k):
        for j in range(3):
            pa[j] += lam[i] * pts[s[i] // 3, j]
            pb[j] += lam[i] * tris[t, 3 * (s[i] % 3) + j]
    if radius > 0.0:  # from the axis to the capsule's surface, towards the cabin
        g0, g1, g2 = pb[0] - pa[0], pb[1] - pa[1], pb[2] - pa[2]
        gap = math.sqrt(_dot3(g0, g1, g2, g0, g1, g2))
        if gap > 0.0:
            pa[0] += radius * g0 / gap
            pa[1] += radius * g1 / gap
            pa[2] += radius * g2 / gap
    return d, pa, pb
