"""The energy's rows as stencils: every row of `L`, `M`, `H` and `C` (eq. 7) is a few
vertex indices and their coefficients. The residuals, the dense and sparse operators,
the factor's local step and the least-squares solvers' Jacobian all derive from these
tables, so that a new kind of row is written once.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Complex, Float, Int

# A polygon vertex less the mean of its two loop neighbours: `(i, previous, next)`.
LAPLACIAN = (1.0, -0.5, -0.5)
# An edge vector `v_i - v_j`: `(i, j)`.
EDGE = (1.0, -1.0)
# A handle's vertex.
HANDLE = (1.0,)


class Stencil(eqx.Module):
    """Rows `y_r = sum_k coef[r, k] V[rows[r, k]]`, padded with zero coefficients.

    Attributes:
        rows: `(m, k)` vertex indices of each row.
        coef: `(m, k)` their coefficients.
    """

    rows: Int[Array, "m k"]
    coef: Float[Array, "m k"]

    @classmethod
    def fixed(cls, rows: Int[Array, "m k"], coefficients: tuple[float, ...], dtype) -> Stencil:
        """Rows that all share `coefficients` (the Laplacian, edge and handle rows)."""
        return cls(rows, jnp.broadcast_to(jnp.asarray(coefficients, dtype), rows.shape))

    @classmethod
    def concatenate(cls, *stencils: Stencil) -> Stencil:
        """The rows of every stencil, in order, padded to the widest (repeating each row's
        last index with a zero coefficient)."""
        width = max(s.rows.shape[1] for s in stencils)

        def pad(s):
            extra = width - s.rows.shape[1]
            return (jnp.concatenate([s.rows, jnp.repeat(s.rows[:, -1:], extra, 1)], 1),
                    jnp.pad(s.coef, ((0, 0), (0, extra))))

        rows, coef = zip(*(pad(s) for s in stencils))
        return cls(jnp.concatenate(rows), jnp.concatenate(coef))

    @property
    def count(self) -> int:
        return self.rows.shape[0]

    def vectors(self, vertices: Float[Array, "n 2"]) -> Float[Array, "m 2"]:
        """Each row applied to `(n, 2)` vertices."""
        return jnp.einsum("mk,mkd->md", self.coef, vertices[self.rows])

    def triplets(self) -> tuple[Int[Array, " mk"], Int[Array, " mk"], Float[Array, " mk"]]:
        """The rows as a sparse matrix's `(row, column, value)` entries (repeated entries
        add up)."""
        m, k = self.rows.shape
        return jnp.repeat(jnp.arange(m), k), self.rows.reshape(-1), self.coef.reshape(-1)


def apply_stencils(rows: Int[Array, "m k"], coef: Float[Array, "m k"],
                   columns: Float[Array, "2 n"]) -> Complex[Array, " m"]:
    """`D V`: each row `r` is `sum_k coef[r, k] V[rows[r, k]]`, gathered as complex
    numbers (one complex scalar per index gathers faster on the CPU than a row of two
    floats)."""
    return jnp.sum(coef * jax.lax.complex(columns[0], columns[1])[rows], axis=1)


def apply_stencils_transpose(rows: Int[Array, "m k"], coef: Float[Array, "m k"],
                             u: Complex[Array, " m"], n: int) -> Complex[Array, " n"]:
    """`D^T u`, the transpose of `apply_stencils`, onto `n` vertices."""
    return jnp.zeros(n, u.dtype).at[rows.reshape(-1)].add((coef * u[:, None]).reshape(-1))


def transpose_table(rows: Int[ArrayLike, "m k"], coef: Float[ArrayLike, "m k"],
                    n: int) -> Int[np.ndarray, "n d"]:
    """For each of `n` vertices, the entries of the stencil rows that touch it: flat
    indices into `rows.reshape(-1)`, padded with `m * k` (one past the last entry).

    `D^T u` is then a gather per vertex instead of a scatter (`apply_stencils_transpose`),
    which XLA's CPU backend runs several times faster on many right-hand sides. Entries
    with a zero coefficient (the padding of narrower rows) are left out. Computed on the
    host from concrete rows: the table's width is the largest count.
    """
    rows, coef = np.asarray(rows).reshape(-1), np.asarray(coef).reshape(-1)
    entries = np.flatnonzero(coef != 0)
    vertex = rows[entries]
    order = np.argsort(vertex, kind="stable")
    counts = np.bincount(vertex, minlength=n)
    first = np.cumsum(counts) - counts
    table = np.full((n, max(int(counts.max(initial=0)), 1)), rows.size, np.int32)
    sorted_vertex = vertex[order]
    table[sorted_vertex, np.arange(len(order)) - first[sorted_vertex]] = entries[order]
    return table


def length_scale(squared_length: Array, length: ArrayLike) -> Array:
    """The factor that turns a vector of squared length `squared_length` to length
    `length`: `length / |v|`, and 0 for a zero vector (instead of 0/0), with finite
    gradients there. The local step's one nonlinearity, shared by the energy, the
    fixed-G step, the least-squares residuals and the many-frames iteration."""
    nonzero = squared_length > 0
    return jnp.where(nonzero, length * jax.lax.rsqrt(jnp.where(nonzero, squared_length, 1.0)), 0.0)



# Rows in blocks: `((rows, group), ...)`, each block `rows` consecutive rows in groups of
# `group` consecutive rows that turn together (1: each row alone). Static: the layout of
# the local terms' merged rows.
Blocks = tuple[tuple[int, int], ...]


def group_sum(values: Array, blocks: Blocks) -> Array:
    """Each row's group's sum of `values` (rows along the first axis, laid out as
    `blocks`), repeated on every row of the group."""
    parts, start = [], 0
    for rows, group in blocks:
        part = values[start:start + rows]
        if group > 1:
            total = part.reshape(rows // group, group, *part.shape[1:]).sum(1, keepdims=True)
            part = jnp.broadcast_to(total, (rows // group, group, *part.shape[1:])).reshape(
                part.shape)
        parts.append(part)
        start += rows
    return parts[0] if len(parts) == 1 else jnp.concatenate(parts)


def turn_rest(y: Complex[Array, " m"], rest: Complex[Array, " m"], blocks: Blocks
              ) -> Complex[Array, " m"]:
    """The local step's targets: each row's rest vector `rest[r]` turned by the rotation
    that best carries its group's rest vectors onto their current vectors `y` (the 2D
    Procrustes fit, `u = S / |S|` with `S = sum_r y_r conj(rest_r)` over the group).

    A row alone in its group is turned along its own vector, to its rest length (the
    Laplacian and edge rows). A zero fit (zero current or rest vectors) gives a zero
    target, with finite gradients.
    """
    fit = group_sum(y * jnp.conj(rest), blocks)
    return fit * length_scale(jnp.real(fit) ** 2 + jnp.imag(fit) ** 2, 1.0) * rest


def merge_blocks(blocks: Blocks) -> Blocks:
    """`blocks` with neighbours of the same group size merged (one slice each)."""
    out: list[tuple[int, int]] = []
    for rows, group in blocks:
        if out and out[-1][1] == group:
            out[-1] = (out[-1][0] + rows, group)
        elif rows:
            out.append((rows, group))
    return tuple(out)
