"""Mean value and barycentric coordinates, point location, and the polygons of eq. 1."""

from __future__ import annotations

import numpy as np
import scipy.spatial
from jaxtyping import ArrayLike, Bool, Float, Int


def cross(a, b):
    """z-component of the cross product of 2D vectors (numpy's 2D cross is deprecated)."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def triangle_edges(vertices, faces):
    """Each triangle's two edges from its first corner, `(*batch, f, 2)` each, for
    `(*batch, n, 2)` vertices (numpy or JAX arrays)."""
    first = vertices[..., faces[:, 0], :]
    return vertices[..., faces[:, 1], :] - first, vertices[..., faces[:, 2], :] - first


def signed_areas(vertices: Float[ArrayLike, "*batch n 2"],
                 faces: Int[ArrayLike, "f 3"]) -> Float[ArrayLike, "*batch f"]:
    """Twice each triangle's signed area, positive for a counter-clockwise triangle, for
    `(*batch, n, 2)` vertices: numpy in, numpy out; JAX in, JAX out."""
    return cross(*triangle_edges(vertices, faces))


def ring_area(ring: Float[ArrayLike, "k 2"]) -> float:
    """The signed area of a closed polygon (shoelace), positive counter-clockwise."""
    x, y = np.asarray(ring, np.float64).T
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def mean_value_coordinates(
    points: Float[ArrayLike, "n 2"],
    polygons: Float[ArrayLike, "n k 2"],
    valid: Bool[ArrayLike, "n k"] | None = None,
    eps: float = 1e-12,
) -> Float[np.ndarray, "n k"]:
    """Mean value coordinates of each point in its own polygon (Floater 2003, eq. 1).

    Uses the stable form of Hormann and Floater (2006), `tan(alpha_i / 2) = det_i /
    (r_i r_{i+1} + d_i)`. A point on a polygon vertex gets that vertex's one-hot weight,
    a point on an edge the linear interpolation along the edge: both are exact, never NaN.

    Args:
        points: `(n, 2)` query points.
        polygons: `(n, k, 2)` one polygon per point, vertices in order (either orientation),
            padded at the end where `valid` is false.
        valid: `(n, k)` which entries of `polygons` are real vertices (default: all).
        eps: relative tolerance for "on a vertex" and "on an edge".

    Returns:
        `(n, k)` weights: zero on padding, summing to 1, with `sum_i w_i v_i = point`.
    """
    points = np.asarray(points, np.float64)
    polygons = np.asarray(polygons, np.float64)
    n, k, _ = polygons.shape
    valid = np.ones((n, k), bool) if valid is None else np.asarray(valid, bool)
    count = valid.sum(axis=1)
    idx = np.arange(k)[None, :]
    nxt = np.where(idx + 1 < count[:, None], idx + 1, 0)
    prv = np.where(idx > 0, idx - 1, count[:, None] - 1)

    s = polygons - points[:, None, :]
    r = np.linalg.norm(s, axis=2)
    s_next = np.take_along_axis(s, nxt[..., None], axis=1)
    r_next = np.take_along_axis(r, nxt, axis=1)
    det = s[..., 0] * s_next[..., 1] - s[..., 1] * s_next[..., 0]
    dot = np.einsum("nkd,nkd->nk", s, s_next)
    scale = np.max(np.where(valid, r, 0.0), axis=1, keepdims=True)

    at_vertex = valid & (r <= eps * scale)
    on_edge = valid & ~at_vertex & (np.abs(det) <= eps * r * r_next) & (dot < 0)
    on_edge &= np.take_along_axis(~at_vertex, nxt, axis=1)

    with np.errstate(divide="ignore", invalid="ignore"):
        # tan(alpha / 2) = det / (r r' + d) = (r r' - d) / det: the first cancels where
        # the angle nears pi (a point close to a long edge of a thin triangle gives 0 / 0),
        # the second where it nears 0; take the one whose denominator does not cancel.
        rr = r * r_next
        tan_half = np.where(dot >= 0, det / (rr + dot), (rr - dot) / det)
        tan_half = np.where(valid & ~on_edge, tan_half, 0.0)
        tan_prev = np.take_along_axis(tan_half, prv, axis=1)
        lam = np.where(valid, (tan_prev + tan_half) / r, 0.0)
        weights = lam / lam.sum(axis=1, keepdims=True)

    # Exact special cases: a vertex hit wins, then an edge hit.
    edge_rows = on_edge.any(axis=1)
    if edge_rows.any():
        e = np.argmax(on_edge, axis=1)
        rows = np.flatnonzero(edge_rows)
        ei, en = e[rows], nxt[rows, e[rows]]
        ri, rn = r[rows, ei], r_next[rows, ei]
        weights[rows] = 0.0
        weights[rows, ei] = rn / (ri + rn)
        weights[rows, en] = ri / (ri + rn)
    vertex_rows = at_vertex.any(axis=1)
    if vertex_rows.any():
        rows = np.flatnonzero(vertex_rows)
        weights[rows] = 0.0
        weights[rows, np.argmax(at_vertex[rows], axis=1)] = 1.0
    return np.where(valid, weights, 0.0)


def barycentric_coordinates(
    points: Float[np.ndarray, "n 2"], triangles: Float[np.ndarray, "n 3 2"]
) -> Float[np.ndarray, "n 3"]:
    """Barycentric coordinates of each point in its own triangle."""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    area = cross(b - a, c - a)
    wa = cross(b - points, c - points) / area
    wb = cross(c - points, a - points) / area
    return np.stack([wa, wb, 1.0 - wa - wb], axis=1)


def distance_outside(points: Float[np.ndarray, "n 2"],
                     triangles: Float[np.ndarray, "n 3 2"]) -> Float[np.ndarray, " n"]:
    """How far each point lies outside its own triangle, beyond the edge its smallest
    barycentric coordinate belongs to (0 inside)."""
    bary = barycentric_coordinates(points, triangles)
    k = np.argmin(bary, axis=1)
    rows = np.arange(len(k))
    edge = np.linalg.norm(triangles[rows, (k + 2) % 3] - triangles[rows, (k + 1) % 3], axis=1)
    area2 = np.abs(cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]))
    # The height over that edge is area2 / edge; the coordinate is the fraction of it.
    return np.maximum(-bary[rows, k], 0.0) * area2 / np.maximum(edge, 1e-300)


# A smallest barycentric coordinate below this is a point on an edge, or outside.
ON_AN_EDGE = 1e-9


def _smallest_coordinates(points, a, ab, ac, inv_area):
    """Each point's smallest barycentric coordinate in each of its triangles: `points`
    `(n, 2)` against triangles `(n, k, ...)` or `(k, ...)`."""
    p = points[:, None, :] - a
    wb = cross(p, ac) * inv_area
    wc = cross(ab, p) * inv_area
    return np.minimum(np.minimum(wb, wc), 1.0 - wb - wc)


def locate_points(
    points: Float[np.ndarray, "n 2"],
    vertices: Float[np.ndarray, "v 2"],
    faces: Int[np.ndarray, "f 3"],
    chunk: int = 4096,
    candidates: int = 16,
) -> tuple[Int[np.ndarray, " n"], Float[np.ndarray, " n"]]:
    """The triangle containing each point, and how far inside it is.

    Returns the face index maximising the smallest barycentric coordinate, and that
    coordinate (negative: the point is outside every triangle). Only one triangle holds
    a point inside it, so it is looked for among the `candidates` triangles whose
    centroids are nearest first; the points that none of those holds inside are compared
    with every triangle.
    """
    tri = vertices[faces]
    a, ab, ac = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    inv_area = 1.0 / cross(ab, ac)
    k = min(candidates, len(faces))
    _, near = scipy.spatial.cKDTree(tri.mean(axis=1)).query(points, k=k)
    near = near.reshape(len(points), k)
    low = _smallest_coordinates(points, a[near], ab[near], ac[near], inv_area[near])
    best = np.argmax(low, axis=1)
    rows = np.arange(len(points))
    face, depth = near[rows, best], low[rows, best]
    # Outside every candidate, or on an edge (another triangle, perhaps no candidate,
    # may hold it as well): compared with every triangle.
    outside = np.flatnonzero(depth < ON_AN_EDGE)
    for start in range(0, len(outside), chunk):
        rest = outside[start : start + chunk]
        low = _smallest_coordinates(points[rest], a, ab, ac, inv_area)
        face[rest] = np.argmax(low, axis=1)
        depth[rest] = low[np.arange(len(rest)), face[rest]]
    return face, depth
