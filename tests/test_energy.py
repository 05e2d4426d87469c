import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mvcjax
from mvcjax import datasets
from mvcjax.energy import rigid_alignment
from mvcjax.energy._factor import dense_factor, operators

from conftest import directional_derivatives, drag, local_point

# Tests that compare with references to many digits, or the solvers' internals, are
# marked float64; the others run in float32, as users do.


@pytest.mark.float64
def test_every_residual_vanishes_at_rest(horse_rig):
    e, rest = horse_rig.energy, horse_rig.energy.rest
    for term in [mvcjax.advanced.laplacian_residual, mvcjax.advanced.mvc_residual,
                 mvcjax.advanced.length_residual]:
        assert float(jnp.abs(term(e, rest)).max()) < 1e-12
    pinned = e.handle_points(rest)
    assert float(jnp.abs(mvcjax.advanced.handle_residual(e, rest, pinned)).max()) == 0
    assert float(mvcjax.advanced.total_energy(e, rest, e.handle_points(rest))) < 1e-24
    assert float(horse_rig.energy_at(horse_rig.control_mesh.vertices,
                                     horse_rig.handle_positions)) < 1e-18


@pytest.mark.float64
def test_energy_is_the_weighted_sum_of_squared_terms(horse_rig):
    e = horse_rig.energy
    t, v = local_point(horse_rig, np.ones((5, 2)), 2e-3)
    w = e.weights
    expected = (
        w.laplacian * jnp.sum(mvcjax.advanced.laplacian_residual(e, v) ** 2)
        + w.mvc * jnp.sum(mvcjax.advanced.mvc_residual(e, v) ** 2)
        + w.length * jnp.sum(mvcjax.advanced.length_residual(e, v) ** 2)
        + w.handle * jnp.sum(mvcjax.advanced.handle_residual(e, v, t) ** 2)
    )
    assert float(mvcjax.advanced.total_energy(e, v, t)) == pytest.approx(float(expected), rel=1e-12)


@pytest.mark.float64
def test_energy_gradient_matches_finite_differences(horse_rig):
    e = horse_rig.energy
    t, v = local_point(horse_rig, [[20.0, 5.0]] + [[0.0, 0.0]] * 4, 4e-3, seed=1)
    exact, approx = directional_derivatives(lambda x: mvcjax.advanced.total_energy(e, x, t), v,
                                            seed=2,
                                            h=1e-8)
    assert exact == pytest.approx(approx, rel=1e-6)


def test_zero_length_laplacians_are_safe():
    # A square sampled with a mid-edge vertex: straight stretches have zero rest Laplacian.
    outer = np.array([[0, 0], [5, 0], [10, 0], [10, 10], [0, 10.0]])
    shape = mvcjax.Shape.from_polygon(outer)
    rig = mvcjax.Rig.build(shape, [[2.0, 2.0], [8.0, 8.0]], control=mvcjax.GivenControl(
        np.array([[0, 0], [5, 0], [10, 0], [10, 10], [0, 10], [2, 2], [8, 8.0]]),
        np.array([[0, 1, 5], [1, 2, 6], [1, 6, 5], [2, 3, 6], [3, 4, 6], [4, 5, 6], [4, 0, 5]]),
    ))
    assert float(jnp.min(rig.energy.laplacian_length)) == 0.0
    flat = rig.control_mesh.vertices.at[1].set(jnp.array([5.0, 0.0]))
    grad = jax.grad(lambda v: rig.energy_at(v, rig.handle_positions))(flat)
    assert bool(jnp.all(jnp.isfinite(grad)))
    out = rig.deform(drag(rig, [[3.0, 0.0], [0.0, 0.0]]))
    assert bool(jnp.all(jnp.isfinite(out)))


@pytest.mark.float64
def test_g_solves_the_normal_equations(horse_rig):
    e = horse_rig.energy
    lap, mvc, length, handle = operators(e)
    w = e.weights
    factor = dense_factor(e)
    normal = (w.laplacian * lap.T @ lap + w.mvc * mvc.T @ mvc + w.length * length.T @ length
              + w.handle * handle.T @ handle)
    np.testing.assert_allclose(normal @ factor.handle, w.handle * handle.T, atol=1e-9)


