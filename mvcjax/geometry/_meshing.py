"""Shape mesh and control mesh construction (numpy, shapely, Triangle; build time only)."""

from __future__ import annotations

import numpy as np
import shapely
import triangle
from jaxtyping import Float, Int
from scipy.spatial import cKDTree

from ._coordinates import cross, signed_areas
from ._shape import Shape


def _resample_ring(ring: np.ndarray, step: float) -> np.ndarray:
    """Ring vertices plus evenly spaced points on every edge longer than `step`."""
    nxt = np.roll(ring, -1, axis=0)
    # A length that is a whole number of steps must not gain a point from rounding: the
    # same shape anywhere else would get another mesh.
    pieces = np.linalg.norm(nxt - ring, axis=1) / step
    counts = np.maximum(np.ceil(pieces * (1 - 1e-9)).astype(int), 1)
    first = np.repeat(np.cumsum(counts) - counts, counts)
    t = (np.arange(counts.sum()) - first) / np.repeat(counts, counts)
    start = np.repeat(ring, counts, axis=0)
    return start + t[:, None] * (np.repeat(nxt, counts, axis=0) - start)


def _ring_segments(offset: int | np.integer, n: int) -> np.ndarray:
    i = np.arange(n)
    return np.stack([offset + i, offset + (i + 1) % n], axis=1)


def _triangulate(rings: list[np.ndarray], points: np.ndarray, options: str):
    """Triangle on the closed `rings` (the first outer, the others holes) plus `points`.

    Vertices are numbered ring after ring, then the points; returns Triangle's output
    and the input vertices.
    """
    sizes = [len(r) for r in rings]
    offsets = np.cumsum([0, *sizes])
    vertices = np.concatenate([*rings, np.reshape(points, (-1, 2))])
    data = dict(
        vertices=vertices,
        segments=np.concatenate([_ring_segments(o, n) for o, n in zip(offsets, sizes)]),
    )
    if len(rings) > 1:
        inside = [shapely.Polygon(r).representative_point().coords[0] for r in rings[1:]]
        data["holes"] = np.asarray(inside, dtype=np.float64)
    return triangle.triangulate(data, options), vertices


def _insert_on_boundary(rings: list[np.ndarray], point: np.ndarray, tol: float):
    """Insert `point` into the nearest ring edge (or snap to a vertex within `tol`)."""
    best = None
    for r, ring in enumerate(rings):
        a, b = ring, np.roll(ring, -1, axis=0)
        ab = b - a
        t = np.clip(np.einsum("ij,ij->i", point - a, ab) / np.einsum("ij,ij->i", ab, ab), 0, 1)
        d = np.linalg.norm(a + t[:, None] * ab - point, axis=1)
        k = int(np.argmin(d))
        if best is None or d[k] < best[0]:
            best = (d[k], r, k)
    _, r, k = best
    ring = rings[r]
    near = np.linalg.norm(ring - point, axis=1)
    if near.min() <= tol:
        return
    rings[r] = np.insert(ring, k + 1, point, axis=0)


DETAIL = 1e-3


def thin_outline(shape: Shape, spacing: float) -> Shape:
    """The shape with its outline simplified by at most `DETAIL * spacing`, where it has
    more than four vertices per `spacing` on average.

    An outline far denser than the meshes (a contour of 100,000 points) would be kept
    whole by Triangle, which grades the mesh down to its vertices, and walked point by
    point by the control polygon; a thousandth of an edge is no visible change.
    """
    polygon = shape.polygon
    if sum(len(r) for r in shape.rings) < 4 * polygon.length / spacing:
        return shape  # not denser than the mesh: every vertex kept
    outline = shapely.simplify(polygon, DETAIL * spacing, preserve_topology=True)
    try:
        return Shape.from_polygon(np.asarray(outline.exterior.coords)[:-1],
                                  [np.asarray(r.coords)[:-1] for r in outline.interiors])
    except (ValueError, AttributeError):  # simplified into something else: keep it whole
        return shape


