"""Skinning: how points inside the control mesh follow its vertices, `V_S = W V_C`.

A skinning method is a small frozen object (`BlendedMVCSkinning`, `MVCSkinning`,
`BarycentricSkinning`) that turns rest points and a control mesh into sparse weights;
`Skinning` holds those weights as arrays and applies them inside JAX.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from . import _coordinates as coords, _topology as topology
from ._batching import only_batched, with_batching_rule
from ._module import JittableModule
from ._xla import materialise


class AbstractSkinning(eqx.Module):
    """A way of writing each point inside a control mesh as a weighted sum of control
    vertices. Subclasses implement `combine`; `weights_at` locates the points first."""

    def weights_at(
        self,
        points: Float[np.ndarray, "n 2"],
        vertices: Float[np.ndarray, "c 2"],
        faces: Int[np.ndarray, "f 3"],
        what: str = "points",
    ) -> tuple[Int[np.ndarray, "n k"], Float[np.ndarray, "n k"]]:
        """The weights of rest `points` over the control mesh `(vertices, faces)`.

        Returns control vertex indices `(n, k)` and their weights `(n, k)`, rows summing
        to one, padded with index 0 and weight 0. Raises `ValueError` if a point lies
        outside every control triangle (`what` names the points in that message).
        """
        points = np.asarray(points, np.float64).reshape(-1, 2)
        vertices = np.asarray(vertices, np.float64)
        faces = np.asarray(faces, np.int64)
        face, depth = coords.locate_points(points, vertices, faces)
        outside = np.flatnonzero(depth < -1e-9)
        if len(outside):
            raise ValueError(
                f"{len(outside)} of the {len(points)} {what} lie outside the control mesh "
                f"(e.g. {what}[{outside[0]}], at {points[outside[0]].round(6).tolist()} in the "
                "rig's frame); the control mesh must cover every point it carries."
            )
        corners = faces[face]
        bary = coords.barycentric_coordinates(points, vertices[corners])
        return self.combine(points, vertices, faces, face, bary)

    @abc.abstractmethod
    def combine(self, points, vertices, faces, face, bary) -> tuple[np.ndarray, np.ndarray]:
        """The weights, given each point's containing `face` and barycentric coordinates
        `bary` in it (`(n,)` and `(n, 3)`)."""


class BarycentricSkinning(AbstractSkinning):
    """The containing triangle's barycentric coordinates (the paper's "control mesh
    only"): continuous, piecewise linear, with kinks along control edges."""

    def combine(self, points, vertices, faces, face, bary):
        return faces[face], bary


class MVCSkinning(AbstractSkinning):
    """The paper's eq. 1: mean value coordinates over the containing triangle and the
    vertices across its edges. It jumps across control edges, where neighbours on either
    side use other polygons."""

    def combine(self, points, vertices, faces, face, bary):
        polygons, valid = topology.face_star_polygons(faces, topology.face_neighbours(faces))
        index, valid = polygons[face], valid[face]
        return index, coords.mean_value_coordinates(points, vertices[index], valid)


class BlendedMVCSkinning(AbstractSkinning):
    """Mean value coordinates over the star of each corner of the containing triangle,
    blended by the barycentric coordinates `b` (the default).

    Two triangles sharing an edge agree along it, so the map is continuous, and it is the
    smoothest of the three. Each corner's term is corrected by `b_v (e_v - MVC(v))`, which
    vanishes on the star's rim and makes the map interpolate the control vertices: a
    point on a control vertex follows it exactly.
    """

    def combine(self, points, vertices, faces, face, bary):
        corners = faces[face]
        stars, star_valid = topology.vertex_stars(faces, len(vertices))
        # MVC of each control vertex in its own star: one-hot on the boundary, the M
        # term's weights inside.
        at_vertex = coords.mean_value_coordinates(vertices, vertices[stars], star_valid)
        index, weight = [corners], [bary**2]
        for k in range(3):
            v = corners[:, k]
            w = coords.mean_value_coordinates(points, vertices[stars[v]], star_valid[v])
            index.append(stars[v])
            weight.append(bary[:, k : k + 1] * (w - bary[:, k : k + 1] * at_vertex[v]))
        return _merge_duplicates(np.concatenate(index, axis=1), np.concatenate(weight, axis=1))


