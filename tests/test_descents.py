"""The structured descents against optimistix's own with a dense Cholesky linear solve."""

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
import pytest

import mvcjax
from mvcjax.solvers._descents import (
    DoglegDescent,
    StructuredDampedNewtonDescent,
    StructuredDoglegDescent,
    StructuredNewtonDescent,
)
from mvcjax.solvers._least_squares import ScaledProblem

from conftest import local_point

# Agreement with references to many digits, and the solvers' internals: in float64.
pytestmark = pytest.mark.float64

CHOLESKY = lx.Normal(lx.Cholesky())
# CG to convergence (a looped budget), so that the steps are exact and comparable.
EXACT = {"cg_steps": 2000, "cg_rtol": 1e-13}
PAIRS = {
    "newton": (StructuredNewtonDescent, optx.NewtonDescent(linear_solver=CHOLESKY)),
    "damped_newton": (StructuredDampedNewtonDescent,
                      optx.DampedNewtonDescent(linear_solver=CHOLESKY)),
    "dogleg": (StructuredDoglegDescent, DoglegDescent(linear_solver=CHOLESKY)),
}


@pytest.fixture(scope="module")
def point(horse_rig):
    # A dragged, perturbed point, and optimistix's view of it (residuals and Jacobian).
    targets, start = local_point(horse_rig, [[60.0, -10.0]] + [[0.0, 0.0]] * 4, 1e-3, seed=5)
    problem = ScaledProblem(horse_rig.energy, targets)
    y = problem.scaled(start)
    return horse_rig, problem, y, autodiff_info(problem, y)


def autodiff_info(problem, y):
    """Optimistix's view of the residuals at `y`: a `jax.linearize`."""
    r, linear = jax.linearize(problem.residuals, y)
    jac = lx.FunctionLinearOperator(linear, jax.eval_shape(lambda: y))
    return optx.FunctionInfo.ResidualJac(r, jac)


@pytest.mark.parametrize("step_size", [10.0, 1.0, 0.3, 1e-3])
@pytest.mark.parametrize("name", list(PAIRS))
def test_structured_descent_steps_are_optimistix_steps(point, name, step_size):
    # Given optimistix's view of the point, the step of optimistix's own descent.
    rig, problem, y, f_info = point
    structured, reference = PAIRS[name]
    ours = structured(problem, rig.factor.normal_operator(), rig.factor.normal_inverse_operator(),
                      **EXACT)

    def step(descent, f_info):
        state = descent.query(y, f_info, descent.init(y, eqx.filter_eval_shape(lambda: f_info)))
        return descent.step(jnp.asarray(step_size), state)

    (mine, result), (expected, expected_result) = step(ours, f_info), step(reference, f_info)
    assert result == optx.RESULTS.successful and expected_result == optx.RESULTS.successful
    scale = float(jnp.abs(expected).max())
    assert scale > 0
    np.testing.assert_allclose(mine, expected, rtol=1e-7, atol=1e-8 * scale)


def test_structured_descents_keep_float32(horse, point):
    # In float32 (with jax_enable_x64 on) every state and step stays float32.
    rig32 = mvcjax.Rig.build(horse, mvcjax.datasets.horse_handles(), dtype=jnp.float32)
    targets, start = local_point(rig32, [[60.0, -10.0]] + [[0.0, 0.0]] * 4)
    problem = ScaledProblem(rig32.energy, targets)
    y = problem.scaled(start)
    f_info = autodiff_info(problem, y)
    for structured, _ in PAIRS.values():
        descent = structured(problem, rig32.factor.normal_operator(),
                             rig32.factor.normal_inverse_operator(), cg_steps=8, cg_rtol=1e-2)
        state = descent.query(y, f_info, descent.init(y, eqx.filter_eval_shape(lambda: f_info)))
        assert {leaf.dtype for leaf in jax.tree.leaves(state)
                if jnp.issubdtype(leaf.dtype, jnp.floating)} == {jnp.dtype(jnp.float32)}
        step, _ = descent.step(jnp.asarray(0.5), state)
        assert step.dtype == jnp.float32
