"""Optimistix's least-squares solvers on the residuals of the energy (6)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx

from ._base import (
    CG_KEYWORDS_REMOVED,
    AbstractSolver,
    check_count,
    check_steps,
    check_tolerance,
    checked_in_init,
    python_scalar,
)
from ._descents import (
    DoglegDescent,
    StructuredDampedNewtonDescent,
    StructuredDoglegDescent,
    StructuredNewtonDescent,
)
from ._least_squares import NEAR_MINIMUM, ScaledProblem, check_jacobian_fits, default_tol
from ._normal_cg import HessianCG, StructuredCG


def _least_squares_solver(solver: lx.AbstractLinearSolver) -> lx.AbstractLinearSolver:
    # Cholesky and CG need a square, positive definite operator: the Jacobian's normal one.
    return lx.Normal(solver) if isinstance(solver, (lx.Cholesky, lx.CG)) else solver


class _OptimistixLeastSquares(AbstractSolver):
    """Shared plumbing: solve in coordinates scaled to the unit diagonal, report the result.

    Attributes:
        rtol, atol: optimistix's Cauchy tolerances on coordinates scaled to the unit
            bounding-box diagonal (default 1e-10 in float64, 1e-5 in float32).
        max_steps: the step budget; `converged` is false if it ran out.
        linear_solver: how each step's linear least-squares problem is solved:
            `mvcjax.advanced.StructuredCG()` (default) uses the energy's structure (see
            there); a lineax solver such as `lx.Cholesky()` materialises the Jacobian
            by forward-mode autodiff and solves with it densely (through its normal
            matrix for Cholesky and CG): exact steps, each far more expensive
            (`benchmarks/solvers.py` compares them), refused above 1 GiB.

    Refused, naming the option (TypeError for a wrong type, ValueError for a bad
    value): tolerances other than None or a finite number >= 0, `max_steps` not a
    whole number >= 1, a `linear_solver` that is neither.
    """

    _REMOVED = CG_KEYWORDS_REMOVED

    rtol: float | None = eqx.field(default=None, static=True, converter=python_scalar)
    atol: float | None = eqx.field(default=None, static=True, converter=python_scalar)
    max_steps: int = eqx.field(default=256, static=True, converter=python_scalar)
    linear_solver: StructuredCG | lx.AbstractLinearSolver = eqx.field(
        default=StructuredCG(), static=True, converter=checked_in_init)

    def __check_init__(self):
        for name in ("rtol", "atol"):
            check_tolerance(self, name, "1e-10 in float64, 1e-5 in float32")
        check_count(self, "max_steps")
        name = type(self).__name__
        fix = {"cg": "mvcjax.advanced.StructuredCG()", "cholesky": "lx.Cholesky()"}
        if isinstance(self.linear_solver, str):
            raise TypeError(
                f"{name}(linear_solver={self.linear_solver!r}): a linear solver is an object; "
                f"write linear_solver={fix.get(self.linear_solver, fix['cg'])} "
                "(import lineax as lx).")
        if not isinstance(self.linear_solver, (StructuredCG, lx.AbstractLinearSolver)):
            raise TypeError(f"{name}(linear_solver={self.linear_solver!r}): give "
                            f"{fix['cg']} or a lineax solver such as {fix['cholesky']}.")

    def _tolerances(self, dtype) -> tuple[float, float]:
        """`rtol` and `atol`, the defaults for `dtype` where not given."""
        return tuple(default_tol(dtype) if t is None else float(t)
                     for t in (self.rtol, self.atol))

    def _parts(self, dense: lx.AbstractLinearSolver
               ) -> tuple[type, optx.AbstractDescent, optx.AbstractSearch]:
        """The structured descent's class, optimistix's own descent with the `dense`
        linear solver, and the search."""
        raise NotImplementedError

    def _configured(self, problem: ScaledProblem, factor, dtype):
        linear = self.linear_solver
        structured_cg = isinstance(linear, StructuredCG)
        # The dense descent is only built, not run, beside the structured one.
        dense = lx.Normal(lx.Cholesky()) if structured_cg else _least_squares_solver(linear)
        structured, descent, search = self._parts(dense)
        tols = dict(zip(("rtol", "atol"), self._tolerances(dtype)))
        if structured_cg:
            return _GaussNewtonFamily(
                **tols, descent=structured(
                    problem=problem, normal=factor.normal_operator(),
                    preconditioner=factor.normal_inverse_operator(), cg_steps=linear.steps,
                    cg_rtol=linear.rtol, cg_deflate=linear.deflate),
                search=search)
        check_jacobian_fits(problem.energy, dtype,
                            f"{type(self).__name__}(linear_solver={linear!r})",
                            f"the default {type(self).__name__}() or ")
        return _GaussNewtonFamily(**tols, descent=descent, search=search)

    def solve(self, energy, factor, targets, init):
        problem = ScaledProblem(energy, targets)
        sol = optx.least_squares(
            lambda y, args: problem.residuals(y),
            self._configured(problem, factor, init.dtype),
            problem.scaled(init),
            # Implicit gradients by CG on the Hessian: optimistix's default would form it
            # densely (13 GB in float64 for a 20k-vertex full solve).
            adjoint=optx.ImplicitAdjoint(linear_solver=HessianCG(
                jax.lax.stop_gradient(factor).normal_inverse_operator())),
            max_steps=self.max_steps,
            throw=False,
        )
        tol = self._tolerances(init.dtype)
        near = problem.fixed_g_distance(
            jax.lax.stop_gradient(sol.value),
            jax.lax.stop_gradient(factor).normal_inverse_operator(), max(tol)
        ) <= NEAR_MINIMUM * max(tol)
        return problem.result(sol.value, (sol.result == optx.RESULTS.successful) & near,
                              sol.stats["num_steps"])

    def fixed_steps(self, steps):
        return dataclasses.replace(self, max_steps=check_steps(self, steps), rtol=0.0, atol=0.0)

    def history(self, energy, factor, targets, init, steps):
        problem = ScaledProblem(energy, targets)
        solver = self._configured(problem, factor, init.dtype)

        def fn(y, args):
            return problem.residuals(y), None

        y0 = problem.scaled(init)
        tags = frozenset()
        state = solver.init(fn, y0, None, {}, jax.eval_shape(problem.residuals, y0), None, tags)
        # The state holds jaxprs (static) beside arrays: carry only the arrays, as
        # optimistix's own loop does.
        dynamic0, static = eqx.partition(state, eqx.is_array)

        def body(carry, _):
            y, dynamic = carry
            y, state, _ = solver.step(fn, y, None, {}, eqx.combine(static, dynamic), tags)
            return (y, eqx.partition(state, eqx.is_array)[0]), problem.energy_at(y)

        _, energies = jax.lax.scan(body, (y0, dynamic0), length=steps)
        return jnp.concatenate([problem.energy_at(y0)[None], energies])


class _GaussNewtonFamily(optx.AbstractGaussNewton):
    """Optimistix's Gauss-Newton loop with any descent and search: `optimistix.GaussNewton`,
    `LevenbergMarquardt` and `Dogleg` are this loop with theirs."""

    rtol: float
    atol: float
    descent: optx.AbstractDescent
    search: optx.AbstractSearch
    norm: Callable = optx.max_norm
    verbose: Callable[..., None] = lambda *args, **kwargs: None


class GaussNewton(_OptimistixLeastSquares):
    """Gauss-Newton on the energy (6) through optimistix, to a tolerance.

    Each step solves the Gauss-Newton least-squares problem of the Jacobian
    `A - db/dV` (by default matrix-free, see `linear_solver`). The full step is taken
    when it lowers the energy enough and is shortened by backtracking (Armijo) when it
    does not: the energy (6) has large residuals where the length-only targets `delta`
    and `e` are far from met, and there plain Gauss-Newton (`optimistix.GaussNewton`,
    `line_search=False`) can wander.
    Gradients through the solve are implicit (optimistix's `ImplicitAdjoint`).

    Attributes:
        rtol, atol, max_steps, linear_solver: see the shared
            options (`mvcjax.solvers._optimistix._OptimistixLeastSquares`).
        line_search: backtrack (Armijo) when the full step does not lower the energy
            enough; `False` takes every full step, as `optimistix.GaussNewton` does.
    """

    line_search: bool = eqx.field(default=True, static=True)

    def _parts(self, dense):
        search = optx.BacktrackingArmijo() if self.line_search else optx.LearningRate(1.0)
        return StructuredNewtonDescent, optx.NewtonDescent(linear_solver=dense), search


class LevenbergMarquardt(_OptimistixLeastSquares):
    """Levenberg-Marquardt on the energy (6): `optimistix.LevenbergMarquardt`'s loop and
    classical trust region, with the structured damped-Newton descent
    (`StructuredDampedNewtonDescent`; optimistix's own with `linear_solver="cholesky"`).

    Same conventions as `GaussNewton`; the trust region makes it robust from far away.
    With `linear_solver="cg"` the damped system `J^T J + lambda I` is preconditioned
    by `N^{-1}` alone, which suits the small damping near a solution.
    """

    def _parts(self, dense):
        return (StructuredDampedNewtonDescent, optx.DampedNewtonDescent(linear_solver=dense),
                optx.ClassicalTrustRegion())


class Dogleg(_OptimistixLeastSquares):
    """Powell's dogleg trust-region method on the energy (6): `optimistix.Dogleg`'s loop,
    trust region and dogleg step, with the Newton point and the gradient from the
    structured Gauss-Newton matrix (`StructuredDoglegDescent`; optimistix's descent with
    `linear_solver="cholesky"`).

    Same conventions as `GaussNewton`: tolerances on coordinates scaled to the unit
    diagonal.
    """

    def _parts(self, dense):
        return (StructuredDoglegDescent, DoglegDescent(linear_solver=dense),
                optx.ClassicalTrustRegion())
