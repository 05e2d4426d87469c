"""Solver options and weights: refused when they make no sense, and convergence that means
convergence (regressions of reported false convergence)."""

import re

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
import pytest

import mvcjax
from mvcjax import datasets

from conftest import directional_derivatives

# Tests that compare with references to many digits, or the solvers' internals, are
# marked float64; the others run in float32, as users do.

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
    (dict(rtol="tight"), TypeError, "finite number >= 0.*got str"),
    (dict(max_steps=-1), ValueError, "at least 1"),
    (dict(max_steps=10.0), TypeError, "whole number"),
    (dict(linear_solver="cg"), TypeError, r"linear_solver=mvcjax.advanced.StructuredCG\(\)"),
    (dict(linear_solver="cholesky"), TypeError, r"linear_solver=lx.Cholesky\(\)"),
    (dict(linear_solver=3), TypeError, "or a lineax solver"),
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


@pytest.mark.parametrize("solver", [*LEAST_SQUARES, mvcjax.FoldFree], ids=lambda s: s.__name__)
@pytest.mark.parametrize("key", ["steps", "rtol", "deflate"])
def test_removed_cg_keywords_say_what_to_write(solver, key):
    fix = rf"write linear_solver=mvcjax\.advanced\.StructuredCG\({key}="
    removed = rf"{solver.__name__}\(\.\.\.\): cg_{key}= was removed"
    with pytest.raises(TypeError, match=f"{removed}; {fix}"):
        solver(**{f"cg_{key}": 1})


@pytest.mark.parametrize("spelling, fix", [
    ("JaxoptGaussNewton", "mvcjax.advanced.JaxoptGaussNewton()"),
    (mvcjax.advanced.JaxoptLevenbergMarquardt, "mvcjax.advanced.JaxoptLevenbergMarquardt()"),
    ("FoldFree", "mvcjax.FoldFree()"),
    ("newton", "mvcjax.GaussNewton()"),
])
@pytest.mark.float64
def test_a_solver_named_as_a_string_or_class_is_answered_where_it_lives(stick, spelling, fix):
    with pytest.raises(TypeError, match=rf"write solver={re.escape(fix)}"):
        stick.deform(stick.handle_positions, solver=spelling)


@pytest.mark.parametrize("solver", [mvcjax.advanced.JaxoptGaussNewton,
                                    mvcjax.advanced.JaxoptLevenbergMarquardt])
def test_jaxopt_options_are_checked(solver):
    with pytest.raises(ValueError, match="finite number >= 0"):
        solver(tol=-1.0)
    with pytest.raises(ValueError, match="at least 1"):
        solver(max_steps=0)


@pytest.mark.parametrize("kwargs, message", [
    (dict(laplacian=None, arap=None), "corners that no edge-length row reaches"),
    (dict(handle=1e-30), "ratio"),
    (dict(length=1e20), "ratio"),
    (dict(handle=1e30), "ratio"),
    (dict(mvc=float("inf")), "finite number"),
])
def test_degenerate_weights_are_refused(kwargs, message):
    # Each gave NaN (or "Factor is exactly singular") before.
    with pytest.raises(ValueError, match=message):
        mvcjax.Weights(**kwargs)


@pytest.mark.float64
def test_a_rig_refuses_weights_that_hold_nothing_but_the_handles(stick):
    with pytest.raises(ValueError, match="at least one shape term"):
        datasets.model("stick").rig(weights=mvcjax.Weights(0.0, 0.0, 0.0, arap=None))
    with pytest.raises(ValueError, match="at least one shape term"):
        stick.with_weights(mvcjax.Weights(0.0, 0.0, 0.0, arap=None))


@pytest.mark.parametrize("tiny", [mvcjax.Weights(mvc=1e-34, handle=1e-28, arap=1e-30),
                                  mvcjax.Weights(1e-30, 1e-30, 1e-30, 1e-28, arap=None)],
                         ids=["default", "paper"])
@pytest.mark.float64
def test_weights_of_any_overall_scale_solve_alike(stick, stick_targets, tiny):
    # At 1e-30 everywhere optimistix stopped after one step and reported convergence:
    # its absolute tolerance saw residuals scaled by 1e-15.
    stick = stick.with_weights(jax.tree.map(lambda w: w * 1e30, tiny))
    for solver in [mvcjax.GaussNewton(), mvcjax.FixedG(iterations=50)]:
        plain, info = stick.solve(stick_targets, solver, return_info=True)
        scaled, scaled_info = stick.with_weights(tiny).solve(stick_targets, solver,
                                                             return_info=True)
        assert bool(scaled_info.converged) == bool(info.converged)
        np.testing.assert_allclose(scaled, plain, atol=1e-9 * float(stick.frame.scale))
        assert float(scaled_info.energy) == pytest.approx(1e-30 * float(info.energy), rel=1e-9)


