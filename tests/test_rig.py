import re

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import pytest

import mvcjax
from mvcjax import datasets
from mvcjax.geometry import boundary_loops

from conftest import directional_derivatives, drag, scipy_minimum

RIGID = mvcjax.advanced.RigidStart()

# A pose against the same pose computed again, on the horse (about 500 units across) in
# float32: a few roundings.
ROUNDING = dict(rtol=0, atol=1e-3)


def test_public_arrays(horse_rig32):
    sm, cm = horse_rig32.shape_mesh, horse_rig32.control_mesh
    assert sm.vertices.shape[1] == 2 and sm.faces.shape[1] == 3
    n = cm.vertices.shape[0]
    assert sorted(np.concatenate([cm.outer, cm.inner]).tolist()) == list(range(n))
    np.testing.assert_allclose(cm.vertices[cm.handles], datasets.horse_handles(), atol=1e-9)
    np.testing.assert_allclose(sm.vertices[sm.handles], datasets.horse_handles(), atol=1e-9)
    # V_CG are shape vertices.
    inner = np.asarray(cm.vertices[cm.inner])
    d = np.min(np.linalg.norm(inner[:, None] - np.asarray(sm.vertices)[None], axis=2), axis=1)
    assert d.max() < 1e-9


def test_rest_targets_give_the_rest_shape(horse_rig32):
    out = horse_rig32.deform(horse_rig32.handle_positions)
    np.testing.assert_allclose(out, horse_rig32.shape_mesh.vertices, **ROUNDING)


@pytest.mark.parametrize("angle", [0.3, 0.7, 2.5])
def test_rigid_motion_of_targets_moves_the_result_rigidly(horse_rig32, horse, angle):
    rot = jnp.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    shift = jnp.array([40.0, -25.0])
    targets = drag(horse_rig32, [[30.0, 10.0], [0, 0], [0, 0], [0, 0], [0, 0]])
    base = horse_rig32.deform(targets)
    moved = horse_rig32.deform(targets @ rot.T + shift)
    err = jnp.max(jnp.linalg.norm(moved - (base @ rot.T + shift), axis=1))
    assert float(err) < 1e-3 * horse.diagonal


@pytest.mark.float64
def test_handles_land_at_default_weights(horse_rig, horse):
    # One hoof dragged 60 units: every handle within 0.5% of the diagonal of its target.
    targets = drag(horse_rig, [[60.0, 0.0], [0, 0], [0, 0], [0, 0], [0, 0]])
    out = horse_rig.deform(targets)
    miss = jnp.linalg.norm(out[horse_rig.shape_mesh.handles] - targets, axis=1)
    assert float(miss.max()) < 0.005 * horse.diagonal


@pytest.mark.float64
def test_handle_weight_makes_handles_land(horse_rig):
    # Why the default handle weight is not the paper's 1: the handles then stop short,
    # pulled back by the many rows of the other terms.
    targets = drag(horse_rig, [[60.0, 0.0], [0, 0], [0, 0], [0, 0], [0, 0]])
    solver = mvcjax.FixedG(iterations=3000, anderson=5, stop_early=True)
    misses = []
    for weights in [mvcjax.Weights.paper(handle=1.0), mvcjax.Weights.paper()]:
        rig = horse_rig.with_weights(weights)
        out = rig.deform(targets, solver)
        misses.append(float(jnp.linalg.norm(out[rig.shape_mesh.handles] - targets, axis=1).max()))
    assert misses[0] > 20 * misses[1]


@pytest.mark.float64
def test_jit_vmap_grad(horse_rig):
    frames = jnp.stack([drag(horse_rig, np.full((5, 2), s)) for s in [0.0, 5.0, 10.0]])
    batched = jax.jit(jax.vmap(lambda t: horse_rig.deform(t)))(frames)
    single = jnp.stack([horse_rig.deform(t) for t in frames])
    np.testing.assert_allclose(batched, single, atol=1e-9)

    landmark = 100

    def loss(t):
        return jnp.sum(horse_rig.deform(t)[landmark] ** 2)

    exact, approx = directional_derivatives(loss, frames[1], h=1e-4)
    assert exact == pytest.approx(approx, rel=1e-6)