def triangulate_shape(
    shape: Shape, spacing: float, handles: Float[np.ndarray, "h 2"]
) -> tuple[Float[np.ndarray, "n 2"], Int[np.ndarray, "f 3"], Int[np.ndarray, " h"]]:
    """Quality triangulation of the shape with edges about `spacing` long.

    Every handle becomes a vertex: one on the boundary (within a tiny tolerance) is
    inserted into its edge, one inside is a free vertex of the triangulation.

    Returns:
        vertices `(n, 2)`, counter-clockwise faces `(f, 3)`, and the vertex index of
        every handle `(h,)`.
    """
    tol = 1e-9 * shape.diagonal
    boundary = shapely.MultiLineString([np.vstack([r, r[:1]]) for r in shape.rings])
    # Within twice `thin_outline`'s detail: a handle on the outline before it was thinned.
    near_boundary = max(1e-6 * shape.diagonal, 2 * DETAIL * spacing)
    on_boundary = shapely.distance(shapely.points(handles), boundary) <= near_boundary
    rings = [_resample_ring(r, spacing) for r in shape.rings]
    for p in handles[on_boundary]:
        _insert_on_boundary(rings, p, tol)
    max_area = np.sqrt(3.0) / 4.0 * spacing**2
    # Triangle reads the area switch as plain digits: an exponent ("a6.8e-05") would be
    # read as another switch, and the area constraint lost.
    area = np.format_float_positional(max_area, trim="-")
    out, _ = _triangulate(rings, handles[~on_boundary], f"pq28a{area}Q")
    verts, faces = np.asarray(out["vertices"], np.float64), np.asarray(out["triangles"], np.int64)
    # Neighbours in the plane become neighbours in memory: a run of vertices then
    # follows a few control vertices, which the skinning of many frames exploits.
    order = hilbert_order(verts)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    verts, faces = verts[order], rank[faces]
    handle_idx = cKDTree(verts).query(handles)[1]
    return verts, counter_clockwise(verts, faces), handle_idx.astype(np.int64)


def hilbert_order(points: Float[np.ndarray, "n 2"], bits: int = 16) -> Int[np.ndarray, " n"]:
    """The order of `points` along a Hilbert curve over their bounding square (`bits`
    levels): points close along it are close in the plane, and unlike a Morton order
    the curve never jumps. Ties keep their input order."""
    points = np.asarray(points, np.float64)
    lo, size = points.min(axis=0), np.ptp(points, axis=0).max()
    side = 1 << bits
    cell = np.clip((points - lo) / max(size, np.finfo(float).tiny) * side, 0, side - 1)
    x, y = cell[:, 0].astype(np.int64), cell[:, 1].astype(np.int64)
    d = np.zeros(len(points), np.int64)
    s = side >> 1
    while s > 0:  # the classic xy -> d conversion, one level at a time
        rx, ry = (x & s) > 0, (y & s) > 0
        d += s * s * ((3 * rx) ^ ry)
        flip = ~ry & rx
        x = np.where(flip, s - 1 - x, x)
        y = np.where(flip, s - 1 - y, y)
        x, y = np.where(~ry, y, x), np.where(~ry, x, y)
        s >>= 1
    return np.argsort(d, kind="stable")


def counter_clockwise(verts, faces):
    signed = signed_areas(verts, faces)
    faces = faces.copy()
    faces[signed < 0] = faces[signed < 0][:, [0, 2, 1]]
    return faces


MAX_SAMPLES = 200_000
# Above this many pieces the gap cut is merged into lines before it is buffered.
MANY_CUT_PIECES = 5_000


