"""Rig: the shape mesh, the control mesh, the skinning weights and the solver's data."""

from __future__ import annotations

from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ..core import (
    Programs,
    as_points,
    check_targets,
    compiled_by,
    is_real_number,
    is_traced,
    programs_field,
    refusing_removed,
    to_device,
    whole_number,
)
from ..energy import (
    LAPLACIAN,
    AbstractFactor,
    Energy,
    FactorBySize,
    Term,
    Weights,
    as_factor_method,
    check_shape_held,
    check_weights,
    total_energy,
)
from ..geometry import (
    BarycentricSkinning,
    BlendedMVCSkinning,
    Frame,
    Shape,
    Skinning,
    as_skinning,
    bounding_frame,
    check_representable,
    frame_array,
    interior_edges,
    inverted_count,
    mean_value_coordinates,
    points_to_local,
    signed_areas,
    thin_outline,
    triangulate_shape,
    vertex_stars,
)
from ..solvers import DEFAULT_SOLVER, AbstractSolver, SkinnedMesh, check_solver
from . import _pins
from ._control import PaperControl, as_control
from ._handles import Handles, check_handles, make_handles, pin
from ._ladder import SizeLadder, cut_factor, keep_twin, padded_twin, twin_parts
from ._posable import AbstractRig, ControlMesh, ShapeMesh
from ._stack import pad_rows, stack_rigs
from ._start import AbstractStart, Init, TurnedStart, checked_start, turn_weights


class _BuildOptions(NamedTuple):
    """`Rig.build`'s arguments, checked; the handles' points and bones, and the frame
    that maps the shape to its own unit-size coordinates."""

    points: np.ndarray
    bones: np.ndarray
    weights: Weights
    skinning: Any
    max_triangles: int
    control: Any
    factor: Any
    dtype: Any
    frame: tuple


def _checked_build_options(shape, handles, weights, skinning, max_triangles, control, factor,
                           ladder, dtype) -> _BuildOptions:
    """`Rig.build`'s arguments checked, in the order they are documented."""
    if not isinstance(shape, Shape):
        raise TypeError(
            f"shape must be an mvcjax.Shape, got {type(shape).__name__}; build one with "
            "Shape.from_polygon(outer, holes) or Shape.from_image(mask)."
        )
    dtype = _check_dtype(dtype)
    points, bones, _ = check_handles(shape, handles)
    weights = Weights() if weights is None else check_weights(weights)
    skinning = as_skinning(skinning)
    max_triangles = whole_number(max_triangles, "max_triangles")
    control = as_control(control)
    factor = as_factor_method(factor)
    if ladder is not None and not isinstance(ladder, SizeLadder):
        raise TypeError(f"ladder must be an mvcjax.SizeLadder() or None, got "
                        f"{ladder!r}.")
    if ladder is not None and weights.mvc is None:
        raise ValueError(
            "ladder=SizeLadder() holds each padded control vertex of its twin by a mean "
            "value row, and Weights(mvc=None) leaves that term out: give it a weight "
            "(a small one, as the default's, bends nothing: its rows live in the factor "
            "only), or build without ladder=.")
    centre, scale = bounding_frame(shape.outer)
    check_representable(centre, scale, dtype)
    return _BuildOptions(points, bones, weights, skinning, max_triangles, control, factor,
                         dtype, (centre, scale))


def _meshed_parts(shape: Shape, shape_spacing, options: _BuildOptions) -> tuple:
    """The shape mesh, the control mesh, the skinning's rows and the handles' rows of a
    rig, in the shape's own frame (`Rig._assemble` takes them)."""
    frame = options.frame
    scale, control = frame[1], options.control
    local = Shape.from_polygon(points_to_local(shape.outer, frame),
                               [points_to_local(h, frame) for h in shape.holes])
    local_points = points_to_local(options.points, frame)
    control_spacing = getattr(control, "spacing", None)
    margin = control.margin if isinstance(control, PaperControl) else None
    shape_spacing, control_spacing, margin = _spacings(
        local, scale, shape_spacing, control_spacing, margin
    )
    _check_mesh_size(local, shape_spacing, scale, options.max_triangles)
    samples = control.bone_samples(control_spacing, frame)
    pinned, row_pin, rows = pin(local_points, options.bones, samples, 1e-6)
    handle_rows = make_handles(local_points, options.bones, rows, options.dtype)

    local = thin_outline(local, shape_spacing)
    shape_vertices, shape_faces, shape_pinned = triangulate_shape(
        local, shape_spacing, pinned
    )
    parts = control.build(local, shape_vertices, shape_faces, shape_pinned, pinned,
                          control_spacing, margin, frame)
    if parts.is_shape_mesh:
        n = len(shape_vertices)
        skin = (np.arange(n)[:, None], np.ones((n, 1)), BarycentricSkinning())
    else:
        skin_index, skin_weight = options.skinning.weights_at(
            shape_vertices, parts.vertices, parts.faces, what="shape vertices"
        )
        _check_rig(shape_vertices, parts.vertices, parts.faces, skin_index, skin_weight)
        skin = (skin_index, skin_weight, options.skinning)
    return ((shape_vertices, shape_faces, shape_pinned[row_pin]),
            (parts.vertices, parts.faces, parts.loops, parts.inner, parts.pinned[row_pin]),
            skin, handle_rows)