def test_rig_is_a_pytree_and_jits_as_an_argument(horse_rig32):
    leaves = jax.tree.leaves(horse_rig32)
    assert all(isinstance(x, jax.Array) for x in leaves)
    out = jax.jit(lambda r, t: r.deform(t))(horse_rig32, horse_rig32.handle_positions)
    np.testing.assert_allclose(out, horse_rig32.shape_mesh.vertices, **ROUNDING)


@pytest.mark.parametrize("solver", [mvcjax.FixedG(), mvcjax.GaussNewton(), mvcjax.Dogleg(),
                                    mvcjax.LevenbergMarquardt()],
                         ids=lambda s: type(s).__name__)
def test_new_targets_or_weights_never_recompile(horse_rig32, solver):
    traces = []

    @jax.jit
    def deform(rig, targets):
        traces.append(1)
        return rig.deform(targets, solver)

    deform(horse_rig32, horse_rig32.handle_positions)
    deform(horse_rig32, drag(horse_rig32, np.ones((5, 2))))
    deform(horse_rig32.with_weights(mvcjax.Weights(handle=50.0, arap=2.0)),
           drag(horse_rig32, 3 * np.ones((5, 2))))
    assert len(traces) == 1
    with_weights = jax.jit(lambda r, w: r.with_weights(w))
    with_weights(horse_rig32, mvcjax.Weights(mvc=3.0))
    with_weights(horse_rig32, mvcjax.Weights(mvc=4.0, arap=0.5))
    assert with_weights._cache_size() == 1


@pytest.mark.float64
@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_float32_and_float64(horse, dtype):
    rig = mvcjax.Rig.build(horse, datasets.horse_handles(), dtype=dtype)
    targets = drag(rig, [[60.0, 0.0], [0, 0], [0, 0], [0, 0], [0, 0]])
    for solver in [mvcjax.FixedG(), mvcjax.GaussNewton()]:
        out = rig.deform(targets, solver)
        assert out.dtype == dtype
        assert bool(jnp.all(jnp.isfinite(out)))
    rest = rig.deform(rig.handle_positions)
    tol = (1e-5 if dtype == jnp.float32 else 1e-12) * horse.diagonal
    np.testing.assert_allclose(rest, rig.shape_mesh.vertices, atol=tol)


def test_shapes_with_holes(ring_shape):
    rig = mvcjax.Rig.build(ring_shape, [[35.0, 0.0], [-35.0, 0.0]])
    assert rig.control_mesh.vertices.shape[0] > 10
    out = rig.deform(drag(rig, [[20.0, 0.0], [0.0, 0.0]]))
    assert bool(jnp.all(jnp.isfinite(out)))
    assert float(out[rig.shape_mesh.handles[0], 0]) == pytest.approx(55.0, abs=0.5)


def test_letter_with_a_counter():
    mask = np.zeros((60, 50), bool)
    mask[5:55, 5:45] = True      # an "O"-like block letter
    mask[18:42, 17:33] = False   # its counter
    shape = mvcjax.Shape.from_image(mask)
    assert len(shape.holes) == 1
    rig = mvcjax.Rig.build(shape, [[25.0, 50.0], [25.0, 8.0]])
    out = rig.deform(drag(rig, [[0.0, 10.0], [0.0, 0.0]]))
    assert bool(jnp.all(jnp.isfinite(out)))


@pytest.fixture(scope="module")
def ring_full(ring_shape):
    # The sparse factor, as on any shape mesh above 1000 vertices; small enough for scipy.
    return mvcjax.Rig.build(ring_shape, [[35.0, 0.0], [-35.0, 0.0]], control=mvcjax.FullSolve(),
                            shape_spacing=9.0, factor=mvcjax.advanced.SparseLU())


@pytest.mark.float64
def test_full_solve_is_on_the_shape_mesh(ring_full):
    sm, cm = ring_full.shape_mesh, ring_full.control_mesh
    np.testing.assert_array_equal(cm.vertices, sm.vertices)
    np.testing.assert_array_equal(cm.handles, sm.handles)
    # Both boundary loops (outer and hole) are V_CP; every other vertex is V_CG.
    loops = boundary_loops(np.asarray(sm.faces))
    assert len(loops) == 2
    assert sorted(np.asarray(cm.outer).tolist()) == sorted(np.concatenate(loops).tolist())
    assert cm.outer.shape[0] + cm.inner.shape[0] == sm.vertices.shape[0]
    assert ring_full.skinning.indices.shape == (sm.vertices.shape[0], 1)
    np.testing.assert_allclose(ring_full.deform(ring_full.handle_positions), sm.vertices,
                               atol=1e-10)


