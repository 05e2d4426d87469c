"""jaxopt's least-squares solvers on the residuals of the energy (6).

jaxopt is no longer maintained and warns so on import; mvcjax imports it lazily, with that
one warning silenced, and pins the version it was tested with (0.8.5).

Differentiate through them as `jax.jit(jax.grad(f))`, not `jax.grad(jax.jit(f))`: the
latter makes jaxopt 0.8.5's implicit differentiation leak a tracer ("No constant handler
for type DynamicJaxprTracer"), an upstream bug that the other solvers do not have.
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp

from ._base import AbstractSolver, check_count, check_steps, check_tolerance, python_scalar
from ._least_squares import ScaledProblem, check_jacobian_fits


def _jaxopt():
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="JAXopt is no longer maintained",
                                category=DeprecationWarning)
        import jaxopt
    return jaxopt


class _JaxoptLeastSquares(AbstractSolver):
    """Shared plumbing: run a jaxopt solver on the scaled residuals, report the result.

    Attributes:
        tol: tolerance on jaxopt's error, the norm of the gradient of half the squared
            residuals in coordinates scaled to the unit diagonal (default 1e-8 in
            float64, 1e-4 in float32: a gradient, not a step, so about the square of
            the step tolerance of the optimistix solvers' scale).
        max_steps: the step budget; `converged` is false if it ran out first.

    Refused, naming the option (TypeError for a wrong type, ValueError for a bad
    value): `tol` other than None or a finite number >= 0, `max_steps` not a whole
    number >= 1.
    """

    _MODULE = "mvcjax.advanced"
    # Differentiated eagerly, the rig runs the solve op by op (mvcjax.core.compiled_by):
    # through a nested jit, jaxopt's implicit gradients would leak a tracer.
    inline_when_differentiated: ClassVar[bool] = True

    tol: float | None = eqx.field(default=None, static=True, converter=python_scalar)
    max_steps: int = eqx.field(default=256, static=True, converter=python_scalar)

    def __check_init__(self):
        check_tolerance(self, "tol", "1e-8 in float64, 1e-4 in float32")
        check_count(self, "max_steps")

    def _solver(self, residual_fun, tol: float):
        raise NotImplementedError

    def _configured(self, energy, init):
        check_jacobian_fits(energy, init.dtype, type(self).__name__)
        tol = (1e-8 if init.dtype.itemsize >= 8 else 1e-4) if self.tol is None else self.tol
        shape = init.T.shape  # the scaled problem's coordinate-major layout
        # Flat parameters: jaxopt's Levenberg-Marquardt materialises the Jacobian as a matrix.
        return self._solver(lambda x, p: p.residuals(x.reshape(shape)).reshape(-1), tol), tol

    def solve(self, energy, factor, targets, init):
        solver, tol = self._configured(energy, init)
        problem = ScaledProblem(energy, targets)
        # Gradients are implicit: jaxopt differentiates the optimality condition with
        # respect to the arguments of `run`, so the problem (targets, weights) is passed
        # there; closed over, it would leak tracers out of jaxopt's custom VJP.
        x, state = solver.run(problem.scaled(init).reshape(-1), problem)
        return problem.result(x.reshape(init.T.shape), state.error <= tol, state.iter_num)

    def fixed_steps(self, steps):
        return dataclasses.replace(self, max_steps=check_steps(self, steps), tol=0.0)

    def history(self, energy, factor, targets, init, steps):
        solver, _ = self._configured(energy, init)
        problem = ScaledProblem(energy, targets)
        x0 = problem.scaled(init).reshape(-1)

        def body(carry, _):
            x, state = solver.update(*carry, problem)
            return (x, state), problem.energy_at(x.reshape(init.T.shape))

        _, energies = jax.lax.scan(body, (x0, solver.init_state(x0, problem)), length=steps)
        return jnp.concatenate([problem.energy_at(x0.reshape(init.T.shape))[None], energies])


class JaxoptGaussNewton(_JaxoptLeastSquares):
    """Gauss-Newton by `jaxopt.GaussNewton` (full steps, no line search)."""

    def _solver(self, residual_fun, tol):
        jaxopt = _jaxopt()
        return jaxopt.GaussNewton(residual_fun=residual_fun, maxiter=self.max_steps, tol=tol,
                                  implicit_diff_solve=jaxopt.linear_solve.solve_lu)


class JaxoptLevenbergMarquardt(_JaxoptLeastSquares):
    """Levenberg-Marquardt by `jaxopt.LevenbergMarquardt`, Cholesky on the normal equations
    of the materialised Jacobian."""

    def _solver(self, residual_fun, tol):
        jaxopt = _jaxopt()
        return jaxopt.LevenbergMarquardt(
            residual_fun=residual_fun, maxiter=self.max_steps, tol=tol, xtol=0.0, gtol=0.0,
            solver="cholesky", materialize_jac=True,
            implicit_diff_solve=jaxopt.linear_solve.solve_lu,
        )
