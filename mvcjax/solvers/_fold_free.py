"""A solver that never folds: the energy (6) plus barriers on the triangles' areas,
minimised by Gauss-Newton steps that never cross a flat triangle."""

from __future__ import annotations

import functools
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ..energy import rigid_start
from ..geometry import area_along, first_flat, signed_areas
from ._base import (
    CG_KEYWORDS_REMOVED,
    AbstractSolver,
    SkinnedMesh,
    SolveInfo,
    check_count,
    check_tolerance,
    checked_in_init,
    converged_and_finite,
    python_scalar,
)
from ._least_squares import NEAR_MINIMUM, ScaledProblem, default_tol
from ._normal_cg import GaussNewtonMatrix, StructuredCG, _dot, conjugate_gradient, hessian_solve
from ._optimistix import GaussNewton

# Armijo's sufficient decrease, and how many times a step may be halved.
_ARMIJO = 1e-4
_HALVINGS = 40
# A search that finds no decrease where the model promised less than this many times
# `rtol` of the objective has stopped at the minimum, to rounding.
_STALL = 100.0
# The share of the largest safe step a trial step may take: the barrier is infinite at
# a flat triangle, so the trial must stop short of it.
_SAFE_SHARE = 0.9


# The shape mesh's barrier enters each step's linear solve through its most squeezed
# triangles only (a fold is local: few triangles are near flat at once); its gradient
# takes every active triangle.
_SHAPE_ROWS = 32

_UNCONSTRAINED = GaussNewton()


def _model_matvec(model, barriers, models, count, p, normal_p):
    """The Gauss-Newton matrix of the energy and the barriers times `p`, given
    `normal_p = N p`: the energy's `N p` less its rotation terms, plus each barrier's
    `J^T J p` over its most squeezed triangles (`models`)."""
    return (normal_p - model.correction(p)
            + sum(b.vjp(m, b.jvp(m, p), count) for b, m in zip(barriers, models)))


def _model_at(problem, barriers, normal, inverse, y, points):
    """The Gauss-Newton model of the energy and the barriers at `y` (the barriers'
    `points` carried there): `(model, gradient, matvec)`, the energy's
    `GaussNewtonMatrix`, the whole gradient and the whole matrix's product."""
    count = y.shape[1]
    model = GaussNewtonMatrix.at(problem, normal, inverse, y)
    parts = [b.linearise(count, p) for b, p in zip(barriers, points)]
    gradient = model.gradient + sum(g for g, _ in parts)
    matvec = functools.partial(_model_matvec, model, barriers, tuple(m for _, m in parts),
                               count)
    return model, gradient, matvec


def _deflated_direction(linear_solver, inverse, model, gradient, matvec, y, previous):
    """The Gauss-Newton step (to be subtracted) by conjugate gradients, deflated by the
    step `previous` that led to `y` with the curvature observed along it
    (`GaussNewtonMatrix.solve` says why); the gradient if they broke down."""
    last_y, last_normal, last_gradient = previous
    d = y - last_y
    normal_d = model.normal_point - last_normal
    observed = _dot(d, gradient - last_gradient)
    x, _ = conjugate_gradient(matvec, gradient, inverse.mv, linear_solver.rtol,
                              linear_solver.steps, (d, matvec(d, normal_d), normal_d, observed))
    # Conjugate gradients on a positive semidefinite matrix give a descent
    # direction; the gradient itself is the fallback if they broke down.
    return jnp.where(_dot(x, gradient) > 0, x, gradient)


def _trial_value(problem, barriers, lines, y, direction, t):
    """The objective (residuals and barriers) at `y + t direction`, the barriers from
    their areas along the step (`lines`)."""
    r = problem.residuals(y + t * direction)
    return jnp.sum(r * r) + sum(b.value_along(line, t) for b, line in zip(barriers, lines))


