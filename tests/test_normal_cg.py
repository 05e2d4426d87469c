"""Preconditioned conjugate gradients and the structured Gauss-Newton matrix solved by them."""

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import pytest

import mvcjax
from mvcjax.solvers import _normal_cg
from mvcjax.solvers._least_squares import ScaledProblem
from mvcjax.solvers._normal_cg import GaussNewtonMatrix, conjugate_gradient

from conftest import local_point

# Tests that compare with references to many digits, or the solvers' internals, are
# marked float64; the others run in float32, as users do.


@pytest.mark.float64
def test_conjugate_gradient_solves_a_positive_definite_system():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(30, 30))
    matrix = jnp.asarray(a @ a.T + 0.1 * np.eye(30))
    b = jnp.asarray(rng.normal(size=(30, 2)))
    jacobi = 1.0 / jnp.diag(matrix)
    x, steps = conjugate_gradient(lambda v, _: matrix @ v, b, lambda r: jacobi[:, None] * r,
                                  rtol=1e-12, max_steps=500)
    np.testing.assert_allclose(x, np.linalg.solve(matrix, b), rtol=1e-8, atol=1e-10)
    assert 0 < int(steps) <= 500


@pytest.mark.float64
@pytest.mark.parametrize("case", ["stops early", "runs out", "zero curvature"])
def test_unrolled_and_looped_conjugate_gradients_agree(monkeypatch, case):
    # A short budget runs unrolled, with the stopping test as a mask; a long one loops.
    # With the same budget both stop at the same iteration with the same iterate.
    rng = np.random.default_rng(1)
    a = rng.normal(size=(40, 40))
    matrix = jnp.asarray(a @ a.T / 40 + np.diag(np.linspace(1.0, 3.0, 40)))
    b = jnp.asarray(rng.normal(size=(40,)))
    if case == "zero curvature":
        # The right-hand side lies in the null space: the first direction has none.
        matrix = matrix.at[:, :20].set(0.0).at[:20, :].set(0.0)
        b = b.at[20:].set(0.0)
    rtol = 1e-2 if case == "stops early" else 0.0

    def run():
        return conjugate_gradient(lambda v, _: matrix @ v, b, lambda r: r, rtol, 12)

    unrolled = run()
    monkeypatch.setattr(_normal_cg, "UNROLL_STEPS", 0)
    looped = run()
    assert int(unrolled[1]) == int(looped[1])
    if case == "stops early":
        assert 0 < int(unrolled[1]) < 12
    if case == "runs out":
        assert int(unrolled[1]) == 12
    if case == "zero curvature":
        assert np.all(np.asarray(unrolled[0]) == 0)
    assert np.all(np.isfinite(np.asarray(unrolled[0])))
    np.testing.assert_allclose(unrolled[0], looped[0], rtol=1e-12, atol=1e-14)


def test_conjugate_gradient_zero_right_hand_side_gives_zero_not_nan():
    x, steps = conjugate_gradient(lambda v, _: 2 * v, jnp.zeros((4, 2)), lambda r: r, 1e-8, 10)
    assert np.all(np.asarray(x) == 0) and int(steps) == 0


def test_conjugate_gradient_stops_on_zero_curvature():
    # A singular direction: the iteration stops instead of dividing by zero.
    matrix = jnp.diag(jnp.array([1.0, 0.0]))
    x, _ = conjugate_gradient(lambda v, _: matrix @ v, jnp.array([0.0, 1.0]), lambda r: r, 1e-8, 10)
    assert np.all(np.isfinite(np.asarray(x)))


@pytest.mark.parametrize("rtol, max_steps", [(1e-13, 200), (1e-3, 12), (0.0, 5)],
                         ids=["looped", "unrolled, stops early", "unrolled, runs out"])
@pytest.mark.float64
def test_conjugate_gradient_hands_the_operator_the_unpreconditioned_direction(rtol, max_steps):
    # An operator N - C with preconditioner N^{-1}: given N p for free, it never forms N p,
    # and the iterates are those of the same operator forming N p itself.
    rng = np.random.default_rng(2)
    a = rng.normal(size=(30, 30))
    normal = jnp.asarray(a @ a.T + 30 * np.eye(30))
    c = 0.5 * rng.normal(size=(30, 5))  # C below 30 I: N - C stays positive definite
    correction = jnp.asarray(c @ c.T)
    b = jnp.asarray(rng.normal(size=(30,)))
    normal_inverse = jnp.linalg.inv(normal)
    x, steps = conjugate_gradient(lambda p, normal_p: normal_p - correction @ p, b,
                                  lambda r: normal_inverse @ r, rtol, max_steps)
    formed, formed_steps = conjugate_gradient(lambda p, _: normal @ p - correction @ p, b,
                                              lambda r: normal_inverse @ r, rtol, max_steps)
    assert int(steps) == int(formed_steps)
    np.testing.assert_allclose(x, formed, rtol=1e-10, atol=1e-12)
    if max_steps == 200:
        np.testing.assert_allclose(x, np.linalg.solve(normal - correction, b), rtol=1e-7)
    if rtol == 1e-3:
        assert 0 < int(steps) < max_steps


