import jax.numpy as jnp
import numpy as np
import pytest
import shapely
from scipy.spatial import Voronoi

import mvcjax
from mvcjax.geometry._meshing import (
    control_polygon,
    hilbert_order,
    triangulate_control,
    triangulate_shape,
    voronoi_ridges,
)


def u_shape(gap):
    """Two 100-long prongs joined at the top, `gap` apart."""
    left = np.array([[0, 0], [10, 0], [10, 100], [10 + gap, 100], [10 + gap, 0], [20 + gap, 0],
                     [20 + gap, 120], [0, 120]], dtype=float)
    return mvcjax.Shape.from_polygon(left)


def control_region(rig):
    cm = rig.control_mesh
    v, f = np.asarray(cm.vertices), np.asarray(cm.faces)
    return shapely.union_all([shapely.Polygon(v[t]) for t in f])


def test_voronoi_ridges_agree_with_qhull():
    """The Voronoi diagram from Triangle's Delaunay triangulation against scipy's (Qhull):
    the same ridges between the same points, ending at the same vertices."""
    pts = np.random.default_rng(3).random((400, 2)) * 7.0 - 3.0
    centres, ridge_points, ridge_vertices = voronoi_ridges(pts)
    vor = Voronoi(pts)

    def ends(vertices, pairs, ridges):
        return {tuple(sorted(p)): sorted(tuple(np.round(vertices[v], 6)) if v >= 0 else ()
                                         for v in r) for p, r in zip(pairs, ridges)}

    assert (ends(centres, ridge_points, ridge_vertices)
            == ends(vor.vertices, vor.ridge_points, vor.ridge_vertices))


def test_voronoi_ridges_of_cocircular_samples():
    """On a grid, four samples share each circle: the ridges of positive length are
    exactly those between neighbours (cells are squares), each vertex at a cell corner."""
    pts = np.stack(np.meshgrid(np.arange(12.0), np.arange(9.0)), axis=-1).reshape(-1, 2)
    centres, ridge_points, ridge_vertices = voronoi_ridges(pts)
    ends = np.where(ridge_vertices[..., None] >= 0, centres[np.maximum(ridge_vertices, 0)],
                    np.inf)
    positive = (ridge_vertices < 0).any(axis=1) | (
        np.linalg.norm(ends[:, 0] - ends[:, 1], axis=1) > 1e-9)
    pairs = {tuple(sorted(p)) for p in ridge_points[positive]}
    gap = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    assert pairs == {(i, j) for i, j in zip(*np.nonzero(np.isclose(gap, 1.0))) if i < j}
    np.testing.assert_allclose(centres % 1.0, 0.5, atol=1e-9)


@pytest.mark.parametrize("gap", [0.3, 1.0, 6.0])
def test_control_polygon_never_bridges_a_gap(gap):
    shape = u_shape(gap)
    loops = control_polygon(shape, margin=4.0, spacing=15.0)
    polygon = shapely.Polygon(loops[0], loops[1:])
    assert polygon.is_valid and polygon.contains(shape.polygon)
    # The gap stays outside the polygon down its length; only its last few units below
    # the bridge at y = 100 are rounded off, as an offset rounds any concave corner.
    for y in [5.0, 50.0, 90.0]:
        assert not polygon.covers(shapely.Point(10 + gap / 2, y))


@pytest.mark.parametrize("scale", [1.0, 2.0**-12])
def test_the_control_polygon_honours_its_spacing_on_straight_sides(scale):
    # The straight snake's offset has two long straight sides, one edge each; a limb
    # with one polygon edge a side cannot bend, whatever the energy.
    from mvcjax import datasets

    shape = mvcjax.Shape.from_polygon(np.asarray(datasets.snake().outer) * scale)
    spacing = 11.0 * scale
    loops = control_polygon(shape, margin=spacing / 3, spacing=spacing)
    ring = loops[0]
    edges = np.linalg.norm(np.roll(ring, -1, axis=0) - ring, axis=1)
    assert edges.max() <= spacing * (1 + 1e-9)
    assert len(ring) >= 2 * 400 / 11  # both long sides, split
    polygon = shapely.Polygon(ring)
    assert polygon.is_valid and polygon.contains(shape.polygon)


def test_horse_control_mesh_keeps_the_front_legs_apart(horse_rig32, horse):
    region = control_region(horse_rig32)
    assert region.covers(horse.polygon)
    # Across the front legs, the control mesh is two separate pieces: nothing bridges the
    # one-pixel slot between them.
    for y in np.arange(25.0, 66.0, 5.0):  # the slot ends at y = 78
        across = region.intersection(shapely.LineString([(240.0, y), (285.0, y)]))
        assert across.geom_type == "MultiLineString" and len(across.geoms) == 2, y
    # Every control triangle lies inside the shape grown by the margin: no bridging.
    assert region.difference(horse.polygon.buffer(10.0)).area < 1e-6