@pytest.mark.float64
def test_full_solve_reaches_the_scipy_minimum(ring_full, ring_shape):
    targets = drag(ring_full, [[5.0, 2.0], [0.0, 0.0]])
    solver = mvcjax.FixedG(iterations=5000, rtol=1e-11, stop_early=True, anderson=5)
    vertices, info = ring_full.solve(targets, solver, return_info=True)
    assert bool(info.converged), int(info.iterations)
    # Dogbox: on this mesh MINPACK's LM crawls to the same point.
    minimum, minimum_energy = scipy_minimum(ring_full, targets, ring_full.start(targets),
                                            method="dogbox")
    assert np.abs(np.asarray(vertices) - minimum).max() < 1e-6 * ring_shape.diagonal
    assert float(info.energy) == pytest.approx(minimum_energy, rel=1e-8)


@pytest.mark.float64
@pytest.mark.parametrize("name", ["GaussNewton", "Dogleg", "LevenbergMarquardt"])
def test_structured_solvers_run_on_the_sparse_factor(ring_full, ring_shape, name):
    # The default optimistix solvers need N and N^{-1} only: the host's sparse solve
    # preconditions their conjugate gradients, and they reach the accelerated
    # fixed-G iteration's minimum.
    targets = drag(ring_full, [[5.0, 2.0], [0.0, 0.0]])
    # From one start, so that they meet in one minimum.
    reference, energy = ring_full.solve(
        targets, mvcjax.FixedG(iterations=5000, rtol=1e-11, stop_early=True, anderson=5),
        init=RIGID, return_info=True)
    energy = energy.energy
    vertices, info = jax.jit(lambda t: ring_full.solve(t, getattr(mvcjax, name)(), init=RIGID,
                                                       return_info=True))(targets)
    assert bool(info.converged), int(info.iterations)
    # The energy has several minima a hair apart (README, "several minima"): each solver
    # must reach a stationary point at the reference's energy, most often the same one.
    gradient = jax.grad(lambda v: ring_full.energy_at(v, targets))(vertices)
    assert float(jnp.abs(gradient).max()) < 1e-6
    assert float(info.energy) == pytest.approx(float(energy), rel=1e-3)
    if name != "LevenbergMarquardt":
        assert np.abs(np.asarray(vertices - reference)).max() < 1e-8 * ring_shape.diagonal


def test_a_dense_jacobian_that_does_not_fit_is_refused(horse):
    full = mvcjax.Rig.build(horse, datasets.horse_handles(), control=mvcjax.FullSolve(),
                            shape_spacing=4.0)
    with pytest.raises(ValueError, match=r"the default GaussNewton\(\) or"):
        full.solve(full.handle_positions, mvcjax.GaussNewton(linear_solver=lx.Cholesky()))
    with pytest.raises(ValueError, match="use mvcjax.FixedG"):
        full.solve(full.handle_positions, mvcjax.advanced.JaxoptLevenbergMarquardt())
    assert bool(jnp.all(jnp.isfinite(full.deform(full.handle_positions + 5.0))))


def test_user_control_mesh(horse, horse_rig32):
    cm = horse_rig32.control_mesh
    rig = mvcjax.Rig.build(horse, datasets.horse_handles(),
                           control=mvcjax.GivenControl(np.asarray(cm.vertices),
                                                       np.asarray(cm.faces)))
    assert rig.control_mesh.outer.shape == cm.outer.shape
    targets = drag(rig, [[30.0, 0.0], [0, 0], [0, 0], [0, 0], [0, 0]])
    np.testing.assert_allclose(rig.deform(targets), horse_rig32.deform(targets), **ROUNDING)