def voronoi_ridges(points: Float[np.ndarray, "n 2"]):
    """The Voronoi diagram of `points`, as the dual of their Delaunay triangulation by
    Shewchuk's Triangle (exact predicates, at ease with the cocircular samples of
    parallel sides).

    Returns:
        the Voronoi vertices (the triangles' circumcentres), the pair of points each ridge
        separates, and each ridge's two vertices (-1 for the unbounded end of a ridge on
        the convex hull), as scipy's `Voronoi` names them.
    """
    out = triangle.triangulate({"vertices": points}, "nQ")
    tri, neighbours = out["triangles"], out["neighbors"]
    a, b, c = (points[tri[:, k]] for k in range(3))
    ab, ac = b - a, c - a
    ab2, ac2 = (ab**2).sum(axis=1), (ac**2).sum(axis=1)
    # Triangle's triangles turn counter-clockwise by its exact predicates; a sliver whose
    # rounded area is not positive has its centre far out on the correct side.
    twice_area = 2.0 * np.maximum(cross(ab, ac), np.finfo(float).eps * np.sqrt(ab2 * ac2))
    centres = a + np.stack([ac[:, 1] * ab2 - ab[:, 1] * ac2,
                            ab[:, 0] * ac2 - ac[:, 0] * ab2], axis=1) / twice_area[:, None]
    # Edge k of triangle i lies opposite its corner k, shared with triangle neighbours[i, k].
    i = np.repeat(np.arange(len(tri)), 3)
    k = np.tile(np.arange(3), len(tri))
    j = neighbours.ravel()
    once = (j < 0) | (i < j)
    i, k, j = i[once], k[once], j[once]
    ridge_points = np.stack([tri[i, (k + 1) % 3], tri[i, (k + 2) % 3]], axis=1)
    return centres, ridge_points, np.stack([i, j], axis=1)


def _gap_cuts(shape: Shape, margin: float, step: float | None = None):
    """Pieces of the exterior medial axis closer than `margin` to the shape.

    An outward offset by `margin` closes every gap narrower than `2 * margin`. The
    medial axis of the outside, where its clearance is below the margin, is exactly
    where the offset would merge two parts of the boundary that are far apart along
    the boundary itself: cutting the offset along it keeps every gap open.
    It is approximated by the Voronoi ridges between boundary samples (`step` apart)
    whose distance along the boundary exceeds `pi * margin` (closer ones belong to
    one concave corner, which an offset may round off). The samples are refined until
    they are denser than the narrowest gap found, so that the axis is smooth.

    Ridges between samples across the shape itself (the interior medial axis of a thin
    part) are no gap, and are left out before the narrowest gap is measured.

    Returns:
        the cut as shapely lines (or None where no gap is narrower than `2 * margin`),
        and the narrowest gap width found.
    """
    perimeter = sum(float(np.linalg.norm(np.roll(r, -1, axis=0) - r, axis=1).sum())
                    for r in shape.rings)
    if step is None:
        step = margin / 4.0
        if perimeter / step > MAX_SAMPLES:
            raise ValueError(
                f"margin={margin:.3g} (in units of the shape's diagonal) is too small for the "
                f"control polygon to trace: its gap search would sample the outline "
                f"{perimeter / step:,.0f} times. Use a margin of at least "
                f"{4 * perimeter / MAX_SAMPLES:.2g} times the shape's diagonal."
            )
    # Refining past this many samples would make the gap search very slow; gaps narrower
    # than the samples are still cut, only more coarsely.
    step = max(step, perimeter / MAX_SAMPLES)
    samples, ring_id, arc, length = [], [], [], []
    for r, ring in enumerate(shape.rings):
        pts = _resample_ring(ring, step)
        seg = np.linalg.norm(np.roll(pts, -1, axis=0) - pts, axis=1)
        samples.append(pts)
        ring_id.append(np.full(len(pts), r))
        arc.append(np.concatenate([[0.0], np.cumsum(seg)[:-1]]))
        length.append(np.full(len(pts), seg.sum()))
    pts, ring_id, arc, length = map(np.concatenate, (samples, ring_id, arc, length))
    centres, ridge_points, ridge_vertices = voronoi_ridges(pts)
    a, b = ridge_points[:, 0], ridge_points[:, 1]
    along = np.abs(arc[a] - arc[b])
    along = np.minimum(along, length[a] - along)
    far = (ring_id[a] != ring_id[b]) | (along > np.pi * margin)
    half_gap = 0.5 * np.linalg.norm(pts[a] - pts[b], axis=1)
    reach = 1.05 * margin
    keep = far & (half_gap < reach)
    mid = 0.5 * (pts[a] + pts[b])
    keep[keep] = ~shapely.contains_xy(shape.polygon, mid[keep, 0], mid[keep, 1])
    if not keep.any():
        return None, np.inf
    a, b, half_gap = a[keep], b[keep], half_gap[keep]
    ridge = ridge_vertices[keep]
    pa, pb = pts[a], pts[b]
    mid = 0.5 * (pa + pb)
    u = np.stack([pa[:, 1] - pb[:, 1], pb[:, 0] - pa[:, 0]], axis=1)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    tmax = np.sqrt(np.maximum(reach**2 - half_gap**2, 0.0))
    ends = centres[np.maximum(ridge, 0)]
    t = np.einsum("rkd,rd->rk", ends - mid[:, None, :], u)
    # An infinite ridge is a ray from its finite vertex, away from the samples.
    away = np.where(np.einsum("rd,rd->r", mid - pts.mean(axis=0), u) > 0, np.inf, -np.inf)
    t = np.where(ridge < 0, away[:, None], t)
    t0 = np.maximum(t.min(axis=1), -tmax)
    t1 = np.minimum(t.max(axis=1), tmax)
    ok = t1 > t0
    if not ok.any():
        return None, np.inf
    narrowest = 2.0 * float(half_gap[ok].min())
    finer = max(narrowest / 4.0, 1e-3 * margin, perimeter / MAX_SAMPLES)
    if step > narrowest / 2.0 and finer < step:
        return _gap_cuts(shape, margin, finer)
    lines = np.stack([mid + t0[:, None] * u, mid + t1[:, None] * u], axis=1)[ok]
    cut = _outside(shapely.linestrings(lines), shape.polygon)
    return (None, np.inf) if cut.is_empty else (cut, narrowest)


