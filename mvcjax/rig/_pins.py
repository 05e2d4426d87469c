"""Pins placed and taken out on a built rig, without new meshes or new programs.

A rig's arrays keep their shapes when a pin comes or goes: spare target rows
(`with_spare_pins`) wait inactive, their row of `C` all zeros; placing one
(`with_pin`) writes the control triangle under the point and its barycentric
coordinates into that row, taking one out (`without_pin`) zeroes it again. Only the
factor is recomputed (a dense `G` by the rig's compiled program, a sparse one on the
host), so solving, skinning and drawing reuse the programs compiled for the rig.

A placed pin holds the control mesh at its point; the shape there follows through the
skinning, which agrees with the control triangle's barycentric map at its corners and
comes within a small fraction of an edge of it inside.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..core import is_whole_number, to_device
from ..geometry import barycentric_coordinates, locate_points, points_to_local
from ._handles import as_point

# The width of a row of `C` that can hold a pin inside a control triangle.
_PIN_WIDTH = 3


def _set_row(array, row: int, value) -> Any:
    """`array` with `array[row] = value`, edited on the host: an eager update on the
    device would compile a small program for every new shape."""
    host = np.array(array)
    host[row] = value
    return to_device(host, host.dtype)


def _padded(a: np.ndarray, width: int) -> np.ndarray:
    return np.pad(a, ((0, 0), (0, width - a.shape[1])))


def with_spare_pins(rig, count: Any):
    """`rig` with `count` more target rows, each a point handle that pins nothing until
    placed (`with_pin`). The targets then have `count` more rows (any finite values
    while a row is inactive)."""
    if not is_whole_number(count) or count < 1:
        raise ValueError(f"with_spare_pins(count={count!r}): count is how many spare pins to "
                         "add, a whole number >= 1.")
    count = int(count)
    h, e = rig.handles, rig.energy
    t, dtype = h.count, e.rest.dtype
    new = np.arange(t, t + count, dtype=np.int32)
    zeros = np.zeros(count)
    handles = eqx.tree_at(
        lambda h: (h.rest, h.first, h.second, h.along, h.length, h.rigid, h.active,
                   h.padding), h,
        (jnp.concatenate([h.rest, jnp.zeros((count, 2), dtype)]),
         *(jnp.concatenate([a, to_device(new, np.int32)]) for a in (h.first, h.second)),
         *(jnp.concatenate([a, to_device(zeros, dtype)]) for a in (h.along, h.length)),
         *(jnp.concatenate([a, to_device(zeros.astype(bool), bool)])
           for a in (h.rigid, h.active, h.padding))))
    width = max(_PIN_WIDTH, e.handles.shape[1])
    energy = eqx.tree_at(
        lambda e: (e.handles, e.handle_coef), e,
        (to_device(np.concatenate([_padded(np.asarray(e.handles), width),
                                   np.zeros((count, width), np.int32)]), np.int32),
         to_device(np.concatenate([_padded(np.asarray(e.handle_coef), width),
                                   np.zeros((count, width))]), dtype)))
    more = to_device(np.zeros(count, np.int32), np.int32)
    rig = eqx.tree_at(
        lambda r: (r.handles, r.energy, r.factor, r.shape_mesh.handles, r.control_mesh.handles,
                   r.turns), rig,
        (handles, energy, rig.factor.rebuild(energy),
         jnp.concatenate([rig.shape_mesh.handles, more]),
         jnp.concatenate([rig.control_mesh.handles, more]),
         jnp.concatenate([rig.turns, jnp.zeros((rig.turns.shape[0], count), dtype)], axis=1)))
    return rig


def _check_row(rig, row: Any) -> int:
    t = rig.handles.count
    if not is_whole_number(row) or not -t <= row < t:
        raise ValueError(f"row={row!r}: a pin is a row of the targets, a whole number from 0 to "
                         f"{t - 1} (this rig has {t} target rows).")
    return int(row) % t


def _bone_of(rig, row: int) -> np.ndarray | None:
    bones = np.asarray(rig.handles.bones).reshape(-1, 2)
    hit = np.flatnonzero((bones == row).any(axis=1))
    return bones[hit[0]] if len(hit) else None


def pinned_row(rig, row: int) -> int:
    """The row of `C` that target row `row` of a point handle pins."""
    return int(np.flatnonzero(np.asarray(rig.handles.first) == row)[0])


def _local_frame(rig) -> tuple[np.ndarray, float]:
    return np.asarray(rig.frame.centre, np.float64), float(rig.frame.scale)


def with_pin(rig, row: Any, point: Any):
    """`rig` with target row `row`, a point handle (a spare one, or one given to
    `Rig.build`), pinning the shape at rest point `point` (the user's coordinates)."""
    row = _check_row(rig, row)
    if _bone_of(rig, row) is not None:
        raise ValueError(f"row {row} is an end of a bone; with_pin places point handles "
                         "(a spare pin from Rig.with_spare_pins, or a point handle).")
    point = as_point(point, "point")
    frame = _local_frame(rig)
    shape = rig.shape_mesh
    vertices = np.asarray(shape.vertices, np.float64)
    _, inside = locate_points(point[None], vertices, np.asarray(shape.faces))
    local_point = points_to_local(point[None], frame)
    if inside[0] < -1e-9:
        nearest = vertices[np.argmin(np.linalg.norm(vertices - point, axis=1))]
        raise ValueError(f"point {point.tolist()} lies outside the shape; a pin goes on or "
                         f"inside it, e.g. at the shape mesh's vertex {nearest.tolist()}.")
    control = np.asarray(rig.energy.rest, np.float64)
    faces = np.asarray(rig.control_mesh.faces)
    which, _ = locate_points(local_point, control, faces)
    bary = np.clip(barycentric_coordinates(local_point, control[faces[which]])[0], 0.0, None)
    bary /= bary.sum()
    h, e = rig.handles, rig.energy
    pinned = pinned_row(rig, row)
    width = e.handles.shape[1]
    if width < _PIN_WIDTH:
        raise ValueError("this rig's handle rows hold one vertex each; call "
                         "rig.with_spare_pins(count) first, which makes room for pins "
                         "placed anywhere.")
    index = np.zeros(width, np.int32)
    index[:_PIN_WIDTH] = faces[which[0]]
    coef = np.zeros(width)
    coef[:_PIN_WIDTH] = bary
    energy = eqx.tree_at(lambda e: (e.handles, e.handle_coef), e,
                         (_set_row(e.handles, pinned, index),
                          _set_row(e.handle_coef, pinned, coef)))
    handles = eqx.tree_at(lambda h: (h.rest, h.active), h,
                          (_set_row(h.rest, row, local_point[0]), _set_row(h.active, row, True)))
    nearest_shape = int(np.argmin(np.linalg.norm(vertices - point, axis=1)))
    nearest_control = int(faces[which[0]][np.argmax(bary)])
    return eqx.tree_at(
        lambda r: (r.handles, r.energy, r.factor, r.shape_mesh.handles, r.control_mesh.handles),
        rig, (handles, energy, rig.factor.rebuild(energy),
              _set_row(shape.handles, pinned, nearest_shape),
              _set_row(rig.control_mesh.handles, pinned, nearest_control)))


def without_pin(rig, row: Any):
    """`rig` with target row `row` pinning nothing (both rows of a bone, for a bone's
    end). Its target row stays, and is ignored until `with_pin` places it again."""
    row = _check_row(rig, row)
    bone = _bone_of(rig, row)
    rows = np.asarray([row] if bone is None else bone)
    h, e = rig.handles, rig.energy
    active = np.asarray(h.active).copy()
    active[rows] = False
    if not active.any():
        raise ValueError(f"row {row} is the rig's last pin; with no pin the shape is free "
                         "to drift anywhere (the energy has no unique minimum). Place "
                         "another pin first (Rig.with_pin), then take this one out.")
    first, second = np.asarray(h.first), np.asarray(h.second)
    off = ~(active[first] & active[second])
    coef = np.array(e.handle_coef)
    coef[off] = 0.0
    energy = eqx.tree_at(lambda e: e.handle_coef, e, to_device(coef, coef.dtype))
    handles = eqx.tree_at(lambda h: h.active, h, to_device(active, bool))
    return eqx.tree_at(lambda r: (r.handles, r.energy, r.factor), rig,
                       (handles, energy, rig.factor.rebuild(energy)))


def with_rows(rig, rows: Any):
    """`rig` keeping only the target rows `rows` (in their order; a bone's two rows go
    together), dropping the others and everything they pin: a rig of new shapes, for
    keeping a posing session's pins without its unused spare rows."""
    h, e = rig.handles, rig.energy
    rows = np.asarray(rows, np.int64)
    t = h.count
    keep = np.zeros(t, bool)
    keep[rows] = True
    bones = np.asarray(h.bones, np.int64).reshape(-1, 2)
    if (keep[bones[:, 0]] != keep[bones[:, 1]]).any():
        raise ValueError("with_rows keeps a bone's two rows together, or neither.")
    new_index = np.full(t, -1)
    new_index[rows] = np.arange(len(rows))
    first, second = np.asarray(h.first), np.asarray(h.second)
    pinned = np.flatnonzero(keep[first] & keep[second])
    # Pinned rows keep the order of their target rows, as `pin` makes them.
    pinned = pinned[np.argsort(new_index[first[pinned]], kind="stable")]
    take = lambda a, index: jnp.asarray(a)[to_device(index, np.int32)]  # noqa: E731
    handles = eqx.tree_at(
        lambda h: (h.rest, h.first, h.second, h.along, h.length, h.rigid, h.padding, h.bones,
                   h.active), h,
        (take(h.rest, rows),
         to_device(new_index[first[pinned]], np.int32),
         to_device(new_index[second[pinned]], np.int32),
         take(h.along, pinned), take(h.length, pinned), take(h.rigid, pinned),
         take(h.padding, pinned),
         to_device(new_index[bones[keep[bones[:, 0]]]].reshape(-1, 2), np.int32),
         take(h.active, rows)))
    energy = eqx.tree_at(lambda e: (e.handles, e.handle_coef), e,
                         (take(e.handles, pinned), take(e.handle_coef, pinned)))
    # Each vertex's turn stays a weighted mean of the kept rows' (a spare row's column
    # is zero, so dropping one changes nothing).
    turns = take(rig.turns.T, pinned).T
    total = jnp.sum(turns, axis=1, keepdims=True)
    turns = turns / jnp.where(total > 0, total, 1.0)
    return eqx.tree_at(
        lambda r: (r.handles, r.energy, r.factor, r.shape_mesh.handles, r.control_mesh.handles,
                   r.turns), rig,
        (handles, energy, rig.factor.rebuild(energy), take(rig.shape_mesh.handles, pinned),
         take(rig.control_mesh.handles, pinned), turns))


def pin_state(rig) -> tuple[np.ndarray, ...]:
    """What the pins of `rig` are, as a few small host arrays (a session's undo history
    keeps these instead of rigs, each with a factor of its own)."""
    return tuple(np.asarray(a) for a in (
        rig.handles.rest, rig.handles.active, rig.energy.handles, rig.energy.handle_coef,
        rig.shape_mesh.handles, rig.control_mesh.handles))


def with_pin_state(rig, state: tuple[np.ndarray, ...]):
    """`rig` with the pins of `state` (`pin_state` of a rig of the same shapes)."""
    arrays = [to_device(a, a.dtype) for a in state]
    rest, active, index, coef, shape_handles, control_handles = arrays
    energy = eqx.tree_at(lambda e: (e.handles, e.handle_coef), rig.energy, (index, coef))
    return eqx.tree_at(
        lambda r: (r.handles.rest, r.handles.active, r.energy, r.factor, r.shape_mesh.handles,
                   r.control_mesh.handles), rig,
        (rest, active, energy, rig.factor.rebuild(energy), shape_handles, control_handles))
