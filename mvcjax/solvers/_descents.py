"""Optimistix descents that solve each step's linear problem with the energy's structure
(`GaussNewtonMatrix`): Gauss-Newton's, Levenberg-Marquardt's and the dogleg's.

Optimistix's own Gauss-Newton loop runs them: it hands each descent the point `y`, from
which the descent builds the Gauss-Newton matrix in closed form, and the Jacobian (a
`jax.linearize` of the residuals), which its searches (Armijo backtracking, the classical
trust region) and the dogleg use. The loop and its stopping test stay optimistix's.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx
from jaxtyping import Array, Float

from ._least_squares import ScaledProblem
from ._normal_cg import GaussNewtonMatrix


class _StructuredDescent(optx.AbstractDescent):
    """What the three descents share: the problem, the factor and the CG budget.

    Attributes:
        problem: the scaled residuals (optimistix's `fn`, as data).
        normal, preconditioner: `N` and `N^{-1}` (`GaussNewtonMatrix`).
        cg_steps, cg_rtol: the conjugate-gradient budget per linear solve.
        cg_deflate: deflate each solve by the previous step, with the curvature observed
            along it (`GaussNewtonMatrix.solve`).
    """

    problem: ScaledProblem
    normal: lx.AbstractLinearOperator
    preconditioner: lx.AbstractLinearOperator
    cg_steps: int = eqx.field(static=True)
    cg_rtol: float = eqx.field(static=True)
    cg_deflate: bool = eqx.field(static=True, default=True)

    def _matrix(self, y, f_info: optx.FunctionInfo.ResidualJac) -> GaussNewtonMatrix:
        del f_info
        return GaussNewtonMatrix.at(self.problem, self.normal, self.preconditioner, y)

    def _previous(self, y) -> _Previous:
        # At the start there is no step yet: the previous point is this one (a zero step
        # deflates nothing), the gradient unread.
        return _Previous(y, self.normal.mv(y), jnp.zeros_like(y))

    def _solve(self, matrix: GaussNewtonMatrix, step, damping=0.0):
        return matrix.solve(self.cg_rtol, self.cg_steps, damping,
                            previous=step if self.cg_deflate else None)


class _Previous(eqx.Module):
    """The point of the last query, `N` times it and the gradient there: from them the
    next query's step that led to its point, by which its solve is deflated, and the
    curvature observed along that step (`GaussNewtonMatrix.solve`)."""

    point: Float[Array, "2 n"]
    normal_point: Float[Array, "2 n"]
    gradient: Float[Array, "2 n"]

    def step_to(self, y, matrix: GaussNewtonMatrix) -> tuple[Array, Array, Array]:
        """`(d, N d, d^T (g(y) - g))` from the last query's point to `y` (zero at the
        first), `g` the gradient `J^T r`."""
        d = y - self.point
        return (d, matrix.normal_point - self.normal_point,
                jnp.vdot(d, matrix.gradient - self.gradient))


class _NewtonState(eqx.Module):
    newton: Float[Array, "2 n"]
    result: optx.RESULTS
    previous: _Previous


class StructuredNewtonDescent(_StructuredDescent):
    """`optimistix.NewtonDescent` for the least-squares residuals, by
    `GaussNewtonMatrix.solve`, deflated by the previous step."""

    def init(self, y, f_info_struct):
        del f_info_struct
        return _NewtonState(y, optx.RESULTS.successful, self._previous(y))

    def query(self, y, f_info, state):
        matrix = self._matrix(y, f_info)
        newton, result = self._solve(matrix, state.previous.step_to(y, matrix))
        return _NewtonState(newton, optx.RESULTS.promote(result),
                            _Previous(y, matrix.normal_point, matrix.gradient))

    def step(self, step_size, state):
        return -step_size * state.newton, state.result


class _DampedState(eqx.Module):
    point: tuple[Array, Array, Array, Array]  # GaussNewtonMatrix.at_point
    step: tuple[Array, Array, Array]  # _Previous.step_to
    previous: _Previous


class StructuredDampedNewtonDescent(_StructuredDescent):
    """`optimistix.DampedNewtonDescent` (Levenberg-Marquardt's): the damping
    `1 / step_size` is added to the structured Gauss-Newton matrix, still
    preconditioned by `N^{-1}` (which suits the small damping near a solution), and
    the solve deflated by the previous step."""

    def init(self, y, f_info_struct):
        del f_info_struct
        # The first step is always accepted, so this state's step is never taken: zeros.
        shapes = jax.eval_shape(
            lambda: GaussNewtonMatrix.at(self.problem, self.normal, self.preconditioner,
                                         y).at_point())
        zeros = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)
        no_step = (jnp.zeros_like(y), jnp.zeros_like(y), jnp.zeros((), y.dtype))
        return _DampedState(zeros, no_step, self._previous(y))

    def query(self, y, f_info, state):
        matrix = self._matrix(y, f_info)
        return _DampedState(matrix.at_point(), state.previous.step_to(y, matrix),
                            _Previous(y, matrix.normal_point, matrix.gradient))

    def step(self, step_size, state):
        matrix = GaussNewtonMatrix(self.problem, self.normal, self.preconditioner, *state.point)
        # optimistix's damping, 1 / step_size, capped where the step size vanishes.
        dtype = matrix.gradient.dtype
        damping = (1 / jnp.maximum(step_size, jnp.finfo(dtype).eps)).astype(dtype)
        x, result = self._solve(matrix, state.step, damping)
        return -x, optx.RESULTS.promote(result)


def dogleg_init(y, f_info_struct):
    """`optimistix.DoglegDescent.init` with its norms in `y`'s dtype: optimistix makes
    them with `jnp.array(0.0)`, float64 under `jax_enable_x64`, and a float32 solve then
    fails on the cond between accepted and rejected steps."""
    state = optx.DoglegDescent().init(y, f_info_struct)
    zero = jnp.zeros((), y.dtype)
    return eqx.tree_at(lambda s: (s.newton_norm, s.cauchy_norm), state, (zero, zero))


class DoglegDescent(optx.DoglegDescent):
    """`optimistix.DoglegDescent` with `dogleg_init` (the dense `linear_solver`)."""

    def init(self, y, f_info_struct):
        return dogleg_init(y, f_info_struct)


class _DoglegState(eqx.Module):
    dogleg: Any  # optimistix's
    previous: _Previous


class StructuredDoglegDescent(_StructuredDescent):
    """`optimistix.DoglegDescent` with its Newton point by `GaussNewtonMatrix.solve`,
    deflated by the previous step; its Cauchy point and the step between them are
    optimistix's (`|J g|^2` from optimistix's Jacobian: one product, and exact where
    `N` less the rotations would cancel in float32)."""

    def init(self, y, f_info_struct):
        return _DoglegState(dogleg_init(y, f_info_struct), self._previous(y))

    def query(self, y, f_info, state):
        matrix = self._matrix(y, f_info)
        grad = matrix.gradient
        denom = jnp.sum(f_info.jac.mv(grad) ** 2)
        denom_nonzero = denom > jnp.finfo(denom.dtype).eps
        scaling = jnp.where(denom_nonzero, jnp.sum(grad**2) / jnp.where(denom_nonzero, denom, 1),
                            0.0)
        newton, result = self._solve(matrix, state.previous.step_to(y, matrix))
        cauchy = -scaling * grad
        dogleg = eqx.tree_at(
            lambda s: (s.newton, s.cauchy, s.newton_norm, s.cauchy_norm, s.result), state.dogleg,
            (-newton, cauchy, optx.two_norm(newton), optx.two_norm(cauchy),
             optx.RESULTS.promote(result)),
        )
        return _DoglegState(dogleg, _Previous(y, matrix.normal_point, matrix.gradient))

    def step(self, step_size, state):
        return optx.DoglegDescent().step(step_size, state.dogleg)
