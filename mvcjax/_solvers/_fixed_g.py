"""The paper's iteration V <- G b(V) (eq. 8), with G precomputed once; optionally with
Anderson acceleration."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._energy import total_energy
from ._base import AbstractSolver, SolveInfo


class _Anderson(eqx.Module):
    """The last `m` differences of iterates and of fixed-point residuals (ring buffer)."""

    d_g: Array  # (m, N) differences of G b(V)
    d_f: Array  # (m, N) differences of G b(V) - V
    valid: Array  # (m,) which rows hold data since the last restart
    g: Array  # (N,) last G b(V)
    f: Array  # (N,) last G b(V) - V
    count: Array  # steps since the last restart


def _anderson_init(m: int, size: int, dtype) -> _Anderson:
    z = jnp.zeros((m, size), dtype)
    return _Anderson(z, z, jnp.zeros(m, bool), jnp.zeros(size, dtype), jnp.zeros(size, dtype),
                     jnp.zeros((), jnp.int32))


def _anderson_extrapolate(state: _Anderson, g, f, regularisation):
    """Anderson's (type II) mix of the remembered steps, and the updated memory."""
    m = state.d_g.shape[0]
    slot = jnp.mod(state.count - 1, m)
    has_prev = state.count > 0
    d_g = jnp.where(has_prev, state.d_g.at[slot].set(g - state.g), state.d_g)
    d_f = jnp.where(has_prev, state.d_f.at[slot].set(f - state.f), state.d_f)
    valid = jnp.where(has_prev, state.valid.at[slot].set(True), state.valid)
    d_f_masked = jnp.where(valid[:, None], d_f, 0.0)
    gram = d_f_masked @ d_f_masked.T
    # Tikhonov regularisation relative to the data's scale keeps the small system sound
    # when the remembered steps are nearly parallel.
    ridge = regularisation * jnp.trace(gram) + jnp.finfo(g.dtype).tiny
    gram = gram + jnp.diag(jnp.where(valid, ridge, 1.0))
    gamma = jnp.linalg.solve(gram, d_f_masked @ f)
    mixed = g - jnp.where(valid[:, None], d_g, 0.0).T @ gamma
    new = _Anderson(d_g, d_f, valid, g, f, state.count + 1)
    return mixed, new


class FixedG(AbstractSolver):
    """The paper's fixed-`G` iteration: `V <- G b(V)` from the start, `iterations` times.

    Each step is a local step (turn every Laplacian and edge target towards the current
    shape, keeping its rest length) and a global step (one product with `G`). This
    local-global scheme lowers the energy at every step but converges slowly (linearly,
    with a rate near 1 on real shapes). The paper stops after 15 steps, which is visibly
    short of the minimum; `anderson=m` accelerates it, and `stop_early=True` with more
    iterations solves to a tolerance.

    Attributes:
        iterations: the number of steps (the maximum with `stop_early`).
        rtol: convergence tolerance on the largest vertex move `|G b(V) - V|`, relative
            to the rest bounding-box diagonal. `converged` reports whether it was met.
        stop_early: stop as soon as the tolerance is met. This runs a `while_loop`,
            which `jax.grad` cannot reverse; a fixed-length loop is differentiated by
            unrolling.
        anderson: if positive, Anderson acceleration over the last `anderson` steps,
            with three safeguards: a ridge on the small least-squares system, an energy
            check (an extrapolation that does not lower the energy below the plain
            step's is rejected for the plain step) and a restart of the memory then.
        regularisation: the ridge, relative to the trace of the system.
        unroll: fully unroll a fixed-length loop of at most this many steps (fewer
            dispatches of tiny kernels, longer compilation).
    """

    iterations: int = eqx.field(default=15, static=True)
    rtol: float = eqx.field(default=1e-6, static=True)
    stop_early: bool = eqx.field(default=False, static=True)
    anderson: int = eqx.field(default=0, static=True)
    regularisation: float = eqx.field(default=1e-10, static=True)
    unroll: int = eqx.field(default=32, static=True)

    def __check_init__(self):
        if self.iterations < 1:
            raise ValueError(f"FixedG(iterations={self.iterations}): needs at least 1 iteration.")
        if self.anderson < 0:
            raise ValueError(f"FixedG(anderson={self.anderson}): the memory must be >= 0.")

    def _advance(self, energy, factor, targets, init):
        """One step `(v, memory) -> (v, largest move, memory)` and the initial memory."""
        handle_part = factor.handle_part(targets)
        shape = init.shape

        def plain(v):
            return factor.step(v, handle_part)

        if not self.anderson:

            def advance(v, memory):
                g = plain(v)
                return g, jnp.max(jnp.abs(g - v)), memory

            return advance, None

        def advance(v, memory):
            g = plain(v)
            f = (g - v).reshape(-1)
            mixed, memory = _anderson_extrapolate(memory, g.reshape(-1), f, self.regularisation)
            mixed = mixed.reshape(shape)
            better = total_energy(energy, mixed, targets) <= total_energy(energy, g, targets)
            memory = jax.tree.map(
                lambda new, fresh: jnp.where(better, new, fresh),
                memory,
                _anderson_init(self.anderson, f.size, v.dtype),
            )
            return jnp.where(better, mixed, g), jnp.max(jnp.abs(f)), memory

        return advance, _anderson_init(self.anderson, init.size, init.dtype)

    def solve(self, energy, factor, targets, init):
        advance, memory0 = self._advance(energy, factor, targets, init)
        tol = self.rtol * energy.scale
        inf = jnp.asarray(jnp.inf, init.dtype)
        carry0 = (jnp.zeros((), jnp.int32), init, inf, memory0)

        def body(carry):
            k, v, _, memory = carry
            v, residual, memory = advance(v, memory)
            return k + 1, v, residual, memory

        if self.stop_early:
            carry = jax.lax.while_loop(
                lambda c: (c[0] < self.iterations) & (c[2] > tol), body, carry0
            )
        else:
            carry = jax.lax.fori_loop(
                0, self.iterations, lambda _, c: body(c), carry0,
                unroll=self.iterations <= self.unroll,
            )
        iterations, vertices, residual, _ = carry
        info = SolveInfo(
            converged=residual <= tol,
            iterations=iterations,
            energy=total_energy(energy, vertices, targets),
        )
        return vertices, info

    def history(self, energy, factor, targets, init, steps):
        advance, memory0 = self._advance(energy, factor, targets, init)

        def body(carry, _):
            v, memory = carry
            v, _, memory = advance(v, memory)
            return (v, memory), total_energy(energy, v, targets)

        _, energies = jax.lax.scan(body, (init, memory0), length=steps)
        return jnp.concatenate([total_energy(energy, init, targets)[None], energies])
