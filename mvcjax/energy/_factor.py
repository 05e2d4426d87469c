"""The global step of the fixed-G iteration (eq. 8): `V <- (A^T W A)^{-1} A^T W b(V)`.

Two factors behind one interface (`handle_part`, `step`):

- `DenseFactor`: the paper's `G = (A^T W A)^{-1} A^T W`, a dense matrix computed once.
  One step is one small matrix product: the right choice on a control mesh of a few
  hundred vertices. It is pure JAX, so new weights recompute it inside `jit` and `grad`.
- `SparseFactor`: the normal matrix `N = A^T W A` factored once on the host by a sparse
  LU (SuperLU, through scipy, with a symmetric fill-reducing ordering), applied inside
  the iteration through `jax.pure_callback` wrapped in `jax.lax.custom_linear_solve`,
  so that `jax.grad` differentiates through it (the transposed solve is the same
  solve: `N` is symmetric). It stores `O(nnz)` numbers where a dense `G` would store
  `n x 3n`: the full solve on a shape mesh of 20k or 100k vertices fits in memory.
"""

from __future__ import annotations

import abc
import itertools
import weakref
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import scipy.sparse
import scipy.sparse.linalg
from jaxtyping import Array, ArrayLike, Complex, Float, Int

from ..core import checked_option, compiled_by, to_device
from ._energy import Energy
from ._stencils import (
    Blocks,
    Stencil,
    apply_stencils,
    apply_stencils_transpose,
    length_scale,
    merge_blocks,
    transpose_table,
    turn_rest,
)


def operator_triplets(energy: Energy) -> list[tuple[Array, Array, Array, int]]:
    """Each term's constant matrix (`L, M, H, C` of eq. 7, then any extra term) as
    `(rows, cols, values, row_count)`.

    Duplicate `(row, col)` entries add up (the zero-weight padding of the MVC rings
    adds zeros). Pure JAX: works on traced and on concrete energies.
    """
    return [(*s.triplets(), s.count) for s in energy.stencils()]


def operators(energy: Energy) -> tuple[Float[Array, "rows n"], ...]:
    """Each term's constant matrix, dense, `(rows, n)` each."""
    n = energy.num_vertices
    return tuple(
        jnp.zeros((count, n), energy.rest.dtype).at[rows, cols].add(values)
        for rows, cols, values, count in operator_triplets(energy)
    )


@compiled_by()
def _operator_arrays(energy: Energy):
    # One compiled call (cached by shapes) instead of dozens of eager small ones.
    return [t[:3] for t in operator_triplets(energy)]


def sparse_operators(energy: Energy) -> tuple[scipy.sparse.csr_matrix, ...]:
    """Each term's constant matrix as a scipy CSR matrix (float64)."""
    n = energy.num_vertices
    counts = [t.count for t in energy.terms()]
    return tuple(
        scipy.sparse.csr_matrix(
            (np.asarray(values, np.float64), (np.asarray(rows), np.asarray(cols))),
            shape=(count, n),
        )
        for (rows, cols, values), count in zip(_operator_arrays(energy), counts)
    )


def _local_rows(
    energy: Energy,
) -> tuple[Int[Array, "m 3"], Float[Array, "m 3"], Complex[Array, " m"]]:
    """The rows of every local term (the Laplacian and edge rows, and any rotated term)
    merged, so that the local step is one gather: row `r` is
    `y_r = sum_k coef[r, k] V[rows[r, k]]`, its target its rest vector turned by its
    group's rotation (`turn_rest`; the groups laid out as `local_blocks` says)."""
    local = [t for t in energy.terms() if t.is_local]
    merged = Stencil.concatenate(*(t.stencil for t in local))
    return merged.rows, merged.coef, jnp.concatenate([t.local_rest() for t in local])


def local_blocks(energy: Energy) -> Blocks | None:
    """The blocks of a factor's local rows (`AbstractFactor.blocks`): None where every
    row turns alone. From the terms' shapes only: nothing is computed or compiled."""
    terms = jax.eval_shape(lambda e: e.terms(), energy)
    blocks = merge_blocks(sum((t.blocks() for t in terms if t.is_local), ()))
    return blocks if any(group > 1 for _, group in blocks) else None