def _array(a, dtype) -> Array:
    return to_device(a, dtype)


def _ints(a) -> Array:
    return _array(a, np.int32)


def _check_dtype(dtype):
    """The rig's float dtype: float32 or float64, float64 only under 64-bit JAX."""
    if dtype is None:
        return jnp.asarray(0.0).dtype
    try:
        dt = np.dtype(dtype)
    except TypeError:
        raise TypeError(
            f"dtype={dtype!r} is not a dtype; use jnp.float32 or jnp.float64."
        ) from None
    if dt not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise ValueError(
            f"dtype={dt.name}: a rig is float32 or float64 (lower precisions cannot hold the "
            "solve, complex numbers are not coordinates); use jnp.float32 or jnp.float64."
        )
    if dt == np.float64 and not jax.config.jax_enable_x64:
        raise ValueError(
            "dtype=float64 needs 64-bit JAX, which is off: call "
            "jax.config.update('jax_enable_x64', True) at the start of your program (mvcjax "
            "never changes it), or use dtype=jnp.float32."
        )
    return jnp.dtype(dt)


def _length(value, name: str) -> float | None:
    if value is None:
        return None
    if not is_real_number(value):
        raise TypeError(f"{name} must be a length (a positive number), got {value!r}.")
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a positive length (finite), got {value}.")
    return float(value)


def shape_thickness(shape: Shape) -> float:
    """About how thick the shape is: twice its area over its perimeter (a bar's width, a
    disc's radius)."""
    polygon = shape.polygon
    return 2.0 * polygon.area / polygon.length


def _spacings(local: Shape, scale: float, shape_spacing, control_spacing, margin):
    """The meshes' lengths in the rig's frame: the user's, or defaults that follow the
    shape's size and, for thin shapes, its thickness."""
    unit = np.sqrt(local.area)
    given = [_length(v, n) for v, n in [(shape_spacing, "shape_spacing"),
                                         (control_spacing, "PaperControl(spacing=...)"),
                                         (margin, "PaperControl(margin=...)")]]
    shape_spacing, control_spacing, margin = (None if v is None else v / scale for v in given)
    if control_spacing is None:
        control_spacing = unit / 8.0
    if shape_spacing is None:
        shape_spacing = min(unit / 40.0, shape_thickness(local) / 2.0)
    if margin is None:
        margin = control_spacing / 3.0
    return shape_spacing, control_spacing, margin


def _check_mesh_size(local: Shape, shape_spacing: float, scale: float, max_triangles: int):
    """Refuse, before meshing, a shape mesh larger than `max_triangles`.

    A quality mesh has triangles about `shape_spacing` across, and no larger than the
    shape is thick (its angles stay above 28 degrees), so the count is about the area
    over the area of such a triangle.
    """
    size = min(shape_spacing, shape_thickness(local))
    estimate = local.area / (np.sqrt(3.0) / 4.0 * size**2)
    if estimate > max_triangles:
        if shape_spacing <= shape_thickness(local):
            larger = shape_spacing * scale * np.sqrt(estimate / max_triangles)
            fix = f"pass a larger shape_spacing (about {larger:.3g} for that many)"
        else:
            fix = ("thicken the shape (its triangles cannot be larger than it is thick, "
                   f"about {shape_thickness(local) * scale:.3g}; e.g. shape.polygon.buffer)")
        raise ValueError(
            f"The shape mesh would have about {estimate:,.0f} triangles (shape_spacing "
            f"{shape_spacing * scale:.3g}, over an area of {local.area * scale**2:.3g}), more "
            f"than max_triangles={max_triangles:,}: {fix}, or raise max_triangles if that is "
            "what you want."
        )


def _laplacian_index(loops: list[np.ndarray]) -> np.ndarray:
    rows = [np.stack([lp, np.roll(lp, 1), np.roll(lp, -1)], axis=1) for lp in loops]
    return np.concatenate(rows)


