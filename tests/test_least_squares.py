"""The least-squares solvers' shared problem: scaled, coordinate-major residuals."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mvcjax
from mvcjax._solvers._least_squares import ScaledProblem

from conftest import drag


@pytest.fixture(scope="module")
def problem(horse_rig):
    targets = drag(horse_rig, np.array([[60.0, -10.0]] + [[0.0, 0.0]] * 4))
    weights = mvcjax.Weights(laplacian=2.0, mvc=0.5, length=3.0, handle=40.0)
    energy = horse_rig.with_weights(weights).energy
    vertices = energy.rest + jax.random.normal(jax.random.key(1), energy.rest.shape)
    return ScaledProblem(energy, targets), vertices


def test_scaling_round_trips(problem):
    p, vertices = problem
    y = p.scaled(vertices)
    assert y.shape == (2, vertices.shape[0])
    np.testing.assert_allclose(p.unscaled(y), vertices, rtol=1e-12)


def test_residuals_are_the_energy(problem):
    # Merged and reordered, the rows still square and sum to the energy (6).
    p, vertices = problem
    r = p.residuals(p.scaled(vertices))
    energy = mvcjax.total_energy(p.energy, vertices, p.targets)
    assert float(jnp.sum(r * r)) * float(p.energy.scale) ** 2 == pytest.approx(float(energy),
                                                                              rel=1e-12)


def test_residual_jacobian_gives_the_energy_gradient(problem):
    # J^T r in scaled coordinates is half the energy's gradient, scaled: the
    # linearisation every least-squares solver step uses is the energy's.
    p, vertices = problem
    r, vjp = jax.vjp(p.residuals, p.scaled(vertices))
    (jtr,) = vjp(r)
    gradient = jax.grad(mvcjax.total_energy, argnums=1)(p.energy, vertices, p.targets)
    np.testing.assert_allclose(jtr.T * float(p.energy.scale), 0.5 * gradient,
                               rtol=1e-9, atol=1e-9 * float(jnp.abs(gradient).max()))


def test_energy_of_columns_is_the_energy(problem):
    p, vertices = problem
    energy = mvcjax.total_energy(p.energy, vertices, p.targets)
    assert float(p.energy_of_columns(vertices.T)) == pytest.approx(float(energy), rel=1e-12)
