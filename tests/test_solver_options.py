"""Solver options and weights: refused when they make no sense, and convergence that means
convergence (regressions of reported false convergence)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mvcjax
from mvcjax import datasets

from conftest import directional_derivatives

LEAST_SQUARES = [mvcjax.GaussNewton, mvcjax.LevenbergMarquardt, mvcjax.Dogleg]


@pytest.fixture(scope="module")
def stick():
    return datasets.model("stick").rig(dtype=jnp.float64)


@pytest.fixture(scope="module")
def stick_targets(stick):
    return stick.handle_positions + jnp.asarray(datasets.stick_drag())


@pytest.mark.parametrize("solver", LEAST_SQUARES, ids=lambda s: s.__name__)
@pytest.mark.parametrize("kwargs, error, message", [
    (dict(rtol=-1.0), ValueError, "finite number >= 0"),
    (dict(atol=float("nan")), ValueError, "finite number >= 0"),
    (dict(rtol="tight"), TypeError, "a tolerance is a number"),
    (dict(max_steps=-1), ValueError, "at least 1"),
    (dict(max_steps=10.0), TypeError, "whole number"),
    (dict(cg_steps=0), ValueError, "at least 1"),
    (dict(cg_rtol=float("nan")), ValueError, "relative decrease"),
])
def test_least_squares_options_are_checked(solver, kwargs, error, message):
    with pytest.raises(error, match=message):
        solver(**kwargs)


@pytest.mark.parametrize("kwargs, error, message", [
    (dict(iterations=2.0), TypeError, r"FixedG\(iterations=2.0\): a whole number"),
    (dict(iterations=0), ValueError, "at least 1"),
    (dict(iterations=True), TypeError, "whole number"),
    (dict(anderson=-1), ValueError, "at least 0"),
    (dict(rtol=float("nan")), ValueError, "finite number"),
])
def test_fixed_g_options_are_checked(kwargs, error, message):
    with pytest.raises(error, match=message):
        mvcjax.FixedG(**kwargs)


@pytest.mark.parametrize("solver", [mvcjax.JaxoptGaussNewton, mvcjax.JaxoptLevenbergMarquardt])
def test_jaxopt_options_are_checked(solver):
    with pytest.raises(ValueError, match="finite number >= 0"):
        solver(tol=-1.0)
    with pytest.raises(ValueError, match="at least 1"):
        solver(max_steps=0)


@pytest.mark.parametrize("kwargs, message", [
    (dict(laplacian=0.0, mvc=0.0, length=0.0), "at least one shape term"),
    (dict(handle=1e-30), "ratio"),
    (dict(length=1e20), "ratio"),
    (dict(handle=1e30), "ratio"),
    (dict(mvc=float("inf")), "finite number"),
])
def test_degenerate_weights_are_refused(kwargs, message):
    # Each gave NaN (or "Factor is exactly singular") before.
    with pytest.raises(ValueError, match=message):
        mvcjax.Weights(**kwargs)


def test_weights_of_any_overall_scale_solve_alike(stick, stick_targets):
    # At 1e-30 everywhere optimistix stopped after one step and reported convergence:
    # its absolute tolerance saw residuals scaled by 1e-15.
    tiny = mvcjax.Weights(1e-30, 1e-30, 1e-30, 1e-28)
    for solver in [mvcjax.GaussNewton(), mvcjax.FixedG(iterations=50)]:
        plain, info = stick.solve(stick_targets, solver, return_info=True)
        scaled, scaled_info = stick.with_weights(tiny).solve(stick_targets, solver,
                                                             return_info=True)
        assert bool(scaled_info.converged) == bool(info.converged)
        np.testing.assert_allclose(scaled, plain, atol=1e-9 * float(stick.frame.scale))
        assert float(scaled_info.energy) == pytest.approx(1e-30 * float(info.energy), rel=1e-9)


@pytest.mark.parametrize("solver", LEAST_SQUARES, ids=lambda s: s.__name__)
def test_negative_tolerances_no_longer_fake_convergence(solver, stick, stick_targets):
    # GaussNewton(rtol=-1, atol=-1) reported converged after one step at energy 5000.
    good, info = stick.solve(stick_targets, solver(), return_info=True)
    assert bool(info.converged)
    zero = solver(rtol=0.0, atol=0.0, max_steps=5)
    _, info = stick.solve(stick_targets, zero, return_info=True)
    assert not bool(info.converged)


def test_an_infinite_energy_is_not_converged(stick):
    targets = np.asarray(stick.handle_positions).copy()
    targets[0] = 1e200
    for solver in [mvcjax.FixedG(), mvcjax.GaussNewton()]:
        _, info = stick.solve(targets, solver, return_info=True)
        assert not bool(info.converged) or np.isfinite(float(info.energy))


def test_gradient_through_a_solve_that_stops_early(stick, stick_targets):
    # jax.grad through FixedG(stop_early=True) failed with JAX's while-loop error.
    solver = mvcjax.FixedG(iterations=20000, rtol=1e-9, stop_early=True)

    def loss(t):
        return jnp.sum(stick.deform(t, solver)[::7] ** 2)

    _, info = stick.solve(stick_targets, solver, return_info=True)
    assert bool(info.converged) and int(info.iterations) < 20000
    exact, approx = directional_derivatives(jax.jit(loss), stick_targets, h=1e-6)
    assert exact == pytest.approx(approx, rel=1e-5)
