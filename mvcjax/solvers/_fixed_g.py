"""The paper's iteration V <- G b(V) (eq. 8), with G precomputed once; optionally with
Anderson acceleration."""

from __future__ import annotations

import dataclasses

import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx
from jaxtyping import Array

from ..core import only_batched, with_batching_rule
from ..energy import total_energy
from ._base import (
    AbstractSolver,
    SolveInfo,
    check_count,
    check_steps,
    check_tolerance,
    checked_in_init,
    converged_and_finite,
    python_scalar,
)
from ._least_squares import ScaledProblem
from ._normal_cg import hessian_solve

# The stopping test bounds the distance to the fixed point, |r| / (1 - rho), from the
# residual r = G b(V) - V and the contraction rho of the plain step V <- G b(V), measured
# between successive iterates. Plain steps measure rho exactly once the slowest mode
# dominates; Anderson's steps measure it along their own directions, which for stretches
# of a few steps see less than the slowest mode: hence the largest of the last
# CONTRACTION_WINDOW measurements. rho is counted as at most MAX_CONTRACTION: a
# measurement at or above 1 (the first steps, rounding noise at the floor) bounds
# nothing, and the cap keeps such solves stoppable.
CONTRACTION_WINDOW = 32
MAX_CONTRACTION = 0.999
# Fewer frames than this under jax.vmap step as JAX batches the single frame's loop,
# which is faster for a few frames than stepping them together (the `fixed_g_few` rows of
# `benchmarks/vmap_rules.py`).
FEWEST_FRAMES_STEPPED_TOGETHER = 8


def _contraction(image_move, move):
    """How much the plain step shrank a move between two iterates (`|G b(V') - G b(V)|`
    over `|V' - V|`), within `[0, MAX_CONTRACTION]`; the cap where there is no move."""
    moved = move > 0
    ratio = jnp.where(moved, image_move / jnp.where(moved, move, 1), MAX_CONTRACTION)
    return jnp.clip(ratio, 0, MAX_CONTRACTION)


