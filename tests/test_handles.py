"""Handles: point handles and bones (segment handles), through every solver, many
frames and gradients."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mvcjax
from mvcjax import datasets

from conftest import directional_derivatives, scipy_minimum

# Against scipy, finite differences and converged references to many digits: in float64
# (`bone_rig` and the tests marked); what users run, in float32.

SHOULDER = (22.0, 139.0)


@pytest.fixture(scope="module")
def character():
    return datasets.model("character")


def character_handles(model, stretch=False):
    """Head and ankles as points, the spine and the right arm as bones, the left wrist a
    point: targets are rows 0 (head), 1-2 (spine), 3-4 (arm), 5, 6, 7."""
    h = model.handles
    return [h[0], mvcjax.Bone((0.0, 95.0), (0.0, 150.0)), mvcjax.Bone(SHOULDER, h[3],
            stretch=stretch), h[2], h[4], h[5]]


@pytest.fixture(scope="module")
def bone_rig(character):
    return mvcjax.Rig.build(character.shape, character_handles(character), dtype=jnp.float64,
                            **character.options)


def turned(point, centre, degrees, scale=1.0):
    t = np.radians(degrees)
    rot = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    return np.asarray(centre) + scale * rot @ (np.asarray(point) - np.asarray(centre))


def arm_raised(rig, degrees=60.0, scale=1.0):
    """The rest targets with the arm bone's end turned about its start."""
    t = np.array(rig.handle_positions)
    t[4] = turned(t[4], t[3], degrees, scale)
    return jnp.asarray(t)


def arm_pins(rig, vertices):
    """The control vertices the arm bone pins, from its start to its end."""
    rows = np.flatnonzero(np.asarray(rig.handles.first) == 3)
    return np.asarray(vertices)[np.asarray(rig.control_mesh.handles)[rows]]


@pytest.mark.float64
def test_points_are_one_target_and_one_pin_each(horse_rig):
    h = datasets.horse_handles()
    assert horse_rig.handles.count == len(h) and horse_rig.handles.bones.shape == (0, 2)
    np.testing.assert_allclose(horse_rig.handle_positions, h, atol=1e-12)
    t = horse_rig.handle_positions + 3.0
    np.testing.assert_allclose(horse_rig.pinned_targets(t), t, atol=1e-12)


@pytest.mark.float64
def test_targets_follow_the_order_the_handles_were_given(bone_rig, character):
    given = character_handles(character)
    rest = np.asarray(bone_rig.handle_positions)
    np.testing.assert_allclose(rest[[0, 5, 6, 7]], np.asarray([given[0], *given[3:]]),
                               atol=1e-9)
    np.testing.assert_allclose(rest[1:3], [given[1].start, given[1].end], atol=1e-9)
    np.testing.assert_allclose(bone_rig.bones, [[given[1].start, given[1].end],
                                                [given[2].start, given[2].end]], atol=1e-9)
    assert "6 handles (2 bones; 8 targets" in repr(bone_rig)


@pytest.mark.float64
def test_a_bone_pins_its_segment_at_about_the_control_spacing(bone_rig):
    rest = arm_pins(bone_rig, bone_rig.control_mesh.vertices)
    assert len(rest) >= 4
    start, end = np.asarray(bone_rig.bones[1])
    gaps = np.linalg.norm(np.diff(rest, axis=0), axis=1)
    np.testing.assert_allclose(gaps, gaps[0], rtol=1e-9)
    np.testing.assert_allclose(rest[[0, -1]], [start, end], atol=1e-9)
    # All on the segment, evenly from end to end.
    d = (end - start) / np.linalg.norm(end - start)
    assert np.abs((rest - start) @ np.array([-d[1], d[0]])).max() < 1e-9


@pytest.mark.parametrize("dtype", [jnp.float32, pytest.param(jnp.float64,
                                                               marks=pytest.mark.float64)])
