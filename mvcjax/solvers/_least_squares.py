"""What the least-squares solvers (optimistix, jaxopt) share: the residuals in coordinates
scaled to the unit diagonal, their tolerances, and a guard on the Jacobian's size."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Complex, Float, Int

from ..energy import (
    NORMAL_WEIGHT,
    Blocks,
    Energy,
    Stencil,
    apply_stencils,
    apply_stencils_transpose,
    group_sum,
    length_scale,
    merge_blocks,
    total_energy,
)
from ._base import SolveInfo, converged_and_finite

_JACOBIAN_LIMIT_BYTES = 2**30


# A solve is declared converged only where the fixed-G step (`fixed_g_distance`) is at
# most this many times its tolerance: the solvers' step-size tests alone stop in flat
# valleys far from the minimum.
NEAR_MINIMUM = 100.0


def default_tol(dtype) -> float:
    # Tolerances on coordinates scaled to the unit diagonal: near sqrt(eps) is what a
    # least-squares fit can resolve in that precision.
    return 1e-10 if jnp.finfo(dtype).bits >= 64 else 1e-5


def check_jacobian_fits(energy: Energy, dtype, name: str, alternative: str = "") -> None:
    """Refuse a dense Jacobian that would not fit, with the way out, instead of running out
    of memory (the full solve on a shape mesh of thousands of vertices)."""
    size = 2 * energy.row_count() * 2 * energy.num_vertices * jnp.dtype(dtype).itemsize
    if size > _JACOBIAN_LIMIT_BYTES:
        raise ValueError(
            f"{name} materialises the dense Jacobian of the energy, {size / 2**30:.1f} GiB for "
            f"this rig's {energy.num_vertices} control vertices; on a mesh this large use "
            f"{alternative}mvcjax.FixedG (with anderson=... and stop_early=True to solve to a "
            "tolerance)."
        )


class ScaledProblem(eqx.Module):
    """The energy's residuals in coordinates centred on the rest mesh and scaled to its
    unit diagonal, so that tolerances mean the same on every shape.

    The unknowns `y` are coordinate-major, `(2, n)`, the layout of the factor's products
    (`AbstractFactor.solve_normal` preconditions the solvers' linear solves). The
    residuals are those of `mvcjax.advanced.residuals` divided by the scale, in another
    order and in two gathers of points as complex numbers: the rows of the turned terms
    and the handles (narrow stencils, each turned to its rest length: zero for a handle,
    which only moves by its target), then the linear terms' rows (the mean value rows,
    as wide as a vertex's ring). Every optimistix step linearises them (its line search
    and trust regions use the Jacobian) and jaxopt's also transposes them, so the fewer
    gathers the better (one per term, as `mvcjax.advanced.residuals` has, costs half as
    much again); the structured descents use the stencils directly (`stencils`,
    `stencils_transpose`). All of it is derived from `Energy.terms`.

    Attributes:
        energy: the energy (6).
        targets: `(h, 2)` the handle targets.
        rows, coef: `(m, k)` the local terms' and the handles' stencils.
        length: `(m,)` their rest lengths, in scaled units (zero for the handles).
        rotation: `(m,)` their rest vectors, in scaled units, where a term is rotated
            (its rows turn together, `Term.rotated`); None otherwise.
        blocks: how the rows share rotations (`Blocks`), where `rotation` is given.
        offset: `(m,)` what each stencil is measured from (the handle targets, scaled).
        row_weight: `(m,)` the square root of each stencil's weight (`Weights.normalised`).
        linear_rows, linear_coef: `(g, k)` the linear terms' rows, their coefficients
            times the square root of their weight.
    """

    energy: Energy
    targets: Float[Array, "h 2"]
    rows: Int[Array, "m 3"]
    coef: Float[Array, "m 3"]
    length: Float[Array, " m"]
    offset: Complex[Array, " m"]
    row_weight: Float[Array, " m"]
    linear_rows: Int[Array, "g k"]
    linear_coef: Float[Array, "g k"]
    rotation: Complex[Array, " m"] | None
    blocks: Blocks | None = eqx.field(static=True)

    def __init__(self, energy: Energy, targets: Float[Array, "h 2"]):
        self.energy = energy
        self.targets = targets
        # Weights normalised: tolerances then do not depend on their overall scale (at
        # 1e-30 everywhere, optimistix's absolute tolerance would stop after one step).
        terms = energy.terms(normalised=True)
        dtype = energy.rest.dtype
        # The turned rows, then the handles' (turned to length zero, measured from the
        # targets), in one gather; the linear rows in another (their stencils are wider).
        narrow = [t for t in terms if t.is_local] + [t for t in terms if t.pinned]
        merged = Stencil.concatenate(*(t.stencil for t in narrow))
        self.rows, self.coef = merged.rows, merged.coef
        rest = jnp.concatenate([
            t.local_rest() / energy.scale if t.is_local else jnp.zeros(t.count, dtype)
            for t in narrow])
        self.length = jnp.abs(rest).astype(dtype)
        blocks = merge_blocks(sum((t.blocks() for t in narrow), ()))
        rotated = any(group > 1 for _, group in blocks)
        self.rotation, self.blocks = (rest, blocks) if rotated else (None, None)
        # A row that pins nothing (coefficients zero, target zero) is measured from zero
        # too, not from the centring's shift: its residual is then zero, not a constant
        # that would count in the tolerances.
        u = (self.scaled(targets) * energy.handle_presence()).astype(dtype)
        self.offset = jnp.concatenate([
            jax.lax.complex(u[0], u[1]) if t.pinned else jnp.zeros(t.count, dtype)
            for t in narrow])
        self.row_weight = jnp.sqrt(jnp.concatenate([
            jnp.broadcast_to(t.weight, (t.count,)) for t in narrow]).astype(dtype))
        linear = Stencil.concatenate(
            Stencil(jnp.zeros((0, 1), jnp.int32), jnp.zeros((0, 1), dtype)),  # none given
            *(Stencil(t.stencil.rows, jnp.sqrt(t.weight).astype(dtype) * t.stencil.coef)
              for t in terms if not t.is_local and not t.pinned))
        self.linear_rows, self.linear_coef = linear.rows, linear.coef

    def scaled(self, vertices: Float[Array, "n 2"]) -> Float[Array, "2 n"]:
        return ((vertices - self.energy.rest.mean(axis=0)) / self.energy.scale).T

    def unscaled(self, y: Float[Array, "2 n"]) -> Float[Array, "n 2"]:
        return y.T * self.energy.scale + self.energy.rest.mean(axis=0)

    def stencils(self, y: Float[Array, "2 n"]) -> Complex[Array, " m"]:
        """`D y`: the Laplacian, edge and handle stencils applied to `y` (offsets not
        subtracted), as complex numbers."""
        return apply_stencils(self.rows, self.coef, y)

    def stencils_transpose(self, u: Complex[Array, " m"]) -> Float[Array, "2 n"]:
        """`D^T u`: the transpose of `stencils`."""
        z = apply_stencils_transpose(self.rows, self.coef, u, self.energy.num_vertices)
        return jnp.stack([jnp.real(z), jnp.imag(z)])

    def residuals(self, y: Float[Array, "2 n"]) -> Float[Array, "2 r"]:
        """All residuals, weighted and scaled, as real and imaginary rows (the rest of
        `linearise`, unused, is dropped by XLA)."""
        return self.linearise(y).residual

    def linearise(self, y: Float[Array, "2 n"]) -> Linearisation:
        """The residuals at `y` and what their Jacobian there is made of (one gather of
        each kind, shared by the residuals, the Jacobian and the Gauss-Newton matrix)."""
        # Every row's coefficients sum to zero (Laplacian, edge and mean value rows) or
        # one (handles, measured from the scaled targets), so the centring drops out.
        v = self.stencils(y) - self.offset
        weight = self.row_weight**2
        if self.rotation is None:
            squared = jnp.real(v) ** 2 + jnp.imag(v) ** 2
            scale = length_scale(squared, self.length)
            turned = scale * v
            turn = 1j * v * length_scale(squared, jnp.ones_like(squared))
            softness = weight * scale * (2 - scale)
        else:
            # A group's rotation u = S / |S| fits S = sum_r v_r conj(c_r); turning it by
            # a small angle moves each target by i u c_r, and the Gauss-Newton matrix
            # loses (2 |S| - sum_r |c_r|^2) / |S|^2 along that angle's derivative.
            fit = group_sum(v * jnp.conj(self.rotation), self.blocks)
            squared = jnp.real(fit) ** 2 + jnp.imag(fit) ** 2
            inverse = length_scale(squared, 1.0)
            turned = fit * inverse * self.rotation
            turn = 1j * turned
            mass = group_sum(self.length**2, self.blocks)
            softness = weight * (2 * squared * inverse - mass) * inverse**2
        mvc = apply_stencils(self.linear_rows, self.linear_coef, y)
        r = jnp.concatenate([self.row_weight * (v - turned), mvc])
        return Linearisation(
            residual=jnp.stack([jnp.real(r), jnp.imag(r)]),
            turn=turn, softness=softness, turned=turned)

    def across(self, turn: Complex[Array, " m"], x: Float[Array, "2 n"]) -> Float[Array, " m"]:
        """How far the stencils of `x` turn each row's rotation, along `turn`: each
        row's own, or summed over its group's rows where rows turn together."""
        across = jnp.real(jnp.conj(turn) * self.stencils(x))
        return across if self.rotation is None else group_sum(across, self.blocks)

    def energy_at(self, y: Float[Array, "2 n"]) -> Float[Array, ""]:
        """The energy (6) at `y`, by `mvcjax.advanced.total_energy` (what solvers report)."""
        return total_energy(self.energy, self.unscaled(y), self.targets)

    def energy_of_columns(self, columns: Float[Array, "2 n"]) -> Float[Array, ""]:
        """The energy (6) at the unscaled coordinate rows `V^T`, from `residuals`: the
        cheaper form, for comparisons inside an iteration."""
        r = self.residuals(self.scaled(columns.T))
        weights = self.energy.weights
        return jnp.sum(r * r) * self.energy.scale**2 * weights.largest() / NORMAL_WEIGHT

    def fixed_g_distance(self, y: Float[Array, "2 n"], inverse, tol: float
                         ) -> Float[Array, ""]:
        """How far `y` is from the minimum, in scaled coordinates, estimated from three
        fixed-G steps `N^{-1} J^T r` from it (`inverse`: the factor's `N^{-1}`).

        One step alone underestimates where the energy is flatter than `N` (a valley that
        a tie-broken weight holds): there the steps shrink by a rate near 1, and the
        minimum is as far as all the steps still to come. So the estimate is the first
        step plus the second over one less the rate at which the third shrank from it
        (infinite where it did not shrink), the largest coordinate of each. Where the
        second step is below the tolerance `tol` the rate is rounding noise (the steps
        of a solve at float32's or float64's floor keep their size): the first step is
        the estimate.
        """
        def step(y):
            r, pullback = jax.vjp(self.residuals, y)
            return inverse.mv(pullback(r)[0])

        first = step(y)
        second = step(y - first)
        third = step(y - first - second)
        d1, d2, d3 = (jnp.max(jnp.abs(s)) for s in (first, second, third))
        rate = d3 / jnp.maximum(d2, jnp.finfo(d2.dtype).tiny)
        still_to_come = jnp.where(rate < 1, d2 / jnp.maximum(1 - rate, 0), jnp.inf)
        return d1 + jnp.where(d2 <= tol, 0.0, still_to_come)

    def result(self, y: Float[Array, "2 n"], converged, iterations
               ) -> tuple[Float[Array, "n 2"], SolveInfo]:
        vertices = self.unscaled(y)
        energy = self.energy_at(y)
        return vertices, SolveInfo(
            converged=converged_and_finite(jnp.asarray(converged), vertices, energy),
            iterations=jnp.asarray(iterations, jnp.int32),
            energy=energy,
        )


class Linearisation(eqx.Module):
    """The scaled residuals at a point and what their Jacobian there needs, from which
    `GaussNewtonMatrix` builds the Gauss-Newton matrix in closed form.

    Attributes:
        residual: `(2, r)` the residuals (`ScaledProblem.residuals`).
        turn: `(m,)` for each stencil row, how its target moves as its rotation turns:
            for a turned row the unit vector across its current vector `v` (as a complex
            number; zero for a zero vector), for a rotated row `i` times its target.
        softness: `(m,)` what the rotation takes off each row's weight along `turn`:
            `W_r c_r (2 - c_r)` for a turned row (`c_r` its rest length over its current
            length), zero for the handle rows, which have no rest length.
        turned: `(m,)` each row's target (its vector turned to its rest length, or its
            rest vector turned by its group's rotation).
    """

    residual: Float[Array, "2 r"]
    turn: Complex[Array, " m"]
    softness: Float[Array, " m"]
    turned: Complex[Array, " m"]
