"""Where a solve starts: the rest control mesh moved rigidly onto the handles, or turned
with them.

The energy (6) has several minima, and every solver settles in the one its start leads
to. From the rest mesh (or the rest mesh moved rigidly), a limb that a bone turns by 90
degrees is squeezed by the first global step, which keeps every Laplacian and edge
vector's rest direction; the local steps then turn it back only slowly, and may leave
it folded. The turned start carries each handle's turn into the mesh instead: the
angle each bone turned through (and, for point handles, the angle of the handles'
best rigid motion) is spread over the control vertices harmonically, every Laplacian
and edge target becomes its rest vector turned by the angle where it lies, and one
global step gives the vertices that meet these targets and the handles best.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse
import scipy.sparse.linalg
from jaxtyping import Array, ArrayLike, Float, Int

from ..core import as_array, finite_when_traced, kind_of, refuse_string
from ..energy import AbstractFactor, Energy, rigid_alignment, rigid_start
from ..geometry import edges as mesh_edges
from ._handles import Handles


class AbstractStart(eqx.Module):
    """Where a solve starts: control vertices for targets in the rig's frame.

    Pass one as `init=` of `Rig.solve`, `Rig.deform`, `Rig.start` (and a character's):
    `TurnedStart()` (the default), `RigidStart()` or `RestStart()`; an explicit
    `(c, 2)` array of control vertices is taken too. A new start subclasses this and
    defines `__call__`.
    """

    @abc.abstractmethod
    def __call__(self, energy: Energy, factor: AbstractFactor, handles: Handles,
                 turns: Float[Array, "n r"], targets: Float[Array, "t 2"]
                 ) -> Float[Array, "n 2"]:
        """The start's `(n, 2)` control vertices for `targets` (a row per target), with
        `turns` the rig's harmonic weights spreading each pinned row over the mesh."""


class TurnedStart(AbstractStart):
    """Every bone's turn, and the handles' rigid turn, spread over the control mesh,
    then one global step: a limb turned far starts turned, not squeezed (the module's
    docstring says how)."""

    def __call__(self, energy, factor, handles, turns, targets):
        return turned_start(energy, factor, handles, turns, targets)


class RigidStart(AbstractStart):
    """The rest mesh moved rigidly (2D Procrustes) to fit the targets."""

    def __call__(self, energy, factor, handles, turns, targets):
        return rigid_start(energy, handles.pinned_targets(targets))


class RestStart(AbstractStart):
    """The rest mesh as it is: the paper's start."""

    def __call__(self, energy, factor, handles, turns, targets):
        return energy.rest


# What `init=` takes: a start, or `(c, 2)` control vertices as an array or nested lists
# (anything else, a string included, is refused by `checked_start` naming what to write).
Init = AbstractStart | Float[ArrayLike, "c 2"] | Sequence

_STARTS = {"turned": "mvcjax.advanced.TurnedStart()", "rigid": "mvcjax.advanced.RigidStart()",
           "rest": "mvcjax.advanced.RestStart()"}


def checked_start(init: Init, shape: tuple[int, int]) -> AbstractStart | Float[ArrayLike, "c 2"]:
    """`init`: a start, or `shape` = `(c, 2)` finite control vertices (checked on the
    host where concrete, when run where traced)."""
    if isinstance(init, AbstractStart):
        return init
    refuse_string("init", init, _STARTS)
    if isinstance(init, str):
        raise TypeError(f"init must be a start, {', '.join(_STARTS.values())}, or a "
                        f"(c, 2) array, got {init!r}.")
    message = ("init holds NaN or infinite coordinates; give finite (x, y) control "
               "vertices (a previous frame's), or a start such as "
               "mvcjax.advanced.TurnedStart().")
    if isinstance(init, jax.core.Tracer):
        checked = finite_when_traced(init, message)
    else:
        checked = as_array(init, "init", f"an array of shape {shape}")
        if checked.dtype.kind not in "iuf":
            raise TypeError(f"init must hold real (x, y) numbers, got {kind_of(checked)}.")
        if not np.all(np.isfinite(checked)):
            raise ValueError(message)
        checked = init
    if tuple(checked.shape) != tuple(shape):
        raise ValueError(f"init must have the control mesh's shape {tuple(shape)}, got "
                         f"{tuple(checked.shape)}.")
    return checked


def turn_weights(
    vertices: Float[np.ndarray, "n 2"],
    faces: Int[np.ndarray, "f 3"],
    pinned: Int[np.ndarray, " r"],
) -> Float[np.ndarray, "n r"]:
    """Harmonic weights that spread a value given at each pinned row over the mesh.

    Row `r` pins vertex `pinned[r]`; rows pinning one vertex share it equally. Every
    other vertex takes the weighted mean of its neighbours (edge weights the inverse
    rest lengths, so that a finely meshed stretch does not pull harder). Each row of the
    result sums to 1: equal values everywhere spread to that value.
    """
    vertices, faces, pinned = np.asarray(vertices), np.asarray(faces), np.asarray(pinned)
    n, r = len(vertices), len(pinned)
    e = mesh_edges(faces)
    w = 1.0 / np.maximum(np.linalg.norm(vertices[e[:, 0]] - vertices[e[:, 1]], axis=1),
                         np.finfo(np.float64).tiny)
    adjacency = scipy.sparse.coo_matrix(
        (np.r_[w, w], (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n)
    ).tocsr()
    laplacian = scipy.sparse.diags(np.asarray(adjacency.sum(axis=1)).ravel()) - adjacency
    fixed = np.unique(pinned)
    share = np.zeros((len(fixed), r))
    share[np.searchsorted(fixed, pinned), np.arange(r)] = 1.0
    share /= share.sum(axis=1, keepdims=True)
    weights = np.zeros((n, r))
    weights[fixed] = share
    free = np.setdiff1d(np.arange(n), fixed)
    if len(free):
        inner = laplacian[free][:, free].tocsc()
        # A part of the mesh no pinned vertex reaches has a singular block: a tiny
        # pull towards the mean keeps it solvable (it then takes the handles' mean).
        inner = inner + scipy.sparse.identity(len(free)) * (1e-12 * w.max())
        boundary = laplacian[free][:, fixed] @ share
        weights[free] = -scipy.sparse.linalg.splu(inner).solve(np.asarray(boundary))
        weights[free] /= np.maximum(weights[free].sum(axis=1, keepdims=True), 1e-300)
    return weights


def handle_turns(handles: Handles, targets: Float[Array, "t 2"],
                 common: Float[Array, ""]) -> Float[Array, " r"]:
    """The angle each pinned row turns through: its bone's, from the bone's rest
    direction to the direction of its targets, taken within half a turn of `common`
    (the handles' rigid turn), or `common` itself for a point handle (and for a row
    that pins nothing)."""
    # A point handle, or a bone dragged to one point, has no direction: it turns with
    # the rest (a stand-in direction keeps the gradients finite).
    d = targets[handles.second] - targets[handles.first]
    rest = handles.rest[handles.second] - handles.rest[handles.first]
    bone = ((handles.first != handles.second) & (jnp.sum(d * d, axis=1) > 0)
            & handles.row_active())
    d = jnp.where(bone[:, None], d, jnp.ones_like(d))
    rest = jnp.where(bone[:, None], rest, jnp.ones_like(rest))
    turn = jnp.arctan2(d[:, 1], d[:, 0]) - jnp.arctan2(rest[:, 1], rest[:, 0])
    relative = jnp.mod(turn - common + jnp.pi, 2 * jnp.pi) - jnp.pi
    return common + jnp.where(bone, relative, 0.0)


def turned_start(
    energy: Energy,
    factor: AbstractFactor,
    handles: Handles,
    weights: Float[Array, "n r"],
    targets: Float[Array, "t 2"],
) -> Float[Array, "n 2"]:
    """The turned start for `targets` (the rig's frame, one row per target): see the
    module's docstring."""
    pinned = handles.pinned_targets(targets)
    rot, _ = rigid_alignment(energy.handle_points(energy.rest), pinned,
                             energy.handle_presence())
    common = jnp.arctan2(rot[1, 0], rot[0, 0])
    angle = weights @ handle_turns(handles, targets, common)
    # A row's angle: the mean of its vertices', weighted as the row weighs them.
    coef = jnp.abs(factor.coef)
    total = jnp.sum(coef, axis=1)  # zero on a padded row (a stack's degenerate triangle)
    row_angle = jnp.sum(coef * angle[factor.rows], axis=1) / jnp.where(total > 0, total, 1)
    part = factor.handle_part(pinned)
    local = part.rest_local * jnp.exp(1j * row_angle.astype(part.rest_local.real.dtype))
    return factor.global_step(local.astype(part.rest_local.dtype), part).T
