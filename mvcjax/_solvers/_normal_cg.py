"""The Gauss-Newton linear solve with the energy's structure: conjugate gradients on the
normal equations, preconditioned by the rig's constant normal matrix.

The residuals of the energy (6) are `W^{1/2} (A V - b(V))`, so their Jacobian is
`W^{1/2} (A - db/dV)` with `A` constant and sparse. Optimistix hands the linear solver
that Jacobian as a matrix-free operator (`jax.linearize` of the residuals: a product
costs about one local step). The normal matrix `J^T J` is `N = A^T W A` (the fixed-G
iteration's matrix, factored once when the rig was built) perturbed by the rotation
terms, so `N^{-1}` is a nearly exact preconditioner: nothing is materialised, and each
conjugate-gradient iteration costs one product with `J`, one with `J^T` and one with
`N^{-1}`. Its first iterate is the fixed-G step (at any `V`, `J^T r = A^T W r`), and
later ones improve on it within the Gauss-Newton model.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx

from .._factor import AbstractFactor


def _dot(a, b):
    return sum(jnp.vdot(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))


def conjugate_gradient(matvec, b, precondition, rtol: float, max_steps: int):
    """Preconditioned conjugate gradients for `matvec(x) = b` from `x = 0`.

    `matvec` must be symmetric positive semidefinite and `precondition` symmetric
    positive definite (pytrees of arrays in, the same out). Stops after `max_steps` or
    when the preconditioned residual norm has fallen by `rtol`; a direction of zero or
    negative curvature ends the iteration instead of dividing by it.

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
    steps, x, *_ = jax.lax.while_loop(cond, body, carry)
    return x, steps


class NormalCG(lx.AbstractLinearSolver):
    """Least squares `min |J x - r|` by preconditioned conjugate gradients on
    `J^T J x = J^T r`, with `N^{-1}` from the rig's factor as the preconditioner.

    A truncated (inexact) Newton solve: it stops after `max_steps` iterations or when
    the preconditioned residual has fallen by `rtol`, and always reports success, since
    any iterate is a descent direction that the outer solver's line search or trust
    region then judges.

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
        x, steps = conjugate_gradient(
            lambda x: transposed.mv(operator.mv(x)), transposed.mv(vector),
            self.factor.solve_normal, self.rtol, self.max_steps,
        )
        return x, lx.RESULTS.successful, {"num_steps": steps}

    def transpose(self, state, options):
        raise NotImplementedError(
            "NormalCG solves the forward Gauss-Newton steps only; gradients through a "
            "solve are implicit and use another linear solver."
        )

    def conj(self, state, options):
        return state, options

    def assume_full_rank(self):
        return True