def test_rest_targets_give_the_rest_shape(character, dtype):
    rig = mvcjax.Rig.build(character.shape, character_handles(character), dtype=dtype)
    moved = rig.deform(rig.handle_positions)
    tol = 1e-5 if dtype == jnp.float32 else 1e-12
    assert float(jnp.abs(moved - rig.shape_mesh.vertices).max()) < tol * character.shape.diagonal


@pytest.mark.float64
def test_a_rigidly_moved_pose_moves_the_shape_rigidly(bone_rig, character):
    rest = np.asarray(bone_rig.handle_positions)
    targets = np.stack([turned(p, (10.0, 50.0), 35.0) for p in rest]) + [300.0, -40.0]
    moved = bone_rig.deform(targets, mvcjax.GaussNewton())
    expected = np.stack([turned(p, (10.0, 50.0), 35.0) for p in
                         np.asarray(bone_rig.shape_mesh.vertices)]) + [300.0, -40.0]
    assert np.abs(np.asarray(moved) - expected).max() < 1e-6 * character.shape.diagonal


@pytest.mark.parametrize("stretch", [False, True])
def test_a_bone_keeps_its_length_unless_asked_to_stretch(character, stretch):
    rig = mvcjax.Rig.build(character.shape, character_handles(character, stretch),
                           **character.options)
    targets = arm_raised(rig, 50.0, scale=1.3)  # the arm's end dragged 30% further out
    pins = arm_pins(rig, rig.solve(targets, mvcjax.GaussNewton()))
    rest_length = float(np.linalg.norm(np.diff(np.asarray(rig.bones[1]), axis=0)))
    length = np.linalg.norm(pins[-1] - pins[0])
    # Within the handles' soft pull (weight 100) of the asked length, 30% from the other.
    assert length == pytest.approx(rest_length * (1.3 if stretch else 1.0), rel=1e-2)
    # Along the target direction, through the middle of the targets either way.
    direction = (targets[4] - targets[3]) / jnp.linalg.norm(targets[4] - targets[3])
    along = (pins - np.asarray(targets[3])) @ np.asarray(direction)
    across = (pins - np.asarray(targets[3])) @ np.asarray([-direction[1], direction[0]])
    assert np.abs(across).max() < 5e-3 * rest_length
    middle = 0.5 * float(jnp.linalg.norm(targets[4] - targets[3]))
    assert 0.5 * (along[0] + along[-1]) == pytest.approx(middle, abs=5e-3 * rest_length)


SOLVERS = {
    "anderson": mvcjax.FixedG(iterations=20000, rtol=1e-11, stop_early=True, anderson=5),
    "gauss_newton": mvcjax.GaussNewton(max_steps=500),
    "levenberg_marquardt": mvcjax.LevenbergMarquardt(max_steps=1000),
    "dogleg": mvcjax.Dogleg(max_steps=500),
    "jaxopt_levenberg_marquardt": mvcjax.advanced.JaxoptLevenbergMarquardt(max_steps=1000),
}


@pytest.fixture(scope="module")
def bone_minimum(bone_rig):
    targets = arm_raised(bone_rig, 30.0)
    return targets, scipy_minimum(bone_rig, targets, bone_rig.start(targets))


@pytest.mark.parametrize("name", list(SOLVERS))
@pytest.mark.float64
def test_every_solver_reaches_the_minimum_with_bones(bone_rig, character, bone_minimum, name):
    targets, (minimum, energy) = bone_minimum
    vertices, info = bone_rig.solve(targets, SOLVERS[name], return_info=True)
    assert bool(info.converged), name
    gap = np.abs(np.asarray(vertices) - minimum).max() / character.shape.diagonal
    assert gap < 1e-5, gap
    assert float(info.energy) == pytest.approx(energy, rel=1e-8)


