"""Character: a figure drawn in layers, one rig per part, all posed by one set of handles.

Each layer is a part with its own shape mesh and control mesh (`Rig`), so that an arm
drawn over the torso at rest is not welded to it. The character's handles are given
once, on the canvas; each part is pinned by the handles that lie in it (a point in two
parts pins both, a bone pins a part it lies in as a bone and a part that holds only one
of its ends at that end). A part with no handle of its own is attached to the part it
overlaps most: a few of its points where they overlap are pinned to where that part
carries them, so that a hand follows its arm. Parts are solved in that order, inside one
compiled program; the character is a pytree like a rig, so it jits, vmaps and
differentiates.

`CharacterRenderer` draws every part with its own layer as texture and lays them over
each other in a draw order that each frame may change.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import shapely
from jaxtyping import Array, ArrayLike, Float, Int
from skimage.measure import label

from ..core import (
    JittableModule,
    Programs,
    check_targets,
    checked_on_entry,
    compiled_by,
    programs_field,
    to_device,
    whole_number,
)
from ..geometry import Shape, Skinning, image_mask, to_uint8
from ..rendering import Checkerboard, MeshAlpha, Renderer, key_layout, refuse_over_budget
from ..rig import (
    AbstractRig,
    AbstractStart,
    Bone,
    ControlMesh,
    Handles,
    Init,
    Rig,
    ShapeMesh,
    TurnedStart,
    checked_start,
    make_handles,
    parse_handles,
    pin,
    shape_thickness,
    solve_in_frame,
)
from ..solvers import DEFAULT_SOLVER, AbstractSolver, check_solver
from ._layers import Layer, load_layers

# Points pinning an attached part to its parent, spread over their overlap.
_ATTACH_POINTS = 3
# An overlap smaller than this fraction of the attached part's area cannot carry it.
_LEAST_OVERLAP = 1e-3


def _part_shapes(layers: list[Layer], alpha_threshold, tolerance) -> list[Shape]:
    shapes = []
    for layer in layers:
        try:
            mask = image_mask(layer.picture, alpha_threshold=alpha_threshold)
        except ValueError as error:
            raise ValueError(f"layer {layer.name!r}: {error}") from error
        regions = int(label(mask, connectivity=1).max())
        if regions > 1:
            raise ValueError(
                f"layer {layer.name!r} holds {regions} separate regions of pixels with alpha "
                f"above {alpha_threshold}; a part is one connected region: split the layer "
                "into one layer per region (two eyes: two layers), or join the regions.")
        shapes.append(Shape.from_image(mask, tolerance=tolerance))
    return shapes


def _feeds(shapes: list[Shape], points, bones, owner, names) -> list[tuple[list, list]]:
    """For each part, its handles for `Rig.build` and, row for row, how each of its
    targets follows the character's: `(first, second, along, length, rigid)` as in
    `Handles`."""
    in_bone = np.zeros(len(points), bool)
    for row, _ in bones:
        in_bone[row:row + 2] = True
    feeds = []
    for shape in shapes:
        area, tol = shape.polygon.buffer(1e-6 * shape.diagonal), 1e-6 * shape.diagonal
        handles, rows = [], []

        def add_point(point, row, tol=tol, handles=handles, rows=rows):
            # Two handles at one spot (bones meeting at a joint in this part) pin it once.
            if not any(isinstance(h, tuple) and np.hypot(*(np.subtract(h, point))) <= tol
                       for h in handles):
                handles.append(tuple(point))
                rows.append(row)

        for row, bone in bones:
            if area.covers(shapely.LineString([bone.start, bone.end])):
                handles.append(Bone(bone.start, bone.end, stretch=bone.stretch))
                rows += [(row, row, 0.0, 0.0, False), (row + 1, row + 1, 0.0, 0.0, False)]
                continue
            # A part holding one end of the bone is pinned there, where the bone puts it.
            for along, end in ((0.0, bone.start), (1.0, bone.end)):
                if area.covers(shapely.Point(end)):
                    add_point(end, (row, row + 1, along, bone.length, not bone.stretch))
        for row in np.flatnonzero(~in_bone):
            if area.covers(shapely.Point(points[row])):
                add_point(points[row], (row, row, 0.0, 0.0, False))
        feeds.append((handles, rows))
    for row in range(len(points)):
        if not any(r[0] == row or r[1] == row for _, rows in feeds for r in rows):
            raise ValueError(
                f"handles[{owner[row]}] at {points[row].tolist()} lies in no part (the "
                f"parts: {', '.join(map(repr, names))}); move it onto the part it should "
                "pin.")
    return feeds


def _parents(shapes, feeds, attach, names) -> list[int]:
    """Each part's parent (-1: none), attached parts after a part that carries them."""
    count = len(shapes)
    index = {name: i for i, name in enumerate(names)}

    def part(key, what):
        if isinstance(key, (int, np.integer)) and not isinstance(key, bool) \
                and 0 <= key < count:
            return int(key)
        if isinstance(key, str) and key in index:
            return index[key]
        raise ValueError(f"attach names {what} {key!r}, which is no part; the parts are "
                         f"{', '.join(map(repr, names))} (or indices 0 to {count - 1}).")

    parents = [-1] * count
    for child, parent in (attach or {}).items():
        child, parent = part(child, "a part"), part(parent, "a parent")
        if child == parent:
            raise ValueError(f"attach asks part {names[child]!r} to follow itself.")
        parents[child] = parent
    for i in range(count):
        if parents[i] < 0 and not feeds[i][1]:
            overlap = [shapes[i].polygon.intersection(shapes[j].polygon).area
                       if j != i else 0.0 for j in range(count)]
            j = int(np.argmax(overlap))
            if overlap[j] <= _LEAST_OVERLAP * shapes[i].area:
                raise ValueError(
                    f"part {names[i]!r} holds no handle and overlaps no other part, so "
                    "nothing can move it; put a handle on it, or draw it overlapping the "
                    "part it hangs from.")
            parents[i] = j
    # Parents are solved first: following parents must end, not go round a loop.
    for i in range(count):
        seen, j = [i], i
        while parents[j] >= 0:
            j = parents[j]
            if j in seen:
                loop = ", ".join(repr(names[k]) for k in seen[seen.index(j):])
                raise ValueError(
                    f"parts {loop} follow each other in a loop (attach, or the overlap of "
                    "parts that hold no handle): attach one of them to a part outside the "
                    "loop, or put a handle on it.")
            seen.append(j)
    return parents