@pytest.mark.float64
def test_rigid_alignment_recovers_a_rotation():
    rng = np.random.default_rng(3)
    p = jnp.asarray(rng.normal(size=(6, 2)))
    angle = 0.7
    rot = jnp.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    q = p @ rot.T + jnp.array([3.0, -1.0])
    r, t = rigid_alignment(p, q)
    np.testing.assert_allclose(r, rot, atol=1e-12)
    np.testing.assert_allclose(p @ r.T + t, q, atol=1e-12)
    # Coinciding targets: identity rotation and a finite gradient.
    g = jax.grad(lambda q: jnp.sum(rigid_alignment(p, q)[0]))(jnp.zeros((6, 2)))
    assert bool(jnp.all(jnp.isfinite(g)))


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
@pytest.mark.parametrize("zeros", [dict(mvc=0, length=0), dict(laplacian=0, length=0),
                                   dict(laplacian=0, mvc=0), dict(laplacian=0)])
@pytest.mark.float64
def test_a_single_term_deforms_without_nan(horse, dtype, zeros):
    # Laplacian-only or mean-value-only deformation leaves some vertices free; the
    # tie-break keeps the minimum unique, the rest pose at rest and a drag finite.
    rig = mvcjax.Rig.build(horse, mvcjax.datasets.horse_handles(), dtype=dtype)
    rig = rig.with_weights(mvcjax.Weights.paper(**zeros))
    diagonal = float(np.linalg.norm(np.ptp(np.asarray(rig.shape_mesh.vertices), axis=0)))
    rest = np.asarray(rig.deform(rig.handle_positions, init=mvcjax.advanced.RestStart()))
    np.testing.assert_allclose(rest, np.asarray(rig.shape_mesh.vertices),
                               atol=(1e-4 if dtype == jnp.float32 else 1e-10) * diagonal)
    t = drag(rig, [[20.0, 5.0]] + [[0.0, 0.0]] * 4)
    v, info = rig.solve(t, mvcjax.GaussNewton(), return_info=True)
    assert np.all(np.isfinite(np.asarray(v)))
    if "laplacian" not in zeros:
        # Without the Laplacian the energy's minimum is near zero, where a relative test
        # stops late: such a solve may say it did not converge, and that is honest.
        assert bool(info.converged)
    assert float(info.handle_miss) < 0.05 * diagonal


@pytest.mark.float64
def test_the_tie_break_is_small_where_a_term_is_zero(horse_rig):
    # With the edge lengths on, a zero Laplacian or mean value weight changes the pose
    # by the tie-break alone: its energy, in the user's weights, is within a hair of
    # the tie-free minimum (found from it by scipy on the energy with those weights).
    rig = horse_rig.with_weights(mvcjax.Weights.paper(mvc=0))
    t = drag(rig, [[20.0, 5.0]] + [[0.0, 0.0]] * 4)
    v = rig.solve(t, mvcjax.GaussNewton(rtol=1e-12, atol=1e-12))
    energy = jax.jit(lambda x: rig.energy_at(x.reshape(-1, 2), t))
    grad = jax.jit(jax.grad(lambda x: rig.energy_at(x.reshape(-1, 2), t)))
    import scipy.optimize
    best = scipy.optimize.minimize(lambda x: float(energy(x)), np.asarray(v).ravel(),
                                   jac=lambda x: np.asarray(grad(x)), method="L-BFGS-B",
                                   options={"maxiter": 2000, "ftol": 1e-15, "gtol": 1e-12})
    assert float(energy(jnp.ravel(v))) <= best.fun * 1.001


def _barycentric_rows(rig):
    """Each inner control vertex and three of its ring, with coefficients 1 and minus
    its barycentric coordinates at rest in their triangle (which reproduce it)."""
    e = rig.energy
    rest = np.asarray(e.rest)
    centre, ring = np.asarray(e.mvc_centre), np.asarray(e.mvc_ring)[:, :3]
    corners = np.concatenate([rest[ring], np.ones(ring.shape + (1,))], axis=2)  # (g, 3, 3)
    point = np.concatenate([rest[centre], np.ones((len(centre), 1))], axis=1)
    coords = np.linalg.solve(np.transpose(corners, (0, 2, 1)), point[:, :, None])[:, :, 0]
    return np.concatenate([centre[:, None], ring], 1), np.concatenate(
        [np.ones((len(centre), 1)), -coords], 1)


