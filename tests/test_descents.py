"""The structured descents against optimistix's own with a dense Cholesky linear solve."""

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
import pytest

import mvcjax
from mvcjax._solvers._descents import (
    DoglegDescent,
    StructuredDampedNewtonDescent,
    StructuredDoglegDescent,
    StructuredNewtonDescent,
)
from mvcjax._solvers._least_squares import ScaledProblem, StructuredJacobian
from mvcjax._solvers._optimistix import _GaussNewtonFamily

from conftest import local_point

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


def structured_info(problem, y):
    """The structured loop's view: the closed-form linearisation."""
    at = problem.linearise(y)
    return optx.FunctionInfo.ResidualJac(at.residual, StructuredJacobian(problem, at))


@pytest.mark.parametrize("info", [autodiff_info, structured_info])
@pytest.mark.parametrize("step_size", [10.0, 1.0, 0.3, 1e-3])
@pytest.mark.parametrize("name", list(PAIRS))
def test_structured_descent_steps_are_optimistix_steps(point, name, step_size, info):
    # Given either linearisation (optimistix's loop or the structured one), the same step.
    rig, problem, y, f_info = point
    structured, reference = PAIRS[name]
    ours = structured(problem, rig.factor.normal_operator(), rig.factor.normal_inverse_operator(),
                      **EXACT)

    def step(descent, f_info):
        state = descent.query(y, f_info, descent.init(y, eqx.filter_eval_shape(lambda: f_info)))
        return descent.step(jnp.asarray(step_size), state)

    (mine, result), (expected, expected_result) = step(ours, info(problem, y)), step(reference,
                                                                                     f_info)
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
    f_info = structured_info(problem, y)
    for structured, _ in PAIRS.values():
        descent = structured(problem, rig32.factor.normal_operator(),
                             rig32.factor.normal_inverse_operator(), cg_steps=8, cg_rtol=1e-2)
        state = descent.query(y, f_info, descent.init(y, eqx.filter_eval_shape(lambda: f_info)))
        assert {leaf.dtype for leaf in jax.tree.leaves(state)
                if jnp.issubdtype(leaf.dtype, jnp.floating)} == {jnp.dtype(jnp.float32)}
        step, _ = descent.step(jnp.asarray(0.5), state)
        assert step.dtype == jnp.float32


@pytest.mark.parametrize("solver", [mvcjax.GaussNewton(), mvcjax.Dogleg(),
                                    mvcjax.LevenbergMarquardt()], ids=lambda s: type(s).__name__)
def test_structured_loop_is_optimistix_gauss_newton_loop(horse_rig, solver):
    # The structured loop (closed-form linearisation, point data carried) against
    # optimistix's own `AbstractGaussNewton` loop with the same descent and search: the
    # same iterates, accepted and rejected steps, and stopping step.
    targets, start = local_point(horse_rig, [[60.0, -10.0]] + [[0.0, 0.0]] * 4)
    problem = ScaledProblem(horse_rig.energy, targets)
    y0 = problem.scaled(start)
    structured = solver._configured(problem, horse_rig.factor, y0.dtype)
    stock = _GaussNewtonFamily(rtol=structured.rtol, atol=structured.atol,
                               descent=structured.descent, search=structured.search)

    @jax.jit
    def run(y0):
        out = {}
        for name, loop in [("structured", structured), ("optimistix", stock)]:
            for steps in (5, 20, 256):
                sol = optx.least_squares(lambda y, args: problem.residuals(y), loop, y0,
                                         max_steps=steps, throw=False)
                out[name, steps] = (sol.value, sol.stats["num_steps"], sol.result)
        return out

    out = run(y0)
    for steps in (5, 20, 256):
        (y, count, result), (y_ref, count_ref, result_ref) = (out["structured", steps],
                                                              out["optimistix", steps])
        assert int(count) == int(count_ref)
        assert (result == optx.RESULTS.successful) == (result_ref == optx.RESULTS.successful)
        np.testing.assert_allclose(y, y_ref, rtol=0, atol=1e-9)
    assert out["structured", 256][2] == optx.RESULTS.successful  # it converged