def _solve_order(parents: list[int]) -> tuple[int, ...]:
    order, done = [], set()

    def visit(i):
        if i in done:
            return
        if parents[i] >= 0:
            visit(parents[i])
        done.add(i)
        order.append(i)

    for i in range(len(parents)):
        visit(i)
    return tuple(order)


def _attach_points(child: Shape, parent: Shape) -> np.ndarray:
    """A few points of the child spread over its overlap with the parent, inside both."""
    overlap = child.polygon.intersection(parent.polygon)
    inner = overlap.buffer(-0.05 * np.sqrt(overlap.area))
    region = inner if inner.area > 0.1 * overlap.area else overlap
    lo, hi = np.asarray(region.bounds[:2]), np.asarray(region.bounds[2:])
    step = np.sqrt(region.area) / 12.0
    x, y = np.meshgrid(np.arange(lo[0], hi[0] + step, step), np.arange(lo[1], hi[1] + step,
                                                                        step))
    grid = np.stack([x.ravel(), y.ravel()], axis=1)
    grid = grid[shapely.contains_xy(region, grid[:, 0], grid[:, 1])]
    if len(grid) == 0:
        point = region.representative_point()
        return np.array([[point.x, point.y]])
    # Farthest-point sampling, from the point farthest from the overlap's centre.
    centre = np.asarray(region.centroid.coords[0])
    chosen = [int(np.argmax(np.linalg.norm(grid - centre, axis=1)))]
    distance = np.linalg.norm(grid - grid[chosen[0]], axis=1)
    while len(chosen) < min(_ATTACH_POINTS, len(grid)):
        chosen.append(int(np.argmax(distance)))
        distance = np.minimum(distance, np.linalg.norm(grid - grid[chosen[-1]], axis=1))
    return grid[chosen]


