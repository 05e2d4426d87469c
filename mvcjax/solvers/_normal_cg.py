"""The Gauss-Newton linear solve with the energy's structure: conjugate gradients on the
Gauss-Newton matrix, kept as the rig's constant normal matrix less the rotation terms,
preconditioned by that constant matrix.

The residuals of the energy (6) are `W^{1/2} (A V - b(V))`. Stencil row `r` (a Laplacian,
edge or handle row `D_r`) has residual `W_r^{1/2} (1 - c_r) v_r`, where `v_r = D_r V`
and `c_r = l_r / |v_r|` turns it to its rest length `l_r`; the mean value rows are
linear. Differentiating, `J_r = W_r^{1/2} (I - c_r P_r) D_r` with `P_r` the projection
across `v_r`, and since `(I - c P)^2 = I - c (2 - c) P`:

    J^T J = N - sum_r W_r c_r (2 - c_r) D_r^T P_r D_r,     N = A^T W A,

and `J^T r = N V - D^T W (c v + offset)`. `N` is what the fixed-G iteration factors once
(`AbstractFactor.normal_inverse_operator`), so `N^{-1}` preconditions the solve. Each
conjugate-gradient iteration then costs one stencil gather and its scatter (the rotation
terms) and one product with `N^{-1}`: the product with `N` itself is never formed, since
the iteration carries it along (`conjugate_gradient`). The mean value rows, constant,
live in `N` and cost nothing per iteration. Optimistix's matrix-free Jacobian
(`jax.linearize` of the residuals, and its transpose) would gather and scatter the mean
value rows too and form every row's derivative, for the same iterates.

The rotations leave `J^T J` soft where `N` is stiff, so the iteration would need tens of
steps to solve the system; a truncated Newton step runs 4 by default. Its first iterate
points along the fixed-G step (`N^{-1} J^T r` is `V` less the fixed-G step from `V`), and
later ones improve on it within the Gauss-Newton model. The soft directions that a
truncated solve leaves out are what the steps keep returning to, and the last step
carries them: each solve is also deflated by it (`GaussNewtonMatrix.solve`), which
cuts the number of steps severalfold for a little more work per step
(`benchmarks/solvers.py` measures both).

Gradients through a solve need the Hessian of the energy at the solution instead:
`HessianCG` solves with it by the same preconditioned conjugate gradients, so that the
implicit adjoint never forms a `2n x 2n` matrix either.
"""

from __future__ import annotations

import functools
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
from jaxtyping import Array, Complex, Float

from ._base import check_count, check_tolerance, python_scalar
from ._least_squares import ScaledProblem, default_tol


def _dot(a, b):
    return sum(jnp.vdot(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))


def _inverse_or_zero(x):
    # 1 / x where x > 0, else 0 (a zero curvature divides nothing), with finite gradients.
    positive = x > 0
    return jnp.where(positive, 1 / jnp.where(positive, x, 1), 0)


UNROLL_STEPS = 16


def _axpy(a, x, y):
    """`a x + y`, leaf by leaf, for pytrees `x` and `y` of the same structure."""
    return jax.tree.map(lambda xi, yi: a * xi + yi, x, y)


def _undeflated(z, r):
    """A direction and its `P^{-1}` unchanged: the undeflated iteration's projection."""
    return z, r


def _conjugate_to(w, aw, uw, inverse, z, r):
    """`z - s w`, `A`-conjugate to `w`, and `P^{-1}` of it (`P^{-1} z` is `r`), given
    `A w`, `P^{-1} w` and `1 / (w^T A w)`."""
    s = _dot(aw, z) * inverse
    return _axpy(-s, w, z), _axpy(-s, uw, r)


def _deflated_start(b, deflation):
    """The deflated iteration's start, `(x, residual, floor, conjugate_to_w)`: the best
    multiple of `w`, its residual, the round-off floor of the stopping test, and the
    projection that keeps the directions conjugate to `w` (`conjugate_gradient`)."""
    w, aw, uw, *observed = deflation
    waw = _dot(w, aw)
    inverse = _inverse_or_zero(waw)
    along = _dot(w, b)
    start = along * inverse
    residual = _axpy(-start, aw, b)
    if observed:
        # The raised operator has `w^T A w` at `c` and `A w` scaled to match: the same
        # residual, from a shorter start.
        curvature = jnp.maximum(waw, observed[0])
        start = along * _inverse_or_zero(curvature)
    x = jax.tree.map(lambda wi: start * wi, w)
    # Where w already solves the system, what is left of the residual is rounding:
    # stop below the start's decrease of the quadratic at round-off, rather than
    # iterate on noise.
    floor = jnp.finfo(inverse.dtype).eps * along**2 * inverse
    return x, residual, floor, functools.partial(_conjugate_to, w, aw, uw, inverse)


