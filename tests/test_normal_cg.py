"""Preconditioned conjugate gradients and the Gauss-Newton linear solve built on them."""

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import pytest

import mvcjax
from mvcjax._solvers import _normal_cg
from mvcjax._solvers._normal_cg import NormalCG, conjugate_gradient

from conftest import drag


def test_conjugate_gradient_solves_a_positive_definite_system():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(30, 30))
    matrix = jnp.asarray(a @ a.T + 0.1 * np.eye(30))
    b = jnp.asarray(rng.normal(size=(30, 2)))
    jacobi = 1.0 / jnp.diag(matrix)
    x, steps = conjugate_gradient(lambda v: matrix @ v, b, lambda r: jacobi[:, None] * r,
                                  rtol=1e-12, max_steps=500)
    np.testing.assert_allclose(x, np.linalg.solve(matrix, b), rtol=1e-8, atol=1e-10)
    assert 0 < int(steps) <= 500


@pytest.mark.parametrize("case", ["stops early", "runs out", "zero curvature"])
def test_unrolled_and_looped_conjugate_gradients_agree(monkeypatch, case):
    # A short budget runs unrolled, with the stopping test as a mask; a long one loops.
    # With the same budget both stop at the same iteration with the same iterate.
    rng = np.random.default_rng(1)
    a = rng.normal(size=(40, 40))
    matrix = jnp.asarray(a @ a.T / 40 + np.diag(np.linspace(1.0, 3.0, 40)))
    b = jnp.asarray(rng.normal(size=(40,)))
    if case == "zero curvature":
        # The right-hand side lies in the null space: the first direction has none.
        matrix = matrix.at[:, :20].set(0.0).at[:20, :].set(0.0)
        b = b.at[20:].set(0.0)
    rtol = 1e-2 if case == "stops early" else 0.0

    def run():
        return conjugate_gradient(lambda v: matrix @ v, b, lambda r: r, rtol, 12)

    unrolled = run()
    monkeypatch.setattr(_normal_cg, "UNROLL_STEPS", 0)
    looped = run()
    assert int(unrolled[1]) == int(looped[1])
    if case == "stops early":
        assert 0 < int(unrolled[1]) < 12
    if case == "runs out":
        assert int(unrolled[1]) == 12
    if case == "zero curvature":
        assert np.all(np.asarray(unrolled[0]) == 0)
    assert np.all(np.isfinite(np.asarray(unrolled[0])))
    np.testing.assert_allclose(unrolled[0], looped[0], rtol=1e-12, atol=1e-14)


def test_conjugate_gradient_zero_right_hand_side_gives_zero_not_nan():
    x, steps = conjugate_gradient(lambda v: 2 * v, jnp.zeros((4, 2)), lambda r: r, 1e-8, 10)
    assert np.all(np.asarray(x) == 0) and int(steps) == 0


def test_conjugate_gradient_stops_on_zero_curvature():
    # A singular direction: the iteration stops instead of dividing by zero.
    matrix = jnp.diag(jnp.array([1.0, 0.0]))
    x, _ = conjugate_gradient(lambda v: matrix @ v, jnp.array([0.0, 1.0]), lambda r: r, 1e-8, 10)
    assert np.all(np.isfinite(np.asarray(x)))


def test_normal_cg_matches_the_dense_least_squares_step(horse_rig):
    # The Gauss-Newton step of the energy at a dragged start: CG run to a tight tolerance
    # gives the dense least-squares solution; its first iterate is along the fixed-G step.
    targets = drag(horse_rig, np.array([[60.0, 0.0]] + [[0.0, 0.0]] * 4))
    start = horse_rig.start(targets).T  # coordinate rows, the factor's layout

    def residual(columns):
        return mvcjax.residuals(horse_rig.energy, columns.T, targets)

    r, linear = jax.linearize(residual, start)
    operator = lx.FunctionLinearOperator(linear, jax.eval_shape(lambda: start))
    tight = NormalCG(horse_rig.factor, rtol=1e-13, max_steps=2000)
    step = lx.linear_solve(operator, r, tight).value
    dense = jax.jacfwd(residual)(start).reshape(r.size, -1)
    expected = np.linalg.lstsq(dense, r, rcond=None)[0].reshape(start.shape)
    np.testing.assert_allclose(step, expected, rtol=1e-7, atol=1e-7 * float(jnp.abs(expected).max()))

    one = lx.linear_solve(operator, r, NormalCG(horse_rig.factor, rtol=0.0, max_steps=1)).value
    fixed_g = start - horse_rig.factor.step(start, horse_rig.factor.handle_part(targets))
    cosine = jnp.sum(one * fixed_g) / (jnp.linalg.norm(one) * jnp.linalg.norm(fixed_g))
    assert float(cosine) == pytest.approx(1.0, abs=1e-10)


def test_structured_step_options_are_checked():
    with pytest.raises(ValueError, match="linear_solver"):
        mvcjax.GaussNewton(linear_solver="qr")
    with pytest.raises(ValueError, match="cg_steps"):
        mvcjax.Dogleg(cg_steps=0)
    with pytest.raises(ValueError, match="cg_rtol"):
        mvcjax.GaussNewton(cg_rtol=1.0)


def test_normal_cg_reports_a_step_it_could_not_take(horse_rig):
    # With a preconditioner that is not positive definite CG cannot leave zero: a
    # breakdown, not a zero step that the outer solver would take for convergence.
    targets = drag(horse_rig, np.array([[60.0, 0.0]] + [[0.0, 0.0]] * 4))
    start = horse_rig.start(targets).T
    r, linear = jax.linearize(lambda c: mvcjax.residuals(horse_rig.energy, c.T, targets), start)
    operator = lx.FunctionLinearOperator(linear, jax.eval_shape(lambda: start))
    factor = horse_rig.factor
    negated = eqx.tree_at(lambda f: f.normal_inverse, factor, -factor.normal_inverse)
    solution = lx.linear_solve(operator, r, NormalCG(negated, rtol=1e-3, max_steps=5),
                               throw=False)
    assert solution.result == lx.RESULTS.breakdown