def _ends(start, end) -> np.ndarray:
    return np.array([0.0, 1.0])


def _feed_handles(rows: list, rest: np.ndarray, dtype) -> Handles:
    """`Handles` whose rows follow the character's targets (no bones of their own)."""
    columns = [np.asarray(c) for c in zip(*rows)] if rows else [np.zeros(0)] * 5
    return make_handles(rest, [], columns, dtype)


class Character(AbstractRig):
    """A character drawn in layers: one rig per part, all posed by one set of handles.

    Build one with `Character.build`. `character.deform(targets)` gives every part's
    deformed shape-mesh vertices, a tuple in the layers' order; `Renderer.build(character,
    layers)` draws them. Like a rig, a character is a pytree: `jax.jit`, `jax.vmap` and
    `jax.grad` take it, and new targets never recompile.

    Attributes:
        parts: a `Rig` per layer, bottom first.
        feeds: per part, how its targets follow the character's (`Handles` rows over the
            character's targets); an attached part's attachment targets come after them.
        attachments: per part, the skinning weights of its attachment points in its
            parent's control mesh (None for a part without a parent).
        handles: the character's handles: its targets at rest (`handles.rest`), their
            count and its bones' rows, as a rig's `Handles` (pinning each bone's two
            ends).
        names: each part's name (static).
        parents: each part's parent, -1 for none (static).
        order: the order the parts are solved in, parents first (static).
        programs: what the character compiled for itself; it goes with the character.
    """

    parts: tuple[Rig, ...]
    feeds: tuple[Handles, ...]
    attachments: tuple[Skinning | None, ...]
    handles: Handles
    names: tuple[str, ...] = eqx.field(static=True)
    parents: tuple[int, ...] = eqx.field(static=True)
    order: tuple[int, ...] = eqx.field(static=True)
    programs: Programs = programs_field()

    @classmethod
    def build(
        cls,
        layers: Any,
        handles: Any,
        *,
        attach: Any = None,
        shape_spacing: Any = None,
        alpha_threshold: Any = 0.5,
        tolerance: Any = 0.5,
        **options: Any,
    ) -> Character:
        """Rig every layer as a part, each pinned by the handles that lie in it.

        Args:
            layers: the parts, bottom first: a layered file (`.psd`, `.ora`) or a list of
                same-size pictures (see `load_layers`). A part is a layer's opaque
                region, in the layer's pixel coordinates (`Shape.from_image`'s: y up).
            handles: the character's handles on the canvas, as for `Rig.build`: `(h, 2)`
                points, or a list of `(x, y)` points and `mvcjax.Bone`s. A point pins
                every part it lies in (a shoulder on the arm and the torso pins both); a
                bone pins a part that holds all of it as a bone, and a part that holds
                only one of its ends at that end. Every handle must lie in some part.
            attach: `{part: parent}` (names or indices): parts that follow another where
                they overlap. A part holding no handle follows, by default, the part it
                overlaps most.
            shape_spacing: edge length of every part's shape mesh (default: the whole
                character's `Rig.build` default, or half a thin part's thickness).
            alpha_threshold: alpha above which a pixel belongs to its part.
            tolerance: how far, in pixels, a part's outline may simplify its pixels'.
            options: further `Rig.build` options for every part (`control`, `skinning`,
                `weights`, `dtype`, ...).
        """
        if options.get("ladder") is not None:
            raise ValueError("Character.build poses its parts in one program of the "
                             "character's own sizes, so ladder= would only add padded "
                             "twins: leave it out.")
        layers = load_layers(layers)
        names = tuple(layer.name for layer in layers)
        shapes = _part_shapes(layers, alpha_threshold, tolerance)
        points, bones, owner = parse_handles(handles)
        feeds = _feeds(shapes, points, bones, owner, names)
        parents = _parents(shapes, feeds, attach, names)
        if shape_spacing is None:
            whole = np.sqrt(sum(s.area for s in shapes)) / 40.0
            spacings = [min(whole, shape_thickness(s) / 2.0) for s in shapes]
        else:
            spacings = [shape_spacing] * len(shapes)
        parts, attachments, feed_rows = [None] * len(shapes), [None] * len(shapes), []
        order = _solve_order(parents)
        for i in order:
            part_handles, rows = feeds[i]
            extra = (np.zeros((0, 2)) if parents[i] < 0
                     else _attach_points(shapes[i], shapes[parents[i]]))
            try:
                parts[i] = Rig.build(shapes[i], [*part_handles, *map(tuple, extra)],
                                     shape_spacing=spacings[i], **options)
            except ValueError as error:
                raise ValueError(f"part {names[i]!r}: {error}") from error
            if parents[i] >= 0:
                attachments[i] = parts[parents[i]].weights_at(extra)
        dtype = parts[0].energy.rest.dtype
        for i, (_, rows) in enumerate(feeds):
            rest = np.asarray(parts[i].handle_positions, np.float64)[:len(rows)]
            feed_rows.append(_feed_handles(rows, rest, dtype))
        return cls(
            parts=tuple(parts),
            feeds=tuple(feed_rows),
            attachments=tuple(attachments),
            handles=make_handles(points, bones, pin(points, bones, _ends, 0.0)[2], dtype),
            names=names,
            parents=tuple(parents),
            order=order,
        )

    @property
    def handle_positions(self) -> Float[Array, "t 2"]:
        """The targets at rest (a row per point handle, two per bone): targets equal to
        these give back the rest pose."""
        return self.handles.rest

    @property
    def shape_mesh(self) -> ShapeMesh:
        """All parts' shape meshes as one (vertices part after part, the layers' order):
        what `jnp.concatenate(character.deform(targets))` poses."""
        meshes = [part.shape_mesh for part in self.parts]
        return ShapeMesh(*_joined([(m.vertices, m.faces, m.handles) for m in meshes]))

    @property
    def control_mesh(self) -> ControlMesh:
        """All parts' control meshes as one, as `shape_mesh` joins the shape meshes."""
        meshes = [part.control_mesh for part in self.parts]
        return ControlMesh(*_joined([(m.vertices, m.faces, m.outer, m.inner, m.handles)
                                     for m in meshes]))

    def part_targets(self, part: int, targets: Float[ArrayLike, "t 2"],
                     parent_control: Any = None) -> Float[Array, "h 2"]:
        """Part `part`'s targets (its rig's) for the character's, its attachment rows
        carried by its parent's control vertices `parent_control` (a part with a
        parent)."""
        own = self.feeds[part].pinned_targets(targets)
        attached = self.attachments[part]
        if attached is None:
            return own
        parent = self.parts[self.parents[part]]
        return jnp.concatenate([own, attached(parent.frame.to_local(parent_control),
                                              parent.frame)])

    def with_weights(self, weights: Any) -> Character:
        """The same character with other term weights (an `mvcjax.Weights`) in every part,
        as `Rig.with_weights` gives them to a rig (no recompilation with dense factors)."""
        parts = tuple(part.with_weights(weights) for part in self.parts)
        return eqx.tree_at(lambda c: c.parts, self, parts)

    def _check_targets(self, targets) -> Float[Array, "t 2"]:
        return check_targets(targets, self.handles.count, self.handles.rest.dtype)

    def _check_init(self, init: Init) -> tuple:
        """`init` for every part: a start, or the part's rows of `(c, 2)` control
        vertices of the joined control mesh."""
        init = checked_start(init, self.control_mesh.vertices.shape)
        if isinstance(init, AbstractStart):
            return (init,) * len(self.parts)
        ends = np.cumsum([part.control_mesh.vertices.shape[0] for part in self.parts])
        return tuple(init[end - part.control_mesh.vertices.shape[0]:end]
                     for part, end in zip(self.parts, ends))

    def start(self, targets: Any, init: Init = TurnedStart()) -> Float[Array, "c 2"]:
        """Starting vertices of the joined control mesh (`control_mesh`) for `(t, 2)`
        targets: every part's start (`Rig.start`, a start), parents first, an
        attached part's attachment targets carried by its parent's start."""
        return _start_parts(self, self._check_targets(targets), init)

    def solve(self, targets: Any, solver: Any = DEFAULT_SOLVER, *, init: Init = TurnedStart(),
              return_info: bool = False):
        """Every part's control vertices for these targets, parents first.

        Args:
            targets: `(t, 2)` where each handle goes (a row per point, two per bone).
            solver: the solver of every part (default: `Rig.solve`'s).
            init: every part's start, a start (see `Rig.start`), or `(c, 2)`
                vertices of the joined control mesh (`control_mesh`): a pose before,
                `character.joined(control)`.
            return_info: also return a `SolveInfo` per part.

        Returns:
            A tuple of `(c_i, 2)` control vertices, a part each in the layers' order (and
            a tuple of `SolveInfo`s if asked for).
        """
        check_solver(solver)
        control, info = _solve_parts(self, self._check_targets(targets), solver,
                                     self._check_init(init))
        return (control, info) if return_info else control

    def skin(self, control: tuple) -> tuple:
        """Every part's shape-mesh vertices carried by its control vertices."""
        return _skin_parts(self, tuple(control))

    def deform(self, targets: Any, solver: Any = DEFAULT_SOLVER, *, init: Init = TurnedStart(),
               return_info: bool = False):
        """Solve, then skin: a tuple of every part's deformed shape-mesh vertices
        `(n_i, 2)` in the layers' order (and a `SolveInfo` per part); the arguments are
        those of `solve`."""
        check_solver(solver)
        vertices, info = _deform_parts(self, self._check_targets(targets), solver,
                                       self._check_init(init))
        return (vertices, info) if return_info else vertices

    def joined(self, posed: tuple | list) -> Float[Array, "*frames n 2"]:
        """Every part's vertices (`solve`, `skin` or `deform`, of a pose or of many
        frames) as one array, in the order of the joined meshes (`shape_mesh`,
        `control_mesh`)."""
        return jnp.concatenate(posed, axis=-2)

    def with_spare_pins(self, count: Any) -> Character:
        """The character itself: its pins are the handles it was built with (a new pin
        needs a new character, `Character.build`)."""
        whole_number(count, "count", minimum=0, what=" of spare pins")
        return self

    def renderer(self, layers: Any, **options: Any) -> CharacterRenderer:
        """A renderer of this character from the layers it was built from: what
        `Renderer.build(character, layers, ...)` returns (`CharacterRenderer.build`
        documents the options)."""
        if layers is None:
            raise ValueError("A character is drawn with its layers: pass the layers it was "
                             "built from as image (Renderer.build(character, layers)).")
        return CharacterRenderer.build(self, layers, **options)

    def __repr__(self) -> str:
        parts = ", ".join(f"{name!r}: {p.shape_mesh.vertices.shape[0]} vertices"
                          + (f", follows {self.names[self.parents[i]]!r}"
                             if self.parents[i] >= 0 else "")
                          for i, (name, p) in enumerate(zip(self.names, self.parts)))
        return f"Character({len(self.parts)} parts: {parts}; {self.handles.count} targets)"