SKINNINGS = {"blended": BlendedMVCSkinning, "mvc": MVCSkinning, "barycentric": BarycentricSkinning}


def as_skinning(skinning) -> AbstractSkinning:
    """A skinning method from an object or its short name ("blended", "mvc", "barycentric")."""
    if isinstance(skinning, AbstractSkinning):
        return skinning
    if isinstance(skinning, type) and issubclass(skinning, AbstractSkinning):
        return skinning()
    if isinstance(skinning, str) and skinning in SKINNINGS:
        return SKINNINGS[skinning]()
    raise ValueError(
        f"skinning must be one of {tuple(SKINNINGS)} or an mvcjax skinning object "
        f"(mvcjax.BlendedMVCSkinning(), mvcjax.MVCSkinning(), mvcjax.BarycentricSkinning()), "
        f"got {skinning!r}."
    )


def _merge_duplicates(index, weight):
    """Rows of `(index, weight)` with each index once (weights summed), padded with zeros."""
    order = np.argsort(index, axis=1, kind="stable")
    index = np.take_along_axis(index, order, axis=1)
    weight = np.take_along_axis(weight, order, axis=1)
    new = np.ones(index.shape, bool)
    new[:, 1:] = index[:, 1:] != index[:, :-1]
    slot = np.cumsum(new, axis=1) - 1
    rows = np.broadcast_to(np.arange(len(index))[:, None], index.shape)
    merged_index = np.zeros((len(index), slot.max(initial=0) + 1), index.dtype)
    merged_weight = np.zeros((len(index), slot.max(initial=0) + 1), weight.dtype)
    merged_index[rows, slot] = index
    np.add.at(merged_weight, (rows, slot), weight)
    return merged_index, merged_weight


