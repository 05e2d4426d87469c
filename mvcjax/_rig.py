"""Rig: the shape mesh, the control mesh, the skinning weights and the solver's data."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import shapely
from jaxtyping import Array, Float, Int

from . import _coordinates as coords
from . import _meshing as meshing
from ._energy import Energy, Weights, rigid_start
from ._factor import AbstractFactor, make_factor
from ._shape import Shape
from ._solvers import AbstractSolver, FixedG


class ShapeMesh(eqx.Module):
    """The dense triangle mesh the user sees.

    Attributes:
        vertices: `(n, 2)` rest vertices.
        faces: `(f, 3)` counter-clockwise triangles.
        handles: `(h,)` the vertex at each handle.
    """

    vertices: Float[Array, "n 2"]
    faces: Int[Array, "f 3"]
    handles: Int[Array, " h"]


class ControlMesh(eqx.Module):
    """The small mesh the energy is solved on.

    Attributes:
        vertices: `(c, 2)` rest vertices, the polygon loops first, then the inner ones.
        faces: `(f, 3)` counter-clockwise triangles.
        outer: `(p,)` the vertices of the enclosing polygon `V_CP`, loop after loop.
        inner: `(g,)` the inner vertices `V_CG`.
        handles: `(h,)` the vertex at each handle.
    """

    vertices: Float[Array, "c 2"]
    faces: Int[Array, "f 3"]
    outer: Int[Array, " p"]
    inner: Int[Array, " g"]
    handles: Int[Array, " h"]


class Skinning(eqx.Module):
    """Each shape vertex as a weighted sum of a few control vertices: `V_S = W V_C`.

    Attributes:
        indices: `(n, k)` control vertices of each shape vertex (padded with 0).
        weights: `(n, k)` their weights (0 on padding); rows sum to 1.
    """

    indices: Int[Array, "n k"]
    weights: Float[Array, "n k"]

    def __call__(self, control_vertices: Float[Array, "c 2"]) -> Float[Array, "n 2"]:
        # Points as complex numbers: gathering one complex scalar per index is about
        # three times faster on the CPU than gathering a row of two floats.
        z = jax.lax.complex(control_vertices[:, 0], control_vertices[:, 1])

        def one(index, weight):
            return jnp.sum(weight * z[index])

        out = jax.vmap(one)(self.indices, self.weights)
        return jnp.stack([jnp.real(out), jnp.imag(out)], axis=1)

    def matrix(self, control_count: int) -> Float[Array, "n c"]:
        """`W` as a dense `(n, control_count)` matrix: for many frames at once, one matrix
        product beats the gather (11 times faster for 256 frames on the 6k horse)."""
        n = self.indices.shape[0]
        return jnp.zeros((n, control_count), self.weights.dtype).at[
            jnp.arange(n)[:, None], self.indices
        ].add(self.weights)


def _default_float():
    return jnp.asarray(0.0).dtype


def _check_handles(shape: Shape, handles) -> np.ndarray:
    handles = np.asarray(handles, dtype=np.float64)
    if handles.ndim != 2 or handles.shape[1] != 2 or len(handles) == 0:
        raise ValueError(
            f"handles must be an array of shape (h, 2) with at least one (x, y) point, got "
            f"shape {handles.shape}."
        )
    if not np.all(np.isfinite(handles)):
        raise ValueError("handles contain NaN or infinite coordinates.")
    tol = 1e-6 * shape.diagonal
    poly = shape.polygon
    dist = shapely.distance(shapely.points(handles), poly)
    for i in np.flatnonzero(dist > tol):
        near = shape.closest_point(handles[i])
        raise ValueError(
            f"handles[{i}] = {handles[i].tolist()} lies outside the shape (distance "
            f"{dist[i]:.4g}); put it on or inside the shape, e.g. at its closest point "
            f"{near.round(6).tolist()} (Shape.closest_point)."
        )
    gap = np.linalg.norm(handles[:, None] - handles[None], axis=2)
    np.fill_diagonal(gap, np.inf)
    i, j = np.unravel_index(np.argmin(gap), gap.shape)
    if gap[i, j] <= tol:
        raise ValueError(
            f"handles[{min(i, j)}] and handles[{max(i, j)}] are at the same spot "
            f"{handles[i].tolist()}; remove one of them."
        )
    return handles


def _spacings(shape: Shape, shape_spacing, control_spacing, margin):
    unit = np.sqrt(shape.area)
    control_spacing = unit / 8.0 if control_spacing is None else float(control_spacing)
    shape_spacing = unit / 40.0 if shape_spacing is None else float(shape_spacing)
    margin = control_spacing / 3.0 if margin is None else float(margin)
    for name, value in [("shape_spacing", shape_spacing), ("control_spacing", control_spacing),
                        ("margin", margin)]:
        if not np.isfinite(value) or value <= 0:
            raise ValueError(f"{name} must be a positive length, got {value}.")
    return shape_spacing, control_spacing, margin


def _laplacian_index(loops: list[np.ndarray]) -> np.ndarray:
    rows = [np.stack([lp, np.roll(lp, 1), np.roll(lp, -1)], axis=1) for lp in loops]
    return np.concatenate(rows)


def _loops_and_inner(vertices, faces):
    """A mesh's boundary loops (`V_CP`, the outer loop first) and its other vertices (`V_CG`)."""
    loops = coords.boundary_loops(faces)
    loops.sort(key=lambda lp: -abs(shapely.Polygon(vertices[lp]).area))
    on_loop = np.zeros(len(vertices), bool)
    on_loop[np.concatenate(loops)] = True
    return loops, np.flatnonzero(~on_loop)