@pytest.mark.float64
def test_undamped_gauss_newton_says_when_it_stalls(bone_rig):
    # With the arm raised, on the paper's energy, jaxopt's undamped Gauss-Newton cycles
    # above the minimum that the damped solvers reach (it converges only for drags of 10
    # degrees or so): it must say so rather than return the stalled pose as a solve.
    bone_rig = bone_rig.with_weights(mvcjax.Weights.paper())
    targets = arm_raised(bone_rig, 30.0)
    _, stalled = bone_rig.solve(targets, mvcjax.advanced.JaxoptGaussNewton(max_steps=500),
                                return_info=True)
    _, damped = bone_rig.solve(targets, SOLVERS["levenberg_marquardt"], return_info=True)
    assert bool(damped.converged)
    assert not bool(stalled.converged)
    assert float(stalled.energy) > float(damped.energy) * (1 + 1e-6)


@pytest.mark.float64
def test_many_frames_with_bones_match_single_frames(bone_rig):
    targets = jnp.stack([arm_raised(bone_rig, d) for d in (0.0, 30.0, 70.0)])
    frames = mvcjax.deform_frames(bone_rig, targets)
    single = jnp.stack([bone_rig.deform(t) for t in targets])
    np.testing.assert_allclose(frames, single, atol=1e-9)


@pytest.mark.parametrize("stretch", [False, True])
@pytest.mark.float64
def test_gradients_through_bone_targets_match_finite_differences(character, stretch):
    rig = mvcjax.Rig.build(character.shape, character_handles(character, stretch),
                           **character.options)
    targets = arm_raised(rig, 40.0)
    probe = jax.random.normal(jax.random.key(1), rig.shape_mesh.vertices.shape)

    def loss(t):
        return jnp.sum(probe * rig.deform(t)) / 100.0

    for seed in range(2):
        exact, approx = directional_derivatives(loss, targets, seed=seed, h=1e-4)
        assert exact == pytest.approx(approx, rel=1e-6, abs=1e-9)


def test_bones_sharing_a_joint_pin_it_once(character):
    hip, knee, ankle = (-13.0, 91.0), (-23.0, 51.0), character.handles[4]
    chain = [mvcjax.Bone(hip, knee), mvcjax.Bone(knee, ankle), character.handles[0]]
    rig = mvcjax.Rig.build(character.shape, chain)
    pinned = np.asarray(rig.control_mesh.handles)
    assert len(np.unique(pinned)) == len(pinned) - 1  # the knee, pinned by both bones
    t = np.array(rig.handle_positions)
    t[1] = t[2] = turned(knee, hip, -30.0)
    t[3] = turned(turned(ankle, hip, -30.0), t[1], 40.0)
    vertices = np.asarray(rig.solve(jnp.asarray(t), mvcjax.GaussNewton()))
    knee_vertex = vertices[pinned[np.asarray(rig.handles.first) == 2][0]]
    assert np.linalg.norm(knee_vertex - t[1]) < 1e-3 * character.shape.diagonal


@pytest.mark.float64
def test_bones_on_the_full_solve_and_a_control_mesh_of_ones_own(bone_rig, character):
    handles = character_handles(character)
    own = mvcjax.Rig.build(character.shape, handles, dtype=jnp.float64,
                           control=mvcjax.GivenControl(bone_rig.control_mesh.vertices,
                                                       bone_rig.control_mesh.faces))
    assert own.control_mesh.handles.shape == bone_rig.control_mesh.handles.shape
    targets = arm_raised(bone_rig)
    np.testing.assert_allclose(own.solve(targets), bone_rig.solve(targets), atol=1e-9)
    full = mvcjax.Rig.build(character.shape, handles, dtype=jnp.float64, control=mvcjax.FullSolve())
    pins = arm_pins(full, full.solve(targets, mvcjax.GaussNewton()))
    on_target = np.asarray(full.pinned_targets(targets))[np.asarray(full.handles.first) == 3]
    assert np.abs(pins - on_target).max() < 1e-2 * character.shape.diagonal