def _joined(meshes: list[tuple]) -> list:
    """Meshes `(vertices, indices...)` as one: vertices stacked, every index array shifted
    by the vertices before its mesh."""
    starts = np.cumsum([0] + [m[0].shape[0] for m in meshes])
    return [jnp.concatenate([m[0] for m in meshes])] + [
        jnp.concatenate([m[k] + start for m, start in zip(meshes, starts)])
        for k in range(1, len(meshes[0]))]


@compiled_by(inline_when_traced=True)
def _start_parts(character: Character, targets, init):
    starts = [None] * len(character.parts)
    for i in character.order:
        parent = character.parents[i]
        own = character.part_targets(i, targets, None if parent < 0 else starts[parent])
        starts[i] = character.parts[i].start(own, init)
    return character.joined(starts)


@compiled_by(inline_when_traced=True)
def _skin_parts(character: Character, control: tuple):
    return tuple(part.skin(c) for part, c in zip(character.parts, control))


@compiled_by(inline_when_traced=True)
def _solve_parts(character: Character, targets, solver: AbstractSolver, init):
    control, info = [None] * len(character.parts), [None] * len(character.parts)
    for i in character.order:
        part = character.parts[i]
        parent = character.parents[i]
        own = character.part_targets(i, targets, None if parent < 0 else control[parent])
        local, info[i] = solve_in_frame(part, own, solver, init[i])
        control[i] = part.frame.to_world(local)
    return tuple(control), tuple(info)


