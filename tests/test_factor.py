"""The global step: the paper's dense G against the sparse factor of the normal matrix."""

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import pytest

import mvcjax
from mvcjax.advanced import DenseFactor, FactorSolver, SparseFactor
from mvcjax.energy._factor import as_factor_method, sparse_operators

from conftest import directional_derivatives, drag, local_point

# Agreement with references to many digits, and the solvers' internals: in float64.
pytestmark = pytest.mark.float64


@pytest.fixture(scope="module")
def small_full(ring_shape):
    """The ring (a shape with a hole) solved on its own coarse shape mesh."""
    return mvcjax.Rig.build(ring_shape, [[35.0, 0.0], [-35.0, 0.0]], control=mvcjax.FullSolve(),
                            shape_spacing=9.0, factor=mvcjax.advanced.SparseLU(), dtype=jnp.float64)


def test_sparse_and_dense_steps_agree(small_full):
    energy = small_full.energy
    dense, sparse = mvcjax.advanced.DenseG()(energy), mvcjax.advanced.SparseLU()(energy)
    assert isinstance(dense, DenseFactor) and isinstance(sparse, SparseFactor)
    targets, v = local_point(small_full, [[10.0, 5.0], [0.0, -3.0]], 1e-2)
    a = dense.step(v.T, dense.handle_part(targets))
    b = sparse.step(v.T, sparse.handle_part(targets))
    np.testing.assert_allclose(a, b, atol=1e-9)


def test_factor_is_chosen_by_size(horse_rig, small_full):
    assert isinstance(horse_rig.factor, DenseFactor)
    # ~150 vertices
    assert isinstance(mvcjax.advanced.FactorBySize()(small_full.energy), DenseFactor)
    with pytest.raises(TypeError, match="factor must be a factor object"):
        as_factor_method("cholesky")(small_full.energy)


def test_gradient_through_the_sparse_solve(small_full):
    def loss(t):
        out = small_full.deform(t, mvcjax.FixedG(iterations=10))
        return jnp.sum(out[::7] ** 2) / 100.0

    exact, approx = directional_derivatives(loss, drag(small_full, [[6.0, 2.0], [0.0, 0.0]]))
    assert exact == pytest.approx(approx, rel=1e-6)


def test_vmap_through_the_sparse_solve(small_full):
    batch = jnp.stack([drag(small_full, [[s, 0.0], [0.0, -s]]) for s in (0.0, 4.0, 9.0)])
    together = jax.jit(jax.vmap(small_full.deform))(batch)
    for k in range(3):
        np.testing.assert_allclose(together[k], small_full.deform(batch[k]), atol=1e-9)


def test_new_weights_refactor_the_sparse_factor(ring_shape, small_full):
    weights = mvcjax.Weights(handle=30.0, arap=0.5)
    built = mvcjax.Rig.build(ring_shape, [[35.0, 0.0], [-35.0, 0.0]], control=mvcjax.FullSolve(),
                             shape_spacing=9.0, factor=mvcjax.advanced.SparseLU(), weights=weights,
                             dtype=jnp.float64)
    targets = drag(small_full, [[8.0, 0.0], [0.0, 0.0]])
    np.testing.assert_allclose(small_full.with_weights(weights).deform(targets),
                               built.deform(targets), atol=1e-9)
    with pytest.raises(ValueError, match="outside the transformation"):
        jax.jit(lambda w: small_full.with_weights(w).deform(targets))(weights)


def test_normal_products_agree_and_invert(small_full):
    # N x: the least-squares solvers' structured Gauss-Newton matrix is N less the
    # rotation terms, on either factor.
    energy = small_full.energy
    dense, sparse = mvcjax.advanced.DenseG()(energy), mvcjax.advanced.SparseLU()(energy)
    x = jax.random.normal(jax.random.key(2), (2, energy.num_vertices), energy.rest.dtype)
    product = sparse.multiply_normal(x)
    np.testing.assert_allclose(product, dense.multiply_normal(x), rtol=1e-10,
                               atol=1e-10 * float(jnp.abs(product).max()))
    np.testing.assert_allclose(sparse.solve_normal(product), x, rtol=1e-8, atol=1e-9)