def _cg_continues(max_steps, stop, carry):
    """Whether the iteration goes on: budget left and the preconditioned residual norm
    (squared, `gamma`) still above `stop`."""
    k, _, _, _, _, gamma = carry
    return (k < max_steps) & (gamma > stop)


def _cg_step(matvec, precondition, conjugate_to_w, carry):
    """One preconditioned conjugate-gradient step; a direction of non-positive curvature
    leaves `x` where it is and zeroes `gamma`, which ends the iteration."""
    k, x, residual, direction, unpreconditioned, gamma = carry
    q = matvec(direction, unpreconditioned)
    curvature = _dot(direction, q)
    ok = curvature > 0
    alpha = jnp.where(ok, gamma / jnp.where(ok, curvature, 1), 0)
    x = _axpy(alpha, direction, x)
    residual = _axpy(-alpha, q, residual)
    z = precondition(residual)
    gamma_next = _dot(residual, z)
    beta = gamma_next / jnp.where(gamma > 0, gamma, 1)
    z, r = conjugate_to_w(z, residual)
    direction = _axpy(beta, direction, z)
    unpreconditioned = _axpy(beta, unpreconditioned, r)
    return k + 1, x, residual, direction, unpreconditioned, jnp.where(ok, gamma_next, 0)


def _iterate(cond, body, carry, max_steps: int):
    """`body` applied while `cond` holds, at most `max_steps` times: unrolled with the
    stopping test as a mask for budgets up to `UNROLL_STEPS`, else a while loop."""
    if max_steps <= UNROLL_STEPS:
        # A few iterations (a truncated Newton step): unrolled, with the stopping test
        # as a mask, so that XLA fuses across iterations instead of running a loop.
        for _ in range(max_steps):
            keep = cond(carry)
            carry = jax.tree.map(lambda a, b_, k=keep: jnp.where(k, a, b_), body(carry), carry)
        return carry
    return jax.lax.while_loop(cond, body, carry)


def conjugate_gradient(matvec, b, precondition, rtol: float, max_steps: int, deflation=None):
    """Preconditioned conjugate gradients for `A x = b` from `x = 0`, or deflated by one
    vector.

    `matvec(p, q)` returns `A p`, given beside each direction `p` the product
    `q = P^{-1} p` with the inverse of the preconditioner `P` (`precondition`), which
    the iteration carries along for free (`P^{-1}` of the preconditioned residual is the
    residual): an operator of the form `P^{-1} - C` then costs only its correction `C`.
    Other operators ignore `q`.

    `deflation`, `(w, A w, P^{-1} w)`, adds the vector `w` to the search space (the
    deflated conjugate gradients of Saad, Yeung, Erhel and Guyomarc'h, 2000, with one
    vector): the iteration starts from the best multiple of `w` and keeps its
    directions `A`-conjugate to `w`, so that after `k` steps `x` minimises
    `x^T A x / 2 - b^T x` over `w` and a Krylov space of dimension `k`. A `w` of zero
    curvature (zero, or in the kernel of `A`) deflates nothing; a `w` that solves the
    system ends it at the start. Each step costs one more inner product. A fourth
    element, a curvature `c` along `w`, raises `w^T A w` to `c` where it is larger: the
    iteration is then that of `A + (c - w^T A w) (A w)(A w)^T / (w^T A w)^2`, the same
    operator on the directions conjugate to `w`.

    `A` must be symmetric positive semidefinite and `P` symmetric positive definite
    (pytrees of arrays in, the same out). Stops after `max_steps` or when the
    preconditioned residual norm has fallen by `rtol` from its start; a direction of
    zero or negative curvature ends the iteration instead of dividing by it. Budgets of
    at most `UNROLL_STEPS` iterations (a truncated Newton step) run unrolled, the
    stopping test a mask: on the CPU that avoids a while loop's overhead, a large part
    of a Gauss-Newton step's fixed cost.

    Returns:
        `(x, steps)`.
    """
    if deflation is None:
        x, residual, floor, conjugate_to_w = jax.tree.map(jnp.zeros_like, b), b, 0.0, _undeflated
    else:
        x, residual, floor, conjugate_to_w = _deflated_start(b, deflation)
    z = precondition(residual)
    gamma0 = _dot(residual, z)
    stop = jnp.maximum((rtol**2) * gamma0, floor)
    direction, unpreconditioned = conjugate_to_w(z, residual)
    carry = (jnp.zeros((), jnp.int32), x, residual, direction, unpreconditioned, gamma0)
    steps, x, *_ = _iterate(functools.partial(_cg_continues, max_steps, stop),
                            functools.partial(_cg_step, matvec, precondition, conjugate_to_w),
                            carry, max_steps)
    return x, steps


