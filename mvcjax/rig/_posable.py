"""What a rig and a layered character both offer: their meshes, and the protocol the
tools on top (posing, fitting, animating, drawing) use for either.

(No `from __future__ import annotations` here: equinox reads `AbstractVar` annotations
as objects.)"""

import abc
from typing import Any

import equinox as eqx
from jaxtyping import Array, Float, Int

from ..core import JittableModule
from ..solvers import DEFAULT_SOLVER
from ._handles import Handles
from ._start import Init, TurnedStart


class ShapeMesh(eqx.Module):
    """The dense triangle mesh the user sees.

    Attributes:
        vertices: `(n, 2)` rest vertices.
        faces: `(f, 3)` counter-clockwise triangles.
        handles: `(r,)` the vertex each handle pins, one per row of `Handles` (a
            point handle pins one, a bone several along its segment).
    """

    vertices: Float[Array, "n 2"]
    faces: Int[Array, "f 3"]
    handles: Int[Array, " r"]


class ControlMesh(eqx.Module):
    """The small mesh the energy is solved on.

    Attributes:
        vertices: `(c, 2)` rest vertices, the polygon loops first, then the inner ones.
        faces: `(f, 3)` counter-clockwise triangles.
        outer: `(p,)` the vertices of the enclosing polygon `V_CP`, loop after loop.
        inner: `(g,)` the inner vertices `V_CG`.
        handles: `(r,)` the vertex each handle pins, as `ShapeMesh.handles`.
    """

    vertices: Float[Array, "c 2"]
    faces: Int[Array, "f 3"]
    outer: Int[Array, " p"]
    inner: Int[Array, " g"]
    handles: Int[Array, " r"]


class AbstractRig(JittableModule):
    """A subject posed by handle targets: a `Rig`, or a `Character` of several rigs.

    The tools take either through this protocol alone. What `solve`, `skin` and `deform`
    return is the subject's own (a rig's `(n, 2)` array, a character's tuple of parts);
    `joined` turns it into one array in the order of `shape_mesh` (or `control_mesh`),
    the meshes that are drawn and counted as one.

    Attributes:
        shape_mesh: the dense mesh drawn (a character's parts joined, bottom first).
        control_mesh: the mesh solved (joined as `shape_mesh` is).
        handles: how the targets pin the subject (`handles.count` target rows).
    """

    shape_mesh: eqx.AbstractVar[ShapeMesh]
    control_mesh: eqx.AbstractVar[ControlMesh]
    handles: eqx.AbstractVar[Handles]

    @property
    @abc.abstractmethod
    def handle_positions(self) -> Float[Array, "h 2"]:
        """The targets at rest: targets equal to these give back the rest pose."""

    @abc.abstractmethod
    def start(self, targets: Any, init: Init = TurnedStart()) -> Float[Array, "c 2"]:
        """Starting vertices of the joined control mesh for `(h, 2)` targets."""

    @abc.abstractmethod
    def solve(self, targets: Any, solver: Any = DEFAULT_SOLVER, *, init: Init = TurnedStart(),
              return_info: bool = False) -> Any:
        """The control vertices for `(h, 2)` targets, from `init` (a start, or
        `(c, 2)` vertices of the joined control mesh)."""

    @abc.abstractmethod
    def skin(self, control: Any) -> Any:
        """The shape-mesh vertices carried by `solve`'s control vertices."""

    @abc.abstractmethod
    def deform(self, targets: Any, solver: Any = DEFAULT_SOLVER, *, init: Init = TurnedStart(),
               return_info: bool = False) -> Any:
        """Solve, then skin."""

    @abc.abstractmethod
    def with_weights(self, weights: Any) -> "AbstractRig":
        """The same subject with other term weights."""

    @abc.abstractmethod
    def with_spare_pins(self, count: Any) -> "AbstractRig":
        """The subject with `count` rows that pins can take later, or the subject itself
        where pins are its handles."""

    @abc.abstractmethod
    def joined(self, posed: Any) -> Float[Array, "*frames n 2"]:
        """What `solve`, `skin` or `deform` gave (for one pose or many frames), as one
        array in the order of the joined mesh."""