@compiled_by(inline_when_traced=True)
def _deform_parts(character: Character, targets, solver: AbstractSolver, init):
    """Every part solved, parents first, and skinned: one compiled program when called
    outside a transformation, as a rig's `deform` is."""
    control, info = _solve_parts(character, targets, solver, init)
    return character.skin(control), info


def _check_order(order, count: int, names) -> Any:
    """A draw order: a permutation of the parts, bottom first (checked where concrete)."""
    if isinstance(order, jax.core.Tracer):
        return order
    host = np.asarray(order)
    if host.shape[-1:] != (count,) or host.dtype.kind not in "iu" or not np.all(
            np.sort(host, axis=-1) == np.arange(count)):
        raise ValueError(
            f"order must list each of the {count} parts once, bottom first (a permutation "
            f"of 0..{count - 1}; the parts: {', '.join(map(repr, names))}), got "
            f"{host.tolist()}.")
    return jnp.asarray(host, jnp.int32)


class CharacterRenderer(JittableModule):
    """Draws a layered character: every part textured by its own layer, the parts laid
    over each other in a draw order that may change from frame to frame.

    Build one with `Renderer.build(character, layers)` (or `CharacterRenderer.build`);
    call it with the parts' vertices (`character.deform(targets)`). The parts are drawn
    as one mesh in one pass, each triangle at its part's draw level, with the layers side
    by side in one texture: a part's edge over another is antialiased as the outline is,
    and a picture costs about what one silhouette of as many vertices costs. It jits,
    vmaps over frames (orders too) and differentiates like `Renderer`.

    Attributes:
        mesh: the `Renderer` of all parts' triangles, their textures side by side.
        part_of_face: `(f,)` the part each triangle belongs to.
        order: `(p,)` the default draw order, bottom first (the layers').
        sizes: each part's number of vertices (static).
        names: the parts' names (static).
        programs: what the renderer compiled for itself; it goes with the renderer.
    """

    mesh: Renderer
    part_of_face: Int[Array, " f"]
    order: Int[Array, " p"]
    sizes: tuple[int, ...] = eqx.field(static=True)
    names: tuple[str, ...] = eqx.field(static=True)
    programs: Programs = programs_field()

    @classmethod
    def build(cls, character: Character, layers: Any, *, window: Any = None,
              size: Any = None, background: Any = (0.0, 0.0, 0.0, 0.0),
              budget: Any = None, **options: Any) -> CharacterRenderer:
        """A renderer for a character.

        Args:
            character: the `Character`.
            layers: the layers it was built from (a layered file or a list of pictures):
                each part's texture.
            window: the rectangle `(xmin, ymin, xmax, ymax)` to draw; default the
                canvas's (`fit_window` makes one that holds a whole animation).
            size: `(rows, cols)` of the output; default the canvas's with its window,
                else 512 pixels along the window's longer side.
            background: straight RGBA where no part is drawn; transparent by default.
            budget: the most pixel tiles one picture may cover, as for `Renderer.build`
                (default: from all the parts' rest meshes).
            options: `antialias`, `alpha` and `dtype`, as for `Renderer.build`.
        """
        if not isinstance(character, Character):
            raise TypeError(f"character must be an mvcjax.Character, got "
                            f"{type(character).__name__}.")
        layers = load_layers(layers)
        if len(layers) != len(character.parts):
            raise ValueError(f"layers holds {len(layers)} layers, the character "
                             f"{len(character.parts)} parts; give the layers it was built "
                             "from.")
        rows, cols = layers[0].picture.shape[:2]
        if window is None:
            window = (-0.5, -0.5, cols - 0.5, rows - 0.5)
            size = (rows, cols) if size is None else size
        # Each part checked and textured as a rig of its own would be, then all laid out
        # as one mesh: the layers side by side, each with a border of its own edge's
        # colours so that lookups at its edge never read the next one.
        unknown = set(options) - {"antialias", "alpha", "dtype"}
        if unknown:
            raise TypeError(f"CharacterRenderer.build got unexpected options {sorted(unknown)}; "
                            "it takes antialias, alpha and dtype besides its arguments.")
        settings = dict(window=window, size=size, background=background, image_window=None,
                        fill=Checkerboard(), depth=None, antialias=True, alpha=MeshAlpha(),
                        budget=None, dtype=None) | options
        parts = [Renderer._prepared(rig, layer.picture, **settings)
                 for rig, layer in zip(character.parts, layers)]
        first = parts[0]
        gap = 2
        textures = [np.pad(np.asarray(p["texture"]), ((0, 0), (gap, gap), (0, 0)),
                           mode="edge") for p in parts]
        width = textures[0].shape[1]
        points = [np.asarray(p["texture_points"]) + [k * width + gap, 0.0]
                  for k, p in enumerate(parts)]
        part_of_face = np.repeat(np.arange(len(parts)), [len(p["faces"]) for p in parts])
        # Each part's triangles in its own renderer's draw order (deepest last), all on
        # the part's level: within a part, the triangle covering a pixel most draws it,
        # so that the part's outline stays one antialiased edge, and where the part folds
        # over itself the deeper triangle is on top.
        if len(parts) > key_layout(len(part_of_face))[1]:
            raise ValueError(f"A character of {len(parts)} parts and {len(part_of_face)} "
                             "triangles has more parts than draw levels: merge layers, or "
                             "build it with a coarser shape_spacing.")
        offsets = np.cumsum([0] + [len(p["vertices"]) for p in parts])[:-1]
        faces = np.concatenate([np.asarray(p["faces"]) + at for p, at in zip(parts, offsets)])
        mesh = Renderer._from_arrays(
            np.asarray(character.shape_mesh.vertices), faces,
            np.concatenate(points), np.concatenate(textures, axis=1),
            first["window"], first["size"], level=to_device(part_of_face, np.int32),
            budget=budget, background=first["background"], antialias=first["antialias"],
            see_through=first["see_through"], dtype=first["dtype"])
        return cls(mesh=mesh, part_of_face=to_device(part_of_face, np.int32),
                   order=to_device(np.arange(len(parts)), np.int32),
                   sizes=tuple(len(p["vertices"]) for p in parts), names=character.names)

    @property
    def shape(self) -> tuple[int, int]:
        """`(rows, cols)` of the pictures drawn."""
        return self.mesh.shape

    @property
    def window(self) -> Float[Array, " 4"]:
        """The rectangle `(xmin, ymin, xmax, ymax)` drawn."""
        return self.mesh.window

    def with_order(self, order: Any) -> Renderer:
        """The renderer of all parts' triangles, drawn in `order` (part indices, bottom
        first): each triangle at its part's place in it."""
        count = len(self.sizes)
        order = self.order if order is None else _check_order(order, count, self.names)
        rank = jnp.zeros(count, jnp.int32).at[order].set(jnp.arange(count, dtype=jnp.int32))
        return eqx.tree_at(lambda r: r.level, self.mesh, rank[self.part_of_face])

    def __call__(self, vertices: Any, order: Any = None,
                 window: Any = None) -> Float[Array, "rows cols 4"]:
        """The picture of the character posed at `vertices`.

        Args:
            vertices: a tuple of every part's `(n_i, 2)` vertices (`character.deform`).
            order: `(p,)` the draw order of this picture, part indices bottom first
                (numbers: no recompilation); default the layers'.
            window: another rectangle `(xmin, ymin, xmax, ymax)` to draw, or
                `mvcjax.advanced.GrownWindow()` (as for `Renderer`).

        Returns:
            `(rows, cols, 4)` straight RGBA in [0, 1].
        """
        return self.with_order(order)(self._joined(vertices), window)

    def _joined(self, vertices) -> Float[Array, "n 2"]:
        shapes = [tuple(getattr(v, "shape", ())) for v in vertices] \
            if isinstance(vertices, (tuple, list)) else None
        if shapes is None or shapes != [(n, 2) for n in self.sizes]:
            raise ValueError(f"vertices must be a tuple of {len(self.sizes)} arrays, a part's "
                             f"vertices each, of shapes {[(n, 2) for n in self.sizes]} "
                             f"(character.deform(targets)), got "
                             f"{shapes if shapes is not None else type(vertices).__name__}.")
        return jnp.concatenate([jnp.asarray(v, self.window.dtype) for v in vertices])

    def frames(self, vertices: Any, order: Any = None, *, chunk: Any = 8) -> np.ndarray:
        """Many pictures, ready to write: `(frames, rows, cols, 4)` `uint8` straight RGBA.

        Args:
            vertices: a tuple of every part's `(frames, n_i, 2)` vertices
                (`deform_frames(character, targets)`).
            order: `(p,)` one draw order, or `(frames, p)` one per frame.
            chunk: frames drawn by one compiled call.
        """
        vertices = tuple(np.asarray(v) for v in vertices)
        frames = vertices[0].shape[0]
        count = len(self.sizes)
        order = np.asarray(self.order if order is None else order)
        order = _check_order(np.broadcast_to(order, (frames, count)), count, self.names)
        joined = np.concatenate(vertices, axis=1)
        self.mesh._warn_if_clipped(joined)
        chunk = min(whole_number(chunk, "chunk", what=" of frames"), frames)
        out = np.empty((frames, *self.shape, 4), np.uint8)
        takes = [np.minimum(np.arange(begin, begin + chunk), frames - 1)
                 for begin in range(0, frames, chunk)]
        refuse_over_budget(self.mesh, [joined[take].astype(self.window.dtype)
                                       for take in takes])
        for begin, take in zip(range(0, frames, chunk), takes):
            batch = tuple(jnp.asarray(v[take], self.window.dtype) for v in vertices)
            with checked_on_entry():  # the budget, above
                pictures = _draw_character_batch(self, batch, order[take])
            done = min(chunk, frames - begin)
            out[begin:begin + done] = to_uint8(np.asarray(pictures[:done]))
        return out


@compiled_by()
def _draw_character_batch(renderer: CharacterRenderer, vertices, order):
    # In its window, given: `frames` warned of what it cuts off, once for all frames.
    return jax.vmap(lambda v, o: renderer(v, o, renderer.window))(vertices, order)

