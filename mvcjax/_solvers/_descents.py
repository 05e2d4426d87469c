"""Optimistix descents that solve each step's linear problem with the energy's structure
(`GaussNewtonMatrix`): Gauss-Newton's, Levenberg-Marquardt's and the dogleg's.

Optimistix hands its descents the Jacobian as an operator. In the structured loop
(`_StructuredGaussNewton`: optimistix's Gauss-Newton step, linearised in closed form)
that operator is a `StructuredJacobian`, which carries the point's linearisation, so
the descent builds the Gauss-Newton matrix from it without gathering the point again;
in optimistix's loop (a `jax.linearize`) the descent builds it from the point `y`,
which optimistix also hands it. The searches (Armijo backtracking, the classical trust
region) and the stopping tests stay optimistix's.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Float

from .._factor import AbstractFactor
from ._least_squares import ScaledProblem, StructuredJacobian
from ._normal_cg import GaussNewtonMatrix


class _StructuredDescent(optx.AbstractDescent):
    """What the three descents share: the problem, the factor and the CG budget.

    Attributes:
        problem: the scaled residuals (optimistix's `fn`, as data).
        factor: the rig's factor.
        cg_steps, cg_rtol: the conjugate-gradient budget per linear solve.
    """

    problem: ScaledProblem
    factor: AbstractFactor
    cg_steps: int = eqx.field(static=True)
    cg_rtol: float = eqx.field(static=True)

    def _matrix(self, y, f_info: optx.FunctionInfo.ResidualJac) -> GaussNewtonMatrix:
        # The structured loop's Jacobian carries the point's linearisation; optimistix's
        # own (a `jax.linearize`) does not, and then it is computed again.
        at = f_info.jac.at if isinstance(f_info.jac, StructuredJacobian) else None
        return GaussNewtonMatrix.at(self.problem, self.factor, y, at)


class _NewtonState(eqx.Module):
    newton: Float[Array, "2 n"]
    result: optx.RESULTS


class StructuredNewtonDescent(_StructuredDescent):
    """`optimistix.NewtonDescent` for the least-squares residuals, by
    `GaussNewtonMatrix.solve`."""

    def init(self, y, f_info_struct):
        del f_info_struct
        return _NewtonState(y, optx.RESULTS.successful)

    def query(self, y, f_info, state):
        del state
        newton, result = self._matrix(y, f_info).solve(self.cg_rtol, self.cg_steps)
        return _NewtonState(newton, optx.RESULTS.promote(result))

    def step(self, step_size, state):
        return -step_size * state.newton, state.result


class _DampedState(eqx.Module):
    point: tuple[Array, Array, Array]  # GaussNewtonMatrix.at_point


class StructuredDampedNewtonDescent(_StructuredDescent):
    """`optimistix.DampedNewtonDescent` (Levenberg-Marquardt's): the damping
    `1 / step_size` is added to the structured Gauss-Newton matrix, still
    preconditioned by `N^{-1}` (which suits the small damping near a solution)."""

    def init(self, y, f_info_struct):
        del f_info_struct
        # The first step is always accepted, so this state is never read: zeros.
        shapes = jax.eval_shape(lambda: GaussNewtonMatrix.at(self.problem, self.factor, y).at_point())
        return _DampedState(jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes))

    def query(self, y, f_info, state):
        del state
        return _DampedState(self._matrix(y, f_info).at_point())

    def step(self, step_size, state):
        matrix = GaussNewtonMatrix(self.problem, self.factor, *state.point)
        # optimistix's damping, 1 / step_size, capped where the step size vanishes.
        dtype = matrix.gradient.dtype
        damping = (1 / jnp.maximum(step_size, jnp.finfo(dtype).eps)).astype(dtype)
        x, result = matrix.solve(self.cg_rtol, self.cg_steps, damping)
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


class StructuredDoglegDescent(_StructuredDescent):
    """`optimistix.DoglegDescent` with its Newton point by `GaussNewtonMatrix.solve`; its
    Cauchy point and the step between them are optimistix's (`|J g|^2` from optimistix's
    Jacobian: one product, and exact where `N` less the rotations would cancel in
    float32)."""

    def init(self, y, f_info_struct):
        return dogleg_init(y, f_info_struct)

    def query(self, y, f_info, state):
        matrix = self._matrix(y, f_info)
        grad = matrix.gradient
        denom = jnp.sum(f_info.jac.mv(grad) ** 2)
        denom_nonzero = denom > jnp.finfo(denom.dtype).eps
        scaling = jnp.where(denom_nonzero, jnp.sum(grad**2) / jnp.where(denom_nonzero, denom, 1),
                            0.0)
        newton, result = matrix.solve(self.cg_rtol, self.cg_steps)
        cauchy = -scaling * grad
        return eqx.tree_at(
            lambda s: (s.newton, s.cauchy, s.newton_norm, s.cauchy_norm, s.result), state,
            (-newton, cauchy, optx.two_norm(newton), optx.two_norm(cauchy),
             optx.RESULTS.promote(result)),
        )

    def step(self, step_size, state):
        return optx.DoglegDescent().step(step_size, state)
