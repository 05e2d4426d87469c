"""A ladder of sizes: rigs of similar sizes padded alike, so that they share compiled
programs.

JAX compiles a program for every set of array shapes. A script that rigs many shapes
(every glyph of a font, a folder of sprites) builds rigs whose sizes all differ by a
few vertices, and each would compile its factor and its solve anew: most of a new
rig's build and first frame. `Rig.build(..., ladder=SizeLadder())` rounds the rig's
sizes up to the rungs of a geometric ladder and keeps, beside the rig, a twin padded
to them (as `Rig.stack` pads, which changes no result). The rig itself keeps its own
sizes: what a user reads from it and gets from it is as without the ladder. Its eager
calls (`deform`, `solve`, `deform_frames`) run the twin's programs, shared by every
rig on the same rungs, and return the rig's own rows; its factor is cut from the
twin's, so the build compiles nothing new either.
"""

from __future__ import annotations

import math
import numbers
import types

import equinox as eqx
import jax
import numpy as np

from ..core import to_device
from ..energy import DenseFactor, local_blocks, transpose_table
from ..geometry import block_width_limit
from ._stack import common_sizes, pad_rig, padded_energy, padded_factors, padded_skinnings


def _step(step) -> float:
    if not (isinstance(step, numbers.Real) and not isinstance(step, bool)
            and 1.0 < step <= 4.0):
        raise ValueError(f"SizeLadder(step={step!r}): the step is the ratio between rungs, "
                         "a number above 1 and at most 4 (sqrt(2), the default, pads a size "
                         "by at most its half again).")
    return float(step)