def _two_new_terms(rig):
    """A linear term (each inner vertex held at a barycentric combination of three of
    its neighbours) and a turned one (each outline vertex's two neighbours keep their
    rest distance), declared on the control mesh in the rig's frame."""
    from mvcjax.advanced import Stencil, Term

    rows, coef = _barycentric_rows(rig)
    loop = rig.energy.laplacian_index
    dtype = rig.energy.rest.dtype
    bary = Term.linear("barycentric", Stencil(jnp.asarray(rows), jnp.asarray(coef, dtype)), 0.5)
    span = Term.turned_from("span", Stencil.fixed(loop[:, 1:], (1.0, -1.0), dtype), 3.0,
                            rig.energy.rest)
    return bary, span


def _residuals_by_hand(rig, local_targets):
    """The energy's residuals with the two new terms written out independently of
    `Term`: what scipy minimises."""
    loop = np.asarray(rig.energy.laplacian_index)
    rest = np.asarray(rig.energy.rest)
    rows, coef = _barycentric_rows(rig)
    rest_span = np.linalg.norm(rest[loop[:, 1]] - rest[loop[:, 2]], axis=1)

    def residuals(x):
        v = x.reshape(-1, 2)
        base = mvcjax.advanced.residuals(rig.energy, v, local_targets)
        bary = jnp.einsum("gk,gkd->gd", coef, v[rows])
        span = v[loop[:, 1]] - v[loop[:, 2]]
        span = span - rest_span[:, None] * span / jnp.linalg.norm(span, axis=1, keepdims=True)
        return jnp.concatenate([base, jnp.sqrt(0.5) * bary.ravel(), jnp.sqrt(3.0) * span.ravel()])

    return residuals


@pytest.mark.float64
@pytest.mark.parametrize("factor", ["dense", "sparse"])
def test_a_new_term_is_one_declaration(horse, factor):
    # Two terms declared as data reach every stage: the reported energy, the fixed-G
    # factor (dense and sparse) and the least-squares linearisation, each solver
    # landing on scipy's minimum of the residuals written out by hand.
    import scipy.optimize

    from mvcjax.advanced import DenseG, SparseLU

    base = mvcjax.Rig.build(horse, datasets.horse_handles(), dtype=jnp.float64,
                            factor=DenseG() if factor == "dense" else SparseLU())
    rig = base.with_terms(*_two_new_terms(base))
    targets = drag(rig, [[40.0, 10.0], [0, 0], [0, 0], [0, 0], [0, 0]])
    local = rig.frame.to_local(rig.pinned_targets(targets))
    fun = jax.jit(_residuals_by_hand(base, local))
    jac = jax.jit(jax.jacfwd(fun))
    start = np.asarray(rig.frame.to_local(rig.start(targets))).ravel()
    ref = scipy.optimize.least_squares(lambda x: np.asarray(fun(x)), start,
                                       jac=lambda x: np.asarray(jac(x)), method="trf",
                                       xtol=1e-15, ftol=1e-15, gtol=1e-15)
    scale = float(rig.frame.scale)
    reference = 2 * ref.cost * scale**2
    without = float(base.energy_at(rig.frame.to_world(ref.x.reshape(-1, 2)), targets))
    assert reference > 1.01 * without  # the new terms weigh in
    assert float(rig.energy_at(rig.frame.to_world(ref.x.reshape(-1, 2)), targets)) == \
        pytest.approx(reference, rel=1e-10)
    for solver in (mvcjax.FixedG(iterations=20000, rtol=1e-10, stop_early=True, anderson=5),
                   mvcjax.GaussNewton(max_steps=500), mvcjax.Dogleg(max_steps=500)):
        vertices, info = rig.solve(targets, solver, return_info=True)
        assert bool(info.converged), solver
        assert float(info.energy) == pytest.approx(reference, rel=1e-8), solver
        np.testing.assert_allclose(np.asarray(rig.frame.to_local(vertices)).ravel(), ref.x,
                                   atol=1e-6)


@pytest.mark.float64
def test_with_terms_refuses_a_handle_term_and_a_term_that_pulls_at_rest(horse_rig):
    from mvcjax.advanced import Stencil, Term

    loop = horse_rig.energy.laplacian_index
    smooth = Term.linear("smooth", Stencil.fixed(loop, (1.0, -0.5, -0.5), jnp.float64), 1.0)
    with pytest.raises(ValueError, match="'smooth' does not vanish at the rest"):
        horse_rig.with_terms(smooth)

    pinned = Term.pinned_to_targets("more handles", Stencil.fixed(
        horse_rig.energy.handles, (1.0,), jnp.float64), 1.0)
    with pytest.raises(TypeError, match="Term.turned"):
        horse_rig.with_terms(pinned)
