"""Stacks: rigs (and their renderers) of different sizes padded to common sizes and
stacked into one batched pytree, so that `jax.vmap` poses and draws them all in one
compiled program.

The padding changes no result, only the arrays' sizes:
- a padded control vertex sits on control vertex 0 at rest, held there by a mean value
  row `V_p - V_0` of its own. Its coefficients sum to zero, as every shape row's do
  (the solvers' centring relies on it); only that row moves it, so the minimum keeps it
  on vertex 0 and the real vertices feel nothing;
- padded Laplacian, edge and face rows all lie on vertex 0: zero vectors of rest length
  zero (residual zero, gradient zero) and triangles without area (never drawn, never
  counted as folded);
- padded rows of `C` have zero coefficients and are marked `Handles.padding`;
- padded shape vertices repeat shape vertex 0 (the skinning gives them its row);
- the packed skinning tiles and blocks, and the dense factor's tables, get zero
  weights.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax
import numpy as np

from ..core import to_device
from ..energy import DenseFactor, dense_factor, local_stencil, transpose_table
from ..geometry import BLOCK_ROWS, Skinning, block_width_limit, pack_blocks, pack_rows, tile_rows

# Past this many bytes of dense factors in one stack, stacking says so instead of
# allocating them (a dense `G` grows with the square of the control vertices).
_FACTOR_LIMIT_BYTES = 2**31


def pad_rows(a: Any, count: int, fill: Any = 0) -> np.ndarray:
    """`a` with rows equal to `fill` appended up to `count` rows."""
    a = np.asarray(a)
    extra = np.broadcast_to(np.asarray(fill, a.dtype), (count - len(a), *a.shape[1:]))
    return np.concatenate([a, extra])


def _columns(a: Any, width: int, fill: Any = 0) -> np.ndarray:
    a = np.asarray(a)
    return np.pad(a, ((0, 0), (0, width - a.shape[1])), constant_values=fill)


def _pad_to(a: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """`a` padded with zeros at the end of every axis up to `shape`."""
    if any(n > s for s, n in zip(shape, a.shape)):
        raise _TooLarge(f"skinning tables of shape {a.shape}, beyond {shape}")
    return np.pad(a, [(0, s - n) for s, n in zip(shape, a.shape)])


class _TooLarge(ValueError):
    """A rig larger than the stack it is to be padded like."""


def stacked(trees: list) -> Any:
    """The trees' leaves stacked, on the host (stacking on the device compiles a program
    for every leaf's shape)."""
    return jax.tree.map(lambda *leaves: to_device(np.stack([np.asarray(x) for x in leaves]),
                                                  leaves[0].dtype), *trees)


def _sizes(rig) -> dict[str, int]:
    """A rig's sizes (a stack's too: counted from the last axes)."""
    e = rig.energy
    return dict(
        shape_vertices=rig.shape_mesh.vertices.shape[-2],
        shape_faces=rig.shape_mesh.faces.shape[-2],
        control_vertices=e.rest.shape[-2],
        control_faces=e.faces.shape[-2],
        outer=rig.control_mesh.outer.shape[-1],
        laplacian=e.laplacian_index.shape[-2],
        ring=e.mvc_ring.shape[-1],
        edges=e.edges.shape[-2],
        pinned=e.handles.shape[-2],
        pin_width=e.handles.shape[-1],
        skin_width=rig.skinning.tile_indices.shape[-2],
    )


def common_sizes(rigs: Sequence[Any]) -> dict[str, int]:
    """The sizes every rig of `rigs` pads to: the largest of each. The mean value rows
    are as many as the control vertices: each rig's own (its inner vertices) and one to
    hold each padded vertex always fit, whatever stack a rig is padded like."""
    sizes = [_sizes(r) for r in rigs]
    common = {k: max(s[k] for s in sizes) for k in sizes[0]}
    common["mvc"] = common["control_vertices"]
    return common