@pytest.mark.parametrize("kind", [mvcjax.advanced.DenseG(), mvcjax.advanced.SparseLU()],
                         ids=["dense", "sparse"])
def test_factors_as_lineax_operators_and_solvers(small_full, kind):
    # N and N^{-1} as lineax operators: N materialises to A^T W A from the sparse
    # operators; lineax's own CG, preconditioned by N^{-1}, solves with N in one step;
    # FactorSolver solves with it directly, and differentiably.
    factor = kind(small_full.energy)
    normal, inverse = factor.normal_operator(), factor.normal_inverse_operator()
    assert lx.is_symmetric(normal) and lx.is_positive_semidefinite(inverse)
    n = small_full.energy.num_vertices
    terms = small_full.energy.terms(normalised=True)
    ops = sparse_operators(small_full.energy)
    expected = sum(float(t.weight) * (op.T @ op).toarray() for t, op in zip(terms, ops))
    x = jax.random.normal(jax.random.key(7), (2, n), jnp.float64)
    np.testing.assert_allclose(normal.mv(x), x @ expected, rtol=1e-9,
                               atol=1e-9 * np.abs(expected).max())
    b = normal.mv(x)
    cg = lx.linear_solve(normal, b, lx.CG(rtol=1e-12, atol=1e-12, max_steps=3),
                         options={"preconditioner": inverse})
    assert cg.stats["num_steps"] <= 2
    np.testing.assert_allclose(cg.value, x, rtol=1e-7, atol=1e-8)
    direct = lx.linear_solve(normal, b, FactorSolver(factor))
    np.testing.assert_allclose(direct.value, x, rtol=1e-8, atol=1e-9)
    grad = jax.grad(lambda c: jnp.sum(lx.linear_solve(normal, c * b, FactorSolver(factor))
                                      .value ** 2))(1.0)
    assert float(grad) == pytest.approx(2 * float(jnp.sum(x**2)), rel=1e-7)
    with pytest.raises(ValueError, match="pass factor.normal_operator"):
        lx.linear_solve(lx.MatrixLinearOperator(jnp.eye(3)), jnp.ones(3), FactorSolver(factor))


def test_gauss_newton_on_the_sparse_factor_matches_the_dense(small_full):
    targets = drag(small_full, [[10.0, 5.0], [0.0, -3.0]])
    sparse, info = small_full.solve(targets, mvcjax.GaussNewton(), return_info=True)
    dense_rig = eqx.tree_at(lambda r: r.factor, small_full,
                            mvcjax.advanced.DenseG()(small_full.energy))
    dense = dense_rig.solve(targets, mvcjax.GaussNewton())
    assert bool(info.converged), int(info.iterations)
    np.testing.assert_allclose(sparse, dense, atol=1e-7 * float(small_full.frame.scale))


def test_gauss_newton_on_the_sparse_factor_over_frames(small_full):
    # vmapped: the host solve of the preconditioner takes the frames as one batch.
    targets = jnp.stack([drag(small_full, [[10.0, 5.0], [0.0, -3.0]]),
                         drag(small_full, [[-4.0, 8.0], [2.0, 0.0]])])
    solver = mvcjax.GaussNewton()
    together = jax.vmap(lambda t: small_full.solve(t, solver))(targets)
    for k in range(2):
        np.testing.assert_allclose(together[k], small_full.solve(targets[k], solver), rtol=0,
                                   atol=1e-7 * float(small_full.frame.scale))


def test_factors_are_blind_to_the_weights_overall_scale(small_full):
    # G does not change when every weight is scaled alike; the factors normalise the
    # weights so that their rounding does not either (1e-30 squared underflowed).
    energy = small_full.energy
    tiny = eqx.tree_at(lambda e: e.weights, energy,
                       jax.tree.map(lambda w: 1e-30 * w, energy.weights))
    targets, v = local_point(small_full, [[10.0, 5.0], [0.0, -3.0]], 1e-2)
    for make in (mvcjax.advanced.DenseG(), mvcjax.advanced.SparseLU()):
        a, b = make(energy), make(tiny)
        np.testing.assert_allclose(b.step(v.T, b.handle_part(targets)),
                                   a.step(v.T, a.handle_part(targets)), atol=1e-12)