def _outside(lines, polygon):
    """The parts of `lines` outside `polygon`, as one multi-line. Only the lines that
    reach into it are cut (an overlay with the whole outline costs its size)."""
    shapely.prepare(polygon)
    crossing = shapely.intersects(polygon, lines)
    cut = shapely.multilinestrings(lines[crossing]).difference(polygon)
    return shapely.multilinestrings(np.concatenate([lines[~crossing],
                                                    shapely.get_parts(cut)]))


def _simplify_ring(ring, spacing, inside, outside, count_min=3):
    """Greedy chords of `ring` inside `inside`, off `outside`, at most `spacing` long."""
    n = len(ring)
    keep = [0]
    i = 0
    while i < n:
        j = i + 1
        while j < n:
            nxt = j + 1
            p, q = ring[i], ring[nxt % n]
            if np.linalg.norm(q - p) > spacing:
                break
            chord = shapely.LineString([p, q])
            if not (inside.covers(chord) and not outside.intersects(chord)):
                break
            j = nxt
        if j >= n:
            break
        keep.append(j)
        i = j
    out = ring[np.asarray(keep)]
    return out if len(out) >= count_min else ring


def control_polygon(shape: Shape, margin: float, spacing: float) -> list[np.ndarray]:
    """Loops of the control polygon `V_CP`: outside the shape, never across a gap.

    The shape is offset outwards by `margin`, the offset is cut along the exterior
    medial axis wherever it would close a gap (`_gap_cuts`), and each resulting loop is
    simplified by chords no longer than `spacing` that stay inside the cut offset and
    off the shape. The first loop encloses the shape (counter-clockwise); the others lie
    inside holes (clockwise).
    """
    poly = shape.polygon
    cut, narrowest = _gap_cuts(shape, margin)
    clearance = min(0.05 * margin, 0.2 * narrowest)
    region = poly.buffer(margin, quad_segs=4)
    if cut is not None and shapely.get_num_geometries(cut) > MANY_CUT_PIECES:
        # The cut comes as a piece per Voronoi ridge, tens of thousands along narrow
        # slots, which GEOS buffers for minutes: snapped to a grid far finer than the
        # clearance, they merge into a few lines, which buffer in a fraction of a second,
        # to within a fiftieth of the clearance.
        cut = shapely.line_merge(shapely.set_precision(cut, clearance / 100))
        cut = cut.simplify(clearance / 50)
    if cut is not None:
        region = region.difference(cut.buffer(clearance, quad_segs=2))
    region = region.union(poly)
    if region.geom_type != "Polygon":
        region = max(region.geoms, key=lambda g: g.intersection(poly).area)
    region = shapely.geometry.polygon.orient(region, 1.0)
    # Chords may leave the scalloped edge of the cut's buffer, but never touch the cut
    # itself (that would close the gap) nor come near the shape.
    inside = poly.buffer(margin * 1.001, quad_segs=4)
    outside = poly.buffer(0.5 * clearance, quad_segs=2)
    if cut is not None:
        outside = outside.union(cut.buffer(0.25 * clearance, quad_segs=2))
    shapely.prepare(inside)
    shapely.prepare(outside)
    loops = []
    for r in [region.exterior, *region.interiors]:
        # The offset keeps a straight side as one edge: split it, so that the polygon's
        # edges are at most `spacing` long there too (a limb needs polygon vertices
        # along it to bend).
        ring = _resample_ring(np.asarray(r.coords)[:-1], spacing)
        loops.append(_simplify_ring(ring, spacing, inside, outside))
    control = shapely.Polygon(loops[0], loops[1:])
    if not control.is_valid or not control.contains(poly):
        raise ValueError(
            "Could not build a control polygon that encloses the shape without crossing "
            f"itself (margin={margin:.4g}, spacing={spacing:.4g}); try a smaller "
            "PaperControl(margin=..., spacing=...), or pass a control mesh of your own."
        )
    return loops


