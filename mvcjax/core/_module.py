"""The base of mvcjax's user-facing pytrees, whose bound methods `jax.jit` takes as they
are: `jax.jit(rig.deform)`."""

from __future__ import annotations

import functools
import types

import equinox as eqx
import jax
import numpy as np


def _structure_hash(tree) -> int:
    leaves, treedef = jax.tree.flatten(tree)
    return hash((treedef, tuple((np.shape(leaf), str(getattr(leaf, "dtype", type(leaf))))
                                for leaf in leaves)))


@functools.cache
def _methods(cls: type) -> dict:
    """The plain functions of `cls` by name: its methods, not its fields, properties,
    classmethods or staticmethods (the nearest definition in the MRO wins)."""
    methods = {}
    for klass in reversed(cls.__mro__):
        for name, attr in vars(klass).items():
            if isinstance(attr, types.FunctionType) and not name.startswith("__"):
                methods[name] = attr
            else:
                methods.pop(name, None)
    return methods


@jax.tree_util.register_pytree_node_class
class Method:
    """A method bound to a `JittableModule`, a pytree of that module (as equinox's are).

    `jax.jit(obj.method)` hashes the method and compares it, at every cache lookup, with
    the one it cached: equinox's bound methods hash their module's fields (arrays have
    no hash) and compare it leaf by leaf (for a rig, some fifty small programs compiled
    on the first call, then every array compared at each lookup). This one hashes
    by the module's structure and is equal at once to the same method of the same
    module.
    """

    __slots__ = ("__func__", "__self__", "__weakref__")

    def __init__(self, func, obj):
        self.__func__, self.__self__ = func, obj

    @property
    def __wrapped__(self):  # what inspect.signature and jax's debug info read
        return functools.partial(self.__func__, self.__self__)

    @property
    def __name__(self) -> str:
        return self.__func__.__name__

    def __getattr__(self, name: str):  # __qualname__, __module__: the function's
        if name in ("__qualname__", "__module__"):
            return getattr(self.__func__, name)
        raise AttributeError(name)

    @property
    def __doc__(self) -> str | None:
        return self.__func__.__doc__

    def __call__(self, *args, **kwargs):
        return self.__func__(self.__self__, *args, **kwargs)

    def __eq__(self, other) -> bool:
        if not isinstance(other, Method) or other.__func__ is not self.__func__:
            return False
        return other.__self__ is self.__self__ or bool(eqx.tree_equal(other.__self__,
                                                                      self.__self__))

    def __hash__(self) -> int:
        return hash((self.__func__, self.__self__))

    def __repr__(self) -> str:
        return f"<bound method {self.__qualname__} of {type(self.__self__).__name__}>"

    def tree_flatten(self):
        return (self.__self__,), self.__func__

    @classmethod
    def tree_unflatten(cls, func, children):
        return cls(func, children[0])


class JittableModule(eqx.Module):
    """An `eqx.Module` hashed by its structure (its tree, its arrays' shapes and dtypes),
    whose methods are `Method`s: `jax.jit(rig.deform)` works.

    Equal modules (equinox compares leaves by value) have equal structures, so the hash
    agrees with `==`; modules of equal structure but other values merely share a bucket.
    A jitted method closes over the module's arrays, which become constants of the
    program; pass the module as an argument instead (`jax.jit(mvcjax.Rig.deform)(rig,
    targets)`) to share one program between modules of the same structure.
    """

    def __hash__(self) -> int:
        return _structure_hash(self)

    def __getattribute__(self, name: str):
        # Before equinox's own, which builds a BoundMethod module at every lookup.
        function = _methods(type(self)).get(name)
        if function is not None:
            return Method(function, self)
        return _MODULE_GETATTRIBUTE(self, name)


_MODULE_GETATTRIBUTE = eqx.Module.__getattribute__
