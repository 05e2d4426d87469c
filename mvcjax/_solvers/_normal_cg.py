"""The Gauss-Newton linear solve with the energy's structure: conjugate gradients on the
normal equations, preconditioned by the rig's constant normal matrix.

The residuals of the energy (6) are `W^{1/2} (A V - b(V))`, so their Jacobian is
`W^{1/2} (A - db/dV)` with `A` constant and sparse. Optimistix hands the linear solver
that Jacobian as a matrix-free operator (`jax.linearize` of the residuals: a product
costs about one local step). The normal matrix `J^T J` is `N = A^T W A` (the fixed-G
iteration's matrix, factored once when the rig was built) less the rotation
terms' `sum_r c_r Y_r^T P_r Y_r` (`P_r` the projection across Laplacian or edge
vector `r`),
so `N^{-1}` is the natural preconditioner: nothing is materialised, and each
conjugate-gradient iteration costs one product with `J`, one with `J^T` and one with
`N^{-1}`, about one fixed-G step in all. The rotations leave `J^T J` soft where `N` is
stiff, so the iteration still needs several steps: 8 by default. Its first iterate points along the fixed-G step (at any `V`,
`J^T r = A^T W r`, since each rotation term's derivative is orthogonal to its
residual), and later ones improve on it within the Gauss-Newton model.

Gradients through a solve need the Hessian of the energy at the solution instead:
`HessianCG` solves with it by the same preconditioned conjugate gradients, so that the
implicit adjoint never forms a `2n x 2n` matrix either.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx

from .._factor import AbstractFactor
from ._least_squares import default_tol


def _dot(a, b):
    return sum(jnp.vdot(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))


UNROLL_STEPS = 16


def conjugate_gradient(matvec, b, precondition, rtol: float, max_steps: int):
    """Preconditioned conjugate gradients for `matvec(x) = b` from `x = 0`.

    `matvec` must be symmetric positive semidefinite and `precondition` symmetric
    positive definite (pytrees of arrays in, the same out). Stops after `max_steps` or
    when the preconditioned residual norm has fallen by `rtol`; a direction of zero or
    negative curvature ends the iteration instead of dividing by it. Budgets of at most
    `UNROLL_STEPS` iterations (a truncated Newton step) run unrolled, the stopping test
    a mask: on the CPU that saves about a third of a Gauss-Newton step's fixed cost.

    Returns:
        `(x, steps)`.
    """
    z = precondition(b)
    gamma0 = _dot(b, z)
    stop = (rtol**2) * gamma0

    def cond(carry):
        k, _, _, _, gamma = carry
        return (k < max_steps) & (gamma > stop)

    def body(carry):
        k, x, residual, direction, gamma = carry
        q = matvec(direction)
        curvature = _dot(direction, q)
        ok = curvature > 0
        alpha = jnp.where(ok, gamma / jnp.where(ok, curvature, 1), 0)
        x = jax.tree.map(lambda xi, di: xi + alpha * di, x, direction)
        residual = jax.tree.map(lambda ri, qi: ri - alpha * qi, residual, q)
        z = precondition(residual)
        gamma_next = _dot(residual, z)
        beta = gamma_next / jnp.where(gamma > 0, gamma, 1)
        direction = jax.tree.map(lambda zi, di: zi + beta * di, z, direction)
        return k + 1, x, residual, direction, jnp.where(ok, gamma_next, 0)

    zero = jax.tree.map(jnp.zeros_like, b)
    carry = (jnp.zeros((), jnp.int32), zero, b, z, gamma0)
    if max_steps <= UNROLL_STEPS:
        # A few iterations (a truncated Newton step): unrolled, with the stopping test
        # as a mask, so that XLA fuses across iterations instead of running a loop.
        for _ in range(max_steps):
            keep = cond(carry)
            carry = jax.tree.map(lambda a, b_: jnp.where(keep, a, b_), body(carry), carry)
    else:
        carry = jax.lax.while_loop(cond, body, carry)
    steps, x, *_ = carry
    return x, steps


def hessian_solve(matvec, b, precondition):
    """`H^{-1} b` for the energy's Hessian `H` (`matvec`, symmetric positive definite at
    a strict minimum), by conjugate gradients preconditioned by `precondition` (the
    factor's `N^{-1}`), to the least-squares solvers' tolerance. Used by implicit
    differentiation; a direction of non-positive curvature (not a minimum) ends it early."""
    return conjugate_gradient(matvec, b, precondition, default_tol(b.dtype), 4 * b.size)[0]


class NormalCG(lx.AbstractLinearSolver):
    """Least squares `min |J x - r|` by preconditioned conjugate gradients on
    `J^T J x = J^T r`, with `N^{-1}` from the rig's factor as the preconditioner.

    A truncated (inexact) Newton solve: it stops after `max_steps` iterations or when
    the preconditioned residual has fallen by `rtol`. It reports success whenever it
    moved (any iterate is a descent direction, which the outer solver's line search or
    trust region then judges) and a breakdown when it could not leave zero with a
    nonzero gradient, so that a solver never takes a zero step for convergence.

    Attributes:
        factor: the rig's factor (its `solve_normal` is the preconditioner).
        rtol: relative decrease of the preconditioned residual norm at which to stop.
        max_steps: the most conjugate-gradient iterations per linear solve.
    """

    factor: AbstractFactor
    rtol: float = eqx.field(static=True)
    max_steps: int = eqx.field(static=True)

    def init(self, operator: lx.AbstractLinearOperator, options: dict[str, Any]):
        del options
        return operator

    def compute(self, state, vector, options):
        del options
        operator = state
        transposed = operator.transpose()
        gradient = transposed.mv(vector)
        x, steps = conjugate_gradient(
            lambda x: transposed.mv(operator.mv(x)), gradient,
            self.factor.solve_normal, self.rtol, self.max_steps,
        )
        stuck = (_dot(x, x) == 0) & (_dot(gradient, gradient) > 0)
        result = lx.RESULTS.where(stuck, lx.RESULTS.breakdown, lx.RESULTS.successful)
        return x, result, {"num_steps": steps}

    def transpose(self, state, options):
        raise NotImplementedError(
            "NormalCG solves the forward Gauss-Newton steps only; gradients through a "
            "solve are implicit and use another linear solver."
        )

    def conj(self, state, options):
        return state, options

    def assume_full_rank(self):
        return True


class HessianCG(lx.AbstractLinearSolver):
    """The implicit adjoint's linear solve: the Jacobian of the gradient of the
    least-squares objective (its Hessian, symmetric) by `hessian_solve`.

    Attributes:
        factor: the rig's factor, without gradients (the preconditioner does not change
            the solution, and optimistix's adjoint takes no tangents through its solver).
    """

    factor: AbstractFactor

    def init(self, operator: lx.AbstractLinearOperator, options: dict[str, Any]):
        del options
        return lx.linearise(operator)

    def compute(self, state, vector, options):
        del options
        return hessian_solve(state.mv, vector, self.factor.solve_normal), lx.RESULTS.successful, {}

    def transpose(self, state, options):
        return state.transpose(), options

    def conj(self, state, options):
        return state, options

    def assume_full_rank(self):
        return True
