import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mvcjax
from mvcjax._energy import rigid_alignment
from mvcjax._factor import dense_factor, operators

from conftest import directional_derivatives, drag, local_point


def test_every_residual_vanishes_at_rest(horse_rig):
    e, rest = horse_rig.energy, horse_rig.energy.rest
    for term in [mvcjax.advanced.laplacian_residual, mvcjax.advanced.mvc_residual,
                 mvcjax.advanced.length_residual]:
        assert float(jnp.abs(term(e, rest)).max()) < 1e-12
    assert float(jnp.abs(mvcjax.advanced.handle_residual(e, rest, rest[e.handles])).max()) == 0
    assert float(mvcjax.advanced.total_energy(e, rest, rest[e.handles])) < 1e-24
    assert float(horse_rig.energy_at(horse_rig.control_mesh.vertices,
                                     horse_rig.handle_positions)) < 1e-18


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


def test_g_solves_the_normal_equations(horse_rig):
    e = horse_rig.energy
    lap, mvc, length, handle = operators(e)
    w = e.weights
    factor = dense_factor(e)
    normal = (w.laplacian * lap.T @ lap + w.mvc * mvc.T @ mvc + w.length * length.T @ length
              + w.handle * handle.T @ handle)
    np.testing.assert_allclose(normal @ factor.handle, w.handle * handle.T, atol=1e-9)


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
def test_a_single_term_deforms_without_nan(horse, dtype, zeros):
    # Laplacian-only or mean-value-only deformation leaves some vertices free; the
    # tie-break keeps the minimum unique, the rest pose at rest and a drag finite.
    rig = mvcjax.Rig.build(horse, mvcjax.datasets.horse_handles(), dtype=dtype)
    rig = rig.with_weights(mvcjax.Weights(**zeros))
    diagonal = float(np.linalg.norm(np.ptp(np.asarray(rig.shape_mesh.vertices), axis=0)))
    rest = np.asarray(rig.deform(rig.handle_positions, init="rest"))
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


def test_the_tie_break_is_small_where_a_term_is_zero(horse_rig):
    # With the edge lengths on, a zero Laplacian or mean value weight changes the pose
    # by the tie-break alone: its energy, in the user's weights, is within a hair of
    # the tie-free minimum (found from it by scipy on the energy with those weights).
    rig = horse_rig.with_weights(mvcjax.Weights(mvc=0))
    t = drag(rig, [[20.0, 5.0]] + [[0.0, 0.0]] * 4)
    v = rig.solve(t, mvcjax.GaussNewton(rtol=1e-12, atol=1e-12))
    energy = jax.jit(lambda x: rig.energy_at(x.reshape(-1, 2), t))
    grad = jax.jit(jax.grad(lambda x: rig.energy_at(x.reshape(-1, 2), t)))
    import scipy.optimize
    best = scipy.optimize.minimize(lambda x: float(energy(x)), np.asarray(v).ravel(),
                                   jac=lambda x: np.asarray(grad(x)), method="L-BFGS-B",
                                   options={"maxiter": 2000, "ftol": 1e-15, "gtol": 1e-12})
    assert float(energy(jnp.ravel(v))) <= best.fun * 1.001