def _control_from_arrays(control, handles, tol):
    vertices, faces = control
    vertices, faces = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    if vertices.ndim != 2 or vertices.shape[1] != 2 or faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(
            "control must be (vertices, faces) with vertices of shape (c, 2) and faces of "
            f"shape (f, 3), got {vertices.shape} and {faces.shape}."
        )
    faces = meshing._counter_clockwise(vertices, faces)
    loops, inner = _loops_and_inner(vertices, faces)
    dist = np.linalg.norm(vertices[None] - handles[:, None], axis=2)
    idx = np.argmin(dist, axis=1)
    bad = np.flatnonzero(dist[np.arange(len(handles)), idx] > tol)
    if len(bad):
        raise ValueError(
            f"handles[{bad[0]}] = {handles[bad[0]].tolist()} is not a vertex of the given "
            "control mesh; every handle must be a control vertex: add it to the mesh."
        )
    return vertices, faces, loops, inner, idx


class Rig(eqx.Module):
    """A shape ready to deform: both meshes, the skinning weights and the solver's data.

    Build one with `Rig.build`. A rig is a pytree of arrays: pass it through `jax.jit`,
    `jax.vmap` and `jax.grad` like any other argument. New targets or new weights
    (`with_weights`) never trigger a recompilation; only new array shapes do.

    Attributes:
        shape_mesh: the dense mesh that is drawn.
        control_mesh: the small mesh that is solved.
        skinning: the weights carrying the shape mesh (`V_S = W V_C`).
        energy: the data and weights of the energy (6).
        factor: the precomputed global step of the fixed-G iteration (the paper's dense
            `G`, or a sparse factor of the normal matrix for large control meshes).
    """

    shape_mesh: ShapeMesh
    control_mesh: ControlMesh
    skinning: Skinning
    energy: Energy
    factor: AbstractFactor

    @classmethod
    def build(
        cls,
        shape: Shape,
        handles,
        *,
        shape_spacing: float | None = None,
        control_spacing: float | None = None,
        margin: float | None = None,
        weights: Weights | None = None,
        control=None,
        skinning: str = "blended",
        factor: str | None = None,
        dtype=None,
    ) -> Rig:
        """Mesh the shape, build the control mesh, and precompute everything.

        Args:
            shape: the shape to deform.
            handles: `(h, 2)` handle points, on or inside the shape.
            shape_spacing: edge length of the shape mesh (default: `sqrt(area) / 60`,
                about 2.3k vertices on a compact shape).
            control_spacing: spacing of the inner control vertices and longest edge of
                the control polygon (default: `sqrt(area) / 8`).
            margin: how far outside the shape the control polygon runs, where no gap is
                narrower than twice that (default: `control_spacing / 3`).
            weights: the term weights (default `Weights()`).
            control: `None` (default) builds the paper's control mesh; `"shape"` solves on
                the shape mesh itself (the paper's "full solve", after Weng et al.: its
                boundary loops are `V_CP`, its interior vertices `V_CG`, every interior
                edge is in `H`, and the skinning is the identity); or a control mesh of
                your own, as `(vertices (c, 2), faces (f, 3))`, covering the shape, with a
                vertex at every handle. Its boundary loops are `V_CP`, every other vertex
                is `V_CG`.
            skinning: how the shape mesh follows the control mesh: `"blended"`
                (default: MVC over the corners' stars blended by barycentric
                coordinates; continuous, and the smoothest), `"mvc"` (the paper's eq. 1,
                which jumps across control edges) or `"barycentric"` (the paper's
                "control mesh only"). Ignored with `control="shape"`.
            factor: the global step of the fixed-G iteration: `"dense"` (the paper's `G`,
                recomputed inside `jit` when weights change), `"sparse"` (a sparse LU of
                the normal matrix, for meshes of thousands of vertices), or `None` (by
                size: dense up to 1000 control vertices).
            dtype: float dtype of the rig's arrays (default: JAX's default float).
        """
        if not isinstance(shape, Shape):
            raise TypeError(
                f"shape must be an mvcjax.Shape, got {type(shape).__name__}; build one with "
                "Shape.from_polygon(outer, holes) or Shape.from_image(mask)."
            )
        handles = _check_handles(shape, handles)
        shape_spacing, control_spacing, margin = _spacings(
            shape, shape_spacing, control_spacing, margin
        )
        weights = Weights() if weights is None else weights
        dtype = _default_float() if dtype is None else jnp.dtype(dtype)

        shape_vertices, shape_faces, shape_handles = meshing.triangulate_shape(
            shape, shape_spacing, handles
        )
        if skinning not in SKINNINGS:
            raise ValueError(f"skinning must be one of {SKINNINGS}, got {skinning!r}.")
        if isinstance(control, str) and control == "shape":
            return cls._full(shape_vertices, shape_faces, shape_handles, weights, factor, dtype,
                             shape.diagonal)
        if isinstance(control, str):
            raise ValueError(
                f"control must be None, 'shape' or (vertices, faces), got {control!r}."
            )
        if control is None:
            loops = meshing.control_polygon(shape, margin, control_spacing)
            inner_shape = meshing.inner_control_vertices(
                shape_vertices, shape_handles, loops, control_spacing
            )
            control_vertices, control_faces = meshing.triangulate_control(
                loops, shape_vertices[inner_shape]
            )
            offsets = np.cumsum([0, *(len(lp) for lp in loops)])
            loops = [np.arange(a, b) for a, b in zip(offsets[:-1], offsets[1:])]
            inner = np.arange(offsets[-1], len(control_vertices))
            control_handles = inner[: len(handles)]
        else:
            control_vertices, control_faces, loops, inner, control_handles = _control_from_arrays(
                control, handles, 1e-6 * shape.diagonal
            )

        skin_index, skin_weight = _skinning_weights(
            shape_vertices, control_vertices, control_faces, skinning
        )
        return cls._assemble(
            (shape_vertices, shape_faces, shape_handles),
            (control_vertices, control_faces, loops, inner, control_handles),
            (skin_index, skin_weight), weights, factor, dtype, shape.diagonal,
        )

    @classmethod
    def _full(cls, vertices, faces, handles, weights, factor, dtype, diagonal) -> Rig:
        """The shape mesh as its own control mesh, carried by the identity."""
        loops, inner = _loops_and_inner(vertices, faces)
        identity = (np.arange(len(vertices))[:, None], np.ones((len(vertices), 1)))
        return cls._assemble(
            (vertices, faces, handles),
            (vertices, faces, loops, inner, handles),
            identity, weights, factor, dtype, diagonal,
        )

    @classmethod
    def _assemble(cls, shape_mesh, control_mesh, skinning, weights, factor, dtype, diagonal):
        shape_vertices, shape_faces, shape_handles = shape_mesh
        control_vertices, control_faces, loops, inner, control_handles = control_mesh
        energy = _energy_data(
            control_vertices, control_faces, loops, inner, control_handles, weights, dtype,
            diagonal,
        )
        as_int = lambda a: jnp.asarray(a, jnp.int32)  # noqa: E731
        return cls(
            shape_mesh=ShapeMesh(
                jnp.asarray(shape_vertices, dtype), as_int(shape_faces), as_int(shape_handles)
            ),
            control_mesh=ControlMesh(
                jnp.asarray(control_vertices, dtype), as_int(control_faces),
                as_int(np.concatenate(loops)), as_int(inner), as_int(control_handles),
            ),
            skinning=Skinning(as_int(skinning[0]), jnp.asarray(skinning[1], dtype)),
            energy=energy,
            factor=make_factor(energy, factor),
        )

    # ---- using the rig --------------------------------------------------------------

    @property
    def handle_positions(self) -> Float[Array, "h 2"]:
        """The handles' rest positions: targets equal to these give back the rest shape."""
        return self.control_mesh.vertices[self.control_mesh.handles]

    def with_weights(self, weights: Weights) -> Rig:
        """The same rig with other term weights.

        Recomputes the factor: with a dense `G` this is jittable and differentiable (no
        recompilation); a sparse factor is refactored on the host, outside `jit`.
        """
        energy = eqx.tree_at(lambda e: e.weights, self.energy, weights.astype(self.energy.rest.dtype))
        return eqx.tree_at(lambda r: (r.energy, r.factor), self, (energy, self.factor.rebuild(energy)))

    def start(self, targets: Float[Array, "h 2"], init="rigid") -> Float[Array, "c 2"]:
        """Starting control vertices: `"rigid"` (the rest mesh moved rigidly to fit the
        targets), `"rest"` (the paper's), or an explicit `(c, 2)` array."""
        if isinstance(init, str):
            if init == "rigid":
                return rigid_start(self.energy, targets)
            if init == "rest":
                return self.energy.rest
            raise ValueError(f"init must be 'rigid', 'rest' or an array, got {init!r}.")
        init = jnp.asarray(init, self.energy.rest.dtype)
        if init.shape != self.energy.rest.shape:
            raise ValueError(
                f"init must have the control mesh's shape {self.energy.rest.shape}, got {init.shape}."
            )
        return init

    def _check_targets(self, targets) -> Float[Array, "h 2"]:
        targets = jnp.asarray(targets)
        h = self.energy.handles.shape[0]
        if targets.shape != (h, 2):
            raise ValueError(
                f"targets must have shape ({h}, 2), one (x, y) per handle, got {targets.shape}; "
                "for several frames, use jax.vmap over a leading axis."
            )
        if not isinstance(targets, jax.core.Tracer) and not bool(jnp.all(jnp.isfinite(targets))):
            raise ValueError("targets contain NaN or infinite values; give finite (x, y) targets.")
        return targets.astype(self.energy.rest.dtype)

    def solve(
        self,
        targets: Float[Array, "h 2"],
        solver: AbstractSolver = FixedG(),
        *,
        init="rigid",
        return_info: bool = False,
    ):
        """Control vertices minimising the energy (6) for these handle targets.

        Args:
            targets: `(h, 2)` where each handle should go.
            solver: a solver (default: the paper's `FixedG()`, 15 iterations).
            init: the start, see `Rig.start`.
            return_info: also return a `SolveInfo` (converged, iterations, energy).

        Returns:
            `(c, 2)` control vertices, and the `SolveInfo` if asked for.
        """
        if not isinstance(solver, AbstractSolver):
            raise TypeError(
                f"solver must be an mvcjax solver such as mvcjax.FixedG() or "
                f"mvcjax.GaussNewton(), got {solver!r}."
            )
        targets = self._check_targets(targets)
        vertices, info = solver.solve(self.energy, self.factor, targets, self.start(targets, init))
        return (vertices, info) if return_info else vertices

    def energy_history(
        self,
        targets: Float[Array, "h 2"],
        solver: AbstractSolver,
        steps: int,
        *,
        init="rigid",
    ) -> Float[Array, " steps+1"]:
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
        if not isinstance(solver, AbstractSolver):
            raise TypeError(f"solver must be an mvcjax solver such as mvcjax.FixedG(), got {solver!r}.")
        if steps < 1:
            raise ValueError(f"steps must be at least 1, got {steps}.")
        targets = self._check_targets(targets)
        return solver.history(self.energy, self.factor, targets, self.start(targets, init), steps)

    def skin(self, control_vertices: Float[Array, "c 2"]) -> Float[Array, "n 2"]:
        """Shape-mesh vertices carried by the control vertices (`V_S = W V_C`)."""
        return self.skinning(control_vertices)

    def deform(
        self,
        targets: Float[Array, "h 2"],
        solver: AbstractSolver = FixedG(),
        *,
        init="rigid",
        return_info: bool = False,
    ):
        """Solve, then skin: the deformed shape-mesh vertices `(n, 2)` (and the info)."""
        vertices, info = self.solve(targets, solver, init=init, return_info=True)
        shape = self.skin(vertices)
        return (shape, info) if return_info else shape

    def __repr__(self) -> str:
        return (
            f"Rig(shape mesh: {self.shape_mesh.vertices.shape[0]} vertices, "
            f"{self.shape_mesh.faces.shape[0]} faces; control mesh: "
            f"{self.control_mesh.vertices.shape[0]} vertices ({self.control_mesh.outer.shape[0]} "
            f"polygon, {self.control_mesh.inner.shape[0]} inner), "
            f"{self.control_mesh.handles.shape[0]} handles)"
        )