class SizeLadder(eqx.Module):
    """Sizes rounded up to the next rung of `ceil(step ** k)`: 1, 2, 3, 4, 6, 8, 12, 16,
    23, 32, 46, 64, 91, 128, ... for the default step `sqrt(2)`.

    Only the shape mesh's and the control mesh's vertex counts are rounded on their own
    (and the pinned rows, which the handles decide); every other size is made from
    them, as large as a mesh of that many vertices can need (triangles, edges, the
    Laplacian's rows, the skinning's tiles), so that rigs differ in two or three
    counts, not a dozen. The twin then does more arithmetic than its rig: up to
    `step` times as many vertices, and four energy rows per control vertex where a
    rig has under three.

    Attributes:
        step: the ratio between rungs, above 1 (a larger step pads more and shares
            more programs).
    """

    step: float = eqx.field(default=2 ** 0.5, static=True, converter=_step)

    def rung(self, n: int) -> int:
        """The smallest rung at least `n`."""
        if n <= 1:
            return max(int(n), 0)
        k = max(math.floor(math.log(n) / math.log(self.step)) - 1, 0)
        while math.ceil(self.step ** k - 1e-9) < n:
            k += 1
        return math.ceil(self.step ** k - 1e-9)

    def padded(self, name: str, n: int) -> int:
        """Size `name` of `n` padded: to its rung, or to a floor where there is one and
        `n` is at least half of it (widths that vary by a few entries between rigs)."""
        floor = _FLOORS.get(name, 0)
        return floor if floor / 2 <= n <= floor else self.rung(n)

    def sizes(self, sizes: dict[str, int]) -> dict[str, int]:
        """A rig's sizes (`_stack.common_sizes`), padded: see the class."""
        n, c = self.rung(sizes["shape_vertices"]), self.rung(sizes["control_vertices"])
        out = {k: self.padded(k, v) for k, v in sizes.items()}
        # A triangulation of v vertices has under 2v triangles and 3v edges, and its
        # polygon (the Laplacian's rows) under v vertices.
        out.update(shape_vertices=n, control_vertices=c, mvc=c, shape_faces=2 * n,
                   control_faces=2 * c, outer=c, laplacian=c, edges=3 * c)
        return {k: max(v, sizes[k]) for k, v in out.items()}

    def table_shape(self, name: str, largest: tuple[int, ...], tile: int,
                    sizes: dict[str, int]) -> tuple[int, ...]:
        """The padded shape of a skinning table (`Skinning`'s fields) packed `largest`
        in tiles of `tile` rows, for a twin of `sizes`."""
        width, n = sizes["skin_width"], sizes["shape_vertices"]
        if name in ("tile_indices", "tile_weights"):
            # The rows of one control triangle share their list, and so their tiles:
            # at most one partly filled tile per triangle.
            tiles = -(-n // tile) + sizes["control_faces"]
            return (width, max(tiles, largest[1]), *largest[2:])
        # As many blocks as the padded rows make, each as wide as a block may be.
        return (largest[0], max(block_width_limit(width), largest[1]), *largest[2:])


# Widths that vary by a few entries between rigs, padded to where most rigs fall: a
# mean value ring, a skinning row (blended), a vertex's local rows.
_FLOORS = {"ring": 12, "skin_width": 23, "spread": 23}


def twin_parts(parts: dict, ladder: SizeLadder):
    """For a rig's parts (its fields but the factor), its padded twin's dense factor
    and energy, and `finish(rig)`, which pads the rig built from them into the twin."""
    sizes = ladder.sizes(common_sizes([types.SimpleNamespace(**parts)]))
    energy = padded_energy(parts["energy"], sizes)
    (factor,) = padded_factors([energy], None, lambda width: ladder.padded("spread", width))

    def finish(rig):
        def shapes(name, largest, tile):
            return ladder.table_shape(name, largest, tile, sizes)

        (skinning,) = padded_skinnings([rig], sizes, None, shapes)
        return pad_rig(rig, sizes, skinning, factor, energy)

    return factor, energy, finish


def keep_twin(rig, twin) -> None:
    """Keep `twin` as `rig`'s, among what the rig keeps for itself (`rig.programs`): it
    goes with the rig, and stays with rigs rebuilt from the very same arrays."""
    rig.programs.kept["twin"] = (jax.tree.flatten(rig), twin)


def padded_twin(rig):
    """The twin `Rig.build(..., ladder=...)` kept for this rig, or None: for a rig
    rebuilt with any other array (`jax.tree.map`, new weights) it would be stale."""
    if "twin" not in rig.programs.kept:
        return None
    (leaves, structure), twin = rig.programs.kept["twin"]
    now, now_structure = jax.tree.flatten(rig)
    same = now_structure == structure and all(a is b for a, b in zip(now, leaves))
    return twin if same else None


def cut_factor(padded: DenseFactor, twin_energy, energy) -> DenseFactor:
    """The dense factor of `energy` (a rig's own) cut from `padded`, that of its padded
    twin's energy `twin_energy`.

    The twin's padded vertices are held each by one row `V_p - V_0` of the linear term,
    and its padded rows are zero: so the real block of the twin's `N^{-1}` is the rig's
    own `N^{-1}` (the Schur complement of the padded block gives back `N`), the real
    rows and columns of its `G` are the rig's `G`, and its `N` differs from the rig's only
    by the holders' weight on vertex 0.
    """
    c = energy.rest.shape[0]
    # Each local term's rows, padded to the twin's count: the rig's are the first.
    local = [(t.name, t.count) for t in _shapes(energy) if t.is_local]
    twin_counts = [t.count for t in _shapes(twin_energy) if t.is_local]
    starts = np.cumsum([0, *twin_counts[:-1]])
    real = np.concatenate([start + np.arange(count)
                           for start, (_, count) in zip(starts, local)])
    host = {k: np.asarray(getattr(padded, k)) for k in
            ("shape", "handle", "normal", "normal_inverse", "rows", "coef", "length")}
    weights = energy.weights.normalised()
    normal = host["normal"][:c, :c].copy()
    normal[0, 0] -= (twin_energy.rest.shape[0] - c) * float(weights.mvc)
    rows, coef = host["rows"][real], host["coef"][real]
    row_weight = np.concatenate([np.full(count, float(getattr(weights, name)))
                                 for name, count in local])
    rotation = None if padded.rotation is None else to_device(
        np.asarray(padded.rotation)[real], padded.rotation.dtype)
    spread = transpose_table(rows, coef, c)
    entries = np.append((coef * row_weight[:, None]).reshape(-1), 0.0)
    dtype = energy.rest.dtype
    real_array = lambda a: to_device(a, dtype)  # noqa: E731
    return DenseFactor(
        shape=real_array(host["shape"][real][:, :c]),
        handle=real_array(host["handle"][:c, :energy.handles.shape[0]]),
        normal=real_array(normal),
        normal_inverse=real_array(host["normal_inverse"][:c, :c]),
        spread=to_device(spread, np.int32), spread_coef=real_array(entries[spread]),
        rows=to_device(rows, np.int32), coef=real_array(coef),
        length=real_array(host["length"][real]), rest=real_array(np.asarray(energy.rest).T),
        handle_rows=energy.handles, handle_coef=energy.handle_coef, rotation=rotation,
        blocks=local_blocks(energy),
    )


def _shapes(energy):
    """The energy's terms, their arrays as shapes only (nothing computed or compiled)."""
    return jax.eval_shape(lambda e: e.terms(), energy)
