"""What the least-squares solvers (optimistix, jaxopt) share: the residuals in coordinates
scaled to the unit diagonal, their tolerances, and a guard on the Jacobian's size."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from .._energy import Energy, total_energy
from .._factor import _local_rows
from ._base import SolveInfo

_JACOBIAN_LIMIT_BYTES = 2**30


def default_tol(dtype) -> float:
    # Tolerances on coordinates scaled to the unit diagonal: near sqrt(eps) is what a
    # least-squares fit can resolve in that precision.
    return 1e-10 if jnp.finfo(dtype).bits >= 64 else 1e-5


def check_jacobian_fits(energy: Energy, dtype, name: str, alternative: str = "") -> None:
    """Refuse a dense Jacobian that would not fit, with the way out, instead of running out
    of memory (the full solve on a shape mesh of thousands of vertices)."""
    rows = 2 * (energy.laplacian_index.shape[0] + energy.mvc_centre.shape[0]
                + energy.edges.shape[0] + energy.handles.shape[0])
    size = rows * 2 * energy.num_vertices * jnp.dtype(dtype).itemsize
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
    residuals are those of `mvcjax.residuals` divided by the scale, in another order:
    the Laplacian and edge rows merged (one gather of points as complex numbers, as in
    the fixed-G local step), then the mean value and handle rows. Every solver step
    linearises and transposes them, and this form halves what that costs.

    Attributes:
        energy: the energy (6).
        targets: `(h, 2)` the handle targets.
        rows, coef, length: the merged Laplacian and edge rows (see `AbstractFactor`),
            `length` in scaled units.
        row_weight: `(m,)` the square root of each merged row's weight.
    """

    energy: Energy
    targets: Float[Array, "h 2"]
    rows: Int[Array, "m 3"]
    coef: Float[Array, "m 3"]
    length: Float[Array, " m"]
    row_weight: Float[Array, " m"]

    def __init__(self, energy: Energy, targets: Float[Array, "h 2"]):
        self.energy = energy
        self.targets = targets
        self.rows, self.coef, length = _local_rows(energy)
        self.length = length / energy.scale
        w = energy.weights
        self.row_weight = jnp.sqrt(jnp.concatenate([
            jnp.broadcast_to(w.laplacian, energy.laplacian_index.shape[:1]),
            jnp.broadcast_to(w.length, energy.edges.shape[:1]),
        ])).astype(length.dtype)

    def scaled(self, vertices: Float[Array, "n 2"]) -> Float[Array, "2 n"]:
        return ((vertices - self.energy.rest.mean(axis=0)) / self.energy.scale).T

    def unscaled(self, y: Float[Array, "2 n"]) -> Float[Array, "n 2"]:
        return y.T * self.energy.scale + self.energy.rest.mean(axis=0)

    def residuals(self, y: Float[Array, "2 n"]) -> Float[Array, "2 r"]:
        """All residuals, weighted and scaled, as real and imaginary rows."""
        e, w = self.energy, self.energy.weights
        z = jax.lax.complex(y[0], y[1])
        # Every row's coefficients sum to zero (Laplacian, edges) or one (mean value
        # coordinates), so the centring drops out of the L, H and M rows.
        v = jnp.sum(self.coef * z[self.rows], axis=1)
        sq = jnp.real(v) ** 2 + jnp.imag(v) ** 2
        nonzero = sq > 0
        turned = v * jnp.where(nonzero, self.length * jax.lax.rsqrt(jnp.where(nonzero, sq, 1.0)), 0.0)
        local = self.row_weight * (v - turned)
        mvc = jnp.sqrt(w.mvc) * (z[e.mvc_centre] - jnp.sum(e.mvc_weight * z[e.mvc_ring], axis=1))
        u = self.scaled(self.targets)
        handle = jnp.sqrt(w.handle) * (z[e.handles] - jax.lax.complex(u[0], u[1]))
        r = jnp.concatenate([local, mvc, handle])
        return jnp.stack([jnp.real(r), jnp.imag(r)])

    def energy_at(self, y: Float[Array, "2 n"]) -> Float[Array, ""]:
        return total_energy(self.energy, self.unscaled(y), self.targets)

    def result(self, y: Float[Array, "2 n"], converged, iterations
               ) -> tuple[Float[Array, "n 2"], SolveInfo]:
        vertices = self.unscaled(y)
        return vertices, SolveInfo(
            converged=jnp.asarray(converged),
            iterations=jnp.asarray(iterations, jnp.int32),
            energy=self.energy_at(y),
        )
