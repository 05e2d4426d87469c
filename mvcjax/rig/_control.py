"""The control mesh: how `Rig.build` makes the small mesh the energy is solved on.

Three options, as objects: the paper's control mesh built from the shape
(`PaperControl`, the default), the shape mesh itself (`FullSolve`, after Weng et al.),
or a mesh of the user's (`GivenControl`). Each knows where to pin a bone and how to
make its mesh once the shape mesh exists.
"""

from __future__ import annotations

import abc
import itertools
from typing import NamedTuple

import equinox as eqx
import numpy as np
import shapely

from ..core import as_points, checked_option
from ..geometry import (
    boundary_loops,
    control_polygon,
    counter_clockwise,
    inner_control_vertices,
    points_to_local,
    triangulate_control,
)
from ._handles import bone_samples, bone_samples_on


class ControlParts(NamedTuple):
    """A control mesh in the rig's frame, as `Rig.build` assembles it.

    Attributes:
        vertices: `(c, 2)` vertices.
        faces: `(f, 3)` counter-clockwise triangles.
        loops: the boundary loops `V_CP`, the outer one first.
        inner: `(g,)` the other vertices, `V_CG`.
        pinned: `(p,)` the vertex at each pinned point.
        is_shape_mesh: whether it is the shape mesh itself (carried by the identity).
    """

    vertices: np.ndarray
    faces: np.ndarray
    loops: list[np.ndarray]
    inner: np.ndarray
    pinned: np.ndarray
    is_shape_mesh: bool = False


def loops_and_inner(vertices, faces) -> tuple[list[np.ndarray], np.ndarray]:
    """A mesh's boundary loops (`V_CP`, the outer loop first) and its other vertices (`V_CG`)."""
    loops = boundary_loops(faces)
    loops.sort(key=lambda lp: -abs(shapely.Polygon(vertices[lp]).area))
    on_loop = np.zeros(len(vertices), bool)
    on_loop[np.concatenate(loops)] = True
    return loops, np.flatnonzero(~on_loop)


class AbstractControl(eqx.Module):
    """How `Rig.build` makes the control mesh. Everything is in the rig's frame
    (centred, unit diagonal); `frame = (centre, scale)` maps the user's coordinates
    there, `(x - centre) / scale`."""

    def bone_samples(self, spacing: float, frame):
        """`samples(start, end)`: where along a bone (0 to 1) to pin it."""
        del frame
        return lambda a, b: bone_samples(a, b, spacing)

    @abc.abstractmethod
    def build(self, local, shape_vertices, shape_faces, shape_pinned, pinned, spacing: float,
              margin: float, frame) -> ControlParts:
        """The control mesh, given the shape (`local`, a `Shape`), its mesh, the shape
        vertex at each pinned point and the pinned points themselves."""


class PaperControl(AbstractControl):
    """The paper's control mesh: a polygon `V_CP` around the shape, a little outside it
    and into its gaps, and inner vertices `V_CG` picked among the shape mesh's, the
    pinned handles first.

    Attributes:
        spacing: spacing of the inner vertices and longest edge of the polygon, in the
            shape's units (default: `sqrt(area) / 8`).
        margin: how far outside the shape the polygon runs, where no gap is narrower
            than twice that (default: `spacing / 3`).
    """

    spacing: float | int | None = eqx.field(default=None, static=True)
    margin: float | int | None = eqx.field(default=None, static=True)

    def build(self, local, shape_vertices, shape_faces, shape_pinned, pinned, spacing, margin,
              frame):
        loops = control_polygon(local, margin, spacing)
        inner_shape = inner_control_vertices(shape_vertices, shape_pinned, loops, spacing)
        vertices, faces = triangulate_control(loops, shape_vertices[inner_shape])
        offsets = np.cumsum([0, *(len(lp) for lp in loops)])
        loops = [np.arange(a, b) for a, b in itertools.pairwise(offsets)]
        inner = np.arange(offsets[-1], len(vertices))
        return ControlParts(vertices, faces, loops, inner, inner[: len(pinned)])


