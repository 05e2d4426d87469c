import numpy as np
import pytest
import triangle
from hypothesis import given, settings, strategies as st

from mvcjax.geometry._topology import (
    boundary_edges,
    boundary_loops,
    edges,
    face_neighbours,
    face_pairs,
    interior_edges,
    vertex_stars,
)

# A square split into a fan around its centre (vertex 4).
FAN = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])


def reference_stars(faces, count):
    """Stars walked one vertex at a time with dictionaries: slow, obviously right."""
    nxt: dict[int, dict[int, int]] = {}
    for a, b, c in faces.tolist():
        nxt.setdefault(a, {})[b] = c
        nxt.setdefault(b, {})[c] = a
        nxt.setdefault(c, {})[a] = b
    stars = []
    for v in range(count):
        around = nxt.get(v, {})
        starts = [b for b in around if b not in set(around.values())]
        ring = [v, starts[0]] if starts else [next(iter(around))]
        while ring[-1] in around and (starts or around[ring[-1]] != ring[0]):
            ring.append(around[ring[-1]])
        stars.append(ring)
    return stars


def annulus_mesh(points: int, holes: bool, max_area: float):
    """A Triangle mesh of a disc (or an annulus with a hole)."""
    t = np.linspace(0, 2 * np.pi, points, endpoint=False)
    ring = np.stack([np.cos(t), np.sin(t)], 1)
    segments = np.stack([np.arange(points), np.roll(np.arange(points), -1)], 1)
    data = dict(vertices=ring, segments=segments)
    if holes:
        data = dict(vertices=np.concatenate([ring, 0.4 * ring]),
                    segments=np.concatenate([segments, segments + points]), holes=[[0.0, 0.0]])
    mesh = triangle.triangulate(data, f"pqa{max_area:.6f}")
    return mesh["vertices"], mesh["triangles"]


def test_fan():
    assert face_neighbours(FAN)[0].tolist() == [-1, 2, 3]  # across 0-1, 1-4, 4-0
    stars, valid = vertex_stars(FAN, 5)
    assert stars[4][valid[4]].tolist() == [0, 1, 2, 3]  # interior: the 1-ring in order
    assert stars[0][valid[0]].tolist() == [0, 1, 4, 3]  # boundary: itself, then its fan
    assert [lp.tolist() for lp in boundary_loops(FAN)] == [[0, 1, 2, 3]]
    assert len(edges(FAN)) == 8 and len(boundary_edges(FAN)) == 4
    assert interior_edges(FAN).tolist() == [[0, 4], [1, 4], [2, 4], [3, 4]]
    assert {tuple(sorted(p)) for p in face_pairs(FAN).tolist()} == {(0, 1), (1, 2), (2, 3), (0, 3)}


@settings(max_examples=10, deadline=None)
@given(points=st.integers(3, 40), holes=st.booleans(), max_area=st.floats(0.005, 0.5))
def test_stars_and_loops_match_a_walk(points, holes, max_area):
    vertices, faces = annulus_mesh(points, holes, max_area)
    stars, valid = vertex_stars(faces, len(vertices))
    for v, ring in enumerate(reference_stars(faces, len(vertices))):
        assert stars[v][valid[v]].tolist() == ring
    loops = boundary_loops(faces)
    assert len(loops) == 1 + holes
    assert sum(len(lp) for lp in loops) == len(boundary_edges(faces))
    for lp in loops:  # the outer loop runs counter-clockwise, a hole clockwise
        x, y = vertices[lp].T
        area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
        assert (area > 0) == (np.linalg.norm(vertices[lp[0]]) > 0.7)
    # Euler: every interior edge has two faces, every boundary edge one.
    assert 2 * len(interior_edges(faces)) + len(boundary_edges(faces)) == 3 * len(faces)
    assert len(face_pairs(faces)) == len(interior_edges(faces))


def test_pinched_meshes_are_named():
    # Two triangles meeting at vertex 7 only.
    bowtie = np.array([[0, 1, 7], [7, 3, 4]])
    with pytest.raises(ValueError, match="vertex 7 "):
        vertex_stars(bowtie, 8)
    with pytest.raises(ValueError, match="vertex 7 "):
        boundary_loops(bowtie)


def test_a_vertex_in_no_face_has_an_empty_star():
    _stars, valid = vertex_stars(FAN, 6)
    assert not valid[5].any()
