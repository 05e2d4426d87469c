"""Folds: triangles turned inside out, counted and kept from happening (pure JAX)."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ._coordinates import cross, signed_areas, triangle_edges


def inverted_count(vertices: Float[Array, "n 2"], faces: Int[Array, "f 3"],
                   rest: Float[Array, "n 2"]) -> Int[Array, ""]:
    """How many triangles have turned inside out (or flat) since `rest`: their signed
    area has left the rest area's sign. A triangle without rest area (a stack's padding,
    `Rig.stack`) has no inside to turn out, and is not counted."""
    now, before = signed_areas(vertices, faces), signed_areas(rest, faces)
    return jnp.sum((now * jnp.sign(before) <= 0) & (before != 0)).astype(jnp.int32)


def area_along(vertices: Float[Array, "n 2"], direction: Float[Array, "n 2"],
               faces: Int[Array, "f 3"]) -> tuple[Array, Array, Array]:
    """Twice each triangle's signed area along the line `vertices + t direction`, as
    the coefficients `(a, b, c)` of `a + b t + c t^2`."""
    e1, e2 = triangle_edges(vertices, faces)
    d1, d2 = triangle_edges(direction, faces)
    return cross(e1, e2), cross(e1, d2) + cross(d1, e2), cross(d1, d2)


def first_flat(a: Float[Array, " f"], b: Float[Array, " f"], c: Float[Array, " f"]
               ) -> Float[Array, ""]:
    """The smallest `t > 0` where some `a + b t + c t^2` (twice a triangle's area along
    a line, `area_along`) reaches zero: infinite if none does, zero if a triangle is
    already flat or inverted. A triangle flat all along the line (`a = b = c = 0`: a
    stack's padding, `Rig.stack`) does not count. The roots are taken in the form that
    does not cancel."""
    inf = jnp.asarray(jnp.inf, a.dtype)

    def positive(root):
        return jnp.where(jnp.isfinite(root) & (root > 0), root, inf)

    disc = b * b - 4 * a * c
    real = disc >= 0
    # With c = 0 the second root is the linear one, -a / b; the first is infinite.
    q = -0.5 * (b + jnp.where(b >= 0, 1.0, -1.0) * jnp.sqrt(jnp.where(real, disc, 0.0)))
    first = jnp.where(c != 0, q / jnp.where(c != 0, c, 1.0), inf)
    second = jnp.where(q != 0, a / jnp.where(q != 0, q, 1.0), inf)
    roots = jnp.where(real, jnp.minimum(positive(first), positive(second)), inf)
    never = (a == 0) & (b == 0) & (c == 0)
    return jnp.min(jnp.where(a > 0, roots, jnp.where(never, inf, 0.0)), initial=inf)


def largest_safe_step(vertices: Float[Array, "n 2"], direction: Float[Array, "n 2"],
                      faces: Int[Array, "f 3"]) -> Float[Array, ""]:
    """The largest `t >= 0` with every triangle of `vertices + s direction` still
    counter-clockwise for all `0 <= s < t` (infinite if none ever flattens): the
    smallest positive root of each triangle's area along the line (Smith and Schaefer
    2015)."""
    return first_flat(*area_along(vertices, direction, faces))