class FullSolve(AbstractControl):
    """The shape mesh as its own control mesh (the paper's "full solve", after Weng et
    al.): its boundary loops are `V_CP`, its interior vertices `V_CG`, every interior
    edge is in `H`, and the skinning is the identity. Exact, and far slower.

    Attributes:
        spacing: how far apart a bone's pinned points are, in the shape's units
            (default: `PaperControl`'s default spacing, so that a full solve pins the
            same points as the default rig; give the `PaperControl`'s spacing to match
            another).
    """

    spacing: float | int | None = eqx.field(default=None, static=True)

    def build(self, local, shape_vertices, shape_faces, shape_pinned, pinned, spacing, margin,
              frame):
        loops, inner = loops_and_inner(shape_vertices, shape_faces)
        return ControlParts(shape_vertices, shape_faces, loops, inner, shape_pinned, True)


class GivenControl(AbstractControl):
    """A control mesh of your own, covering the shape, in the shape's coordinates. Its
    boundary loops are `V_CP`, every other vertex is `V_CG`. Every point handle, and
    both ends of every bone, must be one of its vertices; a bone pins every vertex on
    its segment.

    Attributes:
        vertices: `(c, 2)` vertices.
        faces: `(f, 3)` triangles (vertex indices; either orientation).
    """

    vertices: np.ndarray
    faces: np.ndarray

    def __init__(self, vertices, faces):
        self.vertices = as_points(vertices, "GivenControl vertices", "c")
        try:
            faces = np.asarray(faces)
        except ValueError:
            faces = np.asarray([], object)
        if faces.dtype.kind not in "iu" or faces.ndim != 2 or faces.shape[1] != 3:
            raise ValueError(
                "GivenControl faces must be an integer array of shape (f, 3), vertex indices "
                f"of each triangle, got {faces.dtype.name} of shape {faces.shape}."
            )
        n = len(self.vertices)
        if faces.size and (faces.min() < 0 or faces.max() >= n):
            raise ValueError(
                f"GivenControl faces index vertices {faces.min()} to {faces.max()}, but there "
                f"are {n} vertices; indices run from 0 to {n - 1}."
            )
        self.faces = faces.astype(np.int64)

    def bone_samples(self, spacing, frame):
        vertices = points_to_local(self.vertices, frame)
        return lambda a, b: np.union1d([0.0, 1.0], bone_samples_on(a, b, vertices, 1e-6))

    def build(self, local, shape_vertices, shape_faces, shape_pinned, pinned, spacing, margin,
              frame):
        vertices = points_to_local(self.vertices, frame)
        faces = counter_clockwise(vertices, self.faces)
        loops, inner = loops_and_inner(vertices, faces)
        dist = np.linalg.norm(vertices[None] - pinned[:, None], axis=2)
        at = np.argmin(dist, axis=1)
        bad = np.flatnonzero(dist[np.arange(len(pinned)), at] > 1e-6)
        if len(bad):
            centre, scale = frame
            raise ValueError(
                f"The handle point {(pinned[bad[0]] * scale + centre).tolist()} is not a "
                "vertex of the given control mesh; every point handle and both ends of every "
                "bone must be control vertices: add it to the mesh."
            )
        return ControlParts(vertices, faces, loops, inner, at)


def as_control(control) -> AbstractControl:
    """The control-mesh option of `Rig.build`: an `AbstractControl`, or a TypeError that
    names the object to write (for `"shape"` or a `(vertices, faces)` pair too)."""
    described = ("a control-mesh object, mvcjax.PaperControl(spacing=..., margin=...), "
                 "mvcjax.FullSolve() or mvcjax.GivenControl(vertices, faces)")
    if isinstance(control, (tuple, list)) and len(control) == 2:
        raise TypeError(f"control must be {described}, got a (vertices, faces) pair; write "
                        "control=mvcjax.GivenControl(vertices, faces).")
    return checked_option(
        "control", control, AbstractControl,
        {"shape": "mvcjax.FullSolve()", "paper": "mvcjax.PaperControl()"},
        described=described, default="mvcjax.PaperControl()", module="mvcjax")