def _distance_bound(residual, contraction):
    """The distance to the fixed point that a residual implies at this contraction."""
    return residual / (1 - contraction)


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
    # Tikhonov regularisation relative to the data's scale (at least the dtype's
    # resolution, below which it would add nothing) keeps the small system sound when the
    # remembered steps are nearly parallel. Steps below the rounding noise of the
    # residual carry no information: no mix then, and no solve whose overflow would turn
    # the gradients through the rejected branch into NaN.
    eps = jnp.finfo(g.dtype).eps
    trace = jnp.trace(gram)
    usable = trace > eps**2 * (f @ f) + jnp.finfo(g.dtype).tiny
    ridge = jnp.asarray(max(regularisation, float(eps)), g.dtype) * trace
    gram = jnp.where(usable, gram + jnp.diag(jnp.where(valid, ridge, 1.0)),
                     jnp.eye(m, dtype=g.dtype))
    gamma = jnp.where(usable, jnp.linalg.solve(gram, d_f_masked @ f), jnp.zeros((), g.dtype))
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
        rtol: convergence tolerance on the distance to the fixed point (the minimum),
            relative to the rest bounding-box diagonal. The distance is estimated as the
            largest coordinate of the residual `G b(V) - V` over `1 - rho`, where `rho`
            is the contraction of the step `V <- G b(V)` measured between successive
            iterates (the largest of the last few measurements, and at most 0.999: the
            estimate is at most 1000 times the residual, an underestimate only where the
            iteration contracts more slowly still). The residual alone says little where
            the iteration contracts slowly: on real shapes the distance is hundreds of
            times the residual, and plain steps need thousands of iterations to meet the
            default (`anderson=5`, a few hundred). A tolerance below the rounding noise
            of the residual times that factor (about 1e-12 in float64) may never be met.
            `converged` reports whether the tolerance was met.
        stop_early: stop as soon as the tolerance is met. With the checkpointed adjoint
            this runs equinox's checkpointed while loop: as fast as a plain one, and
            reverse mode (`jax.grad`) differentiates the iterations run by recomputing
            them from checkpoints, but forward mode (`jax.jvp`, `jax.jacfwd`) is refused
            (JAX's TypeError about a custom_vjp function). `optx.ImplicitAdjoint()`
            supports both modes, and for a solve run to convergence it is cheaper and
            exact at the minimum.
        adjoint: how gradients flow through the solve, an optimistix adjoint, or None
            (default) for `optx.ImplicitAdjoint()` with `anderson` and `stop_early`
            together and `optx.RecursiveCheckpointAdjoint()` otherwise.
            `optx.RecursiveCheckpointAdjoint()` differentiates every iteration of the
            loop: exact for what was computed, even after 15 iterations, at the memory
            cost of all of them in reverse mode. Through Anderson's mixing run to a
            tolerance it differentiates least-squares fits to differences at the
            rounding noise, which may leave the derivative of the minimum far behind
            (float32 most): hence the default there. `optx.ImplicitAdjoint()` applies
            the implicit function theorem at the returned vertices, taken to be a
            stationary point of the energy: one linear solve with the energy's Hessian,
            whatever the number of iterations. Right for solves run to convergence, so
            it requires `stop_early=True`. Its linear solve is conjugate gradients
            preconditioned by the rig's factor (a dense solve would form the Hessian):
            leave its `linear_solver` at the default.
        anderson: if positive, Anderson acceleration over the last `anderson` steps,
            with three safeguards: a ridge on the small least-squares system, an energy
            check (an extrapolation that does not lower the energy below the plain
            step's is rejected for the plain step) and a restart of the memory then.
        regularisation: the ridge, relative to the trace of the system.
        unroll: fully unroll a fixed-length loop of at most this many steps (fewer
            dispatches of tiny kernels, longer compilation).

    Refused, naming the option (TypeError for a wrong type, ValueError for a bad
    value): `iterations` not a whole number >= 1, `anderson` or `unroll` not a whole
    number >= 0, `rtol` or `regularisation` not a finite number >= 0, an `adjoint` other
    than those two, and `optx.ImplicitAdjoint()` without `stop_early=True`.
    """

    iterations: int = eqx.field(default=15, static=True, converter=python_scalar)
    rtol: float = eqx.field(default=1e-6, static=True, converter=python_scalar)
    stop_early: bool = eqx.field(default=False, static=True)
    anderson: int = eqx.field(default=0, static=True, converter=python_scalar)
    regularisation: float = eqx.field(default=1e-10, static=True, converter=python_scalar)
    unroll: int = eqx.field(default=32, static=True, converter=python_scalar)
    adjoint: optx.AbstractAdjoint | None = eqx.field(default=None, static=True,
                                                     converter=checked_in_init)

    def __check_init__(self):
        check_count(self, "iterations")
        check_count(self, "anderson", 0)
        check_count(self, "unroll", 0)
        check_tolerance(self, "rtol")
        check_tolerance(self, "regularisation")
        if isinstance(self.adjoint, str):
            name = "ImplicitAdjoint" if self.adjoint == "implicit" else \
                "RecursiveCheckpointAdjoint"
            raise TypeError(f"FixedG(adjoint={self.adjoint!r}): an adjoint is an optimistix "
                            f"object; write adjoint=optx.{name}() (import optimistix as "
                            "optx).")
        if self.adjoint is not None and not isinstance(
                self.adjoint, (optx.RecursiveCheckpointAdjoint, optx.ImplicitAdjoint)):
            raise TypeError(f"FixedG(adjoint={self.adjoint!r}): choose "
                            "optx.RecursiveCheckpointAdjoint() (through the iterations) or "
                            "optx.ImplicitAdjoint() (at the minimum).")
        if self._implicit and self.adjoint is not None and not isinstance(
                self.adjoint.linear_solver, lx.AutoLinearSolver):
            raise ValueError(
                f"FixedG(adjoint={self.adjoint!r}): the implicit adjoint solves with the "
                "energy's Hessian by conjugate gradients preconditioned by the rig's factor; "
                "write optx.ImplicitAdjoint() without a linear_solver.")
        if self._implicit and not self.stop_early:
            raise ValueError(
                "FixedG(adjoint=optx.ImplicitAdjoint()) differentiates at a minimum, which a "
                f"fixed number of iterations ({self.iterations}) does not reach: add "
                "stop_early=True (with enough iterations, or anderson=...), or leave out "
                "adjoint for optx.RecursiveCheckpointAdjoint()."
            )

    @property
    def _implicit(self) -> bool:
        """Differentiated at the minimum: asked for, or by default (`adjoint=None`) where
        Anderson's mixing runs to a tolerance."""
        if self.adjoint is None:
            return self.stop_early and self.anderson > 0
        return isinstance(self.adjoint, optx.ImplicitAdjoint)

    def _advance(self, energy, factor, targets, init):
        """One step `(v, memory) -> (next v, G b(v), memory)` on the coordinate rows `V^T`
        (the factor's layout), and the initial memory."""
        handle_part = factor.handle_part(targets)
        shape = init.T.shape

        def plain(v):
            return factor.step(v, handle_part)

        if not self.anderson:

            def advance(v, memory):
                g = plain(v)
                return g, g, memory

            return advance, None

        energy_of = ScaledProblem(energy, targets).energy_of_columns

        def advance(v, memory):
            g = plain(v)
            f = (g - v).reshape(-1)
            mixed, memory = _anderson_extrapolate(memory, g.reshape(-1), f, self.regularisation)
            mixed = mixed.reshape(shape)
            better = energy_of(mixed) <= energy_of(g)
            memory = jax.tree.map(
                lambda new, fresh: jnp.where(better, new, fresh),
                memory,
                _anderson_init(self.anderson, f.size, v.dtype),
            )
            return jnp.where(better, mixed, g), g, memory

        return advance, _anderson_init(self.anderson, init.size, init.dtype)

    def solve(self, energy, factor, targets, init):
        if not self._implicit:
            if self.anderson or self.stop_early:
                return self._iterate(energy, factor, targets, init)
            # Under jax.vmap over targets, every frame runs in one loop, frames last.
            return with_batching_rule(self._iterate, self._frames_rule)(
                energy, factor, targets, init)

        def half_gradient(v):
            # Zero exactly where the iteration stops moving: a fixed point of
            # V <- G b(V) is a stationary point of the energy (at any V, the step is
            # V - N^{-1} grad E(V) / 2).
            return 0.5 * jax.grad(total_energy, argnums=1)(energy, v, targets)

        def run(_, start):
            vertices, info = self._iterate(energy, factor, jax.lax.stop_gradient(targets), start)
            # custom_root gives the auxiliary outputs integer tangents, which JAX then
            # rejects: carry the counts as floats.
            return vertices, jnp.stack([info.iterations, info.converged]).astype(start.dtype)

        inverse = factor.normal_inverse_operator()

        def precondition(r):
            return inverse.mv(r.T).T  # vertices (n, 2), the factor's (2, n)

        def tangent_solve(hessian, rhs):
            # A linear solve that JAX can transpose, so that reverse mode works too.
            return jax.lax.custom_linear_solve(
                hessian, rhs, lambda matvec, b: hessian_solve(matvec, b, precondition),
                symmetric=True,
            )

        vertices, (iterations, converged) = jax.lax.custom_root(
            half_gradient, init, run, tangent_solve, has_aux=True
        )
        value = total_energy(energy, vertices, targets)
        return vertices, SolveInfo(
            converged=converged_and_finite(converged > 0, vertices, value),
            iterations=iterations.astype(jnp.int32),
            energy=value,
        )

    def _iterate(self, energy, factor, targets, init):
        advance, memory0 = self._advance(energy, factor, targets, init)
        tol = self.rtol * energy.scale
        dtype = init.dtype
        contractions0 = jnp.full((CONTRACTION_WINDOW,), MAX_CONTRACTION, dtype)
        # (step, v, previous v, G b(previous v), distance bound, contractions, memory)
        carry0 = (jnp.zeros((), jnp.int32), init.T, init.T, init.T,
                  jnp.asarray(jnp.inf, dtype), contractions0, memory0)

        def body(carry):
            k, v, v_prev, g_prev, _, contractions, memory = carry
            v_next, g, memory = advance(v, memory)
            # The test only decides when to stop: no gradient flows through it.
            v_, g_, v_prev_, g_prev_ = jax.lax.stop_gradient((v, g, v_prev, g_prev))
            residual = jnp.max(jnp.abs(g_ - v_))
            contraction = jnp.where(
                k > 0,
                _contraction(jnp.max(jnp.abs(g_ - g_prev_)), jnp.max(jnp.abs(v_ - v_prev_))),
                MAX_CONTRACTION,
            )
            contractions = contractions.at[k % CONTRACTION_WINDOW].set(contraction)
            bound = _distance_bound(residual, jnp.max(contractions))
            return k + 1, v_next, v, g, bound, contractions, memory

        if self.stop_early:
            # Equinox's checkpointed loop runs as a plain while loop, and reverse-mode
            # differentiates it too (lax.while_loop refuses), recomputing from checkpoints.
            carry = eqxi.while_loop(
                lambda c: (c[0] < self.iterations) & (c[4] > tol), body, carry0,
                max_steps=self.iterations, kind="checkpointed",
            )
        else:
            carry = jax.lax.fori_loop(
                0, self.iterations, lambda _, c: body(c), carry0,
                unroll=self.iterations <= self.unroll,
            )
        iterations, columns, _, _, bound, _, _ = carry
        vertices = columns.T
        value = total_energy(energy, vertices, targets)
        info = SolveInfo(
            converged=converged_and_finite(bound <= tol, vertices, value),
            iterations=iterations,
            energy=value,
        )
        return vertices, info

    def _frames_rule(self, axis_size, in_batched, *args):
        if axis_size < FEWEST_FRAMES_STEPPED_TOGETHER:
            return None
        return self._iterate_frames(axis_size, in_batched, *args)

    def _iterate_frames(self, axis_size, in_batched, energy, factor, targets, init):
        """`jax.vmap(self._iterate)` where only the targets (and the starts) vary: all
        frames step together, laid out `(n, 2, f)` (`factor.step_frames`)."""
        if not (only_batched(in_batched, 2, 3) or only_batched(in_batched, 2)):
            return None  # a batch of rigs or weights: JAX's own batching
        init = jnp.broadcast_to(init, (axis_size, *init.shape[-2:]))
        data = factor.handle_part_frames(targets)
        start = jnp.moveaxis(init, 0, -1)  # (n, 2, f)

        def step(_, v):
            return factor.step_frames(v, data)

        def move(new, old):
            return jnp.max(jnp.abs(new - old), axis=(0, 1))  # per frame

        # The stopping test as `_iterate` computes it for plain steps (where a step's
        # contraction is the ratio of its move to the previous one), measured over the
        # steps it looks at only, so that the loop before them stays the bare iteration.
        if self.iterations <= CONTRACTION_WINDOW:
            # The window still holds the first step, which has nothing to compare with.
            before = jax.lax.fori_loop(0, self.iterations - 1, step, start)
            last = step(0, before)
            residual, contraction = move(last, before), MAX_CONTRACTION
        else:
            def tracked_step(i, carry):
                v, previous, largest = carry
                new = step(i, v)
                moved = move(new, v)
                largest = jnp.where(i > 0, jnp.maximum(largest, _contraction(moved, previous)),
                                    largest)
                return new, moved, largest

            before = jax.lax.fori_loop(0, self.iterations - CONTRACTION_WINDOW - 1, step,
                                       start)
            zeros = jnp.zeros(start.shape[-1], start.dtype)
            last, residual, contraction = jax.lax.fori_loop(
                0, CONTRACTION_WINDOW + 1, tracked_step, (before, zeros, zeros))
        bound = _distance_bound(residual, contraction)
        vertices = jnp.moveaxis(last, -1, 0)
        tol = self.rtol * energy.scale

        def frame_info(bound, vertices, targets):
            value = total_energy(energy, vertices, targets)
            return SolveInfo(converged=converged_and_finite(bound <= tol, vertices, value),
                             iterations=jnp.asarray(self.iterations, jnp.int32), energy=value)

        info = jax.vmap(frame_info)(bound, vertices, targets)
        out = (vertices, info)
        return out, jax.tree.map(lambda _: True, out)

    def fixed_steps(self, steps):
        return dataclasses.replace(self, iterations=check_steps(self, steps), stop_early=False,
                                   adjoint=optx.RecursiveCheckpointAdjoint())

    def history(self, energy, factor, targets, init, steps):
        advance, memory0 = self._advance(energy, factor, targets, init)

        def body(carry, _):
            v, memory = carry
            v, _, memory = advance(v, memory)
            return (v, memory), total_energy(energy, v.T, targets)

        _, energies = jax.lax.scan(body, (init.T, memory0), length=steps)
        return jnp.concatenate([total_energy(energy, init, targets)[None], energies])