def _local_fields(energy: Energy) -> dict[str, Array | None]:
    """A factor's local-step arrays (`AbstractFactor`): rows, coefficients, rest
    lengths, and the rest vectors where some term is rotated (`local_blocks`)."""
    rows, coef, rest = _local_rows(energy)
    return dict(rows=rows, coef=coef, length=jnp.abs(rest).astype(energy.rest.dtype),
                rotation=None if local_blocks(energy) is None else rest)


@compiled_by()
def local_stencil(energy: Energy) -> tuple[Int[Array, "m 3"], Float[Array, "m 3"]]:
    # One compiled call (cached by shapes) instead of dozens of eager small ones, each
    # compiled anew for a rig of new sizes.
    rows, coef, _ = _local_rows(energy)
    return rows, coef


def _local_row_weights(energy: Energy) -> Float[Array, " m"]:
    """The weight of each merged turned row (its term's), in `_local_rows`' order."""
    return jnp.concatenate([
        jnp.broadcast_to(t.weight, (t.count,)) for t in energy.terms(normalised=True)
        if t.is_local]).astype(energy.rest.dtype)


class StepData(eqx.Module):
    """What a solve's targets fix for every fixed-G step (`AbstractFactor.handle_part`).

    Steps are taken relative to the rest mesh, which is a fixed point for the rest
    targets: `V' = V_rest + G (b(V) - b(V_rest))`. In float32 the plain `V' = G b(V)`
    rounds `G b` at every step, and 15 steps left the rest shape by 6e-5 of its diagonal
    on a comb; relative to rest, the rest targets give the rest shape exactly, and the
    rounding scales with the deformation.

    Attributes:
        rest_local: `(m,)` `[delta; e]` at the rest mesh, as the step computes it.
        constant: `(2, n)` the rest mesh and the targets' share of the step (`(n, 2, f)`
            for many frames, `handle_part_frames`).
    """

    rest_local: Complex[Array, " m"]
    constant: Float[Array, "2 n"] | Float[Array, "n 2 f"]