def padded_energy(energy, sizes: dict[str, int]):
    e = energy
    c0, c = e.rest.shape[0], sizes["control_vertices"]
    g, w = sizes["mvc"], sizes["ring"]
    holders = np.arange(c0, c)
    # Each padded vertex's row is `V_p - V_0`; further rows `V_0 - V_0` are zero.
    ring_weight = _columns(e.mvc_weight, w)
    ring_weight = pad_rows(pad_rows(ring_weight, len(ring_weight) + len(holders),
                              np.eye(1, w)[0]), g, np.eye(1, w)[0])
    laplacian, edges, pinned = sizes["laplacian"], sizes["edges"], sizes["pinned"]
    dtype = e.rest.dtype
    arrays = dict(
        rest=pad_rows(e.rest, c, np.asarray(e.rest)[0]),
        laplacian_index=pad_rows(e.laplacian_index, laplacian),
        laplacian_length=pad_rows(e.laplacian_length, laplacian),
        mvc_centre=pad_rows(np.concatenate([np.asarray(e.mvc_centre), holders]), g),
        mvc_ring=pad_rows(_columns(e.mvc_ring, w), g),
        mvc_weight=ring_weight,
        edges=pad_rows(e.edges, edges),
        edge_length=pad_rows(e.edge_length, edges),
        handles=pad_rows(_columns(e.handles, sizes["pin_width"]), pinned),
        handle_coef=pad_rows(_columns(e.handle_coef, sizes["pin_width"]), pinned),
        faces=pad_rows(e.faces, sizes["control_faces"]),
    )
    return eqx.tree_at(
        lambda e: [getattr(e, k) for k in arrays], e,
        [to_device(a, np.int32 if a.dtype.kind in "iu" else dtype) for a in arrays.values()])