def _check_rig(shape_vertices, control_vertices, control_faces, skin_index, skin_weight):
    """What every rig must satisfy, checked once at build time: a failure is a bug, and an
    error now instead of a NaN later."""
    area = signed_areas(control_vertices, control_faces)
    problems = []
    flat = area <= 1e-14 * np.abs(area).max(initial=0.0)
    if flat.any():
        problems.append(f"{int(flat.sum())} control triangles have no area")
    if not np.all(np.isfinite(skin_weight)):
        problems.append(f"{int(np.sum(~np.isfinite(skin_weight).all(axis=1)))} skinning rows "
                        "are not finite")
    else:
        sums = skin_weight.sum(axis=1)
        if np.abs(sums - 1).max() > 1e-9:
            problems.append(f"skinning rows sum to {sums.min():.6g}..{sums.max():.6g}, not 1")
        carried = np.einsum("nk,nkd->nd", skin_weight, control_vertices[skin_index])
        miss = np.linalg.norm(carried - shape_vertices, axis=1).max()
        if miss > 1e-8:
            problems.append(f"the skinning misses the rest shape by {miss:.3g} of the diagonal")
    if problems:
        raise ValueError(
            "The rig failed its build check (" + "; ".join(problems) + "). This is a bug in "
            "mvcjax: please report it with the shape and handles. Meanwhile another "
            "shape_spacing, PaperControl(spacing=...) or skinning may avoid it."
        )


