import numpy as np
import pytest

from mvcjax.advanced import mean_value_coordinates
from mvcjax.geometry._coordinates import barycentric_coordinates, distance_outside, locate_points

HEXAGON = np.array([[np.cos(a), np.sin(a)] for a in np.linspace(0, 2 * np.pi, 6, endpoint=False)])
# A non-convex, star-shaped polygon, as the stars of eq. 1 often are.
STAR = np.array([[2, 0], [0.5, 0.5], [0, 2], [-0.5, 0.5],
                 [-2, 0], [-0.5, -0.5], [0, -2], [0.5, -0.5]])


def mvc(points, polygon):
    points = np.atleast_2d(points)
    return mean_value_coordinates(points, np.broadcast_to(polygon, (len(points), *polygon.shape)))


@pytest.mark.parametrize("polygon", [HEXAGON, 3.0 * HEXAGON[::-1], STAR[:-1]])
def test_partition_of_unity_and_linear_precision(polygon):
    rng = np.random.default_rng(0)
    points = rng.uniform(-0.4, 0.4, size=(200, 2))
    w = mvc(points, polygon)
    assert np.all(np.isfinite(w))
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(w @ polygon, points, atol=1e-12)


def test_point_on_a_vertex_is_one_hot():
    w = mvc(HEXAGON[2], HEXAGON)
    np.testing.assert_array_equal(w[0], np.eye(6)[2])


def test_point_on_an_edge_interpolates_linearly():
    p = 0.25 * HEXAGON[4] + 0.75 * HEXAGON[5]
    w = mvc(p, HEXAGON)[0]
    expected = np.zeros(6)
    expected[4], expected[5] = 0.25, 0.75
    np.testing.assert_allclose(w, expected, atol=1e-12)
    p = 0.5 * HEXAGON[5] + 0.5 * HEXAGON[0]  # the closing edge
    np.testing.assert_allclose(mvc(p, HEXAGON)[0][[5, 0]], [0.5, 0.5], atol=1e-12)


def test_padding_is_ignored():
    polygons = np.zeros((1, 8, 2))
    polygons[0, :6] = HEXAGON
    valid = np.zeros((1, 8), bool)
    valid[0, :6] = True
    p = np.array([[0.1, -0.2]])
    w = mean_value_coordinates(p, polygons, valid)
    np.testing.assert_allclose(w[0, :6], mvc(p, HEXAGON)[0], atol=1e-14)
    assert np.all(w[0, 6:] == 0)


def test_barycentric_reproduces_points():
    tri = np.array([[[0, 0], [2, 0], [0, 1.0]]])
    p = np.array([[0.5, 0.25]])
    w = barycentric_coordinates(p, tri)
    np.testing.assert_allclose(w.sum(), 1)
    np.testing.assert_allclose(w @ tri[0], p)


def test_locate_points():
    v = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5]])
    f = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    face, depth = locate_points(np.array([[0.5, 0.1], [0.9, 0.5], [2.0, 2.0]]), v, f)
    assert face[:2].tolist() == [0, 1] and depth[0] > 0 and depth[2] < 0


def test_distance_outside_a_triangle():
    triangle = np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 3.0]])
    points = np.array([[1.0, 1.0], [1.0, -0.25], [-0.5, 1.0], [2.0, 1.5 + 0.4]])
    distance = distance_outside(points, np.broadcast_to(triangle, (4, 3, 2)))
    # Inside; below the bottom edge; left of the left edge; beyond the hypotenuse (whose
    # normal is (3, 4) / 5: 0.4 up is 0.32 out).
    np.testing.assert_allclose(distance, [0.0, 0.25, 0.5, 0.32], atol=1e-12)


def test_locate_points_agrees_with_comparing_every_triangle():
    # It looks among the nearest triangles first: the same face and depth as the same
    # arithmetic through all of them, ties (points on edges and vertices) included.
    from scipy.spatial import Delaunay

    from mvcjax.geometry._coordinates import _smallest_coordinates, cross

    rng = np.random.default_rng(0)
    vertices = rng.uniform(size=(300, 2))
    faces = Delaunay(vertices).simplices
    points = np.concatenate([rng.uniform(-0.2, 1.2, size=(2000, 2)), vertices,
                             0.5 * (vertices[faces[:, 0]] + vertices[faces[:, 1]])])
    face, depth = locate_points(points, vertices, faces)
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    low = _smallest_coordinates(points, a, b - a, c - a, 1 / cross(b - a, c - a))
    np.testing.assert_array_equal(face, np.argmax(low, axis=1))
    np.testing.assert_allclose(depth, low.max(axis=1), atol=1e-12)