def inner_control_vertices(
    vertices: Float[np.ndarray, "n 2"],
    handle_idx: Int[np.ndarray, " h"],
    loops: list[np.ndarray],
    spacing: float,
) -> Int[np.ndarray, " g"]:
    """`V_CG`: shape-mesh vertices about `spacing` apart, the handles first.

    Farthest-point sampling seeded with the handles: the vertex farthest from every
    chosen one is added until every vertex is within `spacing` of a chosen vertex, or
    within `spacing / 2` of the control polygon (closer ones would only make slivers).
    """
    polygon_edges = shapely.MultiLineString([np.vstack([lp, lp[:1]]) for lp in loops])
    dist = 2.0 * shapely.distance(shapely.points(vertices), polygon_edges)
    for h in handle_idx:
        dist = np.minimum(dist, np.linalg.norm(vertices - vertices[h], axis=1))
    chosen = list(handle_idx)
    while True:
        k = int(np.argmax(dist))
        if dist[k] < spacing:
            break
        chosen.append(k)
        dist = np.minimum(dist, np.linalg.norm(vertices - vertices[k], axis=1))
    return np.asarray(chosen, np.int64)


def triangulate_control(
    loops: list[np.ndarray], inner_points: Float[np.ndarray, "g 2"]
) -> tuple[Float[np.ndarray, "c 2"], Int[np.ndarray, "f 3"]]:
    """Constrained triangulation of the polygon loops and the inner points, no new vertex.

    Vertices are numbered loop after loop, then the inner points.
    """
    out, vertices = _triangulate(loops, inner_points, "pQ")
    if len(out["vertices"]) != len(vertices):
        raise ValueError(
            "The control polygon crosses itself or passes through an inner control vertex; "
            "try a smaller PaperControl(spacing=...) or margin."
        )
    return vertices, counter_clockwise(vertices, np.asarray(out["triangles"], np.int64))