@pytest.mark.float64
@pytest.mark.parametrize("solver", LEAST_SQUARES, ids=lambda s: s.__name__)
def test_negative_tolerances_no_longer_fake_convergence(solver, stick, stick_targets):
    # Negative tolerances must not let GaussNewton report convergence after one step.
    _good, info = stick.solve(stick_targets, solver(), return_info=True)
    assert bool(info.converged)
    zero = solver(rtol=0.0, atol=0.0, max_steps=5)
    _, info = stick.solve(stick_targets, zero, return_info=True)
    assert not bool(info.converged)


@pytest.mark.float64
def test_an_infinite_energy_is_not_converged(stick):
    targets = np.asarray(stick.handle_positions).copy()
    targets[0] = 1e200
    for solver in [mvcjax.FixedG(), mvcjax.GaussNewton()]:
        _, info = stick.solve(targets, solver, return_info=True)
        assert not bool(info.converged) or np.isfinite(float(info.energy))


@pytest.mark.float64
def test_gradient_through_a_solve_that_stops_early(stick, stick_targets):
    # jax.grad through FixedG(stop_early=True) failed with JAX's while-loop error.
    solver = mvcjax.FixedG(iterations=20000, rtol=1e-9, stop_early=True)

    def loss(t):
        return jnp.sum(stick.deform(t, solver)[::7] ** 2)

    _, info = stick.solve(stick_targets, solver, return_info=True)
    assert bool(info.converged) and int(info.iterations) < 20000
    exact, approx = directional_derivatives(loss, stick_targets, h=1e-6)
    assert exact == pytest.approx(approx, rel=1e-5)


def test_option_errors_name_the_solver_the_option_and_the_fix():
    with pytest.raises(ValueError) as error:
        mvcjax.GaussNewton(rtol=-1)
    assert str(error.value) == (
        "GaussNewton(rtol=-1): a tolerance must be a finite number >= 0 (or None for the "
        "default 1e-10 in float64, 1e-5 in float32).")
    with pytest.raises(TypeError, match=r"FixedG\(iterations=2.0\).*got float; write e.g. "
                                        r"iterations=2\."):
        mvcjax.FixedG(iterations=2.0)
    mvcjax.FixedG(iterations=np.int64(3), unroll=0, anderson=np.int32(0))  # numpy ints pass
    mvcjax.GaussNewton(rtol=0, atol=np.float32(1e-6))


@pytest.mark.parametrize("make, error, message", [
    (lambda: mvcjax.FixedG(unroll=-1), ValueError, r"FixedG\(unroll=-1\): needs at least 0"),
    (lambda: mvcjax.FixedG(regularisation=-1e-3), ValueError, "regularisation"),
    (lambda: mvcjax.advanced.StructuredCG(rtol="loose"), TypeError,
     r"StructuredCG\(rtol='loose'\)"),
    (lambda: mvcjax.advanced.StructuredCG(steps=4.0), TypeError, "steps"),
    (lambda: mvcjax.advanced.StructuredCG(steps=0), ValueError, "at least 1"),
    (lambda: mvcjax.advanced.StructuredCG(rtol=1.0), ValueError, "relative decrease"),
    (lambda: mvcjax.FoldFree(linear_solver=lx.Cholesky()), TypeError, "StructuredCG"),
    (lambda: mvcjax.advanced.JaxoptGaussNewton(tol=float("inf")), ValueError, "finite number"),
    (lambda: mvcjax.advanced.JaxoptLevenbergMarquardt(max_steps=False), TypeError, "whole number"),
    (lambda: mvcjax.FixedG().fixed_steps(2.5), TypeError, r"fixed_steps\(2.5\)"),
    (lambda: mvcjax.GaussNewton().fixed_steps(0), ValueError, "at least 1 step"),
])
def test_more_options_are_checked(make, error, message):
    with pytest.raises(error, match=message):
        make()


def test_weights_out_of_float32_range_are_refused():
    with pytest.raises(ValueError, match=r"outside \[1e-36, 1e\+36\]"):
        mvcjax.Weights(1e-40, 1e-40, 1e-40, 1e-39)
    with pytest.raises(ValueError,
                       match=r"1.0e\+30 times Weights\(handle=1e-30\).*1e-08 to 1e\+08"):
        mvcjax.Weights(handle=1e-30)
    mvcjax.Weights(laplacian=0.0, mvc=0.0, length=1.0, handle=1e8)  # zeros are not ratios


def test_check_weights_says_how_to_write_weights():
    from mvcjax.energy import check_weights

    weights = mvcjax.Weights(handle=10.0)
    assert check_weights(weights) is weights
    expected = "weights must be an mvcjax.Weights, got dict; write mvcjax.Weights(**{'handle': 10})"
    with pytest.raises(TypeError, match=re.escape(expected)):
        check_weights({"handle": 10})
    with pytest.raises(TypeError, match="rig_weights must be an mvcjax.Weights, got str"):
        check_weights("stiff", name="rig_weights")