def test_scaling_all_weights_under_jit_and_grad_changes_nothing(horse_rig):
    # with_weights rebuilds the dense factor inside jit: its normalisation must jit and
    # differentiate, and the deformation depends on the weights' ratios only.
    targets = drag(horse_rig, np.zeros((horse_rig.handle_positions.shape[0], 2)) + 5.0)

    def loss(s):
        weights = mvcjax.Weights.paper(laplacian=s, mvc=s, length=s, handle=100.0 * s)
        return jnp.sum(horse_rig.with_weights(weights).deform(targets)[::50] ** 2)

    value, grad = jax.jit(jax.value_and_grad(loss))(jnp.asarray(3.0))
    assert float(value) == pytest.approx(float(loss(1.0)), rel=1e-12)
    assert abs(float(grad)) < 1e-9 * float(value)


@pytest.mark.parametrize("weights", [mvcjax.Weights(),
                                     mvcjax.Weights.paper(laplacian=3.0, length=0.5)],
                         ids=["default", "paper"])
def test_steps_of_many_frames_match_single_steps(ring_shape, weights):
    # step_frames applies N^{-1} to A^T W b gathered through the spread table, where step
    # applies G: the same map. On a control mesh with a hole, inner and polygon vertices.
    rig = mvcjax.Rig.build(ring_shape, [[35.0, 0.0], [-35.0, 0.0]], weights=weights,
                           dtype=jnp.float64)
    factor = rig.factor
    assert isinstance(factor, DenseFactor)
    rng = np.random.default_rng(0)
    rest = factor.rest.T
    frames = rest[None] + jnp.asarray(rng.normal(scale=0.02, size=(3, *rest.shape)))
    targets = rest[factor.handle_rows[:, 0]][None] + jnp.asarray(
        rng.normal(scale=0.05, size=(3, factor.handle_rows.shape[0], 2)))
    data = factor.handle_part_frames(targets)
    many = factor.step_frames(jnp.moveaxis(frames, 0, -1), data)
    for k in range(3):
        one = factor.step(frames[k].T, factor.handle_part(targets[k]))
        np.testing.assert_allclose(many[..., k], one.T, atol=1e-12)


def test_spread_table_is_the_transpose_of_the_local_rows(horse_rig):
    # A^T W b by the table's gather equals the dense transpose product.
    from mvcjax.energy import transpose_table
    from mvcjax.energy._factor import _local_row_weights, _local_rows

    factor = horse_rig.factor
    rows, coef, _ = _local_rows(horse_rig.energy)
    m, n = rows.shape[0], factor.rest.shape[1]
    dense = np.zeros((m, n))
    np.add.at(dense, (np.repeat(np.arange(m), rows.shape[1]), np.asarray(rows).reshape(-1)),
              np.asarray(coef).reshape(-1))
    b = np.random.default_rng(1).normal(size=m)
    expected = dense.T @ (np.asarray(_local_row_weights(horse_rig.energy)) * b)
    gathered = np.asarray(factor.spread_coef) * np.append(b, 0.0)[
        np.minimum(np.asarray(factor.spread) // rows.shape[1], m)]
    np.testing.assert_allclose(gathered.sum(axis=1), expected, rtol=1e-12, atol=1e-12)
    # Zero coefficients (the edge rows' padding) are left out of the table.
    table = transpose_table(rows, coef, n)
    touching = np.bincount(np.asarray(rows)[np.asarray(coef) != 0], minlength=n)
    assert table.shape == (n, touching.max())
    np.testing.assert_array_equal((table < rows.size).sum(axis=1), touching)


def test_dense_factor_of_a_traced_energy_asks_for_the_table(horse_rig):
    from mvcjax.energy import dense_factor

    with pytest.raises(ValueError, match="rebuild"):
        jax.jit(lambda e: dense_factor(e).normal)(horse_rig.energy)
    rebuilt = jax.jit(lambda e: horse_rig.factor.rebuild(e).normal_inverse)(horse_rig.energy)
    np.testing.assert_allclose(rebuilt, horse_rig.factor.normal_inverse, rtol=1e-9, atol=1e-9)
