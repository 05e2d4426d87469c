"""The least-squares solvers' shared problem: scaled, coordinate-major residuals."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mvcjax
from mvcjax.solvers._least_squares import ScaledProblem

from conftest import local_point

# Agreement with references to many digits, and the solvers' internals: in float64.
pytestmark = pytest.mark.float64


@pytest.fixture(scope="module")
def problem(horse_rig):
    weights = mvcjax.Weights.paper(laplacian=2.0, mvc=0.5, length=3.0, handle=40.0)
    rig = horse_rig.with_weights(weights)
    targets, vertices = local_point(rig, [[60.0, -10.0]] + [[0.0, 0.0]] * 4, 2e-3, seed=1)
    return ScaledProblem(rig.energy, targets), vertices


def test_scaling_round_trips(problem):
    p, vertices = problem
    y = p.scaled(vertices)
    assert y.shape == (2, vertices.shape[0])
    np.testing.assert_allclose(p.unscaled(y), vertices, rtol=1e-12)


def test_residuals_are_the_energy(problem):
    # Merged and reordered, the rows still square and sum to the energy (6).
    p, vertices = problem
    # The weights scaled so that the largest (40) is 100 (Weights.normalised).
    r = p.residuals(p.scaled(vertices))
    energy = mvcjax.advanced.total_energy(p.energy, vertices, p.targets)
    assert float(jnp.sum(r * r)) * float(p.energy.scale) ** 2 * 0.4 == pytest.approx(
        float(energy), rel=1e-12)


def test_residual_jacobian_gives_the_energy_gradient(problem):
    # J^T r in scaled coordinates is half the energy's gradient, scaled: the
    # linearisation every least-squares solver step uses is the energy's.
    p, vertices = problem
    r, vjp = jax.vjp(p.residuals, p.scaled(vertices))
    (jtr,) = vjp(r)
    gradient = jax.grad(mvcjax.advanced.total_energy, argnums=1)(p.energy, vertices, p.targets)
    np.testing.assert_allclose(jtr.T * float(p.energy.scale) * 0.4, 0.5 * gradient,
                               rtol=1e-9, atol=1e-9 * float(jnp.abs(gradient).max()))


def test_energy_of_columns_is_the_energy(problem):
    p, vertices = problem
    energy = mvcjax.advanced.total_energy(p.energy, vertices, p.targets)
    assert float(p.energy_of_columns(vertices.T)) == pytest.approx(float(energy), rel=1e-12)


def test_linearisation_holds_the_residuals(problem):
    # The closed-form linearisation (from which GaussNewtonMatrix is built, tested
    # against autodiff in test_normal_cg) starts from the residuals themselves.
    p, vertices = problem
    y = p.scaled(vertices)
    np.testing.assert_allclose(p.linearise(y).residual, p.residuals(y), rtol=1e-12,
                               atol=1e-14)


def test_linearisation_at_a_zero_stencil_vector(problem):
    # A stencil vector of zero length (a vertex on its neighbours' line and midway, or
    # every vertex at one point) has no direction: its turn and scale are zero, not NaN.
    p, vertices = problem
    at = p.linearise(jnp.zeros_like(p.scaled(vertices)))
    for leaf in jax.tree.leaves(at):
        assert bool(jnp.all(jnp.isfinite(jnp.abs(leaf))))
    assert float(jnp.abs(at.turn[:-p.energy.handles.shape[0]]).max()) == 0.0