class Rig(AbstractRig):
    """A shape ready to deform: both meshes, the skinning weights and the solver's data.

    Build one with `Rig.build`. A rig is a pytree of arrays: pass it through `jax.jit`,
    `jax.vmap` and `jax.grad` like any other argument. New targets or new weights
    (`with_weights`) never trigger a recompilation; only new array shapes do.

    The meshes are in the user's coordinates; the energy, the factor and the solves work
    in the shape's own frame (centred, unit diagonal: `frame`), so that results do not
    depend on where the shape sits or how large it is. Targets go in, and vertices come
    out, in the user's coordinates.

    Attributes:
        shape_mesh: the dense mesh that is drawn.
        control_mesh: the small mesh that is solved.
        handles: how the targets pin the control mesh (in the rig's frame).
        skinning: the weights carrying the shape mesh (`V_S = W V_C`).
        energy: the data and weights of the energy (6), in the rig's frame.
        factor: the precomputed global step of the fixed-G iteration (the paper's dense
            `G`, or a sparse factor of the normal matrix for large control meshes).
        frame: the map between the user's coordinates and the rig's.
        turns: `(c, r)` harmonic weights that spread the turn of each pinned row (its
            bone's) over the control vertices, for the turned start (`Rig.start`).
        programs: what the rig compiled and keeps for itself (`mvcjax.core.Programs`:
            no leaves, no part of its structure); it goes with the rig.
    """

    shape_mesh: ShapeMesh
    control_mesh: ControlMesh
    handles: Handles
    skinning: Skinning
    energy: Energy
    factor: AbstractFactor
    frame: Frame
    turns: Float[Array, "c r"]
    programs: Programs = programs_field()

    @classmethod
    @refusing_removed(**{key: "control=mvcjax.PaperControl(spacing=..., margin=...)"
                         for key in ("control_spacing", "margin")})
    def build(
        cls,
        shape: Any,
        handles: Any,
        *,
        shape_spacing: Any = None,
        weights: Any = None,
        control: Any = PaperControl(),
        skinning: Any = BlendedMVCSkinning(),
        factor: Any = FactorBySize(),
        dtype=None,
        max_triangles: int = 400_000,
        ladder: Any = None,
    ) -> Rig:
        """Mesh the shape, build the control mesh, and precompute everything.

        Lengths are in the shape's units; the defaults follow the shape's size, so that a
        shape gets the same meshes wherever it sits and however large it is.

        Args:
            shape: the shape to deform, an `mvcjax.Shape`.
            handles: `(h, 2)` handle points, on or inside the shape; or a list of
                handles, each an `(x, y)` point or an `mvcjax.Bone(start, end)` (a
                segment of the shape that follows a dragged segment). The targets then
                have a row per point and two per bone (its start, then its end).
            shape_spacing: edge length of the shape mesh (default: `sqrt(area) / 40`,
                about 3k vertices on a compact shape, or half the shape's thickness,
                twice its area over its perimeter, if that is smaller).
            weights: the term weights (default `Weights()`).
            control: how the control mesh is made: `mvcjax.PaperControl(spacing, margin)`
                (default, the paper's; its spacing also sets how far apart a bone's
                pinned points are), `mvcjax.FullSolve()` (the shape mesh itself) or
                `mvcjax.GivenControl(vertices, faces)` (a mesh of your own).
            skinning: how the shape mesh follows the control mesh:
                `mvcjax.advanced.BlendedMVCSkinning()` (default: continuous, and the smoothest),
                `mvcjax.advanced.MVCSkinning()` (the paper's eq. 1, which jumps across control
                edges) or `mvcjax.advanced.BarycentricSkinning()` (the paper's "control mesh
                only").
                Ignored with `FullSolve()` (the shape mesh carries itself).
            factor: the global step of the fixed-G iteration: `mvcjax.advanced.DenseG()` (the
                paper's `G`, recomputed inside `jit` when weights change),
                `mvcjax.advanced.SparseLU()` (for meshes of thousands of vertices) or
                `mvcjax.advanced.FactorBySize()` (default: dense up to 1000 control
                vertices).
            dtype: `jnp.float32` or `jnp.float64` (default: JAX's default float; float64
                needs `jax_enable_x64`).
            max_triangles: refuse, before meshing, a shape mesh estimated to have more
                triangles than this (a small spacing or a thin shape can ask for
                millions); raise it if you mean it.
            ladder: `mvcjax.SizeLadder()` to share compiled programs between rigs of
                similar sizes (for scripts that rig many shapes): the rig keeps, beside
                itself, a twin padded to the ladder's sizes, and its eager `deform`,
                `solve` and `deform_frames` run the twin's programs, compiled once for
                all the rigs on the same rungs. What the rig holds and returns keeps its
                own sizes, equal to a rig built without the ladder to float rounding
                with `FixedG`'s fixed steps, and to within their tolerance with the
                solvers that stop at one (as in a stack). The twin is not a field:
                transformations, and rigs made from this one but by `with_weights`
                (`with_pin`, `with_terms`, ...), do without it. It takes two to three
                times the rig's memory. Applies to a dense factor only (a control mesh
                of up to `FactorBySize.max_dense` vertices); a larger rig is built
                without. Default None: no twin.
        """
        options = _checked_build_options(shape, handles, weights, skinning, max_triangles,
                                         control, factor, ladder, dtype)
        return cls._assemble(*_meshed_parts(shape, shape_spacing, options), options.weights,
                             options.factor, options.dtype, options.frame, ladder)

    @classmethod
    def _assemble(cls, shape_mesh, control_mesh, skinning, handles, weights, factor, dtype,
                  frame, ladder=None):
        """The rig from its parts, all in the rig's frame (`frame = (centre, scale)` maps
        them back to the user's coordinates)."""
        shape_vertices, shape_faces, shape_pinned = shape_mesh
        control_vertices, control_faces, loops, inner, control_pinned = control_mesh
        centre, scale = frame
        energy = check_shape_held(_energy_data(
            control_vertices, control_faces, loops, inner, control_pinned, weights, dtype,
        ))
        world = lambda v: _array(v * scale + centre, dtype)  # noqa: E731
        parts = dict(
            shape_mesh=ShapeMesh(world(shape_vertices), _ints(shape_faces), _ints(shape_pinned)),
            control_mesh=ControlMesh(
                world(control_vertices), _ints(control_faces),
                _ints(np.concatenate(loops)), _ints(inner), _ints(control_pinned),
            ),
            handles=handles,
            skinning=Skinning.from_rows(*skinning, dtype),
            energy=energy,
            frame=frame_array(centre, scale, dtype),
            turns=_array(turn_weights(control_vertices, control_faces, control_pinned), dtype),
        )
        if ladder is None or not factor.is_dense(len(control_vertices)):
            return cls(**parts, factor=factor(energy))
        # The factor is cut from the twin's: compiled once per rung, not per rig.
        twin_factor, twin_energy, finish = twin_parts(parts, ladder)
        rig = cls(**parts, factor=cut_factor(twin_factor, twin_energy, energy))
        twin = finish(rig)
        keep_twin(rig, twin)  # kept with the rig, in `rig.programs`
        return rig

    @classmethod
    def stack(cls, rigs: Any, *, like: Any = None) -> Rig:
        """Rigs of different shapes as one batched rig, for `jax.vmap`:
        `jax.vmap(lambda r, t: r.deform(t))(stack, targets)` poses them all in one
        compiled program, with `targets` of shape `(len(rigs), h, 2)` (nest a second
        `vmap` over frames: `(len(rigs), frames, h, 2)`), and differentiates like one rig.

        Each rig is padded to the largest sizes among them, in a way that changes no
        result: rig `i`'s deformed shape is the first `rigs[i].shape_mesh.vertices.shape[0]`
        rows of its output, equal to `rigs[i].deform(t)` to float rounding (the rows past
        them repeat its first vertex). The stack solves with a dense `G` (a sparse
        factor cannot be batched), however each rig was built. `Renderer.stack` draws
        such a stack.

        Args:
            rigs: a list of rigs with the same handles' layout (as many target rows,
                bones at the same rows), one dtype and one skinning method.
            like: another stack, whose sizes these rigs are padded to (instead of the
                largest among them), so that the stack reuses the programs compiled
                for it: batches of rigs (a font's glyphs, 100 at a time) padded like
                a stack of the largest compile once. A rig that does not fit is
                refused.
        """
        return stack_rigs(rigs, like, cls)

    @property
    def stacked(self) -> int | None:
        """How many rigs this stack holds (`Rig.stack`), or None for a single rig."""
        return self.frame.scale.shape[0] if self.frame.scale.ndim else None

    def _single(self) -> None:
        if self.stacked is not None:
            raise ValueError(
                f"This rig is a stack of {self.stacked} rigs (Rig.stack): pose it under "
                "jax.vmap, e.g. jax.vmap(lambda r, t: r.deform(t))(stack, targets) with "
                f"targets of shape ({self.stacked}, h, 2), or take rig i out with "
                "jax.tree.map(lambda a: a[i], stack).")

    # ---- using the rig --------------------------------------------------------------

    @property
    def handle_positions(self) -> Float[Array, "*rigs h 2"]:
        """The targets at rest (a row per point handle, two per bone): targets equal to
        these give back the rest shape. A stack's are `(rigs, h, 2)`, a rig's each."""
        if self.stacked is not None:
            return jax.vmap(lambda rig: rig.handle_positions)(self)
        return self.frame.to_world(self.handles.rest)

    @property
    def bones(self) -> Float[Array, "b 2 2"]:
        """Every bone's rest `(start, end)`."""
        return self.handle_positions[self.handles.bones]

    def pinned_targets(self, targets: Any) -> Float[Array, "r 2"]:
        """Where each pinned control vertex (`control_mesh.handles`) goes for these
        `(h, 2)` targets, in the user's coordinates: the rows of `C` the solvers see."""
        return self.frame.to_world(self._pinned(self._check_targets(targets)))

    def _pinned(self, targets: Float[Array, "h 2"]) -> Float[Array, "r 2"]:
        """Checked targets in the user's coordinates -> pinned rows in the rig's frame."""
        return self.handles.pinned_targets(self.frame.to_local(targets))

    def with_weights(self, weights: Any) -> Rig:
        """The same rig with other term weights (an `mvcjax.Weights`).

        Recomputes the factor: with a dense `G` this is jittable and differentiable (no
        recompilation); a sparse factor is refactored on the host, outside `jit`. A rig
        built with a `SizeLadder` gets a twin with the new weights too (outside `jit`).
        """
        weights = check_weights(weights).verified(bool(self.energy.extra))
        energy = check_shape_held(eqx.tree_at(lambda e: e.weights, self.energy,
                                              weights.astype(self.energy.rest.dtype),
                                              is_leaf=lambda x: x is None))
        same_terms = weights.terms() == self.energy.weights.terms()
        if not same_terms and is_traced(weights):
            raise ValueError(
                f"with_weights under jit or grad keeps the rig's terms "
                f"{self.energy.weights.terms()}; these weights have {weights.terms()} (a "
                "weight of None leaves its term out). Call with_weights outside the "
                "transformation to change which terms the energy has.")
        twin = padded_twin(self)
        if twin is None or not same_terms or is_traced(weights):
            factor = self.factor.rebuild(energy, same_terms)
            return eqx.tree_at(lambda r: (r.energy, r.factor), self, (energy, factor))
        # The twin's factor, rebuilt by its program, and the rig's cut from it.
        twin = twin.with_weights(weights)
        factor = cut_factor(twin.factor, twin.energy, energy)
        rig = eqx.tree_at(lambda r: (r.energy, r.factor), self, (energy, factor))
        keep_twin(rig, twin)
        return rig

    def with_terms(self, *terms: Any) -> Rig:
        """The same rig with further terms added to the energy (6) (`mvcjax.advanced.Term`,
        on the control vertices in the rig's frame, the units of `rig.energy.rest`):
        every solver, the fixed-G factor and the energy reported then include them.
        Replaces terms added before. Recomputes the factor, as `with_weights` does."""
        rest = self.energy.rest
        tolerance = float(np.sqrt(np.finfo(rest.dtype).eps))  # of the unit diagonal
        for term in terms:
            if not isinstance(term, Term) or term.pinned:
                raise TypeError(f"with_terms takes mvcjax.advanced.Term.turned(...) or "
                                f"Term.linear(...) terms, got {term!r}.")
            if isinstance(term.stencil.coef, jax.core.Tracer):
                continue
            # The rest pose must stay the minimum for the rest targets (and the fixed-G
            # step is taken relative to it): a term that pulls at rest would deform a
            # shape nobody dragged.
            miss = float(jnp.max(jnp.abs(term.residual(rest, None)), initial=0.0))
            if not miss <= tolerance:
                raise ValueError(
                    f"Term {term.name!r} does not vanish at the rest control mesh (its rows "
                    f"miss their targets by up to {miss:.3g} of the shape's diagonal): give "
                    "a linear term coefficients that reproduce the rest mesh, or a turned "
                    "term the rows' rest lengths (Term.turned_from(..., rig.energy.rest)).")
        energy = check_shape_held(eqx.tree_at(lambda e: e.extra, self.energy, tuple(terms)))
        factor = self.factor.rebuild(energy)
        return eqx.tree_at(lambda r: (r.energy, r.factor), self, (energy, factor))

    def with_spare_pins(self, count: Any) -> Rig:
        """The same rig with `count` spare pins: target rows, after the handles', that pin
        nothing until placed (`with_pin`). Place and take out pins on the result as
        often as you like: the arrays keep their shapes, so nothing is compiled again
        (this call itself makes a rig of new shapes). The targets then have `count`
        more rows; an inactive row's target is ignored (any finite value)."""
        return _pins.with_spare_pins(self, count)

    def with_pin(self, row: Any, point: Any) -> Rig:
        """The same rig with target row `row` (a spare pin, or a point handle) pinning
        the shape at rest point `point`, `(x, y)` on or inside the shape. The pin holds
        the control triangle under `point` by its barycentric coordinates; the meshes
        stay, and only the factor is recomputed (no recompilation). Needs room for such
        rows: call `with_spare_pins` first."""
        return _pins.with_pin(self, row, point)

    def without_pin(self, row: Any) -> Rig:
        """The same rig with target row `row` pinning nothing (for an end of a bone,
        the whole bone); the row stays, ignored, until `with_pin` places it again.
        Refused for the last pin (nothing would hold the shape)."""
        return _pins.without_pin(self, row)

    @property
    def active(self) -> np.ndarray:
        """`(h,)` bool: which rows of the targets pin (all, but for spare pins not yet
        placed and pins taken out)."""
        return np.asarray(self.handles.active)

    def _check_init(self, init: Init) -> AbstractStart | Float[ArrayLike, "c 2"]:
        return checked_start(init, self.energy.rest.shape)

    def _local_start(self, targets: Float[Array, "t 2"],
                     init: AbstractStart | Float[ArrayLike, "c 2"]) -> Float[Array, "c 2"]:
        """The start for targets in the rig's frame (a row per target)."""
        if isinstance(init, AbstractStart):
            return init(self.energy, self.factor, self.handles, self.turns, targets)
        return self.frame.to_local(jnp.asarray(init, self.energy.rest.dtype))

    def start(self, targets: Any, init: Init = TurnedStart()) -> Float[Array, "c 2"]:
        """Starting control vertices for `(h, 2)` targets.

        Args:
            targets: `(h, 2)` where each handle should go.
            init: a start: `mvcjax.advanced.TurnedStart()` (default: every bone's turn,
                and the handles' rigid turn, spread over the control mesh, then one
                global step; a limb turned far starts turned, not squeezed),
                `mvcjax.advanced.RigidStart()` (the rest mesh moved rigidly to fit the
                targets), `mvcjax.advanced.RestStart()` (the paper's start), or an
                explicit `(c, 2)` array (a previous frame's control vertices, for
                instance).
        """
        return _start(self, self._check_targets(targets), self._check_init(init))

    def _check_targets(self, targets) -> Float[Array, "h 2"]:
        self._single()
        return check_targets(targets, self.handles.count, self.energy.rest.dtype)

    def solve(
        self,
        targets: Any,
        solver: Any = DEFAULT_SOLVER,
        *,
        init: Init = TurnedStart(),
        return_info: bool = False,
    ):
        """Control vertices minimising the energy (6) for these handle targets.

        Args:
            targets: `(h, 2)` where each handle should go.
            solver: a solver. The default, `FixedG(iterations=30)` from the turned
                start, comes near the minimum of the default energy on poses that turn
                limbs far; the paper's method is `FixedG()` (15 iterations) with
                `init=mvcjax.advanced.RestStart()` on `Weights.paper()`.
                `mvcjax.FoldFree()` never folds, and `mvcjax.GaussNewton()` solves to a
                tolerance.
            init: the start, see `Rig.start` (default `TurnedStart()`).
            return_info: also return a `SolveInfo` (converged, iterations, energy,
                inverted control triangles, the largest handle miss).

        Returns:
            `(c, 2)` control vertices, and the `SolveInfo` if asked for.
        """
        check_solver(solver)
        vertices, info = _solve(self, self._check_targets(targets), solver,
                               self._check_init(init))
        return (vertices, info) if return_info else vertices

    def energy_history(
        self,
        targets: Any,
        solver: Any,
        steps: Any,
        *,
        init: Init = TurnedStart(),
    ) -> Float[Array, " {steps+1}"]:
        """The energy (6) at the start and after each of `steps` steps of `solver`.

        The solver's stopping criteria are ignored, so that solvers compare over the same
        number of steps (`steps` is static: jit with `static_argnums`). Timing is not
        recorded here: the energy at every step costs extra; time a `solve` instead.

        Args:
            targets: `(h, 2)` where each handle should go.
            solver: any of mvcjax's solvers.
            steps: how many steps to record.
            init: the start, see `Rig.start`.
        """
        check_solver(solver)
        steps = whole_number(steps, "steps")
        local = self.frame.to_local(self._check_targets(targets))
        history = solver.history(self.energy, self.factor, self.handles.pinned_targets(local),
                                 self._local_start(local, self._check_init(init)), steps)
        return history * self.frame.scale**2

    def energy_at(self, control_vertices: Float[ArrayLike, "c 2"],
                  targets: Any) -> Float[Array, ""]:
        """The energy (6) of `(c, 2)` control vertices for `(h, 2)` targets, in the user's
        units (what `SolveInfo.energy` reports)."""
        return total_energy(self.energy, self.frame.to_local(control_vertices),
                            self._pinned(self._check_targets(targets))) * self.frame.scale**2

    def joined(self, posed: Float[ArrayLike, "*frames n 2"]) -> Float[Array, "*frames n 2"]:
        """What `solve`, `skin` or `deform` gave, as it is: a rig is one mesh."""
        return jnp.asarray(posed)

    def skin(self, control_vertices: Float[ArrayLike, "c 2"]) -> Float[Array, "n 2"]:
        """Shape-mesh vertices `(n, 2)` carried by `(c, 2)` control vertices (`V_S = W V_C`)."""
        return _skin(self, jnp.asarray(control_vertices, self.energy.rest.dtype))

    def weights_at(self, points: Any) -> Skinning:
        """Skinning weights for any rest points the control mesh covers: pixels,
        landmarks, a finer mesh. `rig.weights_at(points)(control_vertices)` carries them
        as `skin` carries the shape mesh, with the rig's skinning method.

        Args:
            points: `(n, 2)` rest points, in the user's coordinates.
        """
        points = as_points(points, "points", "n")
        frame = (np.asarray(self.frame.centre, np.float64), float(self.frame.scale))
        control = points_to_local(self.control_mesh.vertices, frame)
        index, weight = self.skinning.method.weights_at(
            points_to_local(points, frame), control, np.asarray(self.control_mesh.faces)
        )
        return Skinning.from_rows(index, weight, self.skinning.method, self.energy.rest.dtype)

    def deform(
        self,
        targets: Any,
        solver: Any = DEFAULT_SOLVER,
        *,
        init: Init = TurnedStart(),
        return_info: bool = False,
    ):
        """Solve, then skin: the deformed shape-mesh vertices `(n, 2)` (and the info) for
        `(h, 2)` targets; the arguments are those of `solve`."""
        check_solver(solver)
        shape, info = _deform(self, self._check_targets(targets), solver,
                              self._check_init(init))
        return (shape, info) if return_info else shape

    def __repr__(self) -> str:
        if self.stacked is not None:
            return (f"Rig(a stack of {self.stacked} rigs padded to "
                    f"{self.shape_mesh.vertices.shape[1]} shape vertices and "
                    f"{self.energy.rest.shape[1]} control vertices, "
                    f"{self.handles.rest.shape[1]} targets)")
        cm = self.control_mesh
        bones = self.handles.bones.shape[0]
        idle = int((~self.active).sum())
        handles = self.handles.count - bones - idle  # a bone takes two rows of targets
        return (
            f"Rig(shape mesh: {self.shape_mesh.vertices.shape[0]} vertices, "
            f"{self.shape_mesh.faces.shape[0]} faces; control mesh: "
            f"{cm.vertices.shape[0]} vertices ({cm.outer.shape[0]} polygon, "
            f"{cm.inner.shape[0]} inner), {handles} handles"
            + (f" ({bones} bones; {self.handles.count} targets, {cm.handles.shape[0]} pinned "
               "vertices)" if bones else "")
            + (f", {idle} target rows pinning nothing (spare pins, pins taken out)"
               if idle else "")
            + ")"
        )