def hessian_solve(matvec, b, precondition):
    """`H^{-1} b` for the energy's Hessian `H` (`matvec`, symmetric positive definite at
    a strict minimum), by conjugate gradients preconditioned by `precondition` (the
    factor's `N^{-1}`), to the least-squares solvers' tolerance. Used by implicit
    differentiation; a direction of non-positive curvature (not a minimum) ends it early."""
    return conjugate_gradient(lambda p, _: matvec(p), b, precondition,
                              default_tol(b.dtype), 4 * b.size)[0]


class GaussNewtonMatrix(eqx.Module):
    """The Gauss-Newton matrix `J^T J` of a `ScaledProblem`'s residuals at one point,
    and the gradient there, in the structured form of the module docstring.

    Attributes:
        problem: the scaled residuals.
        normal: `N`, the rig's constant normal matrix (`AbstractFactor.normal_operator`).
        preconditioner: `N^{-1}` (`AbstractFactor.normal_inverse_operator`), or any
            symmetric positive definite operator near it.
        turn: `(m,)` for each stencil row, the unit vector across its current vector
            (as a complex number; zero for a zero vector).
        softness: `(m,)` `W_r c_r (2 - c_r)`, what the rotation takes off each row's
            weight across it (zero for the handle rows, which have no rest length).
        gradient: `(2, n)` `J^T r`, half the gradient of the scaled energy.
        normal_point: `(2, n)` `N y`, the point times `N` (a term of the gradient).
    """

    problem: ScaledProblem
    normal: lx.AbstractLinearOperator
    preconditioner: lx.AbstractLinearOperator
    turn: Complex[Array, " m"]
    softness: Float[Array, " m"]
    gradient: Float[Array, "2 n"]
    normal_point: Float[Array, "2 n"]

    @classmethod
    def at(cls, problem: ScaledProblem, normal: lx.AbstractLinearOperator,
           preconditioner: lx.AbstractLinearOperator, y: Float[Array, "2 n"]
           ) -> GaussNewtonMatrix:
        """The matrix and the gradient at `y`, from `problem.linearise(y)`."""
        at = problem.linearise(y)
        weight = problem.row_weight**2
        normal_point = normal.mv(y)
        gradient = normal_point - problem.stencils_transpose(weight * (at.turned + problem.offset))
        return cls(problem, normal, preconditioner, turn=at.turn, softness=at.softness,
                   gradient=gradient, normal_point=normal_point)

    def at_point(self) -> tuple[Array, Array, Array, Array]:
        """What depends on the point (`turn`, `softness`, `gradient`, `normal_point`):
        what a descent carries from step to step, instead of the problem and the factor
        again."""
        return self.turn, self.softness, self.gradient, self.normal_point

    def correction(self, x: Float[Array, "2 n"]) -> Float[Array, "2 n"]:
        """`N x - J^T J x`: the rotation terms."""
        across = self.problem.across(self.turn, x)
        return self.problem.stencils_transpose(self.softness * across * self.turn)

    def solve(self, rtol: float, max_steps: int, damping=0.0, previous=None):
        """`(J^T J + damping I)^{-1} J^T r` by conjugate gradients preconditioned by
        `N^{-1}`, truncated after `max_steps` iterations or a relative decrease `rtol`.

        `previous`, `(d, N d, c)`, is the step that led here (this point less the one
        before, `N` times it, and the curvature observed along it, `d` times the change
        of the gradient `J^T r` over it). The rotations make the Gauss-Newton matrix
        soft in a few directions that `N^{-1}` does not see, that a truncated solve
        leaves out, and that the steps then keep returning to: the last step carries
        them. So the solve is deflated by `d` (`conjugate_gradient`): it searches along
        `d` as well as the Krylov space. Along `d` the Gauss-Newton model can be far too
        soft where the residuals are large (it leaves out their second derivatives),
        and a step that trusts it overshoots, backtracks, and zig-zags (the dogleg, whose
        trust region does not bind there, crawled: 99 steps to the gap on the
        character). So the model's curvature along `d` is raised to the observed one
        where that is larger: the matrix solved with is then `J^T J` plus a rank-one
        term along `J^T J d`, positive semidefinite, and the same on the directions
        conjugate to `d`. On the horse, with 4 iterations, Gauss-Newton reaches the
        energy gap of the benchmark in 32 steps instead of 110.

        Returns:
            `(x, result)`: a breakdown when it could not leave zero with a nonzero
            gradient (any iterate that moved is a descent direction, which the outer
            solver's line search or trust region then judges), so that a solver never
            takes a zero step for convergence.
        """
        def matvec(p, normal_p):
            return normal_p - self.correction(p) + damping * p

        deflation = None
        if previous is not None:
            d, normal_d, observed = previous
            deflation = (d, matvec(d, normal_d), normal_d, observed + damping * _dot(d, d))
        x, _ = conjugate_gradient(matvec, self.gradient, self.preconditioner.mv,
                                  rtol, max_steps, deflation)
        g = self.gradient
        stuck = (_dot(x, x) == 0) & (_dot(g, g) > 0)
        return x, lx.RESULTS.where(stuck, lx.RESULTS.breakdown, lx.RESULTS.successful)