def _normal_less_correction(seed, size=30):
    # An operator N - C with preconditioner N^{-1}, the Gauss-Newton matrix's form.
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(size, size))
    normal = jnp.asarray(a @ a.T + size * np.eye(size))
    c = 0.5 * rng.normal(size=(size, 5))
    correction = jnp.asarray(c @ c.T)
    return normal, correction, jnp.asarray(rng.normal(size=(size,))), rng


@pytest.mark.float64
@pytest.mark.parametrize("unroll", [True, False])
@pytest.mark.parametrize("max_steps", [1, 2, 5])
@pytest.mark.parametrize("raised", [False, True])
def test_deflated_conjugate_gradient_minimises_over_the_vector_and_a_krylov_space(
        monkeypatch, unroll, max_steps, raised):
    # The reference, built densely: the minimiser of x^T A x / 2 - b^T x over span{w}
    # plus the Krylov space of (I - Q A) M^{-1} A from (I - Q A) M^{-1} r0, where
    # Q = w w^T / (w^T A w) and r0 = b - A Q b (Saad et al. 2000). With the curvature
    # along w raised to c, the same for A + (c - w^T A w) (A w)(A w)^T / (w^T A w)^2.
    normal, correction, b, rng = _normal_less_correction(4)
    a = normal - correction
    m_inv = jnp.linalg.inv(normal)
    w = jnp.asarray(rng.normal(size=b.shape))
    if not unroll:
        monkeypatch.setattr(_normal_cg, "UNROLL_STEPS", 0)
    deflation = (w, a @ w, normal @ w)
    if raised:
        curvature = 3.0 * (w @ a @ w)
        deflation += (curvature,)
        aw = a @ w
        a = a + (curvature - w @ aw) * jnp.outer(aw, aw) / (w @ aw) ** 2
    x, steps = conjugate_gradient(lambda p, normal_p: normal_p - correction @ p, b,
                                  lambda r: m_inv @ r, 0.0, max_steps, deflation=deflation)
    q = jnp.outer(w, w) / (w @ a @ w)
    project = jnp.eye(b.size) - q @ a
    basis = [w, project @ m_inv @ (b - a @ q @ b)]
    for _ in range(max_steps - 1):
        basis.append(project @ m_inv @ a @ basis[-1])
    basis, _ = jnp.linalg.qr(jnp.stack(basis, axis=1))
    expected = basis @ jnp.linalg.solve(basis.T @ a @ basis, basis.T @ b)
    assert int(steps) == max_steps
    np.testing.assert_allclose(x, expected, rtol=1e-9, atol=1e-12)
    # The residual stays orthogonal to w.
    assert abs(float(w @ (b - a @ x))) <= 1e-10 * float(jnp.linalg.norm(w) * jnp.linalg.norm(b))


@pytest.mark.float64
def test_deflated_conjugate_gradient_edge_cases():
    normal, correction, b, _ = _normal_less_correction(5)
    a = normal - correction
    m_inv = jnp.linalg.inv(normal)

    def run(w, rtol=1e-12, max_steps=200):
        return conjugate_gradient(lambda p, normal_p: normal_p - correction @ p, b,
                                  lambda r: m_inv @ r, rtol, max_steps,
                                  deflation=(w, a @ w, normal @ w))

    exact = jnp.linalg.solve(a, b)
    # Run long, it solves the system.
    x, _ = run(jnp.ones_like(b))
    np.testing.assert_allclose(x, exact, rtol=1e-8)
    # Deflated by the solution, it starts there and takes no step.
    x, steps = run(3.0 * exact, rtol=1e-8)
    np.testing.assert_allclose(x, exact, rtol=1e-10)
    assert int(steps) == 0
    # A curvature below w^T A w changes nothing.
    low, _ = run(jnp.ones_like(b), rtol=0.0, max_steps=3)
    lowered, _ = conjugate_gradient(
        lambda p, normal_p: normal_p - correction @ p, b, lambda r: m_inv @ r, 0.0, 3,
        deflation=(jnp.ones_like(b), a @ jnp.ones_like(b), normal @ jnp.ones_like(b), 0.0))
    np.testing.assert_allclose(lowered, low, rtol=1e-12, atol=1e-14)
    # Deflated by zero (a first Gauss-Newton step, with no previous one), it is plain CG.
    x, steps = run(jnp.zeros_like(b), rtol=0.0, max_steps=4)
    plain, plain_steps = conjugate_gradient(lambda p, normal_p: normal_p - correction @ p, b,
                                            lambda r: m_inv @ r, 0.0, 4)
    assert int(steps) == int(plain_steps) == 4
    np.testing.assert_allclose(x, plain, rtol=1e-12, atol=1e-14)