def _padded_rows(skinning: Skinning, count: int, width: int):
    """The skinning's rows `(indices, weights)` on the host, padded to `count` rows (each
    a copy of row 0) and `width` entries (weight zero)."""
    # On the host: the device's own gathers would compile a program for every size.
    tile_index, tile_weight = np.asarray(skinning.tile_indices), np.asarray(skinning.tile_weights)
    slots, s = np.asarray(skinning.slots), tile_weight.shape[2]
    index = tile_index[:, slots // s].T.astype(np.int64)
    weight = tile_weight[:, slots // s, slots % s].T.astype(np.float64)
    return (pad_rows(_columns(index, width), count, _columns(index, width)[0]),
            pad_rows(_columns(weight, width), count, _columns(weight, width)[0]))


def padded_skinnings(rigs, sizes: dict[str, int], like: Skinning | None,
               shapes=None) -> list[Skinning]:
    """The rigs' skinnings packed alike: one tile size, tiles and blocks padded with
    zero weights to the largest count and width (or to those of `like`, a stack's; or
    to `shapes(name, largest, tile)` of each table, given that function)."""
    rows = [_padded_rows(r.skinning, sizes["shape_vertices"], sizes["skin_width"])
            for r in rigs]
    tile = (max(tile_rows(index) for index, _ in rows) if like is None
            else like.tile_weights.shape[-1])
    tiles = [pack_rows(index, weight, tile) for index, weight in rows]
    blocks = [pack_blocks(index, weight, BLOCK_ROWS, block_width_limit(index.shape[1]))
              for index, weight in rows]
    unblocked = like is not None and like.block_weights.shape[-3] == 0
    if unblocked or any(b is None for b in blocks):  # rows too scattered: none blocked
        blocks = [(np.zeros((0, 1), np.int64), np.zeros((0, 1, BLOCK_ROWS)))] * len(rows)

    def most(arrays, name) -> tuple[int, ...]:
        if like is not None:
            return tuple(int(n) for n in getattr(like, name).shape[1:])
        largest = tuple(int(n) for n in np.max([a.shape for a in arrays], axis=0))
        return largest if shapes is None else shapes(name, largest, tile)

    tile_index = most([t[0] for t in tiles], "tile_indices")
    tile_weight = most([t[1] for t in tiles], "tile_weights")
    block_index = most([b[0] for b in blocks], "block_indices")
    block_weight = most([b[1] for b in blocks], "block_weights")
    out = []
    for rig, (ti, tw, slot), (bi, bw) in zip(rigs, tiles, blocks):
        dtype = rig.energy.rest.dtype
        out.append(Skinning(
            to_device(_pad_to(ti, tile_index), np.int32), to_device(_pad_to(tw, tile_weight),
                                                                    dtype),
            to_device(slot, np.int32), to_device(_pad_to(bi, block_index), np.int32),
            to_device(_pad_to(bw, block_weight), dtype), rig.skinning.method))
    return out


def padded_factors(energies, width: int | None, round_width=None) -> list[DenseFactor]:
    """Dense factors of the padded energies, their spread tables padded alike (with the
    entry past the last, whose coefficient is zero) to the widest (rounded up by
    `round_width`, if given) or to `width`: one size, so one compiled program for them all.

    The padded rows, all on one vertex, are left out of the tables: they are zero
    vectors, and listed they would make the table as wide as their count."""
    spreads = []
    for energy in energies:
        rows, coef = (np.asarray(a) for a in local_stencil(energy))
        zero = (rows == rows[:, :1]).all(axis=1)
        spreads.append((transpose_table(rows, np.where(zero[:, None], 0.0, coef),
                                        energy.num_vertices), rows.size))
    if width is None:
        width = max(s.shape[1] for s, _ in spreads)
        width = width if round_width is None else round_width(width)
    if any(s.shape[1] > width for s, _ in spreads):
        raise _TooLarge(f"a control vertex in more rows than {width}")
    # Padded with the entry past the last, as `transpose_table` pads.
    return [dense_factor(e, to_device(_columns(s, width, past), np.int32))
            for e, (s, past) in zip(energies, spreads)]


def pad_rig(rig, sizes: dict[str, int], skinning: Skinning, factor: DenseFactor, energy):
    """`rig` padded to `sizes`, with its padded skinning, factor and energy."""
    n, r, c = sizes["shape_vertices"], sizes["pinned"], sizes["control_vertices"]
    h, sm, cm = rig.handles, rig.shape_mesh, rig.control_mesh
    dtype = rig.energy.rest.dtype
    ints = lambda a: to_device(a, np.int32)  # noqa: E731
    real = lambda a: to_device(a, dtype)  # noqa: E731
    return eqx.tree_at(
        lambda g: (g.handles.first, g.handles.second, g.handles.along, g.handles.length,
                   g.handles.rigid, g.handles.padding, g.shape_mesh, g.control_mesh,
                   g.skinning, g.energy, g.factor, g.turns), rig,
        (ints(pad_rows(h.first, r)), ints(pad_rows(h.second, r)), real(pad_rows(h.along, r)),
         real(pad_rows(h.length, r)), to_device(pad_rows(h.rigid, r), bool),
         to_device(pad_rows(h.padding, r, True), bool),
         type(sm)(real(pad_rows(sm.vertices, n, np.asarray(sm.vertices)[0])),
                  ints(pad_rows(sm.faces, sizes["shape_faces"])), ints(pad_rows(sm.handles, r))),
         type(cm)(real(pad_rows(cm.vertices, c, np.asarray(cm.vertices)[0])),
                  ints(pad_rows(cm.faces, sizes["control_faces"])),
                  ints(pad_rows(cm.outer, sizes["outer"], np.asarray(cm.outer)[-1])),
                  energy.mvc_centre, ints(pad_rows(cm.handles, r))),
         skinning, energy, factor,
         real(_columns(pad_rows(rig.turns, c, np.asarray(rig.turns)[0]), r))))


def _check_stackable(rigs, Rig) -> None:
    if isinstance(rigs, Rig) or not isinstance(rigs, Sequence) or not len(rigs):
        raise TypeError(f"Rig.stack takes a list of rigs (at least one), got "
                        f"{type(rigs).__name__}.")
    for i, rig in enumerate(rigs):
        if not isinstance(rig, Rig):
            raise TypeError(f"rigs[{i}] is a {type(rig).__name__}, not an mvcjax.Rig.")
        if rig.frame.scale.ndim:
            raise ValueError(f"rigs[{i}] is a stack already; stack the rigs it was made "
                             "of with the others.")
    first = rigs[0]
    layout = (first.handles.count, np.asarray(first.handles.bones).tolist())
    for i, rig in enumerate(rigs[1:], 1):
        if rig.energy.rest.dtype != first.energy.rest.dtype:
            raise ValueError(
                f"rigs[{i}] is {rig.energy.rest.dtype.name}, rigs[0] "
                f"{first.energy.rest.dtype.name}: a stack holds one dtype; build them all "
                "with the same Rig.build(..., dtype=...).")
        if (rig.handles.count, np.asarray(rig.handles.bones).tolist()) != layout:
            raise ValueError(
                f"rigs[{i}] has {rig.handles.count} target rows (bones at rows "
                f"{np.asarray(rig.handles.bones).tolist()}), rigs[0] {layout[0]} (bones at "
                f"rows {layout[1]}): stacked rigs are posed by one array of targets, so "
                "they need the same handles' layout (as many point handles and bones, in "
                "the same order); give every shape that many handles, or stack the rigs "
                "by their handle count.")
        if rig.skinning.method != first.skinning.method:
            raise ValueError(
                f"rigs[{i}] skins with {rig.skinning.method!r}, rigs[0] with "
                f"{first.skinning.method!r}: build them with the same skinning=.")
    for i, rig in enumerate(rigs):
        if rig.energy.extra:
            raise ValueError(f"rigs[{i}] has extra terms (Rig.with_terms): a stack's rigs "
                             "share one energy's form; stack them without, then add none.")
        if rig.energy.weights.mvc is None:
            raise ValueError(
                f"rigs[{i}] has no mean value term (Weights(mvc=None)): a stack holds each "
                "padded control vertex by a mean value row; build the rigs with a mean value "
                "weight (a small one, as the default's, bends nothing: its rows live in the "
                "factor only).")


def stack_rigs(rigs: Any, like: Any, kind: type):
    """One rig whose every array has a leading axis over `rigs` (each of class `kind`),
    padded to common sizes (see the module's docstring), or to those of the stack `like`;
    `Rig.stack` documents it."""
    _check_stackable(rigs, kind)
    sizes = common_sizes(rigs)
    if like is not None:
        _check_like(rigs, like, kind)
        given = {**_sizes(like), "mvc": like.energy.mvc_centre.shape[-1]}
        over = [f"{k.replace('_', ' ')} {sizes[k]} > {given[k]}" for k in sizes
                if sizes[k] > given[k]]
        if over:
            raise ValueError(too_large(", ".join(over)))
        sizes = given
    c, itemsize = sizes["control_vertices"], rigs[0].energy.rest.dtype.itemsize
    # G's two parts, N and its inverse: about five c x c matrices a rig.
    factor_bytes = len(rigs) * 5 * c * c * itemsize
    if factor_bytes > _FACTOR_LIMIT_BYTES:
        raise ValueError(
            f"A stack of {len(rigs)} rigs of up to {c} control vertices needs dense factors "
            f"of about {factor_bytes / 2**30:.1f} GiB (a stack solves with a dense G, "
            "whatever each rig's factor): stack fewer rigs at a time, or build them with "
            "a coarser PaperControl(spacing=...).")
    energies = [padded_energy(r.energy, sizes) for r in rigs]
    try:
        skinnings = padded_skinnings(rigs, sizes, None if like is None else like.skinning)
        factors = padded_factors(energies, None if like is None else like.factor.spread.shape[-1])
    except _TooLarge as e:
        raise ValueError(too_large(str(e))) from None
    padded = [pad_rig(r, sizes, s, f, e)
              for r, s, f, e in zip(rigs, skinnings, factors, energies)]
    stack = stacked(padded)
    return stack


def too_large(what: str) -> str:
    return (f"These rigs do not fit the sizes of the stack given as like= ({what}): stack "
            "them without like=, or make like= a stack of larger rigs (the largest of all "
            "the batches, say).")


def _check_like(rigs, like, Rig) -> None:
    if not isinstance(like, Rig) or like.stacked is None:
        raise TypeError(f"like= takes a stack (Rig.stack), got {type(like).__name__}"
                        + ("" if not isinstance(like, Rig) else " (a single rig)") + ".")
    first = rigs[0]
    same = (like.handles.rest.shape[-2] == first.handles.count
            and np.array_equal(np.asarray(like.handles.bones)[0],
                               np.asarray(first.handles.bones))
            and like.energy.rest.dtype == first.energy.rest.dtype
            and like.skinning.method == first.skinning.method)
    if not same:
        raise ValueError("like= is a stack of rigs with another handles' layout, dtype or "
                         "skinning method than these: stack like rigs like it.")
