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

from ..core import (
    JittableModule,
    checked_option,
    materialise,
    only_batched,
    to_device,
    with_batching_rule,
)
from . import _coordinates as coords, _topology as topology
from ._local_frame import Frame

# How far outside the control mesh, in the rig's frame (unit diagonal), a point may lie:
# a few float32 roundings, so that a control mesh given in float32 (a float32 rig's own
# shape mesh, say) still carries the points of its boundary.
OUTSIDE_TOLERANCE = 1e-6


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
        outside = np.flatnonzero(depth < 0)
        outside = outside[coords.distance_outside(points[outside], vertices[faces[face[
            outside]]]) > OUTSIDE_TOLERANCE]
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


def as_skinning(skinning) -> AbstractSkinning:
    """The skinning option of `Rig.build`: an `AbstractSkinning`, or a TypeError that
    names the object to write (for a short name such as `"mvc"` too)."""
    return checked_option(
        "skinning", skinning, AbstractSkinning,
        {name: f"mvcjax.advanced.{kind.__name__}()" for name, kind in (
            ("blended", BlendedMVCSkinning), ("mvc", MVCSkinning),
            ("barycentric", BarycentricSkinning))},
        described="a skinning object, mvcjax.advanced.BlendedMVCSkinning(), "
                  "mvcjax.advanced.MVCSkinning() or mvcjax.advanced.BarycentricSkinning()",
        default="mvcjax.advanced.BlendedMVCSkinning()")


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


