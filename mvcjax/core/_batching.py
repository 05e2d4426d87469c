"""Functions whose `jax.vmap` takes a faster path than JAX's own batching, and which still
differentiate in both modes."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax


def with_batching_rule(plain: Callable, batched: Callable) -> Callable:
    """`plain`, except that under `jax.vmap` it runs `batched(axis_size, in_batched, *args)`.

    `batched` gets the arguments with the mapped axis first where `in_batched` (a pytree
    of bools like the arguments) says so, and returns `(out, out_batched)` as a
    `jax.custom_batching.custom_vmap` rule does; it may return `None` to decline, and
    `plain` is then vmapped as JAX would.

    `custom_vmap` alone has no reverse mode, so derivatives are taken through `plain`
    (a `custom_jvp` whose rule is `plain`'s own JVP): `jax.grad`, `jax.jacfwd` and their
    vmaps work and agree with `plain`'s; only the primal pass of a vmap is the fast one.
    """

    @jax.custom_batching.custom_vmap
    def fast(*args):
        return plain(*args)

    @fast.def_vmap
    def rule(axis_size: int, in_batched: Any, *args):
        out = batched(axis_size, in_batched, *args)
        if out is not None:
            return out
        axes = [jax.tree.map(lambda b: 0 if b else None, batched_arg)
                for batched_arg in in_batched]
        out = jax.vmap(plain, in_axes=tuple(axes))(*args)
        return out, jax.tree.map(lambda _: True, out)

    @jax.custom_jvp
    def call(*args):
        return fast(*args)

    @call.defjvp
    def jvp(primals, tangents):
        return jax.jvp(plain, primals, tangents)

    return call


def only_batched(in_batched: Any, *mapped: int) -> bool:
    """Whether exactly the positional arguments at `mapped` are batched (all their leaves)
    and no other (none of theirs): the case a fast rule is written for."""
    for position, flags in enumerate(in_batched):
        leaves = jax.tree.leaves(flags)
        if position in mapped:
            if not all(leaves):
                return False
        elif any(leaves):
            return False
    return True


def one_after_another(fn, in_batched, args):
    """`jax.vmap(fn)` as a loop (`jax.lax.map`) over the batched leaves of `args` (mapped
    axis first, as a rule of `with_batching_rule` gets them; `in_batched` flags them),
    the others closed over: a rule for work whose batch is best done item by item."""
    leaves, tree = jax.tree.flatten(args)
    flags = jax.tree.leaves(in_batched)

    def one(batched):
        it = iter(batched)
        return fn(*jax.tree.unflatten(tree, [next(it) if b else x
                                             for x, b in zip(leaves, flags)]))

    return jax.lax.map(one, [x for x, b in zip(leaves, flags) if b])
