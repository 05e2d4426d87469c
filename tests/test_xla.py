import jax
import jax.numpy as jnp
import numpy as np
from jax import export

from mvcjax.core import materialise


def f(x):
    a, b = materialise((x * 2.0, x + 1.0))
    return jnp.sum(a * b)


def test_materialise_changes_no_value_gradient_or_batch():
    x = jnp.arange(5.0)
    np.testing.assert_allclose(jax.jit(f)(x), np.sum(2 * x * (x + 1)))
    np.testing.assert_allclose(jax.grad(f)(x), 4 * x + 2)
    batch = jnp.arange(10.0).reshape(2, 5)
    np.testing.assert_allclose(jax.vmap(f)(batch), np.sum(2 * batch * (batch + 1), axis=1))


def test_materialise_keeps_its_conditional_on_the_cpu_only():
    # The CPU program keeps a conditional through XLA's optimisation (the platform's own
    # switch is folded away); a GPU program has none: the workaround is the CPU's alone.
    x = jnp.arange(5.0)
    compiled = jax.jit(f).lower(x).compile().as_text()
    assert "conditional(" in compiled
    cpu = export.export(jax.jit(f), platforms=["cpu"])(x).mlir_module()
    cuda = export.export(jax.jit(f), platforms=["cuda"])(x).mlir_module()
    assert cpu.count("stablehlo.case") > cuda.count("stablehlo.case")
    assert "is_finite" in cpu and "is_finite" not in cuda