@pytest.mark.float64
def test_a_control_mesh_of_ones_own_needs_the_bone_ends(bone_rig, character):
    handles = character_handles(character)
    handles[2] = mvcjax.Bone(SHOULDER, (45.0, 131.0))  # ends off the given mesh's vertices
    with pytest.raises(ValueError, match="not a vertex of the given control mesh"):
        mvcjax.Rig.build(character.shape, handles,
                         control=mvcjax.GivenControl(bone_rig.control_mesh.vertices,
                                                     bone_rig.control_mesh.faces))


@pytest.mark.parametrize("handles, error, match", [
    ([mvcjax.Bone((0, 100), (0, 100))], ValueError, r"handles\[0\] is a Bone of length 0"),
    ([(0, 175), mvcjax.Bone((-30, 30), (30, 30))], ValueError,
     r"handles\[1\], a Bone .* leaves the shape"),
    ([mvcjax.Bone((0, 95), (0, 150)), "head"], ValueError,
     r"handles\[1\] must be an \(x, y\) point or an mvcjax.Bone"),
    ([mvcjax.Bone((0, 95), (0, 150)), (0, 175, 1)], ValueError, r"handles\[1\]"),
    ([mvcjax.Bone((0, 95), (0, 150)), (0, 175), (0, 175)], ValueError,
     r"handles\[1\] and handles\[2\] are at the same spot"),
    ([mvcjax.Bone((0, 95), (0, 150)), (500, 175)], ValueError,
     r"handles\[1\] = \[500.0, 175.0\] lies outside the shape"),
])
def test_bad_handles_are_refused_by_index(character, handles, error, match):
    with pytest.raises(error, match=match):
        mvcjax.Rig.build(character.shape, handles)


@pytest.mark.parametrize("start, end, stretch, match", [
    ("a", (0, 1), False, "Bone start must be one"),
    ((0, 0), (1, 2, 3), False, "Bone end must be one"),
    ((0, 0), (np.nan, 1), False, "NaN"),
    ((0, 0), (1, 1), "yes", "stretch is True or False"),
])
def test_bad_bones_are_refused(start, end, stretch, match):
    with pytest.raises((TypeError, ValueError), match=match):
        mvcjax.Bone(start, end, stretch=stretch)


@pytest.mark.float64
def test_a_collapsed_bone_target_stays_finite(bone_rig):
    t = np.array(bone_rig.handle_positions)
    t[4] = t[3]  # both ends of the arm bone dragged to one point
    moved = bone_rig.deform(jnp.asarray(t))
    assert bool(jnp.all(jnp.isfinite(moved)))
    g = jax.grad(lambda x: jnp.sum(bone_rig.deform(x) ** 2))(jnp.asarray(t))
    assert bool(jnp.all(jnp.isfinite(g)))


# Scales by powers of two: Triangle then meshes the same numbers (its refinement turns a
# last-bit difference, as other placements give, into another mesh).
@pytest.mark.parametrize("scale", [2.0**-10, 2.0**13])
@pytest.mark.float64
def test_bones_do_not_depend_on_the_shape_s_scale(bone_rig, character, scale):
    offset = np.zeros(2)

    def place(p):
        return np.asarray(p) * scale + offset

    handles = [place(h) if not isinstance(h, mvcjax.Bone) else
               mvcjax.Bone(place(h.start), place(h.end), stretch=h.stretch)
               for h in character_handles(character)]
    shape = mvcjax.Shape.from_polygon(place(character.shape.outer))
    paper = character.options["control"]
    options = {"shape_spacing": character.options["shape_spacing"] * scale,
               "control": mvcjax.PaperControl(spacing=paper.spacing * scale,
                                              margin=paper.margin * scale)}
    moved = mvcjax.Rig.build(shape, handles, dtype=jnp.float64, **options)
    assert moved.control_mesh.handles.shape == bone_rig.control_mesh.handles.shape
    targets = arm_raised(bone_rig, 45.0)
    here = np.asarray(bone_rig.deform(targets))
    there = (np.asarray(moved.deform(place(targets))) - offset) / scale
    assert np.abs(there - here).max() < 1e-8 * character.shape.diagonal