def solve_in_frame(rig: Rig, targets, solver: AbstractSolver, init):
    """The solve in the rig's frame: local control vertices, and the info in the user's
    units, with the folds and the handles' miss counted."""
    local = rig.frame.to_local(targets)
    pinned = rig.handles.pinned_targets(local)
    shape = SkinnedMesh(rig.shape_mesh.faces, rig.skinning)
    vertices, info = solver.solve_skinned(rig.energy, rig.factor, pinned,
                                          rig._local_start(local, init), shape)
    energy = rig.energy
    miss = jnp.sqrt(jnp.max(jnp.sum((energy.handle_points(vertices) - pinned) ** 2, axis=1)))
    info = eqx.tree_at(
        lambda i: (i.inverted, i.handle_miss), info,
        (inverted_count(vertices, energy.faces, energy.rest), miss * rig.frame.scale),
        is_leaf=lambda x: x is None)
    return vertices, info.rescaled(rig.frame.scale)


def _as_twin(rows):
    """`fn(rig, targets, solver, init)` run, for a rig built with a `SizeLadder` and
    called outside any transformation, on its padded twin (whose program the rigs on the
    same rungs share); `rows(rig)` of its first output are the rig's own, cut on the
    host (an eager slice would compile a program for every size)."""
    def wrap(fn):
        def call(rig, targets, solver, init):
            twin = padded_twin(rig)
            given = not isinstance(init, AbstractStart)  # control vertices
            if (twin is None or is_traced(rig, targets, init)
                    or (given and np.shape(init) != rig.energy.rest.shape)):
                return fn(rig, targets, solver, init)
            if given:  # padded vertices start on vertex 0
                init = np.asarray(init)
                init = pad_rows(init, twin.energy.rest.shape[0], init[0])
            out, info = fn(twin, targets, solver, init)
            return to_device(np.asarray(out)[:rows(rig)], out.dtype), info

        return call

    return wrap