class HessianCG(lx.AbstractLinearSolver):
    """The implicit adjoint's linear solve: the Jacobian of the gradient of the
    least-squares objective (its Hessian, symmetric) by `hessian_solve`.

    Attributes:
        preconditioner: `N^{-1}` (`AbstractFactor.normal_inverse_operator`), without
            gradients (the preconditioner does not change the solution, and
            optimistix's adjoint takes no tangents through its solver).
    """

    preconditioner: lx.AbstractLinearOperator

    def init(self, operator: lx.AbstractLinearOperator, options: dict[str, Any]):
        del options
        return lx.linearise(operator)

    def compute(self, state, vector, options):
        del options
        return (hessian_solve(state.mv, vector, self.preconditioner.mv), lx.RESULTS.successful,
                {})

    def transpose(self, state, options):
        return state.transpose(), options

    def conj(self, state, options):
        return state, options

    def assume_full_rank(self):
        return True


class StructuredCG(eqx.Module):
    """Each Gauss-Newton step's linear solve with the energy's structure: conjugate
    gradients on the Gauss-Newton matrix, kept as the rig's constant normal matrix less
    the rotation terms and preconditioned by that constant matrix
    (`GaussNewtonMatrix`), in optimistix's step with the residuals linearised in closed
    form. The default `linear_solver` of `GaussNewton`, `LevenbergMarquardt` and
    `Dogleg`; a lineax solver (`lx.Cholesky()`) materialises the Jacobian instead.

    Attributes:
        steps: the conjugate-gradient budget per step (a truncated Newton step).
        rtol: its relative tolerance, in `[0, 1)`.
        deflate: also search along the previous step (deflated by it), with the model's
            curvature along it raised to the curvature observed over it where that is
            larger (`GaussNewtonMatrix.solve`): far fewer steps for a little more work
            per step (`benchmarks/solvers.py` compares). `False` solves with the
            Gauss-Newton matrix itself (exact steps with a large `steps`).
    """

    steps: int = eqx.field(default=4, static=True, converter=python_scalar)
    rtol: float = eqx.field(default=1e-2, static=True, converter=python_scalar)
    deflate: bool = eqx.field(default=True, static=True)

    def __check_init__(self):
        check_count(self, "steps")
        check_tolerance(self, "rtol")
        if not self.rtol < 1:
            raise ValueError(f"StructuredCG(rtol={self.rtol}): a relative decrease, in [0, 1).")
