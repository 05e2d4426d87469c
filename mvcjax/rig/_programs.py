"""A bound on the compiled programs a process keeps, however many rigs it builds.

Every rig of a new size compiles programs of its own (the build's steps, the solve, the
skinning), and JAX keeps every program it compiled for the life of the process, each
holding memory maps and memory. A script that rigs thousands of shapes of different
sizes (every glyph of a font, a dataset of sprites) would keep them all, until the
process runs out of memory maps and dies. So `Rig.build` notes each rig's size; when a
rig of a new size would make more than `SIZES_KEPT`, JAX's compilation caches are
cleared (`jax.clear_caches`) and the count starts again: the rigs alive stay valid, and
their programs (and any other jitted function of the process) compile anew on their
next call.
"""

from __future__ import annotations

import jax

SIZES_KEPT = 16

# The sizes seen since the caches were last cleared: the process's one budget.
_sizes: set = set()


def size_of(tree) -> tuple:
    """What decides the programs compiled for `tree`: its structure (static fields
    included) and its arrays' shapes and dtypes."""
    leaves, structure = jax.tree.flatten(tree)
    return structure, tuple((getattr(x, "shape", None), str(getattr(x, "dtype", type(x))))
                            for x in leaves)


def note_size(tree) -> bool:
    """Count `tree`'s size among those whose programs are kept; clear JAX's caches first
    if it is new and the budget is full. True if the caches were cleared."""
    size = size_of(tree)
    if size in _sizes:
        return False
    cleared = len(_sizes) >= SIZES_KEPT
    if cleared:
        jax.clear_caches()
        _sizes.clear()
    _sizes.add(size)
    return cleared