def _armijo_search(problem, barriers, y, points, value, gradient, direction):
    """Armijo backtracking along `direction` from short of the first flat triangle:
    `(accepted, step, value there, the points' moves, direction)`."""
    slope = 2 * _dot(gradient, direction)
    # The meshes' points move linearly with the control coordinates: carried
    # once per step, and each triangle's area along the step is a quadratic.
    moves = tuple(b.points(direction) for b in barriers)
    lines = [b.line(p, q) for b, p, q in zip(barriers, points, moves)]
    reach = jnp.min(jnp.stack([first_flat(*line) for line in lines]))
    t0 = jnp.minimum(1.0, _SAFE_SHARE * reach).astype(y.dtype)
    trial_value = functools.partial(_trial_value, problem, barriers, lines, y, direction)

    def short(state):
        t, trial, i = state
        return (trial > value + _ARMIJO * t * slope) & (i < _HALVINGS)

    def halve(state):
        t, _, i = state
        return t / 2, trial_value(t / 2), i + 1

    t, trial, _ = jax.lax.while_loop(short, halve, (t0, trial_value(t0), 0))
    accept = trial <= value + _ARMIJO * t * slope
    return accept, jnp.where(accept, t, 0), trial, moves, direction


def _step_converged(accept, y, new_y, value, new_value, promised, rtol, atol):
    """Whether a step from `y` to `new_y` converged: an accepted step that moved no
    coordinate more than `atol + rtol |y|` and lowered the objective by less than `rtol`
    of it, or no decrease found where the model `promised` next to nothing."""
    moved = jnp.max(jnp.abs(new_y - y) / (atol + rtol * jnp.abs(y)))
    # No decrease along either descent direction: at the minimum to rounding if
    # the Gauss-Newton model promised next to nothing there, else stuck (and
    # then not converged).
    return ((accept & (moved < 1) & (value - new_value <= rtol * value))
            | (~accept & (promised <= _STALL * rtol * value)))


def _running(max_steps, carry):
    """Whether the iteration goes on: steps left, and not stopped."""
    k, *_, (done, _) = carry
    return (k < max_steps) & ~done