SKINNINGS = ("mvc", "blended", "barycentric")


def _skinning_weights(shape_vertices, control_vertices, control_faces, method):
    """Each shape vertex as a combination of control vertices: `(index, weight)`, `(n, k)`.

    - "mvc": the paper's eq. 1, MVC over the containing triangle and its edge neighbours.
      Discontinuous across control edges: neighbours on either side use other polygons.
    - "blended": MVC over the star of each corner of the containing triangle, blended by
      the barycentric coordinates `b`; two triangles sharing an edge agree along it, so
      the map is continuous. Each corner's term is corrected by `b_v (e_v - MVC(v))`,
      which vanishes on the star's rim and makes the map interpolate the control
      vertices (a shape vertex on a control vertex follows it exactly).
    - "barycentric": the containing triangle's barycentric coordinates (the paper's
      "control mesh only"): continuous, piecewise linear, with kinks along control edges.
    """
    face, depth = coords.locate_points(shape_vertices, control_vertices, control_faces)
    outside = np.flatnonzero(depth < -1e-9)
    if len(outside):
        raise ValueError(
            f"{len(outside)} shape vertices lie outside the control mesh (e.g. "
            f"{shape_vertices[outside[0]].round(6).tolist()}); the control mesh must cover the "
            "whole shape."
        )
    corners = control_faces[face]
    bary = coords.barycentric_coordinates(shape_vertices, control_vertices[corners])
    if method == "barycentric":
        return corners, bary
    if method == "mvc":
        polygons, valid = coords.face_star_polygons(
            control_faces, coords.face_neighbours(control_faces)
        )
        index, valid = polygons[face], valid[face]
        return index, coords.mean_value_coordinates(
            shape_vertices, control_vertices[index], valid
        )
    stars, star_valid = coords.vertex_stars(control_faces, len(control_vertices))
    # MVC of each control vertex in its own star: one-hot on the boundary, the M term's
    # weights inside. The blend corrects by it so that a shape vertex on a control vertex
    # follows that vertex exactly.
    at_vertex = coords.mean_value_coordinates(control_vertices, control_vertices[stars], star_valid)
    index, weight = [corners], [bary**2]
    for k in range(3):
        v = corners[:, k]
        w = coords.mean_value_coordinates(shape_vertices, control_vertices[stars[v]], star_valid[v])
        index.append(stars[v])
        weight.append(bary[:, k : k + 1] * (w - bary[:, k : k + 1] * at_vertex[v]))
    return _merge_duplicates(np.concatenate(index, axis=1), np.concatenate(weight, axis=1))


