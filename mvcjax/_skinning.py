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


class Skinning(eqx.Module):
    """Each shape vertex as a weighted sum of a few control vertices: `V_S = W V_C`.

    Attributes:
        indices: `(n, k)` control vertices of each shape vertex (padded with 0).
        weights: `(n, k)` their weights (0 on padding); rows sum to 1.
        method: the skinning method the weights came from.
    """

    indices: Int[Array, "n k"]
    weights: Float[Array, "n k"]
    method: AbstractSkinning = eqx.field(static=True, default=BlendedMVCSkinning())

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
        product beats the gather."""
        n = self.indices.shape[0]
        return jnp.zeros((n, control_count), self.weights.dtype).at[
            jnp.arange(n)[:, None], self.indices
        ].add(self.weights)