class _Barrier(eqx.Module):
    """A barrier on one mesh's triangles: a residual per triangle,
    `sqrt(weight * rest area) * max(0, threshold / s - 1)`, `s` its area over its rest
    area. Zero while a triangle keeps `threshold` of its rest area, so that poses far
    from folding are those of the energy (6) alone; infinite as it flattens. Its square
    is continuously differentiable.

    Each triangle's corners are weighted sums of control vertices: the control mesh's
    own corners (one vertex each), or the shape mesh's as the skinning carries them.

    Attributes:
        faces: `(f, 3)` the triangles, on the mesh's points.
        corner_index, corner_weight: `(f, 3, k)` each corner as control vertices.
        rest_area: `(f,)` twice each triangle's rest area (1 for a triangle without
            area: a stack's padding, `Rig.stack`).
        flat: `(f,)` 1 for a triangle without rest area, which never folds (its share
            of its rest area counts as 1), else 0.
        root_weight: `(f,)` the square root of its weight times its rest area.
        shape: how the points follow the control vertices (None: they are them).
        rows: how many triangles, the most squeezed, enter each step's linear solve.
        threshold: see `FoldFree`.
    """

    faces: Int[Array, "f 3"]
    corner_index: Int[Array, "f 3 k"]
    corner_weight: Float[Array, "f 3 k"]
    rest_area: Float[Array, " f"]
    flat: Float[Array, " f"]
    root_weight: Float[Array, " f"]
    shape: SkinnedMesh | None
    rows: int = eqx.field(static=True)
    threshold: float = eqx.field(static=True)

    @classmethod
    def on(cls, faces, rest, shape, weight, threshold) -> _Barrier:
        """The barrier of `faces` over points carried from the control coordinates
        `rest` by `shape` (or `rest` itself)."""
        if shape is None:
            index, corner_weight = faces[:, :, None], jnp.ones(faces.shape + (1,), rest.dtype)
            rows = faces.shape[0]
        else:
            skinning = shape.skinning
            index, corner_weight = skinning.indices[faces], skinning.weights[faces]
            rows = min(faces.shape[0], _SHAPE_ROWS)
        area = signed_areas((rest if shape is None else shape.carry(rest)).T, faces)
        flat = area == 0
        return cls(faces, index, corner_weight, jnp.where(flat, 1.0, area).astype(rest.dtype),
                   flat.astype(rest.dtype), jnp.sqrt(weight * area).astype(rest.dtype), shape,
                   rows, threshold)

    def points(self, y: Float[Array, "2 c"]) -> Float[Array, "2 n"]:
        return y if self.shape is None else self.shape.carry(y)

    def _residual(self, s, root_weight):
        inside = (s > 0) & (s < self.threshold)
        safe = jnp.where(inside, s, 1)
        residual = root_weight * jnp.where(inside, self.threshold / safe - 1, 0)
        slope = jnp.where(inside, -root_weight * self.threshold / (safe * safe), 0)
        return residual, slope

    def area_shares(self, points: Float[Array, "2 n"]) -> Float[Array, " f"]:
        """Each triangle's area over its rest area (negative if inverted)."""
        return signed_areas(points.T, self.faces) / self.rest_area + self.flat

    def feasible(self, points: Float[Array, "2 n"]) -> Array:
        return jnp.all(self.area_shares(points) > 0)

    def line(self, points, direction) -> tuple[Array, Array, Array]:
        """The areas along `points + t direction` (`area_along`): the barrier's value
        anywhere on the line is then a pass over the triangles, with no gather."""
        return area_along(points.T, direction.T, self.faces)

    def value_along(self, line, t) -> Float[Array, ""]:
        """The squared residuals' sum at `t` on a `line`; infinite past a flat
        triangle."""
        a, b, c = line
        s = (a + t * (b + t * c)) / self.rest_area + self.flat
        r = self._residual(s, self.root_weight)[0]
        return jnp.where(jnp.all(s > 0), jnp.sum(r * r), jnp.inf)

    def _jacobian(self, corners, pick):
        """Residuals and Jacobian rows `(t, 2, 3)` (by the corners' coordinates) of the
        triangles `pick` with corners `(2, t, 3)`."""
        e1, e2 = corners[:, :, 1] - corners[:, :, 0], corners[:, :, 2] - corners[:, :, 0]
        # The area's derivative by corner 1 is e2 turned clockwise, by corner 2 e1
        # turned anticlockwise, and by corner 0 minus their sum.
        d1 = jnp.stack([e2[1], -e2[0]])
        d2 = jnp.stack([-e1[1], e1[0]])
        area = jnp.stack([-d1 - d2, d1, d2], axis=-1)
        rest = self.rest_area[pick]
        residual, slope = self._residual((e1[0] * e2[1] - e1[1] * e2[0]) / rest,
                                         self.root_weight[pick])
        return residual, jnp.moveaxis((slope / rest)[None, :, None] * area, 1, 0)

    def _spread(self, pick, rows, u, count):
        """`J^T u` for the triangles `pick` with Jacobian rows `rows`, onto `count`
        control vertices."""
        by_corner = rows * u[:, None, None]  # (t, 2, 3)
        values = by_corner[:, :, :, None] * self.corner_weight[pick][:, None]  # (t, 2, 3, k)
        index = self.corner_index[pick].reshape(-1)
        flat = jnp.moveaxis(values, 1, 0).reshape(2, -1)
        return jnp.zeros((2, count), u.dtype).at[:, index].add(flat)

    def linearise(self, count: int, points: Float[Array, "2 n"]):
        """At the mesh's `points` (of `count` control vertices): the gradient of half the
        barrier's squared residuals, and the model `(pick, rows)` that `jvp` and `vjp`
        use, the Jacobian rows of the most squeezed triangles."""
        s = self.area_shares(points)
        if self.rows == self.faces.shape[0]:
            pick = jnp.arange(self.rows)
        else:
            pick = jax.lax.top_k(-s, self.rows)[1]
        residual, rows = self._jacobian(points[:, self.faces[pick]], pick)
        gradient = self._spread(pick, rows, residual, count)
        if self.rows < self.faces.shape[0]:
            # More squeezed triangles than rows (rare: a fold is local): the gradient
            # takes them all, onto the mesh's points, then back through the skinning.
            def every(_):
                r, j = self._jacobian(points[:, self.faces], jnp.arange(self.faces.shape[0]))
                by_corner = jnp.moveaxis(j * r[:, None, None], 1, 0)  # (2, f, 3)
                on_points = jnp.zeros_like(points).at[:, self.faces].add(by_corner)
                skinning = self.shape.skinning
                return jnp.zeros((2, count), points.dtype).at[:, skinning.indices].add(
                    on_points[:, :, None] * skinning.weights)

            gradient = jax.lax.cond(jnp.sum(s < self.threshold) > self.rows, every,
                                    lambda _: gradient, None)
        return gradient, (pick, rows)

    def jvp(self, model, p: Float[Array, "2 c"]) -> Float[Array, " t"]:
        pick, rows = model
        corners = jnp.einsum("tjk,dtjk->dtj", self.corner_weight[pick],
                             p[:, self.corner_index[pick]])
        return jnp.einsum("tdj,dtj->t", rows, corners)

    def vjp(self, model, u: Float[Array, " t"], count: int) -> Float[Array, "2 c"]:
        pick, rows = model
        return self._spread(pick, rows, u, count)


