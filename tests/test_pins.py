"""Pins placed and taken out on a built rig: the same answers as without them, the
shape held where a pin is, and nothing compiled again."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize

import mvcjax
from mvcjax import datasets
from mvcjax.advanced import DenseG, SparseLU, residuals

SPARE = 3
HEAD_DRAG = [30.0, 25.0]


def targets_for(rig, offsets, spare_rows=()):
    """The rest targets (spare rows where placed, else at rest) plus `offsets` for the
    handles' rows."""
    t = np.asarray(rig.handle_positions, np.float64).copy()
    t[:len(offsets)] += np.asarray(offsets, np.float64)
    for row, point in spare_rows:
        t[row] = point
    return jnp.asarray(t, rig.energy.rest.dtype)


def inner_point(rig, seed=0):
    """A shape-mesh vertex off the outline and away from the handles."""
    v = np.asarray(rig.shape_mesh.vertices, np.float64)
    boundary = np.unique(np.concatenate(mvcjax.geometry.boundary_loops(
        np.asarray(rig.shape_mesh.faces))))
    handles = np.asarray(rig.handle_positions)[:rig.handles.count]
    far = np.min(np.linalg.norm(v[:, None] - handles[None], axis=2), axis=1)
    ok = np.setdiff1d(np.flatnonzero(far > 0.15 * np.ptp(v[:, 0])), boundary)
    return int(np.random.default_rng(seed).choice(ok))


@pytest.mark.float64
@pytest.mark.parametrize("factor", [DenseG(), SparseLU()], ids=["dense", "sparse"])
def test_spare_pins_change_nothing_until_placed_and_after_taken_out(horse, factor):
    rig = mvcjax.Rig.build(horse, datasets.horse_handles(), dtype=jnp.float64, factor=factor)
    offsets = np.zeros((5, 2))
    offsets[0] = HEAD_DRAG
    plain = rig.deform(targets_for(rig, offsets))
    spare = rig.with_spare_pins(SPARE)
    assert spare.handles.count == 5 + SPARE
    assert spare.active.tolist() == [True] * 5 + [False] * SPARE
    size = float(np.ptp(np.asarray(plain)))
    # Whatever the inactive rows' targets are.
    loose = targets_for(spare, offsets, [(5, [1e3, -1e3]), (7, [0.0, 0.0])])
    assert float(jnp.abs(spare.deform(loose) - plain).max()) < 1e-10 * size
    vertex = inner_point(rig)
    point = np.asarray(rig.shape_mesh.vertices)[vertex]
    placed = spare.with_pin(6, point)
    assert placed.active.tolist() == [True] * 5 + [False, True, False]
    moved = placed.deform(targets_for(placed, offsets, [(6, point)]))
    assert float(jnp.abs(moved - plain).max()) > 1e-3 * size  # the pin holds there
    back = placed.without_pin(6)
    assert float(jnp.abs(back.deform(loose) - plain).max()) < 1e-10 * size


@pytest.mark.float64
def test_a_placed_pin_holds_the_shape_where_it_is_dragged(horse_rig):
    rig = horse_rig.with_spare_pins(SPARE)
    vertex = inner_point(rig, seed=1)
    point = np.asarray(rig.shape_mesh.vertices)[vertex]
    rig = rig.with_pin(5, point)
    size = float(np.ptp(np.asarray(rig.shape_mesh.vertices)[:, 0]))
    goal = point + [0.05 * size, -0.03 * size]
    targets = targets_for(rig, np.zeros((5, 2)), [(5, goal)])
    shape, info = rig.deform(targets, return_info=True)
    assert mvcjax.flipped_triangles(rig.shape_mesh.vertices, shape, rig.shape_mesh.faces) == 0
    # The control mesh meets the pin as it meets any handle; the shape point there
    # follows by the skinning, which departs a little from the triangle's plane inside.
    assert float(info.handle_miss) < 2e-3 * size
    assert np.linalg.norm(np.asarray(shape)[vertex] - goal) < 3e-3 * size
    assert np.linalg.norm(np.asarray(shape)[vertex] - point) > 0.04 * size
    # The pinned row is a barycentric row of C: the minimum it finds is the energy's,
    # as an independent least-squares solver finds it.
    local = rig.frame.to_local(rig.pinned_targets(targets))
    fun = jax.jit(lambda x: residuals(rig.energy, x.reshape(-1, 2), local))
    jac = jax.jit(jax.jacfwd(fun))
    start = np.asarray(rig.frame.to_local(rig.start(targets))).ravel()
    ref = scipy.optimize.least_squares(lambda x: np.asarray(fun(x)), start,
                                       jac=lambda x: np.asarray(jac(x)), method="trf",
                                       xtol=1e-15, ftol=1e-15, gtol=1e-15)
    _, info = rig.solve(targets, mvcjax.GaussNewton(max_steps=200), return_info=True)
    assert bool(info.converged)
    assert float(info.energy) == pytest.approx(2 * ref.cost * float(rig.frame.scale) ** 2,
                                               rel=1e-8)


