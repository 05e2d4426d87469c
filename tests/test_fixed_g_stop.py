"""FixedG's stopping test bounds the distance to the fixed point: the iteration contracts
slowly on the horse, so a small last step is still far from the
minimum, and gradients taken there (implicitly, as at a minimum) are off."""

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

import mvcjax
from mvcjax import datasets

from conftest import drag

# Agreement with references to many digits, and the solvers' internals: in float64.
pytestmark = pytest.mark.float64

# Deep enough that its own distance to the minimum (1e-11 of the diagonal) is far below
# anything the tests compare.
REFERENCE = mvcjax.FixedG(iterations=5000, rtol=1e-11, stop_early=True, anderson=5)

PLAIN_AND_ANDERSON = [pytest.param(5, id="anderson"),
                      pytest.param(0, id="plain", marks=pytest.mark.slow)]


@pytest.fixture(scope="module")
def dragged(horse_rig):
    """Targets for the demo's drag scaled to a largest move of 40 units, a scalar of the
    deformed shape, and its gradient by central differences of the reference solve."""
    offsets = datasets.horse_drag()
    targets = drag(horse_rig, offsets * 40.0 / np.linalg.norm(offsets, axis=1).max())
    weights = jax.random.normal(jax.random.key(1), horse_rig.shape_mesh.vertices.shape,
                                targets.dtype)

    def loss(solver, t):
        return jnp.sum(weights * horse_rig.deform(t, solver))

    reference = jax.jit(lambda t: loss(REFERENCE, t))
    h = 1e-2  # in the horse's units (diagonal 480): small against the shape
    steps = h * jnp.eye(targets.size, dtype=targets.dtype).reshape(-1, *targets.shape)
    fd = np.array([(float(reference(targets + e)) - float(reference(targets - e))) / (2 * h)
                   for e in steps]).reshape(targets.shape)
    return targets, loss, fd


@pytest.mark.parametrize("anderson", PLAIN_AND_ANDERSON)
def test_converged_implicit_gradients_match_finite_differences(horse_rig, dragged, anderson):
    # At the default rtol: a test on the step size alone would stop far enough from the
    # minimum for these gradients to miss the tolerance.
    targets, loss, fd = dragged
    solver = mvcjax.FixedG(iterations=20000, stop_early=True, adjoint=optx.ImplicitAdjoint(),
                           anderson=anderson)
    _, info = horse_rig.solve(targets, solver, return_info=True)
    assert bool(info.converged), int(info.iterations)
    grad = np.asarray(jax.jit(jax.grad(lambda t: loss(solver, t)))(targets))
    error = np.abs(grad - fd).max() / np.abs(fd).max()
    assert error < 1e-4, error


@pytest.mark.parametrize("anderson", PLAIN_AND_ANDERSON)
@pytest.mark.parametrize("rtol", [1e-6, pytest.param(1e-8, marks=pytest.mark.slow)])
def test_converged_vertices_are_within_rtol_of_the_fixed_point(horse, horse_rig, dragged,
                                                               anderson, rtol):
    targets, _, _ = dragged
    solver = mvcjax.FixedG(iterations=20000, rtol=rtol, stop_early=True, anderson=anderson)
    vertices, info = horse_rig.solve(targets, solver, return_info=True)
    assert bool(info.converged), int(info.iterations)
    fixed_point = horse_rig.solve(targets, REFERENCE)
    distance = float(jnp.abs(vertices - fixed_point).max()) / horse.diagonal
    # The estimate is an estimate: within a small factor.
    assert distance < 2 * rtol, distance


def test_a_small_last_step_is_not_convergence(horse_rig, dragged):
    # 3000 plain steps bring the last step below 1e-6 of the diagonal (a test on the
    # step size alone would stop there), but the vertices are still far from the minimum.
    targets, _, _ = dragged
    for solver in [mvcjax.FixedG(iterations=3000, stop_early=True),
                   mvcjax.FixedG(iterations=3000)]:
        _, info = horse_rig.solve(targets, solver, return_info=True)
        assert not bool(info.converged), solver
        assert int(info.iterations) == 3000, solver


def test_frames_report_convergence_as_single_solves_do(horse_rig):
    # Under jax.vmap the plain iteration measures its stopping test over its last steps
    # only; it reports what the unbatched loop does, frame by frame.
    offsets = datasets.horse_drag()
    scales = jnp.asarray([0.0, 1e-3, 0.3, 1.0])[:, None, None]
    targets = horse_rig.handle_positions + scales * offsets
    local = jax.vmap(horse_rig._pinned)(targets)
    starts = jax.vmap(lambda t: horse_rig.frame.to_local(horse_rig.start(t)))(targets)
    for iterations in (5, 33, 3000):  # the window holds the first step, or not
        solver = mvcjax.FixedG(iterations=iterations, unroll=0)
        batched = jax.jit(jax.vmap(solver.solve, (None, None, 0, 0)))
        looped = jax.jit(jax.vmap(solver._iterate, (None, None, 0, 0)))
        (_, fast), (_, plain) = [f(horse_rig.energy, horse_rig.factor, local, starts)
                                 for f in (batched, looped)]
        np.testing.assert_array_equal(fast.converged, plain.converged, err_msg=str(iterations))
    assert list(np.asarray(fast.converged)) == [True, True, False, False]