class FoldFree(AbstractSolver):
    """The energy (6) solved without ever turning a triangle inside out: neither a
    control triangle, nor a triangle of the drawn shape mesh.

    Barriers on the triangles' areas are added to the energy: nothing while a triangle
    keeps `threshold` of its rest area, then growing without bound as it flattens
    (`barrier * rest area * (threshold / s - 1)^2`, `s` its area over its rest area),
    on the control mesh and on the shape mesh as the skinning carries it (which can fold
    inside a control triangle that does not, where neighbouring control triangles turn
    apart). Each step is a Gauss-Newton step of the energy and the barriers together
    (conjugate gradients preconditioned by the rig's factor, deflated by the previous
    step), and its line search never reaches a flat triangle: a trial step stops short
    of the largest step that keeps every triangle's orientation (the smallest positive
    root of each triangle's area along the step), then backtracks until the objective
    falls enough (Armijo). From a start without folds (a start with folds is replaced by
    the rest mesh moved rigidly onto the handles), every pose it visits and returns has
    none. First it solves the energy alone (`GaussNewton()`): where that minimum keeps
    every triangle above `threshold`, the barriers are zero around it, and it is returned
    without a barrier step.

    Where the targets can only be met by folding (a hand pushed through the body), the
    pose stops short of them: `SolveInfo.handle_miss` says by how much, and
    `SolveInfo.energy` is the energy (6) alone. Gradients through the solve are
    implicit, at the minimum of the energy and the barriers.

    Called as `solver.solve(energy, factor, targets, init)` (without a rig), only the
    control mesh is watched.

    Attributes:
        barrier: the barriers' weight, against the energy's weights scaled so that the
            largest is 100 (at the default weights, the edge lengths' is 1).
        threshold: the share of its rest area below which a triangle feels the
            barrier, in (0, 1].
        rtol, atol: the stopping test, on coordinates scaled to the unit bounding-box
            diagonal: a step moving no coordinate more than `atol + rtol |y|`, with the
            objective falling by less than `rtol` of itself (default 1e-10 in float64,
            1e-5 in float32).
        max_steps: the step budget; `converged` is false if it ran out.
        linear_solver: each step's conjugate gradients: their budget and relative
            tolerance (`mvcjax.advanced.StructuredCG`; always deflated by the previous
            step).

    Refused, naming the option: `barrier` not a finite number > 0, `threshold` outside
    (0, 1], tolerances other than None or a finite number >= 0, `max_steps` or
    a `linear_solver` other than a `StructuredCG`.
    """

    _REMOVED = CG_KEYWORDS_REMOVED

    # Vmapped, its line searches and loops run every frame of a batch as long as the
    # slowest one's: `deform_frames` solves its frames one after another.
    frames_together: ClassVar[int] = 1

    barrier: float = eqx.field(default=1.0, static=True, converter=python_scalar)
    threshold: float = eqx.field(default=0.25, static=True, converter=python_scalar)
    rtol: float | None = eqx.field(default=None, static=True, converter=python_scalar)
    atol: float | None = eqx.field(default=None, static=True, converter=python_scalar)
    max_steps: int = eqx.field(default=256, static=True, converter=python_scalar)
    linear_solver: StructuredCG = eqx.field(default=StructuredCG(steps=8), static=True,
                                            converter=checked_in_init)

    def __check_init__(self):
        check_tolerance(self, "barrier")
        if not self.barrier > 0:
            raise ValueError(f"FoldFree(barrier={self.barrier}): the barrier's weight must be "
                             "positive (a zero barrier lets triangles fold).")
        check_tolerance(self, "threshold")
        if not 0 < self.threshold <= 1:
            raise ValueError(f"FoldFree(threshold={self.threshold}): a share of the rest area, "
                             "in (0, 1].")
        for name in ("rtol", "atol"):
            check_tolerance(self, name, "1e-10 in float64, 1e-5 in float32")
        check_count(self, "max_steps")
        if not isinstance(self.linear_solver, StructuredCG):
            raise TypeError(f"FoldFree(linear_solver={self.linear_solver!r}): give a "
                            "mvcjax.advanced.StructuredCG(steps=..., rtol=...).")

    def _problem(self, energy, targets, shape):
        """The scaled residuals and the barriers (the control mesh's, and the shape
        mesh's where it is given)."""
        problem = ScaledProblem(energy, targets)
        rest = problem.scaled(energy.rest)
        barriers = [_Barrier.on(energy.faces, rest, None, self.barrier, self.threshold)]
        if shape is not None:
            barriers.append(_Barrier.on(shape.faces, rest, shape, self.barrier,
                                        self.threshold))
        return problem, tuple(barriers)

    @staticmethod
    def _objective(problem, barriers):
        def objective(y):
            r = problem.residuals(y)
            total = jnp.sum(r * r)
            for b in barriers:
                p = b.points(y)
                total = total + b.value_along(b.line(p, jnp.zeros_like(p)), 0)
            return total

        return objective

    def _step(self, problem, barriers, normal, inverse, rtol, atol, carry):
        """One step of the iteration: the Gauss-Newton direction of the energy and the
        barriers, searched along (or the fixed-G direction where it finds no decrease),
        and whether the iteration has stopped and converged."""
        k, y, points, value, previous, _ = carry
        model, gradient, matvec = _model_at(problem, barriers, normal, inverse, y, points)
        x = _deflated_direction(self.linear_solver, inverse, model, gradient, matvec, y,
                                previous)
        search = functools.partial(_armijo_search, problem, barriers, y, points, value,
                                   gradient)

        # Where the Gauss-Newton direction finds no decrease (its model can be poor
        # next to a barrier), the fixed-G direction `-N^{-1} g` still descends: a loop
        # of at most two searches, so that the search is compiled once.
        def attempt(state):
            tries, _ = state
            direction = jax.lax.cond(tries == 0, lambda: -x, lambda: -inverse.mv(gradient))
            return tries + 1, search(direction)

        none = (jnp.zeros((), bool), jnp.zeros((), y.dtype), value,
                tuple(jnp.zeros_like(p) for p in points), jnp.zeros_like(y))
        _, (accept, step_size, trial, moves, direction) = jax.lax.while_loop(
            lambda state: (state[0] == 0) | ((state[0] < 2) & ~state[1][0]), attempt,
            (jnp.zeros((), jnp.int32), none))
        new_y = y + step_size * direction
        new_points = tuple(p + step_size * q for p, q in zip(points, moves))
        new_value = jnp.where(accept, trial, value)
        # As in the least-squares solvers, a stop counts as convergence only near a
        # minimum (`ScaledProblem.fixed_g_distance`, here of the energy and the barriers).
        near = jnp.max(jnp.abs(inverse.mv(gradient))) <= NEAR_MINIMUM * max(rtol, atol)
        converged = near & _step_converged(accept, y, new_y, value, new_value,
                                           2 * _dot(gradient, x), rtol, atol)
        return (k + 1, new_y, new_points, new_value,
                (y, model.normal_point, gradient), (converged | ~accept, converged))

    def _minimise(self, problem, barriers, factor, start, done):
        normal, inverse = factor.normal_operator(), factor.normal_inverse_operator()
        dtype = start.dtype
        rtol = default_tol(dtype) if self.rtol is None else self.rtol
        atol = default_tol(dtype) if self.atol is None else self.atol
        step = functools.partial(self._step, problem, barriers, normal, inverse, rtol, atol)
        points = tuple(b.points(start) for b in barriers)
        r = problem.residuals(start)
        value = jnp.sum(r * r) + sum(b.value_along(b.line(p, jnp.zeros_like(p)), 0)
                                     for b, p in zip(barriers, points))
        # At the start there is no step yet: a zero step deflates nothing.
        previous = (start, normal.mv(start), jnp.zeros_like(start))
        carry = (jnp.zeros((), jnp.int32), start, points, value, previous, (done, done))
        k, y, _, _, _, (_, converged) = jax.lax.while_loop(
            functools.partial(_running, self.max_steps), step, carry)
        return y, k, converged

    def solve(self, energy, factor, targets, init):
        return self.solve_skinned(energy, factor, targets, init, None)

    def solve_skinned(self, energy, factor, targets, init, shape):
        def half_gradient(y):
            # Where gradients are taken: the minimum of the energy and the barriers,
            # built from the traced targets and weights.
            return 0.5 * jax.grad(self._objective(*self._problem(energy, targets, shape)))(y)

        def run(_, guess):
            energy_, targets_, shape_, factor_ = jax.lax.stop_gradient(
                (energy, targets, shape, factor))
            problem, barriers = self._problem(energy_, targets_, shape_)
            # The energy's own minimum first: where it keeps every triangle above the
            # threshold, the barriers vanish around it and it is their minimum too, at
            # the cost of an unconstrained solve.
            free, free_info = _UNCONSTRAINED.solve(energy_, factor_, targets_,
                                                   problem.unscaled(guess))
            free = problem.scaled(free)
            shares = [b.area_shares(b.points(free)) for b in barriers]
            clear = free_info.converged & jnp.all(jnp.stack(
                [jnp.min(s) >= self.threshold for s in shares]))
            feasible = jnp.all(jnp.stack([b.feasible(b.points(guess)) for b in barriers]))
            fallback = problem.scaled(rigid_start(energy_, targets_))
            # Otherwise the caller's start if it folds nothing, else the rigid one. (The
            # energy's minimum, even unfolded, starts worse where a triangle is near
            # flat: the barrier's steepest.)
            start = jnp.where(clear, free, jnp.where(feasible, guess, fallback))
            y, k, done = self._minimise(problem, barriers, factor_, start, clear)
            steps = k + free_info.iterations
            return y, jnp.stack([steps, done]).astype(y.dtype)

        inverse = jax.lax.stop_gradient(factor).normal_inverse_operator()

        def tangent_solve(hessian, rhs):
            return jax.lax.custom_linear_solve(
                hessian, rhs, lambda matvec, b: hessian_solve(matvec, b, inverse.mv),
                symmetric=True)

        problem = ScaledProblem(energy, targets)
        y, (steps, converged) = jax.lax.custom_root(
            half_gradient, jax.lax.stop_gradient(problem.scaled(init)), run, tangent_solve,
            has_aux=True)
        vertices = problem.unscaled(y)
        value = problem.energy_at(y)
        return vertices, SolveInfo(converged=converged_and_finite(converged > 0, vertices, value),
                                   iterations=steps.astype(jnp.int32), energy=value)
