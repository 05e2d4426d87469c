"""The paper's iteration V <- G b(V) (eq. 8), with G precomputed once."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._energy import Energy, FixedGFactor, edge_targets, laplacian_targets, total_energy
from ._base import AbstractSolver, SolveInfo


def fixed_g_step(
    energy: Energy, factor: FixedGFactor, vertices: Float[Array, "n 2"], handle_part
) -> Float[Array, "n 2"]:
    """One iteration: re-evaluate `delta(V)` and `e(V)`, then apply `G`."""
    rhs = jnp.concatenate([laplacian_targets(energy, vertices), edge_targets(energy, vertices)])
    return factor.shape @ rhs + handle_part


class FixedG(AbstractSolver):
    """The paper's fixed-`G` iteration: `V <- G b(V)` from the start, `iterations` times.

    Each step is a local step (rotate every Laplacian and edge target to the current
    shape, keeping its rest length) and a global step (one product with `G`). It is a
    local-global scheme: cheap steps, slow (linear) convergence. The paper stops after
    15 steps, which on a real shape is visibly short of the minimum; pass more
    iterations with `stop_early=True` to solve to a tolerance.

    Attributes:
        iterations: the number of steps (the maximum with `stop_early`).
        rtol: convergence tolerance on the largest vertex move of the last step,
            relative to the rest bounding-box diagonal.
        stop_early: stop as soon as a step moves no vertex more than `rtol`. This runs
            a `while_loop`, which `jax.grad` cannot reverse; without it the loop has a
            fixed length and is differentiated by unrolling.
        unroll: fully unroll a fixed-length loop of at most this many steps (fewer
            dispatches of tiny kernels; longer compilation).
    """

    iterations: int = eqx.field(default=15, static=True)
    rtol: float = eqx.field(default=1e-6, static=True)
    stop_early: bool = eqx.field(default=False, static=True)
    unroll: int = eqx.field(default=32, static=True)

    def __check_init__(self):
        if self.iterations < 1:
            raise ValueError(f"FixedG(iterations={self.iterations}): needs at least 1 iteration.")

    def solve(self, energy, factor, targets, init):
        handle_part = factor.handle @ targets
        tol = self.rtol * energy.scale

        def step(vertices):
            return fixed_g_step(energy, factor, vertices, handle_part)

        def move(a, b):
            return jnp.max(jnp.abs(a - b))

        if self.stop_early:

            def cond(carry):
                k, _, last = carry
                return (k < self.iterations) & (last > tol)

            def body(carry):
                k, v, _ = carry
                new = step(v)
                return k + 1, new, move(new, v)

            inf = jnp.asarray(jnp.inf, init.dtype)
            iterations, vertices, last = jax.lax.while_loop(cond, body, (0, init, inf))
        else:

            def body(_, carry):
                v, _ = carry
                new = step(v)
                return new, move(new, v)

            unroll = self.iterations <= self.unroll
            vertices, last = jax.lax.fori_loop(
                0, self.iterations, body, (init, jnp.zeros((), init.dtype)), unroll=unroll
            )
            iterations = jnp.asarray(self.iterations)
        info = SolveInfo(
            converged=last <= tol,
            iterations=jnp.asarray(iterations, jnp.int32),
            energy=total_energy(energy, vertices, targets),
        )
        return vertices, info