def pack_blocks(index: np.ndarray, weight: np.ndarray, block: int, max_width: int | None = None):
    """Rows of `(index, weight)` in blocks of `block` consecutive rows, each block a
    dense matrix over the few control vertices its rows use.

    The shape mesh is numbered along a Hilbert curve (`meshing.hilbert_order`), so a
    block covers a compact patch and uses a few dozen of the control vertices: skinning
    many frames is then one batched matrix product over the blocks.

    Returns `(block_index (b, k), block_weight (b, k, block))`: row `block * i + r` is
    `sum_j block_weight[i, j, r] V[block_index[i, j]]`, padded with zeros (the last
    block's missing rows are zero). Rows in no such order (points given in any order,
    or one control vertex a row) make blocks as wide as a dense `W`: past `max_width`
    control vertices in a block, returns `None` before allocating them.
    """
    n, width = index.shape
    count = -(-n // block)
    control = int(index.max(initial=0)) + 1
    row_block = np.repeat(np.arange(n) // block, width)
    keep = weight.reshape(-1) != 0
    keys = row_block[keep] * control + index.reshape(-1)[keep]
    used, slot_of = np.unique(keys, return_inverse=True)
    owner = used // control
    per_block = np.bincount(owner, minlength=count)
    place = np.arange(len(used)) - (np.cumsum(per_block) - per_block)[owner]
    width_used = max(int(per_block.max(initial=0)), 1)
    if max_width is not None and width_used > max_width:
        return None
    block_index = np.zeros((count, width_used), np.int64)
    block_index[owner, place] = used % control
    block_weight = np.zeros((*block_index.shape, block), weight.dtype)
    row = np.repeat(np.arange(n), width)[keep]
    np.add.at(block_weight, (row // block, place[slot_of.reshape(-1)], row % block),
              weight.reshape(-1)[keep])
    return block_index, block_weight


# Rows per block of the many-frames skinning: the time varies little over a wide range
# around it (`benchmarks/frames.py` measures the many-frames path).
BLOCK_ROWS = 256


def block_width_limit(row_width: int) -> int:
    """The most control vertices a block may use before the blocked product stops paying:
    four times a row's entries, or 64 (a Hilbert-ordered horse used 34 to 45 with rows of
    18 to 19)."""
    return max(4 * row_width, 64)


def tile_rows(index: np.ndarray) -> int:
    """Rows per tile for these rows, 8 to 64: the fewest weights streamed plus gathers
    made, a gather (one per tile and entry) counted as eight weights, about its cost
    against a streamed weight on the CPU."""
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
        block_indices: `(b, j)` the control vertices of each block of consecutive rows,
            and `block_weights`, `(b, j, r)` their weights (`pack_blocks`): the layout of
            many frames at once, under `jax.vmap`. Empty (`b = 0`) where the rows are
            too scattered for blocks (`block_width_limit`): `jax.vmap` then maps the
            single frame's skinning over the frames.
        method: the skinning method the weights came from.
    """

    tile_indices: Int[Array, "k t"]
    tile_weights: Float[Array, "k t s"]
    slots: Int[Array, " n"]
    block_indices: Int[Array, "b j"]
    block_weights: Float[Array, "b j r"]
    method: AbstractSkinning = eqx.field(static=True, default=BlendedMVCSkinning())

    @classmethod
    def from_rows(cls, indices: Int[np.ndarray, "n k"], weights: Float[np.ndarray, "n k"],
                  method: AbstractSkinning, dtype) -> Skinning:
        """The skinning of rows `(indices, weights)` (from `AbstractSkinning.weights_at`),
        packed; weights stored as `dtype`."""
        indices, weights = np.asarray(indices, np.int64), np.asarray(weights, np.float64)
        tile_index, tile_weight, slot = pack_rows(indices, weights, tile_rows(indices))
        blocks = pack_blocks(indices, weights, BLOCK_ROWS, block_width_limit(indices.shape[1]))
        if blocks is None:  # no blocked product (`_skin_frames` maps over the frames)
            blocks = np.zeros((0, 1), np.int64), np.zeros((0, 1, BLOCK_ROWS))
        block_index, block_weight = blocks
        return cls(to_device(tile_index, np.int32), to_device(tile_weight, dtype),
                   to_device(slot, np.int32), to_device(block_index, np.int32),
                   to_device(block_weight, dtype), method)

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

    def __call__(self, control_vertices: Float[Array, "c 2"], frame: Frame | None = None
                 ) -> Float[Array, "n 2"]:
        """`W control_vertices`, the shape vertices `(n, 2)`; with a `frame`, mapped by
        `frame.to_world` (the control vertices then in the frame's local coordinates).

        Under `jax.vmap` the frame's map is applied as each block of frames is skinned:
        a pass of its own would read and write the whole result once more, about as
        much memory traffic as the skinning itself."""
        return with_batching_rule(_skin_in, _skin_frames)(self, control_vertices, frame)

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
    # Unrolled over the entries: XLA compiles a reduction over the leading axis into
    # slower code.
    rows = materialise(jnp.stack([
        sum(w[j] * x[j][:, None] for j in range(w.shape[0])).reshape(-1),
        sum(w[j] * y[j][:, None] for j in range(w.shape[0])).reshape(-1),
    ], axis=1))
    return rows[skinning.slots]


def _skin_in(skinning: Skinning, control_vertices, frame):
    out = _skin(skinning, control_vertices)
    return out if frame is None else frame.to_world(out)


def _skin_blocks(skinning: Skinning, control_vertices: Float[Array, "f c 2"], frame):
    """Many frames' skinning as one batched product over the blocks of consecutive rows
    (`pack_blocks`), with frames and coordinates as the rows of its right-hand side."""
    frames, n = control_vertices.shape[0], skinning.slots.shape[0]
    # Coordinate planes, frames last: gathering a block's control vertices moves whole
    # rows of 2f numbers, and the product's rows are the x of every frame, then the y.
    columns = jnp.transpose(control_vertices, (1, 2, 0)).reshape(-1, 2 * frames)  # (c, 2f)
    blocks = jnp.einsum("bkx,bkr->bxr", columns[skinning.block_indices],
                        skinning.block_weights)  # (b, 2f, r)
    b, _, r = blocks.shape
    rows = jnp.transpose(blocks.reshape(b, 2, frames, r), (2, 0, 3, 1)).reshape(frames, b * r, 2)
    rows = rows[:, :n]
    return rows if frame is None else frame.to_world(rows)


def frames_per_product(shape_vertices: int) -> int:
    """Frames skinned by one batched product: 128, or fewer (a power of two, at least 8)
    where 128 frames would pass `2**24` shape vertices in all (over 131k a frame).
    Larger groups spread each product's fixed cost over more frames
    (`benchmarks/throughput.py` measures the batches; see the guide's "Memory for large
    batches")."""
    return 1 << min(7, max(3, (2**24 // max(shape_vertices, 1)).bit_length() - 1))


def skin_frames_into(skinning: Skinning, control_vertices: Float[Array, "f c 2"], frame,
                     out: Float[Array, "f n 2"]) -> Float[Array, "f n 2"]:
    """The skinning of many frames written into `out` (its values unused), a group of
    frames (`frames_per_product`) at a time.

    Given a donated `out`, the result takes its memory and nothing is filled first:
    `jax.vmap` of the skinning loops into a new array filled with zeros, one more pass
    over the whole result."""
    frames = control_vertices.shape[0]
    if skinning.block_weights.shape[0] == 0:  # rows too scattered for blocks
        skinned = jax.lax.map(lambda v: _skin_in(skinning, v, frame), control_vertices)
        return jax.lax.dynamic_update_slice_in_dim(out, skinned, 0, 0)
    group = min(frames, frames_per_product(skinning.slots.shape[0]))
    whole = frames // group

    def one_group(i, out):
        v = jax.lax.dynamic_slice_in_dim(control_vertices, i * group, group)
        return jax.lax.dynamic_update_slice_in_dim(out, _skin_blocks(skinning, v, frame),
                                                   i * group, 0)

    out = jax.lax.fori_loop(0, whole, one_group, out)
    if frames > whole * group:
        rest = _skin_blocks(skinning, control_vertices[whole * group:], frame)
        out = jax.lax.dynamic_update_slice_in_dim(out, rest, whole * group, 0)
    return out


def _skin_frames(frames: int, in_batched, skinning: Skinning, control_vertices, frame):
    """`jax.vmap` of the skinning over control vertices: `_skin_blocks`, a few frames at
    a time (`frames_per_product`).

    Each block's product is dense over its few dozen control vertices (at 6k shape
    vertices, 12 nonzeros a row on average, 19 at most, against 45 columns a block; a
    dense `W` over all 160 wastes nine products in ten) and runs at matrix-product
    speed, where mapping the single frame's sparse skinning over frames gathers element
    by element (`benchmarks/throughput.py` measures both)."""
    if not only_batched(in_batched, 1):
        return None
    if skinning.block_weights.shape[0] == 0:  # rows too scattered for blocks
        out = jax.lax.map(lambda v: _skin_in(skinning, v, frame), control_vertices)
        return out, True
    group = min(frames, frames_per_product(skinning.slots.shape[0]))
    if group == frames:
        return _skin_blocks(skinning, control_vertices, frame), True
    padded = -(-frames // group) * group
    extra = jnp.repeat(control_vertices[-1:], padded - frames, axis=0)
    groups = jnp.concatenate([control_vertices, extra]).reshape(-1, group,
                                                                *control_vertices.shape[1:])
    out = jax.lax.map(lambda v: _skin_blocks(skinning, v, frame), groups)
    return out.reshape(padded, *out.shape[2:])[:frames], True
