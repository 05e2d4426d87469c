"""Compiled programs that belong to the objects they were compiled for.

JAX keeps every program a jitted function compiled for as long as the function lives, and
each holds memory maps and memory; a module-level `jax.jit` lives as long as the process.
A script that rigs thousands of shapes of different sizes (every glyph of a font, a
dataset of sprites) would keep programs for every size until the process runs out of
memory maps. So mvcjax compiles through `Programs`: a rig (its energy, its renderers)
holds one, which holds the programs it ran; they are shared with every live
holder that runs the same function at the same sizes (rigs of one size compile once),
and go when the last of those holders goes and `RECENT` newer programs have run. Nothing
else is cleared: the user's own compiled functions stay as they are.
"""

from __future__ import annotations

import collections
import functools
import weakref
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
from jax._src.core import is_concrete  # public as jax.core.is_concrete, deprecated there
from jax._src.interpreters.ad import JVPTracer, LinearizeTracer  # no public names
from jax._src.interpreters.batching import BatchTracer  # no public name

from ._checks import checks_left_out


class _Static(eqx.Module):
    """A program's outputs that are not arrays, carried through `jit` as static data."""

    value: Any = eqx.field(static=True)


def _split(tree) -> tuple[list, tuple]:
    """`tree`'s array leaves (None elsewhere) and the hashable rest: its structure and
    the leaves that are not arrays."""
    leaves, structure = jax.tree.flatten(tree)
    arrays = [leaf if eqx.is_array(leaf) else None for leaf in leaves]
    rest = tuple(None if eqx.is_array(leaf) else leaf for leaf in leaves)
    return arrays, (structure, rest)


def _join(arrays: list, static: tuple):
    structure, rest = static
    return jax.tree.unflatten(structure, [r if a is None else a
                                          for a, r in zip(arrays, rest)])


class _Compiled:
    """One function compiled for one size of its arguments (their structure, the leaves
    that are not arrays, the arrays' shapes and dtypes): a `jax.jit` of its own, whose
    programs go with it. `donate` names a keyword argument whose array is donated."""

    def __init__(self, fn: Callable, donate: str | None):
        def run(arrays, donated, static):
            args, kwargs = _join(arrays, static[0])
            out = fn(*args, **kwargs, **({donate: donated} if donate else {}))
            dynamic, rest = eqx.partition(out, eqx.is_array)
            return dynamic, _Static(rest)

        run.__name__ = run.__qualname__ = getattr(fn, "__name__", "program")
        self._jitted = jax.jit(run, static_argnums=2, donate_argnums=1 if donate else (),
                               keep_unused=bool(donate))

    def __call__(self, arrays: list, donated, static: tuple):
        dynamic, rest = self._jitted(arrays, donated, static)
        return eqx.combine(dynamic, rest.value)


# The compiled functions some live holder ran, by function and size: how holders of the
# same size find each other's programs. Weak: a holder keeps what it ran, nothing here does.
_SHARED: weakref.WeakValueDictionary = weakref.WeakValueDictionary()

# The last programs run, kept a while after their holders go, so that a rig rebuilt at a
# size just used (a script or a notebook cell run again) does not compile again: a
# bounded cache, like each of JAX's own, of about half a dozen rig sizes' programs.
RECENT = 24
_RECENT: collections.OrderedDict = collections.OrderedDict()


class Programs:
    """What an object (a rig, an energy, a renderer) compiled and keeps for itself: the
    programs it ran, and in `kept` what else it computed for itself (a rig's padded
    twin).

    A field of the object, and a pytree node without leaves whose structure refers to
    it weakly: objects rebuilt from the object's leaves (by `jax.tree.map`,
    `eqx.tree_at`, a trace) hold the same one while it lives, every structure compares
    equal whatever it holds, and no compiled program's cache keeps it alive, so it goes
    with the last object that holds it. Copies and pickles start empty.
    """

    def __init__(self):
        self._ran: dict = {}
        self.kept: dict = {}

    def __repr__(self) -> str:
        return f"Programs({len(self._ran)} compiled)"

    def __reduce__(self):
        return Programs, ()

    def run(self, fn: Callable, args: tuple, kwargs: dict, donate: str | None = None):
        """`fn(*args, **kwargs)`, compiled for these sizes once among all live holders;
        the array of keyword argument `donate`, if named, is donated to the output."""
        kwargs = dict(kwargs)
        donated = kwargs.pop(donate) if donate else None
        arrays, static = _split((args, kwargs))
        # Traced within `checked_on_entry`, a program leaves its checks out: another one.
        static = (static, checks_left_out())
        # The sizes by their hash, so that no key holds on to a structure; two sizes of
        # one hash would share a `jax.jit`, which tells them apart itself.
        key = (fn, donate, hash((static, jax.tree.map(lambda a: (a.shape, a.dtype), donated),
                                 tuple(None if a is None else (a.shape, a.dtype)
                                       for a in arrays))))
        compiled = self._ran.get(key) or _SHARED.get(key) or _Compiled(fn, donate)
        self._ran[key] = _SHARED[key] = _RECENT[key] = compiled
        _RECENT.move_to_end(key)
        while len(_RECENT) > RECENT:
            _RECENT.popitem(last=False)
        return compiled(arrays, donated, static)


