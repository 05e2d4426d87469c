"""Optimistix's least-squares solvers on the residuals of the energy (6)."""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import lineax as lx
import optimistix as optx

from ._base import AbstractSolver
from ._least_squares import ScaledProblem, check_jacobian_fits, default_tol


class _OptimistixLeastSquares(AbstractSolver):
    """Shared plumbing: solve in coordinates scaled to the unit diagonal, report the result."""

    rtol: float | None = eqx.field(default=None, static=True)
    atol: float | None = eqx.field(default=None, static=True)
    max_steps: int = eqx.field(default=256, static=True)

    def _solver(self, rtol: float, atol: float):
        raise NotImplementedError

    def solve(self, energy, factor, targets, init):
        check_jacobian_fits(energy, init.dtype, type(self).__name__)
        rtol = default_tol(init.dtype) if self.rtol is None else self.rtol
        atol = default_tol(init.dtype) if self.atol is None else self.atol
        problem = ScaledProblem(energy, targets)
        sol = optx.least_squares(
            lambda y, args: problem.residuals(y),
            self._solver(rtol, atol),
            problem.scaled(init),
            max_steps=self.max_steps,
            throw=False,
        )
        return problem.result(sol.value, sol.result == optx.RESULTS.successful,
                              sol.stats["num_steps"])


class _DampedGaussNewton(optx.AbstractGaussNewton):
    """Gauss-Newton steps with a backtracking Armijo line search."""

    rtol: float
    atol: float
    norm: Callable = optx.max_norm
    descent: optx.AbstractDescent = optx.NewtonDescent(linear_solver=lx.Normal(lx.Cholesky()))
    search: optx.AbstractSearch = optx.BacktrackingArmijo()
    verbose: Callable[..., None] = lambda *args, **kwargs: None


class GaussNewton(_OptimistixLeastSquares):
    """Gauss-Newton on the energy (6) through optimistix, to a tolerance.

    Each step solves the Gauss-Newton normal equations by Cholesky
    (`lineax.Normal(lineax.Cholesky())`) on the Jacobian `A - db/dV`, materialised by
    forward-mode autodiff. The full step is taken when it lowers the energy enough and
    is shortened by backtracking (Armijo) when it does not: the energy (6) has large
    residuals where the length-only targets `delta` and `e` are far from met, and there
    plain Gauss-Newton (`optimistix.GaussNewton`, `line_search=False`) can wander.
    Gradients through the solve are implicit (optimistix's `ImplicitAdjoint`).

    Attributes:
        rtol, atol: optimistix's Cauchy tolerances on coordinates scaled to the unit
            bounding-box diagonal (default 1e-10 in float64, 1e-5 in float32).
        max_steps: the step budget; `converged` is false if it ran out.
    """

    line_search: bool = eqx.field(default=True, static=True)

    def _solver(self, rtol, atol):
        if self.line_search:
            return _DampedGaussNewton(rtol=rtol, atol=atol)
        return optx.GaussNewton(rtol=rtol, atol=atol, linear_solver=lx.Normal(lx.Cholesky()))


class LevenbergMarquardt(_OptimistixLeastSquares):
    """Levenberg-Marquardt on the energy (6) by `optimistix.LevenbergMarquardt`.

    Same conventions as `GaussNewton`; the trust region makes it robust from far away.
    """

    def _solver(self, rtol, atol):
        return optx.LevenbergMarquardt(rtol=rtol, atol=atol, linear_solver=lx.Normal(lx.Cholesky()))


class Dogleg(_OptimistixLeastSquares):
    """Powell's dogleg trust-region method on the energy (6) by `optimistix.Dogleg`.

    Same conventions as `GaussNewton`: Cholesky on the normal equations of the
    forward-mode Jacobian, tolerances on coordinates scaled to the unit diagonal.
    """

    def _solver(self, rtol, atol):
        return optx.Dogleg(rtol=rtol, atol=atol, linear_solver=lx.Normal(lx.Cholesky()))