@pytest.mark.float64
def test_options_as_objects_build_what_the_old_spellings_do(horse, horse_rig):
    cm = horse_rig.control_mesh
    handles = datasets.horse_handles()
    weights = horse_rig.energy.weights  # the paper's
    given = mvcjax.Rig.build(horse, handles, dtype=jnp.float64, weights=weights,
                             control=mvcjax.GivenControl(cm.vertices, cm.faces),
                             factor=mvcjax.advanced.SparseLU())
    assert isinstance(given.factor, mvcjax.advanced.SparseFactor)
    paper = mvcjax.Rig.build(horse, handles, dtype=jnp.float64, control=mvcjax.PaperControl(),
                             factor=mvcjax.advanced.DenseG(),
                             skinning=mvcjax.advanced.BlendedMVCSkinning(),
                             weights=weights)
    targets = drag(horse_rig, [[30.0, 0.0], [0, 0], [0, 0], [0, 0], [0, 0]])
    for rig in (given, paper):
        np.testing.assert_allclose(rig.deform(targets), horse_rig.deform(targets), atol=1e-8)
    coarse = mvcjax.Rig.build(horse, handles, control=mvcjax.PaperControl(spacing=40.0))
    assert coarse.control_mesh.vertices.shape[0] < cm.vertices.shape[0]
    # FactorBySize decides by the control mesh's size.
    small = mvcjax.Rig.build(horse, handles, factor=mvcjax.advanced.FactorBySize(max_dense=50))
    assert isinstance(small.factor, mvcjax.advanced.SparseFactor)
    with pytest.raises(TypeError, match="factor must be a factor object"):
        mvcjax.Rig.build(horse, handles, factor="lu")


@pytest.mark.parametrize("option, spelling, fix", [
    ("control", "shape", "mvcjax.FullSolve()"),
    ("control", None, "mvcjax.PaperControl()"),
    ("control", mvcjax.FullSolve, "mvcjax.FullSolve()"),
    ("factor", "sparse", "mvcjax.advanced.SparseLU()"),
    ("factor", "dense", "mvcjax.advanced.DenseG()"),
    ("factor", None, "mvcjax.advanced.FactorBySize()"),
    ("skinning", "blended", "mvcjax.advanced.BlendedMVCSkinning()"),
    ("skinning", "mvc", "mvcjax.advanced.MVCSkinning()"),
    ("skinning", mvcjax.advanced.BarycentricSkinning, "mvcjax.advanced.BarycentricSkinning()"),
])
def test_older_spellings_are_refused_with_the_object_to_write(horse, option, spelling, fix):
    with pytest.raises(TypeError, match=rf"{option} must be .*; write {option}={re.escape(fix)}"):
        mvcjax.Rig.build(horse, datasets.horse_handles(), **{option: spelling})
    for removed in ("control_spacing", "margin"):
        with pytest.raises(TypeError, match=rf"{removed}= was removed; write "
                                            r"control=mvcjax\.PaperControl\(spacing="):
            mvcjax.Rig.build(horse, datasets.horse_handles(), **{removed: 40.0})


def test_bad_handles_and_targets_are_explained(horse, horse_rig32):
    with pytest.raises(ValueError, match=r"handles\[1\].*outside the shape.*closest point"):
        mvcjax.Rig.build(horse, [[100.0, 200.0], [5.0, 5.0]])
    with pytest.raises(ValueError, match="same spot"):
        mvcjax.Rig.build(horse, [[100.0, 200.0], [100.0, 200.0]])
    with pytest.raises(ValueError, match=r"shape \(h, 2\)"):
        mvcjax.Rig.build(horse, np.zeros((0, 2)))
    with pytest.raises(ValueError, match=r"targets must have shape \(5, 2\)"):
        horse_rig32.deform(jnp.zeros((4, 2)))
    with pytest.raises(ValueError, match="NaN or infinite"):
        horse_rig32.deform(horse_rig32.handle_positions.at[0, 0].set(jnp.nan))
    with pytest.raises(ValueError, match="finite number >= 0"):
        mvcjax.Weights(length=-1.0)
    with pytest.raises(ValueError, match="positive weight"):
        mvcjax.Weights(handle=0.0)
    with pytest.raises(TypeError, match="mvcjax.Shape"):
        mvcjax.Rig.build(np.zeros((3, 2)), [[0.0, 0.0]])
    with pytest.raises(ValueError, match="positive length"):
        mvcjax.Rig.build(horse, datasets.horse_handles(), shape_spacing=-1.0)
    with pytest.raises(ValueError, match="not a vertex of the given control mesh"):
        cm = horse_rig32.control_mesh
        mvcjax.Rig.build(horse, [[101.0, 200.0]],
                         control=mvcjax.GivenControl(np.asarray(cm.vertices),
                                                     np.asarray(cm.faces)))