@pytest.mark.parametrize("solver", [
    mvcjax.FixedG(), mvcjax.FixedG(stop_early=True, iterations=50),
    mvcjax.FixedG(stop_early=True, iterations=50, adjoint=optx.ImplicitAdjoint()),
    mvcjax.FixedG(anderson=3), mvcjax.GaussNewton(), mvcjax.Dogleg(),
    mvcjax.advanced.JaxoptGaussNewton(),
], ids=repr)
def test_an_overflowing_energy_is_not_converged(solver):
    # A float32 target at 1e20 (in the rig's frame) met the step tolerances at once,
    # and was reported converged with energy inf.
    rig = datasets.model("stick").rig(dtype=jnp.float32)
    targets = np.asarray(rig.frame.to_local(rig.handle_positions)).copy()
    targets[0] = 1e20
    _, info = solver.solve(rig.energy, rig.factor, jnp.asarray(targets), rig.energy.rest)
    assert not np.isfinite(float(info.energy))
    assert not bool(info.converged)


def test_rescaled_info_keeps_convergence_where_its_energy_overflows():
    info = mvcjax.advanced.SolveInfo(converged=jnp.asarray(True), iterations=jnp.asarray(3),
                                     energy=jnp.asarray(1e30, jnp.float32))
    assert float(info.rescaled(10.0).energy) == pytest.approx(1e32, rel=1e-6)
    huge = info.rescaled(jnp.float32(1e10))  # 1e50: past float32's range
    assert bool(huge.converged) and float(huge.energy) == np.inf
    rest = mvcjax.advanced.SolveInfo(converged=jnp.asarray(True), iterations=jnp.asarray(3),
                                     energy=jnp.asarray(0.0, jnp.float32))
    assert float(rest.rescaled(jnp.float32(1e20)).energy) == 0.0  # not 0 * inf


@pytest.mark.parametrize("size", [1e-20, 1e20])
def test_float32_shapes_at_the_ends_of_the_size_range_converge(size):
    # At 1e20 the energy in the user's units was 0 * inf at rest: NaN, "not converged".
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]) * size
    rig = mvcjax.Rig.build(mvcjax.Shape.from_polygon(square),
                           square[[0, 2]] * 0.9 + 0.05 * size, dtype=jnp.float32)
    for solver in (mvcjax.GaussNewton(), mvcjax.FoldFree()):
        _, info = rig.deform(rig.handle_positions, solver, return_info=True)
        assert bool(info.converged) and 0 <= float(info.energy) < 1e-6 * size**2
        posed = rig.handle_positions.at[1].add(0.2 * size)
        _, info = rig.deform(posed, solver, return_info=True)
        assert bool(info.converged) and np.isfinite(float(info.energy))


@pytest.mark.float64
def test_stopping_early_leaves_the_primal_unchanged(stick, stick_targets):
    early = mvcjax.FixedG(iterations=5000, rtol=1e-7, stop_early=True)
    vertices, info = stick.solve(stick_targets, early, return_info=True)
    steps = int(info.iterations)
    assert bool(info.converged) and 1 < steps < 5000
    fixed, fixed_info = stick.solve(stick_targets, mvcjax.FixedG(iterations=steps, unroll=0),
                                    return_info=True)
    np.testing.assert_array_equal(vertices, fixed)
    assert float(info.energy) == float(fixed_info.energy)


@pytest.mark.float64
def test_forward_mode_through_a_solve_that_stops_early(stick, stick_targets):
    # The checkpointed loop that reverse mode needs refuses forward mode; the implicit
    # adjoint, which the docstring names for it, supports both.
    def loss(solver, t):
        return jnp.sum(stick.deform(t, solver)[::7] ** 2)

    d = jnp.ones_like(stick_targets)
    unrolled = mvcjax.FixedG(iterations=20000, rtol=1e-9, stop_early=True)
    with pytest.raises(TypeError, match="forward-mode"):
        jax.jvp(lambda t: loss(unrolled, t), (stick_targets,), (d,))
    implicit = mvcjax.FixedG(iterations=20000, rtol=1e-12, stop_early=True, anderson=5,
                             adjoint=optx.ImplicitAdjoint())
    of_targets = jax.jit(lambda t: loss(implicit, t))  # not one program per operation
    _, tangent = jax.jit(lambda t: jax.jvp(of_targets, (t,), (d,)))(stick_targets)
    h = 1e-3  # each solve stops within its tolerance of the minimum: no smaller steps
    up, down = of_targets(stick_targets + h * d), of_targets(stick_targets - h * d)
    approx = (up - down) / (2 * h)
    assert float(tangent) == pytest.approx(float(approx), rel=1e-5)