def test_shape_mesh_has_a_vertex_at_every_handle(horse):
    handles = np.array([[100.0, 200.0], horse.outer[10], 0.5 * (horse.outer[20] + horse.outer[21])])
    v, f, idx = triangulate_shape(horse, 6.0, handles)
    np.testing.assert_allclose(v[idx], handles, atol=1e-9)
    assert len(np.unique(idx)) == 3
    areas = np.cross(np.c_[v[f[:, 1]] - v[f[:, 0]], np.zeros(len(f))],
                     np.c_[v[f[:, 2]] - v[f[:, 0]], np.zeros(len(f))])[:, 2]
    assert np.all(areas > 0)
    assert 0.5 * areas.sum() == pytest.approx(horse.area, rel=1e-9)


def test_holes_are_respected(ring_shape):
    rig = mvcjax.Rig.build(ring_shape, np.array([[35.0, 0.0], [-35.0, 0.0]]))
    region = control_region(rig)
    assert not region.covers(shapely.Point(0.0, 0.0))
    mesh = shapely.union_all([shapely.Polygon(np.asarray(rig.shape_mesh.vertices)[t])
                              for t in np.asarray(rig.shape_mesh.faces)])
    assert mesh.area == pytest.approx(ring_shape.area, rel=1e-6)  # float32 vertices


@pytest.mark.float64
def test_close_parts_move_independently(horse):
    """One front hoof dragged: the other follows as in the full solve on the shape mesh,
    not as with a control polygon from a plain offset, whose triangles bridge the slot.
    With the paper's energy: the as-rigid-as-possible energy's coarse control triangles
    carry the other hoof further on any control polygon (`docs/folds.md`)."""
    handles = np.array([[280.0, 20], [62, 20], [125, 27], [200, 230], [372, 238], [262, 95]])
    paper = mvcjax.Weights.paper()
    ours = mvcjax.Rig.build(horse, handles, weights=paper)
    coarse = mvcjax.Rig.build(horse, handles, shape_spacing=10.0, weights=paper)
    full = mvcjax.Rig.build(horse, handles, shape_spacing=10.0, weights=paper,
                            control=mvcjax.GivenControl(np.asarray(coarse.shape_mesh.vertices),
                                                        np.asarray(coarse.shape_mesh.faces)))
    # A control polygon from a plain offset, simplified to the control spacing by shapely.
    offset = horse.polygon.buffer(3.0).exterior.simplify(1.0)
    loop = np.asarray(shapely.segmentize(offset, 26.0).coords)[:-1]
    cm = ours.control_mesh
    bridged = mvcjax.Rig.build(horse, handles, weights=paper, control=mvcjax.GivenControl(
        *triangulate_control([loop], np.asarray(cm.vertices[cm.inner]))))
    assert shapely.Polygon(loop).covers(shapely.Point(260.5, 40.0))  # it does bridge

    solver = mvcjax.FixedG(iterations=5000, anderson=5, stop_early=True, rtol=1e-9)

    def other_hoof(rig, offset):
        targets = rig.handle_positions.at[0].add(jnp.asarray(offset))
        out, info = rig.deform(targets, solver, return_info=True)
        assert bool(info.converged)
        rest = np.asarray(rig.shape_mesh.vertices)
        k = int(np.argmin(np.linalg.norm(rest - [255.0, 22.0], axis=1)))
        return np.asarray(out[k]) - rest[k]

    for offset in [[-40.0, 0.0], [40.0, 30.0]]:
        reference = other_hoof(full, offset)
        ours_error = np.linalg.norm(other_hoof(ours, offset) - reference)
        bridged_error = np.linalg.norm(other_hoof(bridged, offset) - reference)
        assert ours_error < 0.25 * bridged_error, (offset, ours_error, bridged_error)


@pytest.mark.parametrize("bits", [1, 3, 5])
def test_hilbert_order_walks_a_grid_in_unit_steps(bits):
    side = 1 << bits
    grid = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)
    shuffled = np.random.default_rng(bits).permutation(grid) * 0.37 + [1e4, -5.0]
    order = hilbert_order(shuffled, bits=bits)
    assert sorted(order) == list(range(len(grid)))
    steps = np.abs(np.diff(shuffled[order], axis=0)).sum(axis=1)
    np.testing.assert_allclose(steps, 0.37)


def test_shape_mesh_vertices_follow_the_hilbert_curve(ring_shape):
    # Consecutive vertices are neighbours in the plane (what the skinning of many frames
    # relies on), and the faces and pinned handles follow the renumbering.
    handles = np.array([[35.0, 0.0], [-50.0, 0.0]])
    verts, faces, pinned = triangulate_shape(ring_shape, 3.0, handles)
    np.testing.assert_array_equal(hilbert_order(verts), np.arange(len(verts)))
    np.testing.assert_allclose(verts[pinned], handles, atol=1e-9)
    edge = np.linalg.norm(verts[faces[:, 0]] - verts[faces[:, 1]], axis=1)
    step = np.linalg.norm(np.diff(verts, axis=0), axis=1)
    assert np.median(step) < 2 * np.median(edge)
    a, b = verts[faces[:, 1]] - verts[faces[:, 0]], verts[faces[:, 2]] - verts[faces[:, 0]]
    assert (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0] > 0).all()  # still counter-clockwise
