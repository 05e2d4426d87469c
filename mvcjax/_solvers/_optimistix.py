"""Optimistix's least-squares solvers on the residuals of the energy (6)."""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax.numpy as jnp
import lineax as lx
import optimistix as optx

from .._energy import residuals, total_energy
from ._base import AbstractSolver, SolveInfo


def _default_tol(dtype) -> float:
    # Tolerances on coordinates scaled to the unit diagonal: near sqrt(eps) is what a
    # least-squares fit can resolve in that precision.
    return 1e-10 if jnp.finfo(dtype).bits >= 64 else 1e-5


_JACOBIAN_LIMIT_BYTES = 2**30


def _check_jacobian_fits(energy, dtype, name):
    """Refuse a dense Jacobian that would not fit, with the way out, instead of running out
    of memory (the full solve on a shape mesh of thousands of vertices)."""
    rows = 2 * (energy.laplacian_index.shape[0] + energy.mvc_centre.shape[0]
                + energy.edges.shape[0] + energy.handles.shape[0])
    size = rows * 2 * energy.num_vertices * jnp.dtype(dtype).itemsize
    if size > _JACOBIAN_LIMIT_BYTES:
        raise ValueError(
            f"{name} materialises the dense Jacobian of the energy, {size / 2**30:.1f} GiB for "
            f"this rig's {energy.num_vertices} control vertices; on a mesh this large use "
            "mvcjax.FixedG (with anderson=... and stop_early=True to solve to a tolerance)."
        )


class _OptimistixLeastSquares(AbstractSolver):
    """Shared plumbing: solve in coordinates scaled to the unit diagonal, report the result."""

    rtol: float | None = eqx.field(default=None, static=True)
    atol: float | None = eqx.field(default=None, static=True)
    max_steps: int = eqx.field(default=256, static=True)

    def _solver(self, rtol: float, atol: float):
        raise NotImplementedError

    def solve(self, energy, factor, targets, init):
        _check_jacobian_fits(energy, init.dtype, type(self).__name__)
        dtype = init.dtype
        rtol = _default_tol(dtype) if self.rtol is None else self.rtol
        atol = _default_tol(dtype) if self.atol is None else self.atol
        centre = energy.rest.mean(axis=0)
        scale = energy.scale

        def fn(y, args):
            return residuals(energy, y * scale + centre, targets) / scale

        sol = optx.least_squares(
            fn,
            self._solver(rtol, atol),
            (init - centre) / scale,
            max_steps=self.max_steps,
            throw=False,
        )
        vertices = sol.value * scale + centre
        info = SolveInfo(
            converged=sol.result == optx.RESULTS.successful,
            iterations=jnp.asarray(sol.stats["num_steps"], jnp.int32),
            energy=total_energy(energy, vertices, targets),
        )
        return vertices, info


class _DampedGaussNewton(optx.AbstractGaussNewton):
    """Gauss-Newton steps with a backtracking Armijo line search."""

    rtol: float
    atol: float
    norm: Callable = optx.max_norm
    descent: optx.AbstractDescent = optx.NewtonDescent(linear_solver=lx.Normal(lx.Cholesky()))
    search: optx.AbstractSearch = optx.BacktrackingArmijo()
    verbose: Callable[..., None] = lambda *args, **kwargs: None


class GaussNewton(_OptimistixLeastSquares):
    """Gauss-Newton on the energy (6) through optimistix, to a tolerance.

    Each step solves the Gauss-Newton normal equations by Cholesky
    (`lineax.Normal(lineax.Cholesky())`) on the Jacobian `A - db/dV`, materialised by
    forward-mode autodiff. The full step is taken when it lowers the energy enough and
    is shortened by backtracking (Armijo) when it does not: the energy (6) has large
    residuals where the length-only targets `delta` and `e` are far from met, and there
    plain Gauss-Newton (`optimistix.GaussNewton`, `line_search=False`) can wander.
    Gradients through the solve are implicit (optimistix's `ImplicitAdjoint`).

    Attributes:
        rtol, atol: optimistix's Cauchy tolerances on coordinates scaled to the unit
            bounding-box diagonal (default 1e-10 in float64, 1e-5 in float32).
        max_steps: the step budget; `converged` is false if it ran out.
    """

    line_search: bool = eqx.field(default=True, static=True)

    def _solver(self, rtol, atol):
        if self.line_search:
            return _DampedGaussNewton(rtol=rtol, atol=atol)
        return optx.GaussNewton(rtol=rtol, atol=atol, linear_solver=lx.Normal(lx.Cholesky()))


class LevenbergMarquardt(_OptimistixLeastSquares):
    """Levenberg-Marquardt on the energy (6) by `optimistix.LevenbergMarquardt`.

    Same conventions as `GaussNewton`; the trust region makes it robust from far away.
    """

    def _solver(self, rtol, atol):
        return optx.LevenbergMarquardt(rtol=rtol, atol=atol, linear_solver=lx.Normal(lx.Cholesky()))