class AbstractFactor(eqx.Module):
    """The global step, precomputed for one set of weights.

    The local-step data is shared: the merged Laplacian and edge rows, then any other
    local term's (`rows`, `coef`), their rest lengths (`length`), and where a term is
    rotated (its rows turn together, `Term.rotated`) their rest vectors (`rotation`) and
    groups (`blocks`, static); and the rest mesh (`rest`) and the rows of `C` (`handle_rows`,
    `handle_coef`), which steps are taken relative to (`StepData`).

    Steps take and return the vertices coordinate-major, as the rows `V^T` of shape
    `(2, n)`, the fixed-G loop's layout, and `(n, 2, f)` for many frames (why: "Vertex
    layouts" in the docs' how-it-works page).
    """

    rows: eqx.AbstractVar[Int[Array, "m 3"]]
    coef: eqx.AbstractVar[Float[Array, "m 3"]]
    length: eqx.AbstractVar[Float[Array, " m"]]
    rest: eqx.AbstractVar[Float[Array, "2 n"]]
    handle_rows: eqx.AbstractVar[Int[Array, "h j"]]
    handle_coef: eqx.AbstractVar[Float[Array, "h j"]]
    rotation: eqx.AbstractVar[Complex[Array, " m"] | None]
    blocks: eqx.AbstractVar[Blocks | None]

    def local_targets(self, columns: Float[Array, "2 n"]) -> Complex[Array, " m"]:
        """`[delta(V); e(V); ...]`: each Laplacian and edge vector turned to its rest
        length, each rotated row's rest vector turned by its group's rotation."""
        y = apply_stencils(self.rows, self.coef, columns)
        if self.rotation is None:
            return y * length_scale(jnp.real(y) ** 2 + jnp.imag(y) ** 2, self.length)
        return turn_rest(y, self.rotation, self.blocks)

    def target_shift(self, targets: Float[Array, "h 2"]) -> Float[Array, "2 h"]:
        """The handle targets less the handles' rest positions, coordinate-major."""
        rest = Stencil(self.handle_rows, self.handle_coef).vectors(self.rest.T)
        return targets.T - rest.T

    @abc.abstractmethod
    def handle_part(self, targets: Float[Array, "h 2"]) -> StepData:
        """What the handle targets fix for every step (computed once per solve)."""

    def step(self, columns: Float[Array, "2 n"], handle_part: StepData) -> Float[Array, "2 n"]:
        """One fixed-G iteration `G b(V)` on the vertices' coordinate rows `V^T`, given
        `handle_part(targets)`."""
        return self.global_step(self.local_targets(columns), handle_part)

    @abc.abstractmethod
    def global_step(self, local: Complex[Array, " m"], handle_part: StepData
                    ) -> Float[Array, "2 n"]:
        """`G b` for given Laplacian and edge targets `[delta; e]` (complex, in the local
        rows' order) and the handle targets of `handle_part`: the vertices, coordinate
        rows, that meet them best."""

    def handle_part_frames(self, targets: Float[Array, "f h 2"]) -> StepData:
        """`handle_part` for many frames: `constant` is `(n, 2, f)`, vertices first and
        frames last (the layout of `step_frames`); `rest_local` is shared."""
        constant = jax.vmap(lambda t: self.handle_part(t).constant)(targets)
        return StepData(self.local_targets(self.rest), jnp.transpose(constant, (2, 1, 0)))

    def step_frames(self, vertices: Float[Array, "n 2 f"], data: StepData) -> Float[Array, "n 2 f"]:
        """`step` for many frames, laid out `(n, 2, f)` (`data` from
        `handle_part_frames`). Vmapped by default; a factor may do better."""
        return jax.vmap(lambda v, c: self.step(v.T, StepData(data.rest_local, c.T)).T,
                        in_axes=-1, out_axes=-1)(vertices, data.constant)

    def _columns(self) -> jax.ShapeDtypeStruct:
        return jax.ShapeDtypeStruct(self.rest.shape, self.rest.dtype)

    def normal_operator(self) -> lx.FunctionLinearOperator:
        """`N = A^T W A` as a lineax operator on coordinate rows `(2, n)`, tagged
        symmetric positive semidefinite (it is definite: the handles pin it)."""
        return lx.FunctionLinearOperator(self.multiply_normal, self._columns(), _SPD)

    def normal_inverse_operator(self) -> lx.FunctionLinearOperator:
        """`N^{-1}`, applied by the factor, as a lineax operator: the preconditioner of
        any conjugate-gradient solve with a matrix near `N` (the least-squares solvers'
        Gauss-Newton matrix, the implicit gradients' Hessian; lineax's `lx.CG` takes it
        as `options={"preconditioner": ...}`)."""
        return lx.FunctionLinearOperator(self.solve_normal, self._columns(), _SPD)

    @abc.abstractmethod
    def solve_normal(self, rhs: Float[Array, "2 n"]) -> Float[Array, "2 n"]:
        """`N^{-1} rhs` (coordinate rows, as `step`) for the constant normal matrix
        `N = A^T W A`: the Gauss-Newton matrix of the energy without its rotations, the
        least-squares solvers' preconditioner."""

    @abc.abstractmethod
    def multiply_normal(self, columns: Float[Array, "2 n"]) -> Float[Array, "2 n"]:
        """`N columns` (coordinate rows, as `step`): the least-squares solvers' structured
        Gauss-Newton matrix is `N` less the rotation terms."""

    @abc.abstractmethod
    def rebuild(self, energy: Energy, same_terms: bool = True) -> AbstractFactor:
        """The same kind of factor for the energy's (new) weights; `same_terms=False`
        where they put other terms in the energy (not under `jit`: the rows' tables are
        made anew on the host)."""


# The normal matrix is symmetric positive definite; lineax asks for the tags.
_SPD = frozenset({lx.symmetric_tag, lx.positive_semidefinite_tag})