def _merge_duplicates(index, weight):
    """Rows of `(index, weight)` with each index once (weights summed), padded with zeros."""
    order = np.argsort(index, axis=1, kind="stable")
    index = np.take_along_axis(index, order, axis=1)
    weight = np.take_along_axis(weight, order, axis=1)
    new = np.ones(index.shape, bool)
    new[:, 1:] = index[:, 1:] != index[:, :-1]
    slot = np.cumsum(new, axis=1) - 1
    rows = np.broadcast_to(np.arange(len(index))[:, None], index.shape)
    merged_index = np.zeros((len(index), slot.max() + 1), index.dtype)
    merged_weight = np.zeros((len(index), slot.max() + 1), weight.dtype)
    merged_index[rows, slot] = index
    np.add.at(merged_weight, (rows, slot), weight)
    return merged_index, merged_weight


def _energy_data(vertices, faces, loops, inner, handles, weights, dtype, diagonal) -> Energy:
    lap_index = _laplacian_index(loops)
    lap_vectors = vertices[lap_index[:, 0]] - 0.5 * (
        vertices[lap_index[:, 1]] + vertices[lap_index[:, 2]]
    )
    stars, star_valid = coords.vertex_stars(faces, len(vertices))
    ring, valid = stars[inner], star_valid[inner]  # an inner vertex's star is its 1-ring
    ring_weight = coords.mean_value_coordinates(vertices[inner], vertices[ring], valid)
    polygon_edges = {
        tuple(sorted(e)) for lp in loops for e in zip(lp.tolist(), np.roll(lp, -1).tolist())
    }
    all_edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    all_edges = np.unique(all_edges, axis=0)
    keep = np.array([tuple(e) not in polygon_edges for e in all_edges.tolist()], bool)
    edges = all_edges[keep]
    edge_length = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)
    as_int = lambda a: jnp.asarray(a, jnp.int32)  # noqa: E731
    return Energy(
        rest=jnp.asarray(vertices, dtype),
        laplacian_index=as_int(lap_index),
        laplacian_length=jnp.asarray(np.linalg.norm(lap_vectors, axis=1), dtype),
        mvc_centre=as_int(inner),
        mvc_ring=as_int(ring),
        mvc_weight=jnp.asarray(ring_weight, dtype),
        edges=as_int(edges),
        edge_length=jnp.asarray(edge_length, dtype),
        handles=as_int(handles),
        weights=weights.astype(dtype),
        scale=jnp.asarray(diagonal, dtype),
    )
