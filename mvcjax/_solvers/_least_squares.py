"""What the least-squares solvers (optimistix, jaxopt) share: the residuals in coordinates
scaled to the unit diagonal, their tolerances, and a guard on the Jacobian's size."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._energy import Energy, residuals, total_energy
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
    unit diagonal, so that tolerances mean the same on every shape."""

    energy: Energy
    targets: Float[Array, "h 2"]

    def scaled(self, vertices: Float[Array, "n 2"]) -> Float[Array, "n 2"]:
        return (vertices - self.energy.rest.mean(axis=0)) / self.energy.scale

    def unscaled(self, y: Float[Array, "n 2"]) -> Float[Array, "n 2"]:
        return y * self.energy.scale + self.energy.rest.mean(axis=0)

    def residuals(self, y: Float[Array, "n 2"]) -> Float[Array, " m"]:
        return residuals(self.energy, self.unscaled(y), self.targets) / self.energy.scale

    def energy_at(self, y: Float[Array, "n 2"]) -> Float[Array, ""]:
        return total_energy(self.energy, self.unscaled(y), self.targets)

    def result(self, y, converged, iterations) -> tuple[Float[Array, "n 2"], SolveInfo]:
        vertices = self.unscaled(y)
        return vertices, SolveInfo(
            converged=jnp.asarray(converged),
            iterations=jnp.asarray(iterations, jnp.int32),
            energy=self.energy_at(y),
        )
