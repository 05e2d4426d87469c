"""Ways around XLA's CPU backend where it computes something slowly."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def to_device(a, dtype) -> jax.Array:
    """The host array `a` as a JAX array of `dtype`, converted on the host and moved by
    `jax.device_put`: `jnp.asarray` stages a copy through a program compiled for every
    new shape, a few milliseconds each, which a rig of new sizes pays for every array."""
    return jax.device_put(np.asarray(a, dtype=dtype, order="C"))


def materialise(tree):
    """`tree`, computed once into memory on the CPU backend; unchanged on any other.

    XLA's CPU fusion would otherwise compute a gather inside each of its consumers: a
    table lookup once per texel and channel instead of once, or a skinning's sum inside
    the gather that reorders it, where the sum no longer runs over contiguous memory.
    It drops `optimization_barrier`s, but not a
    conditional whose predicate it cannot know at compile time: both branches return
    `tree` (the second `+ 0`, so that no pass can prove them the same), and the
    predicate (true unless the first number is not finite) depends on the frame's data,
    since XLA folds one computed from constants (a rig closed over by `jit`). Under vmap
    the conditional becomes a select, which XLA fuses like any other operation.

    Other backends fuse on their own terms, so the conditional is only lowered for the
    CPU (`jax.lax.platform_dependent` picks the branch when the program is lowered).
    """

    def on_cpu(tree):
        keep = jnp.isfinite(jax.lax.stop_gradient(jax.tree.leaves(tree)[0].reshape(-1)[0]))
        return jax.lax.cond(keep, lambda t: t, lambda t: jax.tree.map(lambda a: a + 0, t),
                            tree)

    return jax.lax.platform_dependent(tree, cpu=on_cpu, default=lambda t: t)