class _Weakly:
    """A `Programs` in a pytree structure: held weakly, equal to any other."""

    def __init__(self, programs: Programs):
        self.ref = weakref.ref(programs)

    def __eq__(self, other) -> bool:
        return isinstance(other, _Weakly)

    def __hash__(self) -> int:
        return hash(_Weakly)

    def programs(self) -> Programs:
        return self.ref() or Programs()


jax.tree_util.register_pytree_node(
    Programs, lambda p: ((), _Weakly(p)), lambda weakly, _: weakly.programs())


def programs_field():
    """The `Programs` field of an `eqx.Module`: `programs: Programs = programs_field()`."""
    return eqx.field(default_factory=Programs, repr=False)


def is_traced(*trees) -> bool:
    """True if any leaf of `trees` is a tracer (a transformation is running)."""
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(trees))


def is_staged(*trees) -> bool:
    """True if a transformation stages `trees` out (`jit`, a loop's body): a leaf is a
    tracer without values underneath. Eager `jax.grad`, `jax.jvp` and `jax.vmap` trace
    with values (the primals, the batch) as they go."""
    return not all(_valued(leaf) for leaf in jax.tree.leaves(trees))


def _valued(leaf) -> bool:
    """Whether `leaf` is a value, or a tracer of eager transformations over values."""
    while isinstance(leaf, jax.core.Tracer):
        if is_concrete(leaf):
            return True
        underneath = _UNDERNEATH.get(type(leaf))  # a staged tracer has none
        if underneath is None:
            return False
        leaf = getattr(leaf, underneath)
    return True


# What an eager transformation's tracer carries its values in.
_UNDERNEATH = {BatchTracer: "val", JVPTracer: "primal", LinearizeTracer: "primal"}


def first(*args, **kwargs):
    """The owner of a program that takes it first (a rig, an energy, a renderer)."""
    return args[0]


def compiled_by(owner: Callable = first, *, donate: str | None = None,
                inline_when_traced: bool = False):
    """Decorate `fn` to run compiled, as one of the programs of `owner(*args, **kwargs)`
    (by default the first argument).

    `inline_when_traced`: inside a transformation that stages it out (`jit`),
    run `fn` as it is (the caller's `jit` compiles it) instead of as a nested `jit`: no
    slower there, and jaxopt's implicit gradients leak a tracer through a nested one.
    Under eager `jax.grad`, `jax.jvp` or `jax.vmap` it runs as its program,
    differentiated or batched whole (run inline, every operation of it and of its
    derivative would compile alone), unless an argument has a true
    `inline_when_differentiated` (jaxopt's solvers). A nested `jit` is what a function
    needs that a transformation may run op by op (a `custom_vmap` called outside `vmap`).

    Arguments that are not arrays (numbers, strings, solver options) are compiled in, as
    `jax.jit`'s static arguments would be; the array of keyword argument `donate`, if
    named, is donated (its memory may hold the output).
    """

    def wrap(fn):
        @functools.wraps(fn)
        def call(*args, **kwargs):
            if inline_when_traced and is_traced(args, kwargs) and (
                    is_staged(args, kwargs) or any(
                        getattr(a, "inline_when_differentiated", False)
                        for a in (*args, *kwargs.values()))):
                return fn(*args, **kwargs)
            return owner(*args, **kwargs).programs.run(fn, args, kwargs, donate)

        return call

    return wrap