@pytest.fixture(scope="module", params=["paper", "arap", "mixed"])
def gauss_newton(horse_rig, request):
    # The structured matrix at a dragged, perturbed point, and the residuals' own
    # linearisation there (jax.linearize and its transpose), the reference: for the
    # paper's turned rows, the as-rigid-as-possible term's rotations shared by pairs of
    # rows, and both.
    weights = {
        "paper": mvcjax.Weights.paper(laplacian=2.0, mvc=0.5, length=3.0, handle=40.0),
        "arap": mvcjax.Weights(mvc=0.5, handle=40.0, arap=3.0),
        "mixed": mvcjax.Weights(2.0, 0.5, 3.0, 40.0, arap=5.0),
    }[request.param]
    rig = horse_rig.with_weights(weights)
    targets, start = local_point(rig, [[60.0, -10.0]] + [[0.0, 0.0]] * 4, 1e-3, seed=3)
    problem = ScaledProblem(rig.energy, targets)
    y = problem.scaled(start)
    r, linear = jax.linearize(problem.residuals, y)
    return rig, problem, y, r, linear, GaussNewtonMatrix.at(
        problem, rig.factor.normal_operator(), rig.factor.normal_inverse_operator(), y)


@pytest.mark.float64
def test_gauss_newton_gradient_is_the_residuals_transposed(gauss_newton):
    _, _, y, r, linear, matrix = gauss_newton
    (expected,) = jax.linear_transpose(linear, y)(r)
    np.testing.assert_allclose(matrix.gradient, expected, rtol=1e-9,
                               atol=1e-11 * float(jnp.abs(expected).max()))


@pytest.mark.float64
def test_gauss_newton_matrix_is_the_jacobian_squared(gauss_newton):
    _, _, y, _, linear, matrix = gauss_newton
    x = jax.random.normal(jax.random.key(4), y.shape, y.dtype)
    (expected,) = jax.linear_transpose(linear, y)(linear(x))
    product = matrix.normal.mv(x) - matrix.correction(x)
    np.testing.assert_allclose(product, expected, rtol=1e-9,
                               atol=1e-11 * float(jnp.abs(expected).max()))


@pytest.mark.float64
@pytest.mark.parametrize("damping", [0.0, 0.3])
def test_gauss_newton_solve_matches_the_dense_step(gauss_newton, damping):
    # Run to a tight tolerance, CG gives the dense (damped) least-squares step; its
    # first iterate is along the fixed-G step (N^{-1} J^T r = y - fixed-G step from y).
    rig, problem, y, r, _, matrix = gauss_newton
    dense = jax.jacfwd(problem.residuals)(y).reshape(r.size, -1)
    hessian = dense.T @ dense + damping * jnp.eye(dense.shape[1])
    expected = jnp.linalg.solve(hessian, dense.T @ r.reshape(-1)).reshape(y.shape)
    x, result = matrix.solve(rtol=1e-13, max_steps=2000, damping=damping)
    assert result == lx.RESULTS.successful
    np.testing.assert_allclose(x, expected, rtol=1e-7, atol=1e-7 * float(jnp.abs(expected).max()))
    # Deflated by some previous step, it converges to the same step.
    d = jax.random.normal(jax.random.key(5), y.shape, y.dtype)
    deflated, result = matrix.solve(rtol=1e-13, max_steps=2000, damping=damping,
                                    previous=(d, matrix.normal.mv(d), 0.0))
    assert result == lx.RESULTS.successful
    np.testing.assert_allclose(deflated, expected, rtol=1e-7,
                               atol=1e-7 * float(jnp.abs(expected).max()))

    one, _ = matrix.solve(rtol=0.0, max_steps=1, damping=damping)
    columns = problem.unscaled(y).T
    fixed_g = problem.scaled(rig.factor.step(columns, rig.factor.handle_part(problem.targets)).T)
    along = y - fixed_g
    cosine = jnp.sum(one * along) / (jnp.linalg.norm(one) * jnp.linalg.norm(along))
    assert float(cosine) == pytest.approx(1.0, abs=1e-10)


def test_structured_step_options_are_checked():
    with pytest.raises(TypeError, match="linear_solver"):
        mvcjax.GaussNewton(linear_solver="qr")
    with pytest.raises(ValueError, match="steps"):
        mvcjax.advanced.StructuredCG(steps=0)
    with pytest.raises(ValueError, match="rtol"):
        mvcjax.advanced.StructuredCG(rtol=1.0)


@pytest.mark.float64
def test_gauss_newton_solve_reports_a_step_it_could_not_take(gauss_newton):
    # With a preconditioner that is not positive definite CG cannot leave zero: a
    # breakdown, not a zero step that the outer solver would take for convergence.
    rig, problem, y, *_ = gauss_newton
    negated = -rig.factor.normal_inverse_operator()
    _, result = GaussNewtonMatrix.at(problem, rig.factor.normal_operator(), negated,
                                     y).solve(rtol=1e-3, max_steps=5)
    assert result == lx.RESULTS.breakdown
