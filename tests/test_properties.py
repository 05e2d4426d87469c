"""Property tests: random simple polygons, with and without a hole, at offsets and scales
over many orders of magnitude, with random handles and targets. Every case either raises
an mvcjax ValueError or TypeError that says what was wrong, or returns finite vertices
with rest in, rest out and rigid in, rigid out.

The default profile keeps this to well under a minute; `HYPOTHESIS_PROFILE=long` runs
many more cases (conftest.py)."""

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

import mvcjax

# Agreement with references to many digits, and the solvers' internals: in float64.
pytestmark = pytest.mark.float64


@st.composite
def polygons(draw):
    """A star-shaped polygon around the origin (radii in [0.4, 1]), sometimes with a
    hole: the same star shrunk into the disc every vertex lies outside of."""
    count = draw(st.integers(5, 24))
    radii = np.asarray(draw(st.lists(st.floats(0.4, 1.0), min_size=count, max_size=count)))
    jitter = np.asarray(draw(st.lists(st.floats(-0.3, 0.3), min_size=count, max_size=count)))
    angles = (np.arange(count) + jitter) * 2 * np.pi / count
    outer = np.stack([radii * np.cos(angles), radii * np.sin(angles)], axis=1)
    holes = []
    if draw(st.booleans()):
        t = np.linspace(0, 2 * np.pi, 12, endpoint=False)
        holes = [0.15 * np.stack([np.cos(t), np.sin(t)], axis=1) + [0.0, 0.2]]
    return outer, holes


placements = st.tuples(
    st.floats(-20, 20),  # log10 of the scale
    st.floats(-3, 8),  # log10 of the offset, in units of the shape's size
    st.floats(0, 2 * np.pi),  # direction of the offset
)


@settings(deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(polygon=polygons(), placement=placements,
       drag=st.lists(st.floats(-0.3, 0.3), min_size=4, max_size=4),
       angle=st.floats(-np.pi, np.pi))
def test_random_shapes_anywhere_give_a_clear_error_or_a_sound_result(polygon, placement, drag,
                                                                      angle):
    outer, holes = polygon
    log_scale, log_offset, direction = placement
    scale = 10.0**log_scale
    offset = scale * 10.0**log_offset * np.array([np.cos(direction), np.sin(direction)])
    handles = np.array([[0.0, -0.25], [0.0, 0.35]])  # inside any of these stars, off the hole

    def place(points):
        return np.asarray(points) * scale + offset

    try:
        shape = mvcjax.Shape.from_polygon(place(outer), [place(h) for h in holes])
        rig = mvcjax.Rig.build(shape, place(handles), dtype=jnp.float64,
                               shape_spacing=0.08 * scale)
    except (ValueError, TypeError) as error:
        assert str(error)
        return
    diagonal = shape.diagonal
    # What float64 can hold of coordinates this far out.
    tol = max(1e-7, 16 * np.spacing(np.abs(offset).max() + diagonal) / diagonal) * diagonal

    rest = np.asarray(rig.deform(rig.handle_positions))
    assert np.all(np.isfinite(rest))
    assert np.abs(rest - np.asarray(rig.shape_mesh.vertices)).max() <= tol

    targets = np.asarray(rig.handle_positions) + scale * np.reshape(drag, (2, 2))
    dragged = np.asarray(rig.deform(targets))
    assert np.all(np.isfinite(dragged))
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    centre = targets.mean(axis=0)
    moved = np.asarray(rig.deform((targets - centre) @ rot.T + centre))
    np.testing.assert_allclose(moved, (dragged - centre) @ rot.T + centre, rtol=0,
                               atol=100 * tol)


@pytest.mark.parametrize("bad", [np.nan, np.inf, 1e308])
def test_targets_beyond_float_give_an_error_or_an_honest_info(bad):
    shape = mvcjax.Shape.from_polygon(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]))
    rig = mvcjax.Rig.build(shape, [[0.25, 0.25], [0.75, 0.75]], shape_spacing=0.2,
                           dtype=jnp.float64)
    targets = np.asarray(rig.handle_positions).copy()
    targets[0, 0] = bad
    try:
        vertices, info = rig.solve(targets, mvcjax.GaussNewton(), return_info=True)
    except ValueError as error:
        assert "finite" in str(error)
        return
    finite = bool(np.all(np.isfinite(np.asarray(vertices)))) and np.isfinite(float(info.energy))
    assert finite or not bool(info.converged)
