"""Handles: what the user pins, and how their targets pin the control mesh.

A handle is moved by one or more target points: a point handle by one, a bone (a
segment handle) by its two ends. Each handle pins one or more rest points of the shape
(a bone, points along its segment), each pinned point a control vertex with a row of
`C`, and each row's target is a pure function of the handle's targets. Below the rig,
solvers, factors and frames only ever see those rows: a new kind of handle is written
here alone.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import scipy.sparse
import shapely
from jaxtyping import Array, ArrayLike, Bool, Float, Int
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..core import as_points, to_device
from ..energy import length_scale


class Bone(eqx.Module):
    """A segment handle: the shape along the segment from `start` to `end` follows the
    segment wherever its two ends are dragged.

    Pass bones among the handles of `Rig.build` (`[(x, y), Bone(a, b), ...]`); a bone
    then takes two rows of the targets, where its `start` and its `end` go.

    Attributes:
        start: `(x, y)` one end at rest, on or inside the shape.
        end: `(x, y)` the other end.
        stretch: `False` (default): the bone keeps its rest length, centred between its
            two targets and turned along them (drag one end and the bone swings);
            `True`: it stretches or shrinks to span its targets.
    """

    start: np.ndarray
    end: np.ndarray
    stretch: bool = eqx.field(default=False, static=True)

    def __init__(self, start: Any, end: Any, *, stretch: Any = False):
        self.start = as_point(start, "Bone start")
        self.end = as_point(end, "Bone end")
        if not isinstance(stretch, (bool, np.bool_)):
            raise TypeError(f"Bone(stretch={stretch!r}): stretch is True or False.")
        self.stretch = bool(stretch)

    @property
    def length(self) -> float:
        return float(np.hypot(*(self.end - self.start)))


def as_point(value, name: str, what: str = "one (x, y) point") -> np.ndarray:
    """One point as a float64 `(2,)` array, or an error naming `name`."""
    try:
        array = np.asarray(value)
    except ValueError:
        array = None
    if array is None or array.shape != (2,):
        raise ValueError(f"{name} must be {what}, got {value!r}.")
    return as_points(array[None], name, "1")[0]


class Handles(eqx.Module):
    """How the targets pin the control mesh, in the rig's frame.

    The targets hold one row per point handle and two per bone (its start, then its
    end), in the order the handles were given. Pinned row `r` goes to
    `a + along[r] (b - a)` with `a, b = targets[first[r]], targets[second[r]]` (a point
    handle: `first = second`, `along = 0`); a bone that keeps its length puts it at
    `(a + b) / 2 + (along[r] - 1/2) length[r] (b - a) / |b - a|` instead.

    Attributes:
        rest: `(t, 2)` the targets at rest.
        first, second: `(r,)` the target rows each pinned row follows.
        along: `(r,)` where along its bone each pinned row lies (0 at `start`, 1 at `end`).
        length: `(r,)` the rest length of its bone (0 for a point handle).
        rigid: `(r,)` whether its bone keeps its length.
        bones: `(b, 2)` each bone's target rows (start, end).
        active: `(t,)` whether each target row pins anything. A row that does not
            (a spare pin not yet placed, a pin taken out: `Rig.with_pin`,
            `Rig.without_pin`) has its pinned rows' coefficients and targets at zero,
            so that the arrays, and the compiled programs, keep their shapes.
        padding: `(r,)` whether each pinned row is padding, which never pins (a rig
            padded to the sizes of others, to stack with them: `Rig.stack`).
    """

    rest: Float[Array, "t 2"]
    first: Int[Array, " r"]
    second: Int[Array, " r"]
    along: Float[Array, " r"]
    length: Float[Array, " r"]
    rigid: Bool[Array, " r"]
    bones: Int[Array, "b 2"]
    active: Bool[Array, " t"]
    padding: Bool[Array, " r"]

    @property
    def count(self) -> int:
        """The number of target rows."""
        return self.rest.shape[0]

    def rigid_bones(self, positions: Float[ArrayLike, "t 2"]) -> list[tuple[int, int, float]]:
        """Each bone that keeps its length, as the target rows of its ends and its length
        between `positions` (the rest targets, in the units wanted): host numbers, for
        the interactive and fitting code that reads a rigid bone by its pivot and
        direction."""
        first, second = np.asarray(self.first), np.asarray(self.second)
        rigid, positions = np.asarray(self.rigid), np.asarray(positions, np.float64)
        return [(int(s), int(e), float(np.hypot(*(positions[e] - positions[s]))))
                for s, e in np.asarray(self.bones, np.int64).reshape(-1, 2)
                if rigid[(first == s) & (second == e)].any()]

    def pinned_targets(self, targets: Float[Array, "t 2"]) -> Float[Array, "r 2"]:
        """Where each pinned point goes for these targets (pure JAX); zero for the rows of
        a target row that is not `active`, as their coefficients are."""
        a, b = targets[self.first], targets[self.second]
        along = self.along[:, None]
        d = b - a
        stretched = a + along * d
        # A bone dragged to a single point keeps its centre there, any direction (0/0 -> 0).
        turned = d * length_scale(jnp.sum(d * d, axis=1, keepdims=True),
                                  self.length[:, None])
        kept = 0.5 * (a + b) + (along - 0.5) * turned
        pinned = jnp.where(self.rigid[:, None], kept, stretched)
        return jnp.where(self.row_active()[:, None], pinned, jnp.zeros_like(pinned))

    def row_active(self) -> Bool[Array, " r"]:
        """Whether each pinned row pins (both its target rows are `active`, and it is
        not `padding`)."""
        return self.active[self.first] & self.active[self.second] & ~self.padding


def parse_handles(handles) -> tuple[np.ndarray, list[tuple[int, Bone]], list[int]]:
    """The handles as given: `(t, 2)` rest targets (float64), the bones with the row of
    their start, and the index (in the user's list) of every target row."""
    if isinstance(handles, Bone):
        handles = [handles]
    if not (isinstance(handles, (list, tuple)) and any(isinstance(h, Bone) for h in handles)):
        points = as_points(handles, "handles", "h")
        return points, [], list(range(len(points)))
    rows, bones, owner = [], [], []
    for i, h in enumerate(handles):
        if isinstance(h, Bone):
            bones.append((len(rows), h))
            rows += [h.start, h.end]
            owner += [i, i]
        else:
            rows.append(as_point(h, f"handles[{i}]",
                                 "an (x, y) point or an mvcjax.Bone(start, end)"))
            owner.append(i)
    return np.asarray(rows, np.float64), bones, owner


def check_handles(shape, handles):
    """`parse_handles`, with every point handle and every bone checked against the
    `Shape`: inside it, no two point handles at one spot, no bone of zero length."""
    points, bones, owner = parse_handles(handles)
    polygon, closest = shape.polygon, shape.closest_point
    tol = 1e-6 * shape.diagonal
    is_bone = np.zeros(len(points), bool)
    for row, bone in bones:
        is_bone[row:row + 2] = True
        i = owner[row]
        if bone.length <= tol:
            raise ValueError(
                f"handles[{i}] is a Bone of length {bone.length:.3g} (start {bone.start.tolist()}"
                f", end {bone.end.tolist()}); a bone needs two distinct ends: give it a length, "
                "or use a point handle."
            )
        segment = shapely.LineString([bone.start, bone.end])
        outside = segment.difference(polygon.buffer(tol))
        if not outside.is_empty:
            where = np.asarray(shapely.get_coordinates(outside)).mean(axis=0)
            raise ValueError(
                f"handles[{i}], a Bone from {bone.start.tolist()} to {bone.end.tolist()}, "
                f"leaves the shape (around {where.round(6).tolist()}); a bone must lie on or "
                "inside the shape: shorten it, move its ends inside, or split it into bones "
                "that stay inside."
            )
    loose = np.flatnonzero(~is_bone)
    dist = shapely.distance(shapely.points(points[loose]), polygon)
    for k in np.flatnonzero(dist > tol):
        i, p = owner[loose[k]], points[loose[k]]
        raise ValueError(
            f"handles[{i}] = {p.tolist()} lies outside the shape (distance {dist[k]:.4g}); put "
            f"it on or inside the shape, e.g. at its closest point "
            f"{closest(p).round(6).tolist()} (Shape.closest_point)."
        )
    if len(loose) > 1:
        pairs = cKDTree(points[loose]).query_pairs(tol, output_type="ndarray")
        if len(pairs):
            i, j = sorted(owner[loose[k]] for k in pairs[0])
            raise ValueError(
                f"handles[{i}] and handles[{j}] are at the same spot "
                f"{points[loose[pairs[0][0]]].tolist()}; remove one of them."
            )
    return points, bones, owner


def bone_samples(start: np.ndarray, end: np.ndarray, spacing: float) -> np.ndarray:
    """Where along a bone to pin it: evenly, at most `spacing` apart, both ends included."""
    count = max(2, int(np.ceil(np.hypot(*(end - start)) / spacing)) + 1)
    return np.linspace(0.0, 1.0, count)


def bone_samples_on(start: np.ndarray, end: np.ndarray, vertices: np.ndarray,
                    tol: float) -> np.ndarray:
    """Where along a bone the given mesh has vertices (a control mesh of the user's)."""
    d = end - start
    along = (vertices - start) @ d / (d @ d)
    off = np.linalg.norm(start + along[:, None] * d - vertices, axis=1)
    return np.sort(along[(off <= tol) & (along >= -tol) & (along <= 1 + tol)].clip(0, 1))


def pin(points: np.ndarray, bones: list[tuple[int, Bone]], samples, tol: float):
    """The rest points to pin and the rows that pin them.

    Args:
        points: `(t, 2)` rest targets, in the rig's frame.
        bones: `(row of start, Bone)` for every bone.
        samples: `samples(start, end)`, where along a bone (from 0 to 1) to pin it.
        tol: points closer than this are one pinned point (bones sharing a joint).

    Returns:
        `(p, 2)` distinct points to pin, the pinned point of every row `(r,)`, and the
        rows' `(first, second, along, length, rigid)` for `Handles`.
    """
    in_bone = np.zeros(len(points), bool)
    spots, first, second, along, length, rigid = [], [], [], [], [], []
    for row, bone in bones:
        in_bone[row:row + 2] = True
        a, b = points[row], points[row + 1]
        s = samples(a, b)
        spots.append(a + s[:, None] * (b - a))
        first.append(np.full(len(s), row))
        second.append(np.full(len(s), row + 1))
        along.append(s)
        length.append(np.full(len(s), np.hypot(*(b - a))))
        rigid.append(np.full(len(s), not bone.stretch))
    loose = np.flatnonzero(~in_bone)
    spots.append(points[loose])
    first.append(loose)
    second.append(loose)
    along.append(np.zeros(len(loose)))
    length.append(np.zeros(len(loose)))
    rigid.append(np.zeros(len(loose), bool))
    # Rows in the order of the targets: point handles and bones as the user listed them.
    order = np.argsort(np.concatenate(first), kind="stable")
    spots = np.concatenate(spots)[order]
    rows = [np.concatenate(x)[order] for x in (first, second, along, length, rigid)]
    # Rows at one spot pin one vertex (a joint between two bones).
    pairs = cKDTree(spots).query_pairs(tol, output_type="ndarray")
    n = len(spots)
    graph = scipy.sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                                    shape=(n, n))
    _, label = connected_components(graph, directed=False)
    _, unique, which = np.unique(label, return_index=True, return_inverse=True)
    return spots[unique], which, rows


def make_handles(points, bones, rows, dtype) -> Handles:
    first, second, along, length, rigid = rows
    pairs = np.asarray([[row, row + 1] for row, _ in bones], np.int32).reshape(-1, 2)
    as_ints = lambda a: to_device(a, np.int32)  # noqa: E731
    return Handles(
        rest=to_device(points, dtype),
        first=as_ints(first),
        second=as_ints(second),
        along=to_device(along, dtype),
        length=to_device(length, dtype),
        rigid=to_device(rigid, bool),
        bones=as_ints(pairs),
        active=to_device(np.ones(len(points), bool), bool),
        padding=to_device(np.zeros(len(first), bool), bool),
    )