def pack_rows(index: np.ndarray, weight: np.ndarray, tile: int):
    """Rows of `(index, weight)` packed in tiles of `tile` rows that share their indices.

    A point's row lists the control vertices of its containing control triangle's
    neighbourhood, so all the points of a triangle share one list. Rows are grouped by
    their list, each group split into tiles (the last one padded with zero rows):
    skinning a frame then gathers each tile's few control vertices once, instead of one
    per entry of every row, and streams the weights contiguously.

    Returns `(tile_index (k, t), tile_weight (k, t, tile), slot (n,))`: entry `j` of the
    rows of tile `i` is `tile_weight[j, i]` over control vertex `tile_index[j, i]`, and
    row `r` of the input sits at `slot[r] = tile * i + (its place in the tile)`.
    """
    n, k = index.shape
    lists, group = np.unique(index, axis=0, return_inverse=True)
    group = group.reshape(-1)
    order = np.argsort(group, kind="stable")
    counts = np.bincount(group, minlength=len(lists))
    tiles = -(-counts // tile)
    first_tile = np.cumsum(tiles) - tiles
    first_row = np.cumsum(counts) - counts
    slot = np.empty(n, np.int64)
    slot[order] = first_tile[group[order]] * tile + np.arange(n) - first_row[group[order]]
    tile_weight = np.zeros((tiles.sum() * tile, k), weight.dtype)
    tile_weight[slot] = weight
    tile_weight = tile_weight.reshape(-1, tile, k).transpose(2, 0, 1)
    tile_index = lists[np.repeat(np.arange(len(lists)), tiles)].T
    return tile_index, tile_weight, slot


def tile_rows(index: np.ndarray) -> int:
    """Rows per tile for these rows, 8 to 64: the fewest weights streamed plus gathers
    made, a gather (one per tile and entry) counted as eight weights, as measured."""
    _, counts = np.unique(index, axis=0, return_counts=True)
    return min((8, 16, 32, 64), key=lambda tile: (-(-counts // tile)).sum() * (tile + 8))


class Skinning(JittableModule):
    """Each shape vertex as a weighted sum of a few control vertices: `V_S = W V_C`.

    The rows of `W` are stored packed by `pack_rows`: tiles of rows sharing their control
    vertices, weights laid out entry-major. `indices` and `weights` give them back as
    rows. Build one with `Skinning.from_rows`.

    Attributes:
        tile_indices: `(k, t)` the control vertices of each tile's rows.
        tile_weights: `(k, t, s)` their weights, `s` rows per tile (0 on padding).
        slots: `(n,)` where each shape vertex's row sits among the `t * s` tile rows.
        method: the skinning method the weights came from.
    """

    tile_indices: Int[Array, "k t"]
    tile_weights: Float[Array, "k t s"]
    slots: Int[Array, " n"]
    method: AbstractSkinning = eqx.field(static=True, default=BlendedMVCSkinning())

    @classmethod
    def from_rows(cls, indices: Int[np.ndarray, "n k"], weights: Float[np.ndarray, "n k"],
                  method: AbstractSkinning, dtype) -> Skinning:
        """The skinning of rows `(indices, weights)` (from `AbstractSkinning.weights_at`),
        packed; weights stored as `dtype`."""
        indices, weights = np.asarray(indices, np.int64), np.asarray(weights, np.float64)
        tile_index, tile_weight, slot = pack_rows(indices, weights, tile_rows(indices))
        return cls(jnp.asarray(tile_index.astype(np.int32)),
                   jnp.asarray(tile_weight.astype(dtype)),
                   jnp.asarray(slot.astype(np.int32)), method)

    @property
    def indices(self) -> Int[Array, "n k"]:
        """`(n, k)` control vertices of each shape vertex's row (padded with zero
        weights)."""
        return self.tile_indices[:, self.slots // self.tile_weights.shape[2]].T

    @property
    def weights(self) -> Float[Array, "n k"]:
        """`(n, k)` the rows' weights, summing to one."""
        s = self.tile_weights.shape[2]
        return self.tile_weights[:, self.slots // s, self.slots % s].T

    def __call__(self, control_vertices: Float[Array, "c 2"]) -> Float[Array, "n 2"]:
        return with_batching_rule(_skin, _skin_frames)(self, control_vertices)

    def matrix(self, control_count: int) -> Float[Array, "n c"]:
        """`W` as a dense `(n, control_count)` matrix (for analysis, and other tools:
        mvcjax itself skins from the packed rows, which is faster)."""
        n = self.slots.shape[0]
        return jnp.zeros((n, control_count), self.tile_weights.dtype).at[
            jnp.arange(n)[:, None], self.indices
        ].add(self.weights)


def _skin(skinning: Skinning, control_vertices):
    # Each tile gathers its control vertices once; the weighted sums then stream the
    # weights contiguously, and the rows go back to vertex order in one gather. Each
    # stage is materialised, or XLA would fuse them into one slow loop.
    x, y = materialise((control_vertices[:, 0][skinning.tile_indices],
                        control_vertices[:, 1][skinning.tile_indices]))
    w = skinning.tile_weights
    # Unrolled over the entries: XLA compiles a reduction over the leading axis 2.5x
    # slower.
    rows = materialise(jnp.stack([
        sum(w[j] * x[j][:, None] for j in range(w.shape[0])).reshape(-1),
        sum(w[j] * y[j][:, None] for j in range(w.shape[0])).reshape(-1),
    ], axis=1))
    return rows[skinning.slots]


def _skin_frames(frames: int, in_batched, skinning: Skinning, control_vertices):
    """`jax.vmap` of the skinning over control vertices: frame after frame (`lax.map`).

    JAX's batching would turn `materialise`'s conditionals into selects, which XLA fuses
    (2 to 3 times slower); one product with the dense `W` wastes nine products in ten on
    its zeros, and measured slower than this loop from 6k shape vertices on (65 against
    58 microseconds a frame at 6k, 1.05 against 0.54 ms at 100k)."""
    if not only_batched(in_batched, 1):
        return None
    return jax.lax.map(lambda v: _skin(skinning, v), control_vertices), True
