"""The energy (6) on the control mesh: residual terms L, M, H, C as pure JAX functions."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float, Int

from ..core import Programs, as_array, kind_of, programs_field
from ._stencils import EDGE, LAPLACIAN, Blocks, Stencil, length_scale, turn_rest


def _safe_normalise(v: Float[Array, "m 2"]) -> Float[Array, "m 2"]:
    """Rows of `v` divided by their length; zero rows stay zero, with zero gradient."""
    return v * length_scale(jnp.sum(v * v, axis=-1, keepdims=True), 1.0)


# Beyond this ratio between two positive weights the smaller term is lost to rounding
# in the normal matrix (float32 holds 7 digits, its squares 14).
MAX_WEIGHT_RATIO = 1e8
NORMAL_WEIGHT = 100.0
# The share of the largest shape term's weight that a zero Laplacian or mean value weight
# is raised to (`Weights.tie_broken`): small, yet large enough that the normal matrix of a
# polygon held by the tie alone stays definite in float32.
TIE_WEIGHT = 1e-3
# The default mean value weight: small beside the default as-rigid-as-possible weight (1),
# so that it bends nothing, yet a weight, which holds a stack's padded vertices.
DEFAULT_MVC = 1e-4
# Any positive weight, so that it and its square root stay normal float32 numbers.
WEIGHT_RANGE = (1e-36, 1e36)


def _weight(name: str):
    """The converter of the weight `name`: a number to an array, anything else refused
    by name (JAX's own error speaks of dtypes)."""
    def convert(value):
        if value is None and name != "handle":
            return None  # the term left out of the energy
        if not isinstance(value, jax.Array):
            host = as_array(value, f"Weights({name}=...)", "a number")
            if host.dtype.kind not in "iuf":
                raise TypeError(f"Weights({name}={value!r}): a weight is a number >= 0, got "
                                f"{kind_of(host)}.")
            # Moved, not staged: `jnp.asarray` compiles a program to stage a number.
            return jax.device_put(value)
        return value

    return convert


class Weights(eqx.Module):
    """Weights of the energy's terms, each multiplying a squared norm: the four of the
    paper's energy (6) and the as-rigid-as-possible term.

    The default is the as-rigid-as-possible energy: `arap` and the handles, the mean
    value rows kept at a weight too small to matter (see `mvc`), the Laplacian and edge
    lengths left out.
    It bends limbs, curls strips and letters with far fewer triangles turned inside out
    than the paper's energy (the fold suite, `benchmarks/folds.py`, measures both), at
    the same cost a frame. The paper's energy is `Weights.paper()`: its four terms, all
    1 in the paper but for the handles. The handle rows are a handful among hundreds of
    others, which pull the handles back: at the paper's weight 1 a dragged handle stops
    visibly short of its target. The miss falls about in inverse proportion to the
    handle weight; at 100, the default, it is negligible (`benchmarks/folds.py` reports
    it). Much larger weights only worsen the conditioning of `G` in float32 for no
    visible gain.

    Attributes:
        laplacian: weight of `|L V - delta(V)|^2` (boundary detail, the silhouette);
            default None.
        mvc: weight of `|M V|^2` (inner vertices stay at their mean value position);
            default `DEFAULT_MVC`, a ten-thousandth of the as-rigid-as-possible term's:
            the rows stay, where a stack or a size ladder holds its padded vertices.
            Being linear, they live in the fixed-G factor only and cost nothing a step.
        length: weight of `|H V - e(V)|^2` (edge lengths, local rigidity); default None.
        handle: weight of `|C V - U|^2` (how hard the handles pull); default 100.
        arap: weight of the as-rigid-as-possible term on the control triangles,
            `sum_t area_t |J_t - R_t|^2` (`as_rigid_as_possible`: each triangle's
            deformation gradient against the rotation nearest to it); default 1.

    A weight of None leaves its term out of the energy (and out of the compiled
    programs: no rows, no work), where 0 keeps its rows at no weight. Which terms are
    present shapes the compiled programs; their values, like every weight's, do not.
    `handle` is never None.

    Only the ratios between the weights matter: the solvers and factors use the weights
    scaled to a fixed largest value (`normalised`), so `Weights(1e-30, 1e-30, 1e-30,
    1e-28)` deforms exactly like the default, with energies 1e-30 times as large.

    A single shape term is fine (`Weights(mvc=0, length=0)` deforms by the Laplacian
    alone): where it leaves vertices free, a zero Laplacian or mean value weight is
    raised to a small share of the largest shape weight to decide them (`tie_broken`).

    `laplacian`, `mvc` and `length` all zero leave the shape to `arap`
    (`Weights(0, 0, 0, arap=1)`: the as-rigid-as-possible energy alone) or to the terms
    added by `Rig.with_terms`; a rig without either refuses them (`check_shape_held`).

    Refused (ValueError where the weights are made; TypeError for a weight that is not
    a number): a weight that is not a finite real number >= 0; `handle` zero; two
    positive weights more than
    `MAX_WEIGHT_RATIO` (1e8) apart; a positive weight outside `WEIGHT_RANGE` (1e-36 to
    1e36, float32's range). Traced weights (under `jit` or `grad`) are checked when the
    program runs, by `Rig.with_weights` (`verified`). Something other than a `Weights`
    is refused by `check_weights`.
    """

    laplacian: Float[Array, ""] | None = eqx.field(default=None, converter=_weight("laplacian"))
    mvc: Float[Array, ""] | None = eqx.field(default=DEFAULT_MVC, converter=_weight("mvc"))
    length: Float[Array, ""] | None = eqx.field(default=None, converter=_weight("length"))
    handle: Float[Array, ""] = eqx.field(default=100.0, converter=_weight("handle"))
    arap: Float[Array, ""] | None = eqx.field(default=1.0, converter=_weight("arap"))

    def _values(self) -> dict[str, Array]:
        """The weights given, by name (those not None)."""
        names = ("laplacian", "mvc", "length", "handle", "arap")
        return {k: getattr(self, k) for k in names if getattr(self, k) is not None}

    def terms(self) -> tuple[str, ...]:
        """The names of the terms these weights put in the energy (those not None)."""
        return tuple(self._values())

    def __check_init__(self):
        if self.laplacian is None and self.arap is None:
            raise ValueError(
                "Weights(laplacian=None, arap=None) leaves the control polygon's corners that "
                "no edge-length row reaches free (the energy has no unique minimum): give "
                "laplacian a weight (0 is raised to a small tie-break) or give arap one.")
        values = self._values()
        if any(isinstance(v, jax.core.Tracer) for v in values.values()):
            return  # traced (under jit or grad): checked where the weights were made
        for name, value in values.items():
            v = np.asarray(value)
            if v.shape != () or v.dtype.kind not in "iuf" or not np.isfinite(v) or v < 0:
                raise ValueError(
                    f"Weights({name}={value!r}): each weight must be a finite number >= 0."
                )
        v = {k: float(np.asarray(x)) for k, x in values.items()}
        if v["handle"] <= 0:
            raise ValueError(
                "Weights(handle=0) leaves the control mesh free to drift (the energy has no "
                "unique minimum); give the handles a positive weight."
            )
        positive = {k: x for k, x in v.items() if x > 0}
        for name, x in positive.items():
            if not WEIGHT_RANGE[0] <= x <= WEIGHT_RANGE[1]:
                raise ValueError(
                    f"Weights({name}={x:g}) is outside [{WEIGHT_RANGE[0]:.0e}, "
                    f"{WEIGHT_RANGE[1]:.0e}], too near the limits of float32 (it would round "
                    "to 0 or overflow there). Only the ratios between the weights matter: "
                    "scale them all by the same factor into that range."
                )
        ratio = max(positive.values()) / min(positive.values())
        if ratio > MAX_WEIGHT_RATIO:
            big, small = max(positive, key=positive.get), min(positive, key=positive.get)
            raise ValueError(
                f"Weights({big}={v[big]:g}) is {ratio:.1e} times Weights({small}={v[small]:g}); "
                f"positive weights must lie within a ratio of {MAX_WEIGHT_RATIO:.0e} of each "
                f"other (ratios from {1 / MAX_WEIGHT_RATIO:.0e} to {MAX_WEIGHT_RATIO:.0e}), or the "
                "normal matrix is singular in floating point (the smaller term is lost). Bring "
                "them closer, or set a term you do not want to 0 (the handles' weight must stay "
                "positive)."
            )

    def verified(self, held_by_others: bool = False) -> Weights:
        """The weights, checked when they are used where they are traced (under `jit`
        or `grad`, where `Weights(...)` cannot look at them): a NaN, an infinite or a
        negative weight, a zero handle weight or all shape terms at zero (unless
        `held_by_others`: other terms hold the shape) then raise when the program runs,
        instead of giving NaN vertices."""
        values = tuple(self._values().values())
        if not any(isinstance(v, jax.core.Tracer) for v in values):
            return self
        bad = (~jnp.all(jnp.isfinite(jnp.stack(values))) | (jnp.min(jnp.stack(values)) < 0)
               | (self.handle <= 0) | ((self.holding() <= 0) & (not held_by_others)))
        return jax.tree.map(lambda w: eqx.error_if(
            w, bad, "Weights given under jit or grad must be finite numbers >= 0, with a "
            "positive handle weight and at least one positive shape term (laplacian, mvc or "
            "length); check the values passed in (a log-weight exponentiated keeps them "
            "positive)."), self)

    def astype(self, dtype) -> Weights:
        return jax.tree.map(lambda w: jnp.asarray(w, dtype), self)

    def largest(self) -> Float[Array, ""]:
        return jnp.max(jnp.stack(list(self._values().values())))

    def normalised(self) -> Weights:
        """The weights scaled so that the largest is `NORMAL_WEIGHT` (the default handle
        weight): the same minimisers, and tolerances that mean what they mean at the
        defaults whatever the weights' overall scale (pure JAX, so it jits)."""
        factor = NORMAL_WEIGHT / self.largest()
        return jax.tree.map(lambda w: w * factor, self.tie_broken())

    def largest_shape(self) -> Float[Array, ""]:
        """The largest of the Laplacian, mean value and edge-length weights given (0
        where none is)."""
        given = [w for w in (self.laplacian, self.mvc, self.length) if w is not None]
        return jnp.max(jnp.stack(given)) if given else jnp.zeros((), self.handle.dtype)

    def holding(self) -> Float[Array, ""]:
        """The largest weight of a term that holds the shape (all but the handles')."""
        return self.largest_shape() if self.arap is None else jnp.maximum(
            self.largest_shape(), self.arap)

    @classmethod
    def paper(cls, **weights) -> Weights:
        """The paper's energy (6): the Laplacian, mean value, edge-length and handle
        terms, all 1 in the paper but for the handles (see the class docstring), and no
        as-rigid-as-possible term; any of them given by keyword
        (`Weights.paper(length=3.0)`)."""
        return cls(**{"laplacian": 1.0, "mvc": 1.0, "length": 1.0, "handle": 100.0,
                      "arap": None, **weights})

    def tie_broken(self) -> Weights:
        """The weights with a Laplacian or mean value weight of zero raised to
        `TIE_WEIGHT` times the largest weight of a term that holds the shape (`holding`;
        a positive weight, however small, is the user's and stays).

        Each term alone leaves some vertices free: the Laplacian holds only the outline,
        the mean value rows only the inner vertices, and the edge lengths (every edge
        off the outline) no corner of the outline that no inner edge reaches. With such
        a term at zero the energy would have a valley of minima; the small tie picks a
        point near the one the term picks as its weight goes to zero (the inner
        vertices follow the outline by their mean value coordinates, the outline keeps
        its detail)."""
        tie = TIE_WEIGHT * self.holding()

        def broken(w):
            return None if w is None else jnp.where(w > 0, w, tie)

        return eqx.tree_at(lambda w: (w.laplacian, w.mvc), self,
                           (broken(self.laplacian), broken(self.mvc)),
                           is_leaf=lambda x: x is None)


def check_weights(weights, name: str = "weights") -> Weights:
    """`weights` itself if it is a `Weights`; otherwise a TypeError that says how to
    write one (a dict of weights is a common slip)."""
    if isinstance(weights, Weights):
        return weights
    got = type(weights).__name__
    fix = (f"mvcjax.Weights(**{weights!r})" if isinstance(weights, dict)
           else "e.g. mvcjax.Weights(handle=10.0)")
    raise TypeError(f"{name} must be an mvcjax.Weights, got {got}; write {fix}.")


def check_shape_held(energy: Energy) -> Energy:
    """`energy` itself if a term other than the handles holds the shape: a positive
    Laplacian, mean value or edge-length weight, or a further term (`Energy.extra`).
    Otherwise every control vertex but the handles' is free and the energy has no
    unique minimum: a ValueError that says so. Traced weights pass (`verified` checks
    them when the program runs)."""
    traced = any(isinstance(w, jax.core.Tracer) for w in jax.tree.leaves(energy.weights))
    if energy.extra or traced:
        return energy
    if float(energy.weights.holding()) > 0:
        return energy
    raise ValueError(
        "Weights(laplacian=0, mvc=0, length=0) leaves only the handles: every other "
        "control vertex is free, so the energy has no unique minimum; give at least one "
        "shape term a positive weight (the as-rigid-as-possible term's, Weights(arap=1.0), "
        "among them), or add a term that holds the shape (Rig.with_terms)."
    )


class Term(eqx.Module):
    """One term of the energy (6), declared as data: `weight * |D V - target(V)|^2`.

    Its rows `D` are a stencil (each row a few vertex indices and coefficients), and
    its target is one of four kinds, which is all a solver needs to know:

    - `Term.turned`: each row's current vector turned to its rest length `length`, a
      rotation the local step of the fixed-G iteration recomputes (the Laplacian L
      and the edge lengths H);
    - `Term.rotated`: each row's rest vector `rest` turned by a rotation that a group
      of rows shares, fitted to the group's current vectors in the local step (the
      as-rigid-as-possible term, `as_rigid_as_possible`: a rotation per triangle);
    - `Term.linear`: zero, a constant linear term (the mean value rows M);
    - `Term.pinned`: the handle targets `U`, one row each (the handles C).

    The residuals, the fixed-G local step and global factor, the least-squares
    linearisation and the Gauss-Newton matrix are all derived from the energy's terms
    (`Energy.terms`), so a new term is one declaration.

    Attributes:
        name: the term's name (the weight's, for the built-in ones).
        stencil: its rows.
        weight: its weight (a scalar).
        length: `(m,)` the rows' rest lengths (`turned` terms; None otherwise).
        rest: `(m, 2)` the rows' rest vectors (`rotated` terms; None otherwise).
        group: how many consecutive rows share a rotation (`rotated` terms; None
            otherwise): rows `k * group` to `k * group + group - 1` turn together.
        pinned: whether its rows are measured from the handle targets.
    """

    name: str = eqx.field(static=True)
    stencil: Stencil
    weight: Float[Array, ""]
    length: Float[Array, " m"] | None = None
    rest: Float[Array, "m 2"] | None = None
    group: int | None = eqx.field(default=None, static=True)
    pinned: bool = eqx.field(default=False, static=True)

    @classmethod
    def turned(cls, name: str, stencil: Stencil, weight, length) -> Term:
        return cls(name, stencil, jnp.asarray(weight), length)

    @classmethod
    def turned_from(cls, name: str, stencil: Stencil, weight, rest: Float[Array, "n 2"]
                    ) -> Term:
        """A turned term whose rest lengths are its rows' lengths at `rest`."""
        return cls.turned(name, stencil, weight,
                          jnp.linalg.norm(stencil.vectors(rest), axis=1))

    @classmethod
    def rotated(cls, name: str, stencil: Stencil, weight, rest: Float[Array, "m 2"],
                group: int) -> Term:
        return cls(name, stencil, jnp.asarray(weight), rest=rest, group=group)

    @classmethod
    def linear(cls, name: str, stencil: Stencil, weight) -> Term:
        return cls(name, stencil, jnp.asarray(weight))

    @classmethod
    def pinned_to_targets(cls, name: str, stencil: Stencil, weight) -> Term:
        return cls(name, stencil, jnp.asarray(weight), pinned=True)

    @property
    def count(self) -> int:
        return self.stencil.count

    @property
    def is_local(self) -> bool:
        """Whether the local step turns its targets (a turned or rotated term)."""
        return self.length is not None or self.rest is not None

    def local_rest(self) -> Complex[Array, " m"]:
        """A local term's rest vectors as complex numbers (a turned row's: its rest
        length, whose direction does not matter)."""
        if self.rest is not None:
            return jax.lax.complex(self.rest[:, 0], self.rest[:, 1])
        return self.length.astype(jnp.result_type(self.length, jnp.complex64))

    def blocks(self) -> Blocks:
        """Its rows' groups (`Blocks`): a turned or linear row is a group of its own."""
        return ((self.count, self.group or 1),)

    def residual(self, vertices: Float[Array, "n 2"], targets: Float[Array, "h 2"] | None
                 ) -> Float[Array, "m 2"]:
        """`D V - target(V)`, unweighted."""
        v = self.stencil.vectors(vertices)
        if self.rest is not None:
            t = turn_rest(jax.lax.complex(v[:, 0], v[:, 1]), self.local_rest(), self.blocks())
            return v - jnp.stack([jnp.real(t), jnp.imag(t)], axis=1)
        if self.length is not None:
            return v - self.length[:, None] * _safe_normalise(v)
        return v - targets if self.pinned else v


def as_rigid_as_possible(rest: Float[Array, "n 2"], faces: Int[Array, "f 3"], weight
                         ) -> Term:
    """The as-rigid-as-possible energy of a triangle mesh, a rotation per triangle:
    `weight * sum_t area_t |J_t - R_t|_F^2`, `J_t` the triangle's deformation gradient
    from its rest shape and `R_t` the rotation nearest to it (the local step's fit).

    It equals the cotangent-weighted sum over each triangle's edges of
    `|e - R_t e_rest|^2 / 2` that libigl's `arap` minimises (its "elements" energy),
    with only non-negative weights: each triangle gives two rows, the columns of `J_t`
    times `sqrt(area_t)`, whose rest vectors are the unit axes times `sqrt(area_t)`.
    Degenerate or inverted rest triangles (zero area: a stack's padding) give zero rows.
    Pure JAX, so it is derived inside `jit` from the rest mesh.
    """
    corners = rest[faces]  # (f, 3, 2)
    e1, e2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    double_area = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    valid = double_area > 0
    safe = jnp.where(valid, double_area, 1.0)
    # Gradients of the barycentric coordinates of corners 1 and 2 (rows of the inverse
    # of the rest edge matrix); corner 0's is minus their sum.
    g1 = jnp.stack([e2[:, 1], -e2[:, 0]], axis=1) / safe[:, None]
    g2 = jnp.stack([-e1[:, 1], e1[:, 0]], axis=1) / safe[:, None]
    gradients = jnp.stack([-(g1 + g2), g1, g2], axis=1)  # (f, 3 corners, 2 axes)
    root_area = jnp.where(valid, jnp.sqrt(0.5 * safe), 0.0)
    # Row (t, a): column a of J_t, sum_i v_i (grad phi_i)_a, times sqrt(area_t).
    coef = jnp.transpose(gradients, (0, 2, 1)) * root_area[:, None, None]  # (f, 2, 3)
    rows = jnp.broadcast_to(faces[:, None, :], coef.shape)
    axes = jnp.eye(2, dtype=rest.dtype)[None] * root_area[:, None, None]  # (f, 2, 2)
    return Term.rotated("arap", Stencil(rows.reshape(-1, 3), coef.reshape(-1, 3)), weight,
                        axes.reshape(-1, 2), 2)


class Energy(eqx.Module):
    """Everything the energy (6) needs: the rest control mesh and each term's data.

    Attributes:
        rest: `(n, 2)` rest control vertices.
        laplacian_index: `(p, 3)` rows `(i, previous, next)` along the loops of `V_CP`.
        laplacian_length: `(p,)` rest length of each Laplacian vector.
        mvc_centre: `(g,)` the inner vertices `V_CG`.
        mvc_ring: `(g, k)` each inner vertex's ordered 1-ring (padded with 0).
        mvc_weight: `(g, k)` its mean value coordinates at rest (0 on padding).
        edges: `(e, 2)` the edges `E_CG` (every edge but the polygon's).
        edge_length: `(e,)` their rest lengths.
        handles: `(h, k)` the control vertices of each row of `C`: one vertex for a
            point a handle pins (bones sharing a joint pin its vertex twice), a control
            triangle's three for a pin placed inside one (`Rig.with_pin`).
        handle_coef: `(h, k)` their coefficients: 1 for a pinned vertex, barycentric
            coordinates for a pin inside a triangle, 0 for a row that pins nothing.
        faces: `(f, 3)` the control mesh's counter-clockwise triangles (not a term of
            the energy: what a fold is counted on, and what `FoldFree` keeps unfolded).
        weights: the term weights.
        scale: rest bounding-box diagonal, the unit of tolerances.
        extra: further terms, after the four of the paper (`Term`; their weights
            count as given, beside `weights`).
        programs: what the energy compiled for itself (its factor's programs).
    """

    rest: Float[Array, "n 2"]
    laplacian_index: Int[Array, "p 3"]
    laplacian_length: Float[Array, " p"]
    mvc_centre: Int[Array, " g"]
    mvc_ring: Int[Array, "g k"]
    mvc_weight: Float[Array, "g k"]
    edges: Int[Array, "e 2"]
    edge_length: Float[Array, " e"]
    handles: Int[Array, "h j"]
    handle_coef: Float[Array, "h j"]
    faces: Int[Array, "f 3"]
    weights: Weights
    scale: Float[Array, ""]
    extra: tuple[Term, ...] = ()
    programs: Programs = programs_field()

    @property
    def num_vertices(self) -> int:
        return self.rest.shape[0]

    def terms(self, normalised: bool = False) -> tuple[Term, ...]:
        """The energy's terms, in its order: L, M, H (eq. 7), the as-rigid-as-possible
        term where its weight is given (`Weights.arap`), C, then any `extra`.

        With `normalised`, the weights are those the solvers use
        (`Weights.normalised`), the extra terms' scaled alike: the same minimisers.
        """
        w = self.weights.normalised() if normalised else self.weights
        factor = NORMAL_WEIGHT / self.weights.largest() if normalised else 1.0
        dtype = self.rest.dtype
        mvc = Stencil(jnp.concatenate([self.mvc_centre[:, None], self.mvc_ring], axis=1),
                      jnp.concatenate([jnp.ones_like(self.mvc_weight[:, :1]),
                                       -self.mvc_weight], axis=1))
        declared = (
            (w.laplacian, lambda: Term.turned(
                "laplacian", Stencil.fixed(self.laplacian_index, LAPLACIAN, dtype),
                w.laplacian, self.laplacian_length)),
            (w.mvc, lambda: Term.linear("mvc", mvc, w.mvc)),
            (w.length, lambda: Term.turned("length", Stencil.fixed(self.edges, EDGE, dtype),
                                           w.length, self.edge_length)),
            (w.arap, lambda: as_rigid_as_possible(self.rest, self.faces, w.arap)),
        )
        return (
            *(make() for weight, make in declared if weight is not None),
            Term.pinned_to_targets("handle", self.handle_stencil(), w.handle),
            *(eqx.tree_at(lambda t: t.weight, t, t.weight * factor) for t in self.extra),
        )

    def handle_stencil(self) -> Stencil:
        """The rows of `C`."""
        return Stencil(self.handles, self.handle_coef)

    def handle_points(self, vertices: Float[Array, "n 2"]) -> Float[Array, "h 2"]:
        """`C V`: where each pinned point is for these control vertices (zero for a row
        that pins nothing)."""
        return self.handle_stencil().vectors(vertices)

    def handle_presence(self) -> Float[Array, " h"]:
        """1 for each row of `C` that pins, 0 for one that does not (its coefficients'
        sum)."""
        return jnp.sum(self.handle_coef, axis=1)

    def term(self, name: str) -> Term:
        """The term called `name` (unnormalised weights)."""
        found = [t for t in self.terms() if t.name == name]
        if not found:
            raise ValueError(f"This energy has no {name!r} term (its weight is None); its "
                             f"terms: {[t.name for t in self.terms()]}.")
        return found[0]

    def stencils(self) -> tuple[Stencil, ...]:
        """The rows of every term, in the energy's order."""
        return tuple(t.stencil for t in self.terms())

    def row_count(self) -> int:
        """How many rows (points) the terms have together."""
        return sum(t.count for t in self.terms())


def laplacian_residual(energy: Energy, vertices: Float[Array, "n 2"]) -> Float[Array, "p 2"]:
    """`L V - delta(V)`, unweighted: `delta(V)` is the rest Laplacian's length along
    the current Laplacian's direction (0 for a zero rest or current Laplacian)."""
    return energy.term("laplacian").residual(vertices, None)


def mvc_residual(energy: Energy, vertices: Float[Array, "n 2"]) -> Float[Array, "g 2"]:
    """`M V`: each inner vertex minus the mean value combination of its 1-ring."""
    return energy.term("mvc").residual(vertices, None)


def length_residual(energy: Energy, vertices: Float[Array, "n 2"]) -> Float[Array, "e 2"]:
    """`H V - e(V)`, unweighted: `e(V)` is each current edge vector scaled back to its
    rest length."""
    return energy.term("length").residual(vertices, None)


def handle_residual(
    energy: Energy, vertices: Float[Array, "n 2"], targets: Float[Array, "h 2"]
) -> Float[Array, "h 2"]:
    """`C V - U`: each handle's offset from its target."""
    return energy.term("handle").residual(vertices, targets)


def residuals(
    energy: Energy, vertices: Float[Array, "n 2"], targets: Float[Array, "h 2"]
) -> Float[Array, " m"]:
    """Every term's residual times the square root of its weight, as one vector."""
    return jnp.concatenate([(jnp.sqrt(t.weight) * t.residual(vertices, targets)).reshape(-1)
                            for t in energy.terms()])


def total_energy(
    energy: Energy, vertices: Float[Array, "n 2"], targets: Float[Array, "h 2"]
) -> Float[Array, ""]:
    """The energy (6): the weighted sum of the terms' squared residual norms."""
    r = residuals(energy, vertices, targets)
    return jnp.sum(r * r)


def rigid_alignment(
    rest: Float[Array, "h 2"], targets: Float[Array, "h 2"],
    weights: Float[Array, " h"] | None = None,
) -> tuple[Float[Array, "2 2"], Float[Array, " 2"]]:
    """Rotation `R` and translation `t` with `rest @ R.T + t` closest to `targets`.

    The 2D Procrustes solution (no reflection), each point counted with its weight
    (default 1; rows of weight 0 are left out). One handle gives a translation only;
    handle targets that coincide give the identity rotation, with finite gradients.
    """
    if weights is None:
        weights = jnp.ones(rest.shape[0], targets.dtype)
    weights = weights / jnp.sum(weights)
    mean_rest, mean_target = weights @ rest, weights @ targets
    if rest.shape[0] < 2:
        return jnp.eye(2, dtype=targets.dtype), mean_target - mean_rest
    p = (rest - mean_rest) * weights[:, None]
    q = targets - mean_target
    c = jnp.sum(p * q)
    s = jnp.sum(p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0])
    cs = _safe_normalise(jnp.stack([c, s])[None])[0]
    cs = jnp.where(jnp.any(cs != 0), cs, jnp.array([1.0, 0.0], cs.dtype))
    rot = jnp.array([[cs[0], -cs[1]], [cs[1], cs[0]]])
    return rot, mean_target - mean_rest @ rot.T


def rigid_start(energy: Energy, targets: Float[Array, "h 2"]) -> Float[Array, "n 2"]:
    """The rest control mesh moved rigidly to fit the handle targets best."""
    rot, shift = rigid_alignment(energy.handle_points(energy.rest), targets,
                                 energy.handle_presence())
    return energy.rest @ rot.T + shift