@_as_twin(lambda rig: rig.energy.rest.shape[0])
@compiled_by(inline_when_traced=True)
def _solve(rig: Rig, targets, solver: AbstractSolver, init):
    vertices, info = solve_in_frame(rig, targets, solver, init)
    return rig.frame.to_world(vertices), info


@_as_twin(lambda rig: rig.shape_mesh.vertices.shape[0])
@compiled_by(inline_when_traced=True)
def _deform(rig: Rig, targets, solver: AbstractSolver, init):
    vertices, info = solve_in_frame(rig, targets, solver, init)
    return rig.skinning(vertices, rig.frame), info


@compiled_by(inline_when_traced=True)
def _start(rig: Rig, targets, init):
    return rig.frame.to_world(rig._local_start(rig.frame.to_local(targets), init))


@compiled_by(inline_when_traced=True)
def _skin(rig: Rig, control):
    return rig.skinning(rig.frame.to_local(control), rig.frame)


# A rest Laplacian shorter than this (the rig's frame: a unit diagonal) is a straight
# stretch of the polygon, rounded.
STRAIGHT = 1e-12


def _energy_data(vertices, faces, loops, inner, handles, weights, dtype) -> Energy:
    """The energy's data for a control mesh in the rig's frame (unit diagonal)."""
    lap_index = _laplacian_index(loops)
    lap_vectors = np.einsum("k,pkd->pd", LAPLACIAN, vertices[lap_index])
    lap_length = np.linalg.norm(lap_vectors, axis=1)
    # Collinear polygon vertices (a straight side split to the spacing) have a zero rest
    # Laplacian; rounding leaves ~1e-17, whose target would turn with the noise of a
    # still-straight side (and its derivative with it): zero.
    lap_length[lap_length < STRAIGHT] = 0.0
    stars, star_valid = vertex_stars(faces, len(vertices))
    ring, valid = stars[inner], star_valid[inner]  # an inner vertex's star is its 1-ring
    ring_weight = mean_value_coordinates(vertices[inner], vertices[ring], valid)
    edges = interior_edges(faces, loops)  # H: every edge off the polygon V_CP
    edge_length = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)
    return Energy(
        rest=_array(vertices, dtype),
        laplacian_index=_ints(lap_index),
        laplacian_length=_array(lap_length, dtype),
        mvc_centre=_ints(inner),
        mvc_ring=_ints(ring),
        mvc_weight=_array(ring_weight, dtype),
        edges=_ints(edges),
        edge_length=_array(edge_length, dtype),
        handles=_ints(np.asarray(handles)[:, None]),
        handle_coef=_array(np.ones((len(handles), 1)), dtype),
        faces=_ints(faces),
        weights=weights.astype(dtype),
        scale=_array(1.0, dtype),
    )