class FactorSolver(lx.AbstractLinearSolver):
    """A factor as a lineax linear solver, for its own `normal_operator`:
    `lx.linear_solve(factor.normal_operator(), b, FactorSolver(factor))` solves with `N`
    by the factor (the dense inverse, or the sparse LU), differentiably.

    Attributes:
        factor: the factor whose normal matrix is solved with.
    """

    factor: AbstractFactor

    def init(self, operator: lx.AbstractLinearOperator, options: dict[str, Any]):
        del options
        if operator.in_structure() != self.factor._columns():
            raise ValueError(
                f"FactorSolver solves with its factor's normal matrix, on "
                f"{self.factor._columns()}; the operator given acts on "
                f"{operator.in_structure()}: pass factor.normal_operator()."
            )
        return None

    def compute(self, state, vector, options):
        del state, options
        return self.factor.solve_normal(vector), lx.RESULTS.successful, {}

    def transpose(self, state, options):
        return state, options  # N is symmetric

    def conj(self, state, options):
        return state, options  # and real

    def assume_full_rank(self):
        return True


class DenseFactor(AbstractFactor):
    """The paper's dense `G` (eq. 8), its columns split by what they act on.

    With the weights folded in, one step is `V <- G_shape @ [delta(V); e(V)] + G_handle @ U`.

    Attributes:
        shape: `(m, n)` the columns of `G` acting on `delta` and `e`, transposed
            (`G_shape^T`, for the coordinate-major product).
        handle: `(n, h)` the columns acting on the handle targets.
        normal: `(n, n)` the normal matrix `N = A^T W A`.
        normal_inverse: `(n, n)` `N^{-1}`, where `G = N^{-1} A^T W`.
        spread: `(n, d)` the entries of the local rows (flat indices into `rows`) that
            touch each vertex, padded with `rows.size` (`transpose_table`).
        spread_coef: `(n, d)` their coefficients times their row's weight (0 on
            padding): `A^T W b` for the local rows is a gather of `b` by `spread`.
        rows, coef, length, rest, handle_rows, handle_coef, rotation, blocks: see
            `AbstractFactor`.
    """

    shape: Float[Array, "m n"]
    handle: Float[Array, "n h"]
    normal: Float[Array, "n n"]
    normal_inverse: Float[Array, "n n"]
    spread: Int[Array, "n d"]
    spread_coef: Float[Array, "n d"]
    rows: Int[Array, "m 3"]
    coef: Float[Array, "m 3"]
    length: Float[Array, " m"]
    rest: Float[Array, "2 n"]
    handle_rows: Int[Array, "h j"]
    handle_coef: Float[Array, "h j"]
    rotation: Complex[Array, " m"] | None
    blocks: Blocks | None = eqx.field(static=True)

    def handle_part(self, targets):
        return StepData(self.local_targets(self.rest),
                        self.rest + self.target_shift(targets) @ self.handle.T)

    def global_step(self, local, handle_part):
        b = local - handle_part.rest_local
        return jnp.stack([jnp.real(b), jnp.imag(b)]) @ self.shape + handle_part.constant

    def step_frames(self, vertices, data):
        # Not vmapped: all frames in one product (the layout: "Vertex layouts" in the
        # docs' how-it-works page). The product is `N^{-1} (A^T W b)`, not `G b`:
        # `A^T W b` is a cheap gather (`spread`), and `N^{-1}` is `n x n` where `G` is
        # `n x m`, m near 2.3 n on the horse: fewer flops per frame.
        if self.rotation is not None:  # rotated rows: each frame's step, vmapped
            return super().step_frames(vertices, data)

        def local(coordinate):
            # One gather per stencil column: faster than one gather of all three
            # columns followed by a contraction.
            return sum(self.coef[:, k, None] * coordinate[self.rows[:, k]]
                       for k in range(self.rows.shape[1]))

        x, y = local(vertices[:, 0]), local(vertices[:, 1])
        scale = length_scale(x * x + y * y, self.length[:, None])
        b = jnp.stack([x * scale - jnp.real(data.rest_local)[:, None],
                       y * scale - jnp.imag(data.rest_local)[:, None]], axis=1)
        m, k = self.rows.shape
        row = jnp.minimum(self.spread // k, m - 1)  # the padding's coefficient is 0
        spread = sum(self.spread_coef[:, d, None, None] * b[row[:, d]]
                     for d in range(self.spread.shape[1]))
        return jnp.einsum("nk,kdf->ndf", self.normal_inverse, spread) + data.constant

    def solve_normal(self, rhs):
        return rhs @ self.normal_inverse  # N^{-1} is symmetric

    def multiply_normal(self, columns):
        return columns @ self.normal

    def rebuild(self, energy, same_terms=True):
        return dense_factor(energy, self.spread if same_terms else None)


def dense_factor(energy: Energy, spread: Int[ArrayLike, "n d"] | None = None) -> DenseFactor:
    """Precompute `G` for the energy's weights (pure JAX: jits, differentiates).

    `spread` is the local rows' `transpose_table`, which depends on the mesh only: it is
    computed on the host when not given, so a traced energy (new weights under `jit`)
    must come with its rig's (`factor.rebuild` passes it on).
    """
    if spread is None:
        if isinstance(energy.rest, jax.core.Tracer):
            raise ValueError(
                "dense_factor of a traced energy needs the mesh's spread table: call "
                "rig.factor.rebuild(energy) (or rig.with_weights) instead."
            )
        rows, coef = local_stencil(energy)
        spread = transpose_table(rows, coef, energy.num_vertices)
    return _dense_factor(energy, spread if isinstance(spread, jax.Array)
                         else to_device(spread, np.int32))


@compiled_by()
def _dense_factor(energy: Energy, spread: Int[Array, "n d"]) -> DenseFactor:
    # Weights normalised: the same G, with rounding blind to the weights' scale.
    terms = energy.terms(normalised=True)
    ops = operators(energy)
    normal = sum(t.weight * op.T @ op for t, op in zip(terms, ops))
    turned = [t.weight * op.T for t, op in zip(terms, ops) if t.is_local]
    (handle,) = [t.weight * op.T for t, op in zip(terms, ops) if t.pinned]
    cho = jax.scipy.linalg.cho_factor(normal)
    g = jax.scipy.linalg.cho_solve(cho, jnp.concatenate([*turned, handle], axis=1))
    split = g.shape[1] - handle.shape[1]
    local = _local_fields(energy)
    entries = (local["coef"] * _local_row_weights(energy)[:, None]).reshape(-1)
    return DenseFactor(
        shape=g[:, :split].T, handle=g[:, split:], normal=normal,
        normal_inverse=jax.scipy.linalg.cho_solve(
            cho, jnp.eye(normal.shape[0], dtype=normal.dtype)),
        spread=spread, spread_coef=jnp.append(entries, 0.0)[spread],
        rest=energy.rest.T, handle_rows=energy.handles, handle_coef=energy.handle_coef,
        blocks=local_blocks(energy), **local,
    )


# The host solves alive, by key. A callback is part of the compiled program, so the
# program looks its factor up by a key passed as data: compiled once per size, a rig of
# that size (a new shape, new weights) reuses it instead of compiling and keeping its own.
_HOST_SOLVES: weakref.WeakValueDictionary[int, _HostSolve] = weakref.WeakValueDictionary()
_HOST_KEYS = itertools.count()


def _host_solve(key: Int[ArrayLike, "*batch"],
                rhs: Float[ArrayLike, "*batch n 2"]) -> Float[np.ndarray, "*batch n 2"]:
    # Under vmap the key is broadcast with the right-hand sides: any entry is the key.
    return _HOST_SOLVES[int(np.asarray(key).reshape(-1)[0])](rhs)


class _HostSolve:
    """A sparse LU of the normal matrix, applied on the host to any batch of right-hand
    sides. A static field of the factor: equal to any other of its size (the program
    does not depend on which), found by `key` at run time."""

    def __init__(self, normal: scipy.sparse.csc_matrix):
        self.size = normal.shape[0]
        self.key = next(_HOST_KEYS)
        _HOST_SOLVES[self.key] = self
        # The normal matrix is symmetric positive definite: a symmetric ordering, with
        # pivoting off so that SuperLU keeps it, gives a Cholesky-like fill; partial
        # pivoting would break the symmetry and make large factors far slower.
        self.lu = scipy.sparse.linalg.splu(
            normal, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
            options=dict(SymmetricMode=True),
        )

    def __eq__(self, other) -> bool:
        return isinstance(other, _HostSolve) and other.size == self.size

    def __hash__(self) -> int:
        return hash((_HostSolve, self.size))

    def __call__(self, rhs: Float[ArrayLike, "*batch n 2"]) -> Float[np.ndarray, "*batch n 2"]:
        # rhs: (..., n, 2), any leading batch axes (vmap): solve them all at once as columns.
        rhs = np.asarray(rhs)
        lead = rhs.shape[:-2]
        cols = np.moveaxis(rhs, -2, 0).reshape(self.size, -1).astype(np.float64)
        out = self.lu.solve(cols).reshape((self.size, *lead, rhs.shape[-1]))
        return np.moveaxis(out, 0, -2).astype(rhs.dtype)


class SparseFactor(AbstractFactor):
    """`N = A^T W A` factored once on the host; steps solve `N V = A^T W b(V)`.

    Attributes:
        rows, coef, length, rest, handle_rows, handle_coef, rotation, blocks: see
            `AbstractFactor`.
        row_weight: `(m,)` the weight of each local row (Laplacian or length weight).
        normal_rows, normal_cols, normal_values: `N` as triplets, for the matrix-vector
            product that `custom_linear_solve` differentiates through.
        handle_weight: the handles' weight.
        host: the host-side sparse LU of `N` (static); `host_key` finds it at run time.
    """

    rows: Int[Array, "m 3"]
    coef: Float[Array, "m 3"]
    length: Float[Array, " m"]
    row_weight: Float[Array, " m"]
    normal_rows: Int[Array, " nnz"]
    normal_cols: Int[Array, " nnz"]
    normal_values: Float[Array, " nnz"]
    rest: Float[Array, "2 n"]
    handle_rows: Int[Array, "h j"]
    handle_coef: Float[Array, "h j"]
    handle_weight: Float[Array, ""]
    host_key: Int[Array, ""]
    host: _HostSolve = eqx.field(static=True)
    rotation: Complex[Array, " m"] | None
    blocks: Blocks | None = eqx.field(static=True)

    def _multiply(self, x: Float[Array, "n 2"]) -> Float[Array, "n 2"]:
        return jax.ops.segment_sum(
            self.normal_values[:, None] * x[self.normal_cols], self.normal_rows, self.host.size
        )

    def _solve(self, rhs: Float[Array, "n 2"]) -> Float[Array, "n 2"]:
        def solve(_, b):
            return jax.pure_callback(_host_solve, jax.ShapeDtypeStruct(b.shape, b.dtype),
                                     self.host_key, b, vmap_method="broadcast_all")

        return jax.lax.custom_linear_solve(self._multiply, rhs, solve, symmetric=True)

    def handle_part(self, targets):
        # Here the constant is the targets' share of the right-hand side, C^T W (U - U_rest).
        n = self.host.size
        shift = self.handle_weight * self.target_shift(targets)
        return StepData(self.local_targets(self.rest), jnp.zeros((2, n), targets.dtype).at[
            :, self.handle_rows].add(self.handle_coef * shift[:, :, None]))

    def global_step(self, local, handle_part):
        # A^T W t: scatter each row's weighted target back onto its vertices.
        t = self.row_weight * (local - handle_part.rest_local)
        z = apply_stencils_transpose(self.rows, self.coef, t, self.host.size)
        rhs = jnp.stack([jnp.real(z), jnp.imag(z)], axis=1) + handle_part.constant.T
        return self.rest + self._solve(rhs).T

    def solve_normal(self, rhs):
        return self._solve(rhs.T).T

    def multiply_normal(self, columns):
        return self._multiply(columns.T).T

    def rebuild(self, energy, same_terms=True):
        return sparse_factor(energy)


@compiled_by()
def _sparse_local_rows(energy: Energy):
    """The local step's arrays, and the weight of each row (its term's)."""
    return _local_fields(energy), _local_row_weights(energy)


def sparse_factor(energy: Energy) -> SparseFactor:
    """Factor `N = A^T W A` for the energy's weights (on the host: not under `jit`)."""
    if isinstance(energy.weights.handle, jax.core.Tracer):
        raise ValueError(
            "A sparse factor is computed on the host and cannot be rebuilt under jax.jit or "
            "jax.grad (new weights on a rig with a sparse factor): call rig.with_weights "
            "outside the transformation, or build the rig with factor='dense'."
        )
    terms = energy.terms(normalised=True)
    normal = sum(float(t.weight) * (op.T @ op) for t, op in zip(terms, sparse_operators(energy)))
    (handle,) = [t for t in terms if t.pinned]
    normal = scipy.sparse.coo_matrix(normal)
    host = _HostSolve(normal.tocsc())
    local, row_weight = _sparse_local_rows(energy)
    dtype = energy.rest.dtype
    as_int = lambda a: to_device(a, np.int32)  # noqa: E731
    return SparseFactor(
        **local,
        blocks=local_blocks(energy),
        row_weight=row_weight,
        normal_rows=as_int(normal.row),
        normal_cols=as_int(normal.col),
        normal_values=to_device(normal.data, dtype),
        rest=energy.rest.T,
        handle_rows=energy.handles,
        handle_coef=energy.handle_coef,
        handle_weight=jnp.asarray(handle.weight, dtype),
        host_key=to_device(host.key, np.int32),
        host=host,
    )


class AbstractFactorMethod(eqx.Module):
    """How `Rig.build` computes the rig's factor from its energy."""

    @abc.abstractmethod
    def __call__(self, energy: Energy) -> AbstractFactor:
        """The factor for the energy's weights."""

    def is_dense(self, vertices: int) -> bool:
        """Whether the factor of a control mesh of this many vertices is a `DenseFactor`."""
        return False


class DenseG(AbstractFactorMethod):
    """The paper's dense `G` (eq. 8): a step is one small matrix product. Pure JAX, so
    new weights recompute it inside `jit` and `grad`; for control meshes up to about a
    thousand vertices (it stores `n x 3n` numbers)."""

    def __call__(self, energy):
        return dense_factor(energy)

    def is_dense(self, vertices):
        return True


class SparseLU(AbstractFactorMethod):
    """The normal matrix factored once on the host by a symmetric sparse LU: `O(nnz)`
    memory, for meshes of thousands of vertices (the full solve). New weights refactor
    it on the host, outside `jit`."""

    def __call__(self, energy):
        return sparse_factor(energy)


class FactorBySize(AbstractFactorMethod):
    """`DenseG` up to `max_dense` vertices, where one product beats a sparse solve, and
    `SparseLU` beyond (the default).

    Attributes:
        max_dense: the largest control mesh given a dense `G` (default 1000).
    """

    max_dense: int = eqx.field(default=1000, static=True)

    def is_dense(self, vertices):
        return vertices <= self.max_dense

    def __call__(self, energy):
        method = DenseG() if self.is_dense(energy.num_vertices) else SparseLU()
        return method(energy)


def as_factor_method(factor) -> AbstractFactorMethod:
    """The factor option of `Rig.build`: an `AbstractFactorMethod`, or a TypeError that
    names the object to write (for a name such as `"sparse"` too)."""
    return checked_option(
        "factor", factor, AbstractFactorMethod,
        {"dense": "mvcjax.advanced.DenseG()", "sparse": "mvcjax.advanced.SparseLU()"},
        described="a factor object, mvcjax.advanced.DenseG(), mvcjax.advanced.SparseLU() "
                  "or mvcjax.advanced.FactorBySize()",
        default="mvcjax.advanced.FactorBySize()")