@pytest.mark.float64
def test_a_pin_added_where_the_pose_is_keeps_the_pose(horse_rig):
    solver = mvcjax.GaussNewton(max_steps=100)
    targets = np.asarray(horse_rig.handle_positions).copy()
    targets[0] += HEAD_DRAG
    control = horse_rig.solve(targets, solver)
    pose = horse_rig.skin(control)
    rig = horse_rig.with_spare_pins(1).with_pin(
        5, np.asarray(horse_rig.shape_mesh.vertices)[inner_point(horse_rig, seed=3)])
    # Its target: where its spot of the control mesh is in the pose.
    row = int(np.flatnonzero(np.asarray(rig.handles.first) == 5)[0])
    here = np.asarray(rig.energy.handle_coef)[row] @ np.asarray(control)[
        np.asarray(rig.energy.handles)[row]]
    again = rig.deform(np.concatenate([targets, here[None]]), solver)
    size = float(np.ptp(np.asarray(pose)))
    assert float(jnp.abs(again - pose).max()) < 1e-6 * size


def test_placing_and_taking_out_pins_compiles_nothing(horse_rig32):
    rig = horse_rig32.with_spare_pins(SPARE)
    pose = jax.jit(lambda r, t: r.deform(t))
    vertices = np.asarray(rig.shape_mesh.vertices)
    targets = np.asarray(rig.handle_positions).copy()
    targets[0] += HEAD_DRAG
    first = pose(rig, jnp.asarray(targets))
    rigs = [rig.with_pin(5, vertices[inner_point(rig, seed)]) for seed in range(3)]
    rigs += [rigs[0].with_pin(6, vertices[inner_point(rig, 7)]).without_pin(1)]
    for r in rigs:
        shape = pose(r, jnp.asarray(targets))
        assert bool(jnp.all(jnp.isfinite(shape)))
        assert float(jnp.abs(shape - first).max()) > 0  # each pin changes the pose
    assert pose._cache_size() == 1


def test_the_guides_spelling_poses_every_pinned_rig_with_one_program(horse_rig32, caplog):
    # docs/guide.md: `jax.jit(mvcjax.Rig.deform)`, the rig an argument, compiles once for
    # every rig `with_pin` returns; `jax.jit(rig.deform)`, the rig's arrays constants,
    # compiles for each new rig.
    rig = horse_rig32.with_spare_pins(SPARE)
    vertices = np.asarray(rig.shape_mesh.vertices)
    targets = jnp.asarray(rig.handle_positions)
    rigs = [rig.with_pin(5, vertices[inner_point(rig, seed)]) for seed in range(3)]
    frame = jax.jit(mvcjax.Rig.deform)
    frame(rig, targets).block_until_ready()
    # (jax.jit's cache is shared by every jit of `Rig.deform`: count what these add.)
    compiled = frame._cache_size()
    for r in rigs:
        frame(r, targets).block_until_ready()
    assert frame._cache_size() == compiled
    with jax.log_compiles(True), caplog.at_level("WARNING", logger="jax"):
        for r in rigs:
            jax.jit(r.deform)(targets).block_until_ready()
    compiled = [m for m in caplog.messages if "Finished XLA compilation of jit(deform)" in m]
    assert len(compiled) == len(rigs), caplog.messages


def test_gradients_flow_through_a_placed_pin(horse_rig32):
    rig = horse_rig32.with_spare_pins(1)
    vertex = inner_point(rig, seed=2)
    rig = rig.with_pin(5, np.asarray(rig.shape_mesh.vertices)[vertex])
    targets = jnp.asarray(rig.handle_positions)

    def moved(goal):
        return jnp.sum(rig.deform(targets.at[5].set(goal))[vertex])

    goal = targets[5] + jnp.asarray([3.0, 2.0])
    grad = jax.jit(jax.grad(moved))(goal)
    step = 0.5
    for k in range(2):
        d = jnp.zeros(2).at[k].set(step)
        fd = (moved(goal + d) - moved(goal - d)) / (2 * step)
        assert float(grad[k]) == pytest.approx(float(fd), abs=0.02)
    assert 0.8 < float(grad[0]) < 1.2  # the shape point follows the pin


BAR = [[0, 0], [10, 0], [10, 2], [0, 2]]


def test_a_bone_is_taken_out_whole():
    rig = mvcjax.Rig.build(mvcjax.Shape.from_polygon(BAR),
                           [[0.5, 1.0], mvcjax.Bone([2, 1], [6, 1]), [9.5, 1.0]])
    out = rig.without_pin(2)
    assert out.active.tolist() == [True, False, False, True]
    presence = np.asarray(out.energy.handle_presence())
    on_bone = np.asarray(rig.handles.first) == 1
    assert on_bone.sum() > 2 and not presence[on_bone].any() and presence[~on_bone].all()


def test_bad_pins_say_what_to_do(horse_rig32):
    rig = horse_rig32.with_spare_pins(2)
    with pytest.raises(ValueError, match="outside the shape"):
        rig.with_pin(5, [1e4, 1e4])
    with pytest.raises(ValueError, match="a whole number from 0 to 6"):
        rig.with_pin(7, [0.0, 0.0])
    with pytest.raises(ValueError, match="with_spare_pins"):
        horse_rig32.with_pin(0, np.asarray(horse_rig32.handle_positions)[0])
    with pytest.raises(ValueError, match="count is how many"):
        horse_rig32.with_spare_pins(0)
    bones = mvcjax.Rig.build(mvcjax.Shape.from_polygon(BAR), [mvcjax.Bone([1, 1], [9, 1])])
    bones = bones.with_spare_pins(1)
    with pytest.raises(ValueError, match="end of a bone"):
        bones.with_pin(0, [5.0, 1.0])
    with pytest.raises(ValueError, match="last pin"):
        bones.without_pin(1)
    lone = horse_rig32
    for row in range(4):
        lone = lone.without_pin(row)
    with pytest.raises(ValueError, match="last pin"):
        lone.without_pin(4)
