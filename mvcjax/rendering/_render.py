"""Render: a (deformed) triangle mesh to pixels, textured by its rest positions.

The renderer is a visibility buffer in pure JAX. Every triangle offers the pixels of its
bounding box as candidates, in small square tiles; a prefix sum over the triangles' tile
counts lays the tiles out one after the other, a loop takes them a chunk at a time (as
many chunks as the pose needs), a pixel keeps the candidate that lies on top (a
scatter-max over the draw order), and each pixel is then shaded once from its triangle:
barycentric coordinates, the rest position there, a bilinear lookup of the picture. Edges
on the mesh's boundary are antialiased by coverage, a linear ramp of the pixel's distance
to the edge, so that the picture depends smoothly on the vertices there too; a second
layer (the top candidate covering the whole pixel) shows through where the top one
covers a pixel partly, so that a part drawn over another has clean edges. The draw order
is fixed at rest (`core_depth` by default, in a few bands of depth); where no candidate
covers a pixel wholly (the outline), the one covering it most draws it, so that
neighbours in different bands still draw one edge.

Pixel convention, shared with `Shape.from_image`: a picture of `rows x cols` pixels spans
a window `(xmin, ymin, xmax, ymax)` of the plane, y up; pixel `(row, col)` is the square
whose centre is `(xmin + (col + 0.5) sx, ymax - (row + 0.5) sy)` with
`sx = (xmax - xmin) / cols`, `sy = (ymax - ymin) / rows`. The default window of a picture
is `(-0.5, -0.5, cols - 0.5, rows - 0.5)`, where the centre of pixel `(row, col)` is
`(col, rows - 1 - row)` (`pixels_to_points`).
"""

from __future__ import annotations

import dataclasses
import functools
import warnings
from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ..core import (
    JittableModule,
    Programs,
    as_devices,
    as_points,
    check_when_run,
    checked_on_entry,
    checked_option,
    compiled_by,
    kind_of,
    materialise,
    one_after_another,
    programs_field,
    progress_bar,
    refuse_string,
    to_device,
    whole_number,
    with_batching_rule,
)
from ..geometry import boundary_edges, edges, load_image, on_boundary, to_uint8
from ..rig import AbstractRig, ShapeMesh, pad_rows, stacked, too_large
from ._options import AbstractAlpha, Checkerboard, GrownWindow, MeshAlpha

# A candidate pixel is inside a triangle when its centre is no further than this outside
# an edge (in pixels): shared edges then never leave a crack between their triangles.
_EPS = 1e-4
# A pixel centre within half a pixel outside a boundary edge is partly covered.
_FRINGE = 0.5
# Tiles drawn per step of the raster's loop, and pixels shaded per step of the shading's.
_CHUNK = 2048
_SHADE_CHUNK = 8192
# Pixels listed together for shading (a run along a row of the picture).
_SHADE_RUN = 8
# Coverage steps in a candidate's key, and the bands of depth of the draw order.
_COVERAGE_BITS = 6
_DEPTH_LEVELS = 16
# Triangles offer their candidate pixels in square tiles of one of these sides: the one
# with the fewest candidates for the rest mesh at the picture's resolution.
_TILES = (2, 4, 8, 16)


def as_picture(image, name: str) -> np.ndarray:
    """`(rows, cols, 4)` straight RGBA float32 in [0, 1] from a picture array."""
    try:
        return load_image(image)
    except (TypeError, ValueError) as error:
        raise type(error)(f"{name}: {error}") from None


def _warn_if_on_a_backdrop(picture: np.ndarray, texture_points: np.ndarray) -> None:
    """Say how to avoid a rim where an opaque picture shows its subject on a plain
    backdrop (its four corners one colour, the mesh clear of them: a JPEG of a drawing):
    the shape's edge, traced half a pixel into the backdrop, is drawn in its colour."""
    rows, cols = picture.shape[:2]
    corners = picture[[0, 0, -1, -1], [0, -1, 0, -1]]
    lo, hi = texture_points.min(axis=0), texture_points.max(axis=0)
    clear = lo[0] > 0.5 and lo[1] > 0.5 and hi[0] < cols - 1.5 and hi[1] < rows - 1.5
    if picture[..., 3].min() >= 1.0 and np.ptp(corners, axis=0).max() < 0.05 and clear:
        warnings.warn(
            "image is opaque and its corners share one colour: the shape's edge will show "
            "a rim of that backdrop. Cut the subject out first: "
            "Renderer.build(..., mvcjax.cut_out(image)), which makes the backdrop "
            "transparent.", stacklevel=4)


def check_window(window, name: str) -> np.ndarray:
    w = np.asarray(window, np.float64)
    if w.shape != (4,) or not np.all(np.isfinite(w)) or not (w[2] > w[0] and w[3] > w[1]):
        raise ValueError(f"{name} must be (xmin, ymin, xmax, ymax) with xmin < xmax and "
                         f"ymin < ymax, got {window!r}.")
    return w


def check_size(size) -> tuple[int, int]:
    if (not isinstance(size, (tuple, list)) or len(size) != 2
            or not all(isinstance(s, (int, np.integer)) and not isinstance(s, bool)
                       for s in size)
            or not all(1 <= s <= 16384 for s in size)):
        raise ValueError(f"size must be (rows, cols), two whole numbers from 1 to 16384, got "
                         f"{size!r}.")
    return int(size[0]), int(size[1])


def fit_window(
    points: Any, size: Any = None, *, margin: float = 0.05
) -> tuple[float, float, float, float]:
    """A window `(xmin, ymin, xmax, ymax)` that holds all `points` (`(..., 2)`: a pose, or
    all frames of an animation), with `margin` of its size around them, widened to the
    aspect ratio of `size = (rows, cols)` if given so that pixels stay square."""
    p = np.asarray(points, np.float64).reshape(-1, 2)
    p = as_points(p, "points")
    lo, hi = p.min(axis=0), p.max(axis=0)
    extent = np.maximum(hi - lo, 1e-12 * max(1.0, float(np.abs(p).max())))
    lo, hi = lo - margin * extent, hi + margin * extent
    if size is not None:
        rows, cols = check_size(size)
        centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        pixel = max(half[0] / cols, half[1] / rows)
        half = pixel * np.array([cols, rows])
        lo, hi = centre - half, centre + half
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def to_pixels(points, window, rows: int, cols: int):
    """Plane points to fractional `(col, row)` positions, pixel centres at integers (a
    host array for host arrays: no program compiled for a build's sizes)."""
    xmin, ymin, xmax, ymax = window[0], window[1], window[2], window[3]
    col = (points[..., 0] - xmin) * (cols / (xmax - xmin)) - 0.5
    row = (ymax - points[..., 1]) * (rows / (ymax - ymin)) - 0.5
    stack = np.stack if isinstance(points, np.ndarray) else jnp.stack
    return stack([col, row], axis=-1)


def _bounding_boxes(tri, fringe, rows: int, cols: int):
    """Each triangle's candidate pixels: first column and row, width and height (0 for a
    triangle off the picture or without area)."""
    lo = jnp.ceil(jnp.minimum(jnp.minimum(tri[:, 0], tri[:, 1]), tri[:, 2]) - fringe[:, None])
    hi = jnp.floor(jnp.maximum(jnp.maximum(tri[:, 0], tri[:, 1]), tri[:, 2]) + fringe[:, None])
    limit = jnp.array([cols - 1, rows - 1], tri.dtype)
    lo = jnp.clip(lo, 0, limit)
    hi = jnp.clip(hi, -1, limit)
    extent = jnp.maximum(hi - lo + 1, 0)
    ab, ac = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    area = ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0]
    keep = jnp.all(jnp.isfinite(tri), axis=(1, 2)) & (jnp.abs(area) > 1e-12)
    extent = jnp.where(keep[:, None], extent, 0).astype(jnp.int32)
    return lo.astype(jnp.int32), extent


def _edge_distances(tri):
    """For each triangle, its three edges (ab, bc, ca) as `(normal, offset)`: the signed
    distance `normal . x + offset` of a point to the edge's line, in pixels, positive
    inside, whatever the triangle's orientation (a fold flips it)."""
    # The sums stay reductions (not `_dot2`): these distances decide which triangle a
    # pixel shows, and written-out products may be contracted differently in each
    # program that inlines them (a frame, a batch, a user's jit), so that a pixel on a
    # shared edge, and the gradient through it, would depend on how it was compiled.
    start = tri
    end = jnp.roll(tri, -1, axis=1)
    d = end - start
    squared = jnp.sum(d * d, axis=-1)
    # A collapsed edge has no direction: its normal is zero, and its gradient finite.
    length = jnp.where(squared > 0, jnp.sqrt(jnp.where(squared > 0, squared, 1.0)), 0.0)
    ab, ac = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    sign = jnp.sign(ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0])
    # The left normal (-dy, dx) points inside a positively oriented triangle.
    scale = (sign[:, None] / jnp.where(length > 0, length, 1.0))[..., None]
    normal = jnp.stack([-d[..., 1], d[..., 0]], axis=-1) * scale
    offset = -jnp.sum(normal * start, axis=-1)
    return normal, offset


def _dot2(a, b):
    """`sum(a * b, axis=-1)` over a last axis of two, written out: XLA's CPU backend
    hands a reduction to a library call whose overhead, for a few thousand pairs, is
    many times the arithmetic."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]


def check_drawn_mesh(renderer: Renderer, vertices, faces) -> None:
    """Raise unless `renderer` draws the mesh of these rest `vertices` and `faces` (a
    rig's shape mesh): another mesh, even of the same size, would draw a wrong picture."""
    n, drawn = vertices.shape[0], renderer.rest.shape[0]
    if drawn != n:
        raise ValueError(f"renderer was built for a mesh of {drawn} vertices, but the rig's "
                         f"shape mesh has {n}: build it for this rig, "
                         "mvcjax.Renderer.build(rig, ...).")
    if any(isinstance(a, jax.core.Tracer) for a in (renderer.rest, renderer.faces, vertices)):
        return
    rest = np.asarray(renderer.rest, np.float64)
    # The renderer keeps the triangles in its draw order.
    ours, theirs = np.asarray(renderer.faces), np.asarray(faces)
    same = (np.array_equal(ours[np.lexsort(ours.T)], theirs[np.lexsort(theirs.T)])
            and np.allclose(rest, np.asarray(vertices, np.float64), rtol=1e-5,
                            atol=1e-5 * float(np.ptp(rest))))
    if not same:
        raise ValueError("renderer was built for another mesh of the same size as the rig's "
                         "shape mesh (its rest vertices or triangles differ): build it for "
                         "this rig, mvcjax.Renderer.build(rig, ...).")


def in_window(points, window) -> np.ndarray:
    """`(k,)` whether each of the `(k, 2)` points lies in `window` (edges included)."""
    points, window = np.asarray(points, np.float64), np.asarray(window, np.float64)
    return np.all((points >= window[:2]) & (points <= window[2:]), axis=1)


class Renderer(JittableModule):
    """Draws a triangle mesh at any vertex positions, textured by its rest positions.

    Build one with `Renderer.build` (from a rig or a mesh, a picture or a fill), then call
    it with deformed vertices: `renderer(vertices)` is a `(rows, cols, 4)` straight RGBA
    picture in [0, 1]. It is a pytree of arrays and static sizes: it jits (it is compiled
    on first call), vmaps over frames (`jax.vmap(renderer)(frames)`), and differentiates
    with respect to the vertices, the texture and the window. Numbers (vertices, window,
    texture values) never recompile it; the picture's size and the budget do.

    Attributes:
        faces: `(f, 3)` triangles, in draw order (deepest last, `draw_levels`).
        boundary: `(f, 3)` whether edge ab, bc, ca of each triangle is on the mesh's boundary.
        texture_points: `(n, 2)` each vertex's rest position in the texture, as fractional
            `(col, row)` pixel positions.
        texture: `(h, w, 4)` premultiplied RGBA texture.
        window: `(4,)` the plane's rectangle `(xmin, ymin, xmax, ymax)` the picture shows.
        background: `(4,)` straight RGBA drawn where no triangle is.
        rest: `(n, 2)` the rest vertices.
        level: `(f,)` each triangle's draw level (higher on top; within a level, the
            triangle covering the pixel most, then the later triangle).
        shape: `(rows, cols)` of the pictures drawn (static).
        budget: the most pixel tiles the triangles of one picture may cover (static).
        tile: the side of those tiles, in pixels (static).
        antialias: whether boundary edges are antialiased (static).
        see_through: whether the texture is partly transparent (`alpha=PictureAlpha()`), so
            that the layer beneath shows through it (static).
        programs: what the renderer compiled for itself; it goes with the renderer.
    """

    faces: Int[Array, "f 3"]
    boundary: Bool[Array, "f 3"]
    texture_points: Float[Array, "n 2"]
    texture: Float[Array, "h w 4"]
    window: Float[Array, " 4"]
    background: Float[Array, " 4"]
    rest: Float[Array, "n 2"]
    level: Int[Array, " f"]
    shape: tuple[int, int] = eqx.field(static=True)
    budget: int = eqx.field(static=True)
    tile: int = eqx.field(static=True)
    antialias: bool = eqx.field(static=True)
    see_through: bool = eqx.field(static=True)
    programs: Programs = programs_field()

    @classmethod
    def build(
        cls,
        mesh: Any,
        image: Any = None,
        *,
        size: Any = None,
        window: Any = None,
        image_window: Any = None,
        fill: Any = Checkerboard(),
        background: Any = (0.0, 0.0, 0.0, 0.0),
        depth: Any = None,
        antialias: bool = True,
        alpha: AbstractAlpha | str = MeshAlpha(),  # a string: refused, naming the object
        budget: Any = None,
        dtype: Any = None,
    ) -> Any:  # a Renderer (a CharacterRenderer for a Character)
        """A renderer for a mesh.

        Args:
            mesh: a `Rig` (its shape mesh is drawn), a `ShapeMesh`, or a pair
                `(vertices, faces)` of `(n, 2)` rest vertices and `(f, 3)` triangles. A
                `Character` with its layers as `image` gives a `CharacterRenderer`
                (`window`, `size`, `background`, `antialias`, `alpha`, `budget` and
                `dtype` apply to every part).
            image: the picture the rest mesh lies on: an array `(rows, cols)`,
                `(rows, cols, 3)` or `(rows, cols, 4)` (floats in [0, 1] or integers), or a
                file path. None draws the shape filled with `fill` instead.
            size: `(rows, cols)` of the output. Default: the picture's size when the
                window is the picture's, else 512 pixels along the window's longer side.
            window: the rectangle `(xmin, ymin, xmax, ymax)` of the plane to draw.
                Default: the picture's (`image_window`), or the rest mesh's bounding box
                with a 5% margin without a picture. `fit_window` makes one that holds a
                whole animation. The renderer can also be called with another window.
            image_window: the rectangle the picture covers at rest. Default
                `(-0.5, -0.5, cols - 0.5, rows - 0.5)`: pixel `(row, col)` of the picture
                is centred at `(col, rows - 1 - row)`, the convention of
                `Shape.from_image`, so that a shape made from a picture lies on it.
            fill: without a picture, `Checkerboard()` (in `mvcjax.advanced`: shows
                stretch and shear) or a colour `(r, g, b)` / `(r, g, b, a)` in [0, 1].
            background: straight RGBA `(r, g, b, a)` in [0, 1] where nothing is drawn;
                transparent by default.
            depth: draw order where parts overlap: `(n,)` a depth per rest vertex, larger
                on top (a triangle's depth is its vertices' mean; `depth_from_handles`
                spreads a depth per handle over a rig's mesh). Default `core_depth`: the
                distance along the rest mesh from the shape's core (the point deepest
                inside its outline), so that limbs, a tail or a head lie over the body
                they grow from. It is decided once, from the rest mesh: the same in every
                pose, so that an animation's overlaps never flicker.
            antialias: smooth (and differentiable) boundary edges; False draws hard edges
                for less work (no coverage to compute along the boundary).
            alpha: where the drawn shape's edge comes from (in `mvcjax.advanced`).
                `MeshAlpha()` (default): the mesh is the silhouette (as
                `Shape.from_image` traced it), antialiased by its coverage of each pixel;
                the picture is drawn opaque, its colours carried past its own soft edge
                so that no dark rim comes in. `PictureAlpha()`: the picture's alpha
                multiplies the coverage, for pictures that are partly transparent
                inside.
            budget: the most square pixel tiles (the tile's side is picked for the mesh)
                the triangles' bounding boxes may cover in one picture: the work grows
                with them. Default: sixteen times the rest mesh's in this window plus four
                pictures' worth. A pose that needs more (zooming far in, a part stretched
                many times over) raises an error saying so.
            dtype: float dtype of the computation; default the mesh's.
        """
        drawn_in_parts = getattr(mesh, "renderer", None)
        if drawn_in_parts is not None:  # a subject drawn in parts: a layered `Character`
            return drawn_in_parts(image, window=window, size=size, background=background,
                                  antialias=antialias, alpha=alpha, budget=budget, dtype=dtype)
        return cls._from_arrays(**cls._prepared(
            mesh, image, size=size, window=window, image_window=image_window, fill=fill,
            background=background, depth=depth, antialias=antialias, alpha=alpha,
            budget=budget, dtype=dtype))

    @classmethod
    def _prepared(cls, mesh, image, *, size, window, image_window, fill, background, depth,
                  antialias, alpha, budget, dtype) -> dict:
        """`build`'s arguments checked and turned into `_from_arrays`' host arrays (a
        layered character's renderer lays its parts' out as one mesh)."""
        vertices, faces = _mesh_of(mesh)
        if dtype is None:
            # The mesh's float type, as JAX has it (float64 only with x64 enabled).
            dtype = jax.dtypes.canonicalize_dtype(
                vertices.dtype if vertices.dtype in (np.float32, np.float64) else np.float32)
        dtype = np.dtype(dtype)
        if image is not None:
            picture = as_picture(image, "image")
            h, w = picture.shape[:2]
            image_window = (check_window(image_window, "image_window") if image_window is not None
                            else np.array([-0.5, -0.5, w - 0.5, h - 0.5]))
        else:
            if image_window is not None:
                raise ValueError("image_window places a picture; pass image= too, or drop it.")
            picture, image_window = fill_texture(fill, vertices)
        if window is None:
            window = (image_window if image is not None
                      else np.array(fit_window(vertices, size)))
            if size is None and image is not None:
                size = picture.shape[:2]
        window = check_window(window, "window")
        if size is None:
            extent = window[2:] - window[:2]
            pixel = extent.max() / 512
            size = tuple(int(max(1, round(e / pixel))) for e in extent[::-1])
        rows, cols = check_size(size)
        texture_points = to_pixels(np.asarray(vertices), np.asarray(image_window),
                                   *picture.shape[:2])
        if image is not None:
            _check_cover(picture, texture_points, np.asarray(vertices, np.float64),
                         np.asarray(faces))
            _warn_if_on_a_backdrop(picture, texture_points)
        order, level = draw_levels(depth, vertices, faces)
        faces = faces[order]
        alpha = checked_option("alpha", alpha, AbstractAlpha,
                               {"mesh": "mvcjax.advanced.MeshAlpha()",
                                "picture": "mvcjax.advanced.PictureAlpha()"})
        return dict(vertices=vertices, faces=faces, texture_points=texture_points,
                    texture=_texture(picture, alpha), window=window, size=(rows, cols),
                    level=to_device(level, np.int32), budget=budget, background=background,
                    antialias=antialias, see_through=alpha.see_through, dtype=dtype)

    @classmethod
    def _from_arrays(cls, vertices, faces, texture_points, texture, window,
                     size: tuple[int, int], *, level, budget, background, antialias: bool,
                     see_through: bool, dtype) -> Renderer:
        """The renderer of a mesh whose texture positions and premultiplied texture are
        given as host arrays (`build` checks and prepares them from its arguments)."""
        rows, cols = size
        boundary = on_boundary(faces)
        programs = Programs()
        tile, rest = _tiling(programs, vertices, faces, boundary, window, rows, cols, antialias)
        if budget is None:
            budget = _default_budget(rest, rows, cols, tile)
        budget = whole_number(budget, "budget")
        background = np.asarray(background, np.float64)
        if background.shape == (3,):
            background = np.append(background, 1.0)
        if background.shape != (4,) or not np.all((background >= 0) & (background <= 1)):
            raise ValueError(f"background must be (r, g, b) or (r, g, b, a) in [0, 1], got "
                             f"{background.tolist()}.")
        return cls(
            faces=to_device(faces, np.int32),
            boundary=to_device(boundary, bool),
            texture_points=to_device(texture_points, dtype),
            texture=to_device(texture, dtype),
            window=to_device(window, dtype),
            background=to_device(background, dtype),
            rest=to_device(vertices, dtype),
            level=level,
            shape=(rows, cols),
            budget=int(budget),
            tile=tile,
            antialias=bool(antialias),
            see_through=bool(see_through),
            programs=programs,
        )

    @classmethod
    def stack(cls, renderers: Any, *, like: Any = None) -> Renderer:
        """Renderers of different meshes and pictures as one batched renderer, for
        `jax.vmap`: `jax.vmap(lambda r, v: r(v))(stack, vertices)` draws pose `i` with
        renderer `i`, and a second `vmap` over frames, `jax.vmap(lambda r, f:
        jax.vmap(r)(f))(stack, frames)` with frames `(len(renderers), frames, n, 2)`,
        draws every character's frames, picture after picture, in one program.

        The meshes are padded to the largest (triangles without area, drawn nowhere;
        vertices repeating the first), the pictures to the largest (edge pixels
        repeated): pose `i` has the rows of `renderers[i]`'s vertices first, then any
        values (`Rig.stack`'s output fits). All must draw pictures of one size, with
        the same `antialias`, `alpha` and dtype.

        Args:
            renderers: a list of renderers (`Renderer.build`).
            like: another stack of renderers, whose sizes (and tiles) these are padded
                to, so that the stack reuses the programs compiled for it (as
                `Rig.stack`'s `like`).
        """
        return stack_renderers(renderers, like)

    @property
    def mesh(self) -> Renderer:
        """The renderer of the whole mesh as one: this one (a character's renderer draws
        its parts' meshes joined with `mesh`)."""
        return self

    def __call__(
        self, vertices: Float[ArrayLike, "n 2"], window: Any = None
    ) -> Float[Array, "rows cols 4"]:
        """The picture of the mesh at `vertices`.

        Args:
            vertices: `(n, 2)` vertex positions (deformed), in the plane's coordinates.
            window: `(4,)` another rectangle `(xmin, ymin, xmax, ymax)` to draw (numbers:
                no recompilation); default the renderer's. `GrownWindow()` (in
                `mvcjax.advanced`): the renderer's, grown (keeping square pixels) to hold
                the pose with a 5% margin, for a pose that leaves the picture's frame.

        Returns:
            `(rows, cols, 4)` straight (not premultiplied) RGBA in [0, 1].

        A pose drawn in the renderer's own window (`window=None`) that reaches outside
        it is cut off, and a warning says so: at once for a plain call, when the program
        runs under `jax.jit` and `jax.vmap` (each pose of a batch counted).
        """
        n = self.texture_points.shape[0]
        if not hasattr(vertices, "shape") or tuple(vertices.shape) != (n, 2):
            shape = getattr(vertices, "shape", None)
            raise ValueError(f"vertices must be ({n}, 2), one (x, y) per vertex of the mesh "
                             f"the renderer was built for, got shape {shape}; for many frames "
                             "use renderer.frames(frames) (or jax.vmap(renderer)).")
        vertices = jnp.asarray(vertices, self.texture.dtype)
        refuse_string("window", window, {"grow": "mvcjax.advanced.GrownWindow()"})
        if isinstance(window, str):
            raise TypeError(f"window must be (xmin, ymin, xmax, ymax), None or "
                            f"mvcjax.advanced.GrownWindow(), got {window!r}.")
        if isinstance(window, GrownWindow):
            window = window(self.window, vertices, self.shape)
        if window is None:
            window = self.window
            _warn_when_cut_off(vertices, window)
        window = jnp.asarray(window, self.texture.dtype)
        # Under jax.vmap over frames: one frame after another (`_draw_frames`).
        return with_batching_rule(_draw, _draw_frames)(self, vertices, window)

    def frames(self, vertices: Any, *, levels: Any = None, chunk: Any = None,
               progress: Any = None, devices: Any = None) -> np.ndarray:
        """Many pictures, ready to write: `(frames, rows, cols, 4)` straight RGBA as
        `uint8` numpy, drawn `chunk` frames at a time by one compiled program.

        Args:
            vertices: `(frames, n, 2)` vertex positions, e.g. from `deform_frames`.
            levels: `(frames, f)` integers, each triangle's draw level at each frame
                (in `faces`' order, higher on top, at most `max_level`): a draw order that
                changes from frame to frame, such as a limb passing in front of the body
                and behind it. Default: the renderer's `level` at every frame.
            chunk: frames per compiled batch. Default: as many as fit in about 256 MB
                of working memory (at least 1, at most 64).
            progress: a progress bar (tqdm): True, False, or None for one on a terminal
                when there are more than 10 frames.
            devices: the devices to draw on (default: one, the default device;
                `jax.local_devices()` for all of this process's): consecutive chunks go
                to the devices in turn and are drawn at the same time.
        """
        n = self.texture_points.shape[0]
        frames = np.asarray(vertices)
        if frames.ndim != 3 or frames.shape[1:] != (n, 2):
            raise ValueError(f"vertices must be (frames, {n}, 2), a pose of the mesh's {n} "
                             f"vertices per frame, got shape {frames.shape}.")
        if chunk is None:
            rows, cols = self.shape
            # Bytes a frame holds while drawn: a chunk of candidates' indices, keys and
            # distances, and each pixel's two layers of shading.
            working = 40 * _CHUNK * self.tile**2 + 300 * rows * cols
            chunk = int(np.clip(2**28 // working, 1, 64))
        chunk = whole_number(chunk, "chunk", what=" of frames")
        devices = as_devices(devices)
        # Each device draws with its own copy of the renderer: JAX then runs a chunk on
        # every device at once, each program where its arrays are.
        copies = [self] if devices is None else [jax.device_put(self, d) for d in devices]
        self._warn_if_clipped(frames)
        levels = self._checked_levels(levels, len(frames))
        out = np.empty((len(frames), *self.shape, 4), np.uint8)
        dtype = self.texture.dtype
        refuse_over_budget(self, [_padded(frames[begin:begin + chunk], chunk).astype(dtype)
                                  for begin in range(0, len(frames), chunk)])
        with progress_bar(len(frames), progress, "rendering") as bar:
            for first in range(0, len(frames), chunk * len(copies)):
                drawn = []
                for renderer, begin in zip(copies, range(first, len(frames), chunk)):
                    part = _padded(frames[begin:begin + chunk], chunk).astype(dtype)
                    level = None if levels is None else _padded(levels[begin:begin + chunk],
                                                               chunk)
                    part, level = jax.device_put((part, level), None if devices is None
                                                 else renderer.texture.sharding)
                    with checked_on_entry():  # the budget, above
                        drawn.append((begin, _draw_batch(renderer, part, level)))
                for begin, pictures in drawn:
                    done = min(chunk, len(frames) - begin)
                    # Cut on the host: an eager slice compiles a program for every size.
                    out[begin:begin + done] = to_uint8(np.asarray(pictures)[:done])
                    bar.update(done)
        return out

    def leaves_window(self, frames: Float[ArrayLike, "frames n 2"]) -> np.ndarray:
        """`(frames,)` whether each frame reaches outside the renderer's window (where it
        would be cut off)."""
        frames = np.asarray(frames, np.float64)
        xmin, ymin, xmax, ymax = np.asarray(self.window, np.float64)
        with np.errstate(invalid="ignore"):
            return ((frames[..., 0] < xmin) | (frames[..., 0] > xmax)
                    | (frames[..., 1] < ymin) | (frames[..., 1] > ymax)).any(axis=-1)

    @property
    def max_level(self) -> int:
        """The highest draw level a triangle can have (`levels` of `frames`)."""
        return key_layout(self.faces.shape[0])[1] - 1

    def _checked_levels(self, levels, frames: int) -> np.ndarray | None:
        if levels is None:
            return None
        array = np.asarray(levels)
        shape = (frames, self.faces.shape[0])
        if (array.shape != shape or not np.issubdtype(array.dtype, np.integer)
                or array.min() < 0 or array.max() > self.max_level):
            raise ValueError(f"levels must be {shape} integers from 0 to {self.max_level}, "
                             f"a draw level per triangle per frame, got "
                             f"{array.dtype} {array.shape}.")
        return array.astype(np.int32)

    def _warn_if_clipped(self, frames: np.ndarray) -> None:
        """Say once, for a whole animation, that part of it leaves the window (and is
        cut off in every picture that shows it), and how to keep it all."""
        out = self.leaves_window(frames)
        if out.any():
            xmin, ymin, xmax, ymax = np.asarray(self.window, np.float64)
            first = int(np.argmax(out))
            warnings.warn(
                f"{int(out.sum())} of {len(frames)} frames (the first: frame {first}) reach "
                f"outside the renderer's window ({xmin:g}, {ymin:g}, {xmax:g}, {ymax:g}) and "
                "are cut off there. To keep them whole, build the renderer with "
                "window=mvcjax.fit_window(frames, size) (one window for the whole "
                "animation), or draw single poses with renderer(vertices, "
                "window=mvcjax.advanced.GrownWindow()).",
                stacklevel=3)


def _draw_each(renderer: Renderer, vertices, window):
    """Pictures of `(f, n, 2)` poses in `(f, 4)` windows (or all in one `(4,)` window),
    one after another."""
    if window.ndim == 1:
        # One window for all: closed over, as a loop over the frames would have it.
        return jax.lax.map(lambda v: _draw(renderer, v, window), vertices)
    return jax.lax.map(lambda vw: _draw(renderer, *vw), (vertices, window))


def _draw_each_batched(size: int, in_batched, renderer: Renderer, vertices, window):
    # A batch of sequences (a stack of renderers, each with its frames): one sequence
    # after another, each drawn frame after frame.
    return one_after_another(_draw_each, in_batched, (renderer, vertices, window)), True


_draw_sequence = with_batching_rule(_draw_each, _draw_each_batched)


def _draw_frames(frames: int, in_batched, renderer: Renderer, vertices, window):
    """`jax.vmap(_draw)`: one frame after another inside one program. JAX's batching
    would fuse the batch's shading into larger loops that redo table lookups
    (`benchmarks/vmap_rules.py` times both).

    With one renderer, the frames go to `_draw_sequence`, whose own rule takes over
    when an outer `jax.vmap` maps over a stack of renderers (`Renderer.stack`): stacks
    of characters by frames are then drawn picture by picture too. A batched renderer
    (a stack, or a draw order per frame) is looped over with the poses."""
    if any(jax.tree.leaves(in_batched[0])):
        return one_after_another(_draw, in_batched, (renderer, vertices, window)), True
    _, vertices_batched, _ = in_batched
    if not vertices_batched:
        vertices = jnp.broadcast_to(vertices, (frames, *vertices.shape))
    return _draw_sequence(renderer, vertices, window), True


@compiled_by()
def _draw_batch(renderer: Renderer, frames, levels):
    # In its window, given: `frames` warned of what it cuts off, once for all frames.
    if levels is None:
        return jax.vmap(lambda v: renderer(v, renderer.window))(frames)
    return jax.vmap(lambda v, level: eqx.tree_at(lambda r: r.level, renderer, level)(
        v, renderer.window))(frames, levels)


def _padded(part: np.ndarray, size: int) -> np.ndarray:
    """`part`, its last row repeated up to `size` rows (one compiled size for every
    batch)."""
    return np.concatenate([part, np.repeat(part[-1:], size - len(part), 0)])


def _cut_off(outside, window) -> None:
    """Warn that `outside` poses (a count, or flags) leave `window`."""
    count = int(np.sum(outside))
    if count:
        xmin, ymin, xmax, ymax = np.asarray(window, np.float64).reshape(-1, 4)[0]
        one = count == 1
        warnings.warn(
            f"{count} pose{'' if one else 's'} drawn reach{'es' if one else ''} outside the "
            f"renderer's window ({xmin:g}, {ymin:g}, {xmax:g}, {ymax:g}) and "
            f"{'is' if one else 'are'} cut off there. To keep {'it' if one else 'them'} "
            "whole, draw with renderer(vertices, window=mvcjax.advanced.GrownWindow()), "
            "or build the renderer with window=mvcjax.fit_window(frames, size); a window "
            "passed explicitly draws exactly it, without this warning.", stacklevel=2)


def _warn_when_cut_off(vertices, window) -> None:
    """`_cut_off` for a pose drawn in the renderer's own window: now for concrete
    vertices, when the program runs for traced ones (under `jax.jit`, `jax.vmap`)."""
    if isinstance(vertices, jax.core.Tracer) or isinstance(window, jax.core.Tracer):
        lower, upper = window[:2], window[2:]
        outside = jnp.any((vertices < lower) | (vertices > upper))
        jax.debug.callback(_cut_off, outside, window)
        return
    points, (xmin, ymin, xmax, ymax) = np.asarray(vertices), np.asarray(window)
    with np.errstate(invalid="ignore"):
        _cut_off(np.any((points < (xmin, ymin)) | (points > (xmax, ymax))), window)


def _mesh_of(mesh) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(mesh, AbstractRig):  # a rig, or a character's parts joined
        mesh = mesh.shape_mesh
    if isinstance(mesh, ShapeMesh):
        return np.asarray(mesh.vertices), np.asarray(mesh.faces)
    if isinstance(mesh, (tuple, list)) and len(mesh) == 2:
        vertices = as_points(mesh[0], "mesh vertices")
        faces = np.asarray(mesh[1])
        if faces.dtype.kind not in "iu" or faces.ndim != 2 or faces.shape[1] != 3:
            raise ValueError(f"mesh faces must be (f, 3) integer vertex indices, got "
                             f"{kind_of(faces)} of shape {faces.shape}.")
        if len(faces) == 0 or faces.min() < 0 or faces.max() >= len(vertices):
            raise ValueError(f"mesh faces must index the {len(vertices)} vertices (0 to "
                             f"{len(vertices) - 1}) and be at least one triangle.")
        return np.asarray(mesh[0]), faces.astype(np.int64)
    raise TypeError(f"mesh must be a Rig, a ShapeMesh or a pair (vertices, faces), got "
                    f"{type(mesh).__name__}.")


def _texture(picture: np.ndarray, alpha: AbstractAlpha) -> np.ndarray:
    """The premultiplied texture: the picture's own alpha, or opaque with the colours of
    its visible pixels carried to the transparent ones nearest to them."""
    texture = picture.astype(np.float64)
    if alpha.see_through:
        texture[..., :3] *= texture[..., 3:]
        return texture
    seen = texture[..., 3] > 1 / 255
    if seen.any() and not seen.all():
        import scipy.ndimage

        _, nearest = scipy.ndimage.distance_transform_edt(~seen, return_indices=True)
        texture[..., :3] = texture[nearest[0], nearest[1], :3]
    texture[..., 3] = 1.0
    return texture


# The least share of the rest mesh's area that must lie on the picture's visible pixels
# for the picture to be the mesh's (a mesh traced from it covers nearly all of it).
_LEAST_COVER = 0.5


def _check_cover(picture: np.ndarray, texture_points: np.ndarray, vertices: np.ndarray,
                 faces: np.ndarray) -> None:
    """Refuse a picture whose visible pixels the rest mesh mostly misses: a sprite that
    is not the one the shape was made from, or one placed elsewhere."""
    seen = picture[..., 3] > 1 / 255
    if seen.all():
        return  # visible everywhere (an opaque picture): nothing to compare with
    rows, cols = seen.shape
    centre = np.rint(texture_points[faces].mean(axis=1)).astype(np.int64)  # (col, row)
    inside = ((centre[:, 0] >= 0) & (centre[:, 0] < cols) & (centre[:, 1] >= 0)
              & (centre[:, 1] < rows))
    on = np.zeros(len(faces), bool)
    on[inside] = seen[centre[inside, 1], centre[inside, 0]]
    corners = vertices[faces]
    ab, ac = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    area = np.abs(ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0])
    share = float(area[on].sum() / max(area.sum(), np.finfo(np.float64).tiny))
    if share < _LEAST_COVER:
        raise ValueError(
            f"image: only {share:.0%} of the mesh's area lies on the picture's visible pixels "
            "(alpha above 0): it is not the picture the shape was made from, or it lies "
            "elsewhere. Build the shape from this picture (mvcjax.Shape.from_image), or "
            "place the picture with image_window=(xmin, ymin, xmax, ymax); a picture "
            "meant to show through a different outline can be made opaque (alpha 1).")


def fill_texture(fill, vertices):
    """A texture and its window for a shape drawn without a picture."""
    window = np.array(fit_window(vertices, margin=0.0))
    if isinstance(fill, Checkerboard):
        return fill.picture(), window
    refuse_string("fill", fill, {"checkerboard": "mvcjax.advanced.Checkerboard()"})
    colour = np.asarray(fill, np.float32) if not isinstance(fill, str) else None
    if colour is None or colour.shape not in ((3,), (4,)) or not np.all(
            (colour >= 0) & (colour <= 1)):
        raise ValueError(f"fill must be mvcjax.advanced.Checkerboard() or a colour (r, g, b) "
                         f"or (r, g, b, a) in [0, 1], got {fill!r}.")
    return np.append(colour, 1.0)[:4].reshape(1, 1, 4).astype(np.float32), window


def draw_levels(depth, vertices: np.ndarray, faces: np.ndarray,
                levels: int = _DEPTH_LEVELS) -> tuple[np.ndarray, np.ndarray]:
    """The triangles in draw order and their draw levels, from a depth per vertex
    (`depth=` of `Renderer.build`; None for `core_depth`): `(order, level)`, `order` the
    triangles sorted by depth (a triangle's depth is its vertices' mean) and `level` each
    sorted triangle's level, in at most `levels` bands of depth.

    Within a band, the triangle covering a pixel most is drawn, so that neighbours along
    the outline antialias it as one edge; across bands (and between triangles covering
    the pixel wholly, the later in `order`) the deeper one is on top."""
    if depth is None:
        depth = core_depth(vertices, faces)
    depth = np.asarray(depth, np.float64)
    if depth.shape != (len(vertices),) or not np.all(np.isfinite(depth)):
        raise ValueError(f"depth must be {len(vertices)} finite numbers, one per rest "
                         f"vertex of the mesh, got shape {depth.shape}.")
    levels = min(levels, key_layout(len(faces))[1])
    face_depth = depth[faces].mean(axis=1)
    order = np.argsort(face_depth, kind="stable")
    # Ranks, not values: equal depths share a band, and no band is left empty.
    distinct, inverse = np.unique(face_depth[order], return_inverse=True)
    level = inverse.astype(np.int64) * levels // max(len(distinct), 1)
    return order, level.astype(np.int32)


def _edge_graph(vertices, faces):
    """The mesh's edges as a sparse graph weighted by their rest lengths."""
    vertices = np.asarray(vertices, np.float64)
    n = len(vertices)
    pairs = edges(np.asarray(faces))
    length = np.hypot(*(vertices[pairs[:, 0]] - vertices[pairs[:, 1]]).T)
    return scipy.sparse.coo_matrix((length, (pairs[:, 0], pairs[:, 1])), shape=(n, n)).tocsr()


def core_depth(vertices: Float[ArrayLike, "n 2"],
               faces: Int[ArrayLike, "f 3"]) -> Float[np.ndarray, " n"]:
    """The default draw depth of a mesh's vertices: the distance along the rest mesh from
    the shape's core, the vertex farthest from the outline (one per piece of a mesh in
    several pieces). Parts farther out along the shape (limbs, a tail, a head) are drawn
    over those nearer its middle, whatever the pose.

    Args:
        vertices: `(n, 2)` rest vertices.
        faces: `(f, 3)` triangles.
    """
    faces = np.asarray(faces)
    graph = _edge_graph(vertices, faces)
    inward = scipy.sparse.csgraph.dijkstra(graph, directed=False, min_only=True,
                                           indices=np.unique(boundary_edges(faces)))
    _, piece = scipy.sparse.csgraph.connected_components(graph, directed=False)
    # The deepest vertex of each piece (the first of equals), by a sort on (piece, depth).
    by_piece = np.lexsort((-inward, piece))
    cores = by_piece[np.r_[0, np.flatnonzero(np.diff(piece[by_piece])) + 1]]
    depth = scipy.sparse.csgraph.dijkstra(graph, directed=False, min_only=True, indices=cores)
    # Vertices in no triangle are in no piece with a boundary; they are never drawn.
    return np.where(np.isfinite(depth), depth, 0.0)


def key_layout(faces: int) -> tuple[int, int]:
    """A candidate's key packs, from the high bits down, the triangle's draw level, its
    coverage of the pixel (in `_COVERAGE_BITS` bits) and the triangle, in an int32: the
    triangle's bits, and how many levels fit above (less one: the raster's second layer
    raises candidates a level)."""
    face_bits = max(int(faces - 1).bit_length(), 1)
    return face_bits, 2 ** (31 - face_bits - _COVERAGE_BITS) - 1


def _tiles(tri, fringe, rows: int, cols: int, tile: int):
    """The `tile x tile` pixel tiles that cover each triangle's bounding box: first
    pixel `(col, row)`, last pixel, and the number of tiles across and down."""
    first, extent = _bounding_boxes(tri, fringe, rows, cols)
    across = (extent + tile - 1) // tile
    return first, first + extent - 1, across


def _tile_counts(programs: Programs, vertices, faces, boundary, window, rows, cols,
                 antialias) -> dict[int, int]:
    """How many tiles of each side in `_TILES` the rest mesh's triangles cover."""
    across = programs.run(_tiles_across, (
        np.asarray(vertices[faces], np.float32), np.asarray(boundary),
        np.asarray(window, np.float32), rows, cols, antialias), {})
    return {tile: int(np.sum(np.prod(np.asarray(a, np.int64), axis=1)))
            for tile, a in zip(_TILES, across)}


def _tiling(programs: Programs, vertices, faces, boundary, window, rows, cols,
            antialias) -> tuple[int, int]:
    """The tile side with the fewest candidate pixels for the rest mesh, and how many
    tiles that side needs."""
    counts = _tile_counts(programs, vertices, faces, boundary, window, rows, cols, antialias)
    # A tile is charged as a dozen candidate pixels (its triangle's row, the slot's
    # arithmetic), about its cost against a pixel's.
    tile = min(_TILES, key=lambda t: counts[t] * (t * t + 12))
    return tile, counts[tile]


def _default_budget(rest: int, rows: int, cols: int, tile: int) -> int:
    """Sixteen times the rest mesh's tiles, plus four pictures' worth."""
    return 16 * rest + 4 * -(-rows // tile) * -(-cols // tile)


def stack_tiling(renderers) -> tuple[int, int]:
    """One tile side for renderers drawn as a stack (`Renderer.stack`): the fewest
    candidate pixels over all their rest meshes; and a budget that holds each (its
    own, where it drew with that side, or the default for that side)."""
    rows, cols = renderers[0].shape
    programs = renderers[0].programs
    counts = [_tile_counts(programs, np.asarray(r.rest), np.asarray(r.faces), r.boundary,
                           r.window, rows, cols, r.antialias) for r in renderers]
    tile = min(_TILES, key=lambda t: sum(c[t] for c in counts) * (t * t + 12))
    budget = max(max(r.budget if r.tile == tile else 0, _default_budget(c[tile], rows, cols,
                                                                           tile))
                 for r, c in zip(renderers, counts))
    return tile, budget


def _tiles_across(corners, boundary, window, rows: int, cols: int, antialias: bool):
    # One compiled call at build time instead of dozens of eager ones.
    tri = to_pixels(corners, window, rows, cols)
    fringe = _widest(_fringes(boundary, antialias))
    return [_tiles(tri, fringe, rows, cols, tile)[2] for tile in _TILES]


def _fringes(boundary, antialias: bool):
    """How far (in pixels) outside each edge a pixel centre still counts as a candidate."""
    if antialias:
        return jnp.where(boundary, _FRINGE + _EPS, _EPS)
    return jnp.full(boundary.shape, _EPS)


def _widest(fringe):
    """Each triangle's widest fringe of its three edges (written out as in `_dot2`)."""
    return jnp.maximum(jnp.maximum(fringe[:, 0], fringe[:, 1]), fringe[:, 2])


def _face_table(tri, texture_tri, boundary):
    """Per triangle, what shading a pixel needs, relative to the triangle's first vertex
    `a` (an affine map built from absolute pixel positions would cancel large terms, and
    float32 would lose hundredths of a texel at 1024 pixels): the linear map from
    `p - a` to the texture position (2 x 2), `a`, the texture position at `a`, and for
    each boundary edge its inward normal and the distance of `a` from it (inner edges: a
    zero normal and a far distance, so that they never fade)."""
    normal, _ = _edge_distances(tri)
    a = tri[:, 0]
    relative = tri - a[:, None]  # (f, 3, 2), its first row zero
    # Barycentric weight of vertex k: distance to the opposite edge over k's height,
    # with the opposite edge running from vertex k + 1.
    opposite = jnp.array([1, 2, 0])
    n_opp = normal[:, opposite]
    start = relative[:, [1, 2, 0]]  # start of the edge opposite vertex k
    height = _dot2(n_opp, relative - start)
    height = jnp.where(jnp.abs(height) > 1e-12, height, 1.0)
    linear = n_opp / height[..., None]  # weight_k = linear_k . (p - a) + constant_k
    # (f, 2 texture, 2 pixel), the sum over the corners written out as in `_dot2`.
    uv_linear = sum(texture_tri[:, k, :, None] * linear[:, k, None, :] for k in range(3))
    far = jnp.asarray(1e6, tri.dtype)
    edge_normal = jnp.where(boundary[..., None], normal, 0.0)
    # Distance of `a` from edge k (starting at vertex k), inside positive.
    edge_offset = jnp.where(boundary, -_dot2(normal, relative), far)
    edges = jnp.concatenate([edge_normal, edge_offset[..., None]], axis=-1)  # (f, 3, 3)
    return jnp.concatenate([uv_linear.reshape(-1, 4), a, texture_tri[:, 0],
                            edges.reshape(-1, 9)], axis=1)


def _raster(renderer: Renderer, tri, rows: int, cols: int):
    """Which triangle each pixel shows: the key (`(level, coverage, triangle)`, -1 for
    none) of the top candidate of each pixel, and of the top candidate that covers the
    pixel's centre and all of the pixel (the layer beneath a partly covering one).

    The candidates come in chunks of `_CHUNK` tiles, in a loop that stops after the last
    tile the pose needs: the work follows the pose, not a worst case."""
    face_bits, _ = key_layout(renderer.faces.shape[0])
    table, end, total = _tile_table(renderer, tri, rows, cols)
    pixels = rows * cols
    empty = jnp.full((pixels + 1, 2) if renderer.antialias else pixels + 1, -1, jnp.int32)
    chunks = (total + _CHUNK - 1) // _CHUNK
    candidates = functools.partial(_chunk_candidates, renderer, table, end, total, face_bits,
                                   cols, pixels)
    layers = jax.lax.fori_loop(0, chunks, candidates, empty)
    if not renderer.antialias:
        return face_bits, [layers[:-1]]
    return face_bits, _front_and_back(layers, face_bits)


def _tile_table(renderer: Renderer, tri, rows: int, cols: int):
    """Everything a pixel tile needs from its triangle, in one row per triangle (gathered
    once per tile: a row costs about what one of its numbers does alone); the running
    count of tiles at each triangle's end, and the tiles in all (refused past the
    renderer's budget)."""
    fringe = _fringes(renderer.boundary, renderer.antialias).astype(tri.dtype)
    first, last, across = _tiles(tri, _widest(fringe), rows, cols, renderer.tile)
    tiles = across[:, 0] * across[:, 1]
    end = jnp.cumsum(tiles)
    total = end[-1]
    tri = check_when_run(tri, total.astype(jnp.float32) > renderer.budget,
                         f"the pose {_OVER_BUDGET}")
    normal, offset = _edge_distances(tri)
    boundary = renderer.boundary & renderer.antialias
    far = jnp.asarray(1e6, tri.dtype)
    table = jnp.concatenate([
        normal.reshape(-1, 6),
        offset + fringe,  # inside, fringe included
        offset + _EPS,  # inside, strictly
        jnp.where(boundary, offset, far),  # distance to the boundary edges, for coverage
        first.astype(tri.dtype), last.astype(tri.dtype),
        across[:, :1].astype(tri.dtype), (end - tiles)[:, None].astype(tri.dtype),
    ], axis=1)
    return table, end, total


# What a pose past the renderer's budget is told.
_OVER_BUDGET = ("needs more pixel tiles than the renderer's budget (a zoomed-in window or a "
                "strongly stretched mesh): it would take long to draw. Build the Renderer "
                "with a larger budget= if that is meant, or draw a wider window.")


@compiled_by()
def _tiles_needed(renderer: Renderer, frames):
    """`(frames,)` the pixel tiles each pose needs in the renderer's window."""
    rows, cols = renderer.shape

    def needed(vertices):
        tri = to_pixels(vertices, renderer.window, rows, cols)[renderer.faces]
        return _tile_table(renderer, tri, rows, cols)[2]  # the rest is left unused

    with checked_on_entry():  # what this program computes is the check
        return jax.vmap(needed)(frames)


def refuse_over_budget(renderer: Renderer, chunks: list) -> None:
    """Refuse, on the host, poses (`chunks` of frames, `(chunk, n, 2)` each) that need
    more pixel tiles than `renderer`'s budget: drawn within `checked_on_entry`, they are
    not checked again as they are drawn."""
    counts = [_tiles_needed(renderer, c) for c in chunks]  # all dispatched, then read
    needed = np.concatenate([np.asarray(c) for c in counts])
    over = np.flatnonzero(needed > renderer.budget)
    if len(over):
        raise ValueError(f"frame {over[0]} {_OVER_BUDGET}")


def _chunk_candidates(renderer: Renderer, table, end, total, face_bits: int, cols: int,
                      pixels: int, index, layers):
    """`layers` with the candidate pixels of the `index`-th chunk of `_CHUNK` tiles
    scattered in: each pixel keeps its top key (and, antialiased, its top whole one)."""
    count, tile = renderer.faces.shape[0], renderer.tile
    slot = index * _CHUNK + jnp.arange(_CHUNK, dtype=jnp.int32)
    face = jnp.clip(jnp.searchsorted(end, slot, side="right"), 0, count - 1)
    data = table[face]
    first_t = data[:, 15:17].astype(jnp.int32)
    width = jnp.maximum(data[:, 19].astype(jnp.int32), 1)
    local = slot - data[:, 20].astype(jnp.int32)
    # The tile's own numbers, computed once per tile into memory: fused into each
    # candidate pixel's arithmetic, XLA's CPU backend would redo the tile's lookups
    # and divisions for each of its pixels, in each of the candidates' consumers.
    corner = jnp.stack([first_t[:, 0] + (local % width) * tile,
                        first_t[:, 1] + (local // width) * tile,
                        jnp.where(slot < total, data[:, 17].astype(jnp.int32), -1),
                        data[:, 18].astype(jnp.int32),
                        renderer.level[face] * 2**_COVERAGE_BITS * 2**face_bits + face], axis=1)
    data, corner = materialise((data, corner))
    n = data[:, :6].reshape(-1, 3, 2)
    o_in, o_strict, o_cover = data[:, 6:9], data[:, 9:12], data[:, 12:15]
    offsets = jnp.arange(tile, dtype=jnp.int32)
    col = corner[:, 0, None, None] + offsets[None, None, :]
    row = corner[:, 1, None, None] + offsets[None, :, None]
    valid = (col <= corner[:, 2, None, None]) & (row <= corner[:, 3, None, None])
    pixel = jnp.where(valid, row * cols + col, pixels)
    x, y = col.astype(table.dtype), row.astype(table.dtype)
    along = [n[:, k, 0, None, None] * x + n[:, k, 1, None, None] * y for k in range(3)]
    inside, solid = valid, valid
    for k in range(3):
        inside = inside & (along[k] + o_in[:, k, None, None] >= 0)
        solid = solid & (along[k] + o_strict[:, k, None, None] >= 0)
    # Where several triangles of one level reach a pixel, the one covering it most
    # wins: the coverage is then the same whichever of two neighbours is drawn.
    cover = [along[k] + o_cover[:, k, None, None] for k in range(3)]
    coverage = jnp.clip(0.5 + jnp.minimum(jnp.minimum(cover[0], cover[1]), cover[2]),
                        0.0, 1.0)
    steps = jnp.round(coverage * (2**_COVERAGE_BITS - 1)).astype(jnp.int32)
    key = corner[:, 4, None, None] + steps * 2**face_bits
    front = jnp.where(inside, key, -1)
    if not renderer.antialias:
        return layers.at[pixel].max(front, mode="drop")
    # The second layer: the top candidate covering the pixel's centre and the whole
    # pixel, which shows under a partly covering front triangle (its edge over another
    # part, or over a fold of its own part); a partial front never is one, even where it
    # covers the centre, so that what lies beneath shows there too. Where no candidate
    # covers the whole pixel, the one covering it most whatever its level, which draws
    # the outline there. Whole candidates rank one level up, above every partial one.
    whole = solid & (steps == 2**_COVERAGE_BITS - 1)
    plain = steps * 2**face_bits + jnp.bitwise_and(corner[:, 4, None, None],
                                                   2**face_bits - 1)
    second = jnp.where(whole, key + 2**(_COVERAGE_BITS + face_bits),
                       jnp.where(inside, plain, -1))
    # Both layers in one scatter, a pair of keys per pixel.
    return layers.at[pixel].max(jnp.stack([front, second], axis=-1), mode="drop")


def _front_and_back(layers, face_bits: int) -> list:
    """The pixels' front and back keys from the two scattered layers (`_raster`)."""
    front, beneath = layers[:, 0], layers[:, 1]
    up = 2**(_COVERAGE_BITS + face_bits)
    back = jnp.where(beneath >= up, beneath - up, -1)
    # Where the front triangle covers the whole pixel, nothing shows beneath it. Where it
    # covers part of the pixel and nothing lies wholly beneath, the pixel is on the
    # outline: the triangle covering most of it draws it, as if all were one level (two
    # neighbours of different levels along the outline then draw one edge).
    coverage = 2**_COVERAGE_BITS - 1
    partial = jnp.bitwise_and(front >> face_bits, coverage) < coverage
    front = jnp.where(partial & (back < 0), beneath, front)
    back = jnp.where(back == front, -1, back)
    return [front[:-1], back[:-1]]


@compiled_by()
def _draw(renderer: Renderer, vertices, window):
    rows, cols = renderer.shape
    faces = renderer.faces
    points = to_pixels(vertices, window, rows, cols)
    tri = points[faces]
    # Which triangle a pixel shows is decided without gradients; they flow through the
    # shading (texture position and edge coverage) below.
    face_bits, layers = _raster(renderer, jax.lax.stop_gradient(tri), rows, cols)
    table = materialise(_face_table(tri, renderer.texture_points[faces], renderer.boundary))
    background = _premultiply(renderer.background)
    under = background
    front = layers[0]
    if renderer.antialias:
        # The layer beneath shows only where the front triangle covers a pixel partly
        # (the coverage in its key), or everywhere a picture is partly transparent.
        partial = jnp.bitwise_and(front >> face_bits, 2**_COVERAGE_BITS - 1) \
            < 2**_COVERAGE_BITS - 1
        if renderer.see_through:
            partial = jnp.ones_like(partial)
        beneath = jnp.where(partial, layers[1], -1)
        under = _shade_where(renderer, table, beneath, face_bits, cols, background,
                             background)
    # The front layer is the last: its pixels are written straight (not premultiplied)
    # into a picture of the straight background, so that no pass over the whole picture
    # is left to do.
    colour = _shade_where(renderer, table, front, face_bits, cols, under,
                          _straight(background), finish=_straight)
    return colour.reshape(rows, cols, 4)


def _straight(colour):
    """Premultiplied RGBA (`(..., 4)`) made straight, clipped to [0, 1]."""
    alpha = colour[..., 3:]
    straight = jnp.where(jnp.arange(4) < 3, colour / jnp.where(alpha > 0, alpha, 1.0), colour)
    return jnp.clip(straight, 0.0, 1.0)


def _shade_where(renderer: Renderer, table, layer, face_bits: int, cols: int, under, fill,
                 finish=None):
    """A picture (`(pixels, 4)`) of the colour `fill` (`(4,)`) with the pixels that
    `layer` draws (a key per pixel, -1 for none) shaded over the premultiplied `under`
    (`(pixels, 4)`, or one colour `(4,)` under all), passed through `finish` if given.

    Only the runs of `_SHADE_RUN` pixels that hold a drawn pixel are shaded: they are
    listed first (a prefix sum over the runs, a fraction of one over the pixels), then
    taken `_SHADE_CHUNK` pixels at a time by a loop of a fixed number of steps whose
    steps past the list are skipped (a fixed count keeps it differentiable in reverse
    mode). Runs move as rows of `_SHADE_RUN` pixels: one index per run where a pixel's
    own would cost a lookup each. The loop's length is the shortest of a few
    (`_shade_steps`) that holds the list, and a layer that draws nothing (the layer
    beneath, often) skips it all. A run is listed once, so its colour under is read from
    `under` as given. The picture is filled inside each branch of the loop's length: a
    picture passed in would be copied whole by the branches that keep it."""
    pixels = layer.shape[0]
    runs = -(-pixels // _SHADE_RUN)
    padding = runs * _SHADE_RUN - pixels

    def in_runs(a, value):
        """`(pixels, ...)` as `(runs, _SHADE_RUN, ...)`, the last run padded with `value`."""
        padded = jnp.pad(a, [(0, padding)] + [(0, 0)] * (a.ndim - 1), constant_values=value)
        return padded.reshape(runs, _SHADE_RUN, *a.shape[1:])

    layer = in_runs(layer, -1)
    if under.ndim == 2:
        under = in_runs(under, 0)
    drawn = jnp.any(layer >= 0, axis=1)
    count = jnp.sum(drawn, dtype=jnp.int32)
    chunk = _SHADE_CHUNK // _SHADE_RUN
    lane = jnp.arange(_SHADE_RUN, dtype=jnp.int32)

    def shade(listed, index):
        at = jax.lax.dynamic_slice(listed, (index * chunk,), (chunk,))
        run = jnp.minimum(at, runs - 1)
        key = jnp.where((at < runs)[:, None], layer[run], -1).reshape(-1)
        rows_of = table[jnp.bitwise_and(key, 2**face_bits - 1)].T
        pixel = (run[:, None] * _SHADE_RUN + lane).reshape(-1)
        x = (pixel % cols).astype(table.dtype)
        y = (pixel // cols).astype(table.dtype)
        below = under[run].reshape(-1, 4) if under.ndim == 3 else under
        shaded = _shade(renderer, rows_of, key >= 0, x, y, below)
        if finish is not None:
            shaded = finish(shaded)
        return shaded.reshape(chunk, _SHADE_RUN, 4)

    def shaded_by(steps):
        """The picture with the listed runs shaded by a loop of `steps` chunks."""
        def filled():
            return jnp.broadcast_to(fill, (runs, _SHADE_RUN, 4))

        if steps == 0:
            return filled

        def run():
            position = jnp.cumsum(drawn.astype(jnp.int32))
            listed = jnp.full(steps * chunk, runs, jnp.int32).at[
                jnp.where(drawn, position - 1, steps * chunk)].set(
                jnp.arange(runs, dtype=jnp.int32), mode="drop")

            def step(carry, index):
                skip = lambda i: jnp.zeros((chunk, _SHADE_RUN, 4), fill.dtype)  # noqa: E731
                return carry, jax.lax.cond(index * chunk < count,
                                           functools.partial(shade, listed), skip, index)

            # Each step's runs come out as its own rows, written once at the end: a
            # picture carried through the loop would be copied at every step.
            _, shaded = jax.lax.scan(step, None, jnp.arange(steps))
            return filled().at[listed].set(shaded.reshape(-1, _SHADE_RUN, 4), mode="drop")
        return run

    ladder = _shade_steps(runs * _SHADE_RUN)
    needed = (count + chunk - 1) // chunk
    branch = jnp.searchsorted(jnp.asarray(ladder), needed)
    shaded = jax.lax.switch(branch, [shaded_by(steps) for steps in ladder])
    return shaded.reshape(-1, 4)[:pixels]


def _shade_steps(pixels: int) -> tuple[int, ...]:
    """The shading loop's lengths to choose from: none, an eighth, a half and all of the
    picture's chunks (each length is compiled once, in a branch of its own)."""
    steps = -(-pixels // _SHADE_CHUNK)
    return tuple(sorted({0, -(-steps // 8), -(-steps // 2), steps}))


def _premultiply(rgba):
    return jnp.concatenate([rgba[:3] * rgba[3], rgba[3:]])


def _shade(renderer: Renderer, table, drawn, x, y, under):
    """Pixels drawn by the triangles whose `table` columns are given (`(17, p)`), over the
    premultiplied `under` (`(p, 4)`, or `(4,)` under all), where `drawn`."""
    dx, dy = x - table[4], y - table[5]
    u = table[0] * dx + table[1] * dy + table[6]
    v = table[2] * dx + table[3] * dy + table[7]
    if renderer.antialias:
        edge = [table[8 + 3 * k] * dx + table[9 + 3 * k] * dy + table[10 + 3 * k]
                for k in range(3)]
        coverage = jnp.clip(0.5 + jnp.minimum(jnp.minimum(edge[0], edge[1]), edge[2]), 0.0, 1.0)
    else:
        coverage = jnp.ones_like(u)
    coverage = jnp.where(drawn, coverage, 0.0)
    u, v, coverage = materialise((u, v, coverage))
    colour = _bilinear(renderer.texture, u, v)
    # Premultiplied "over": what lies under shows through where the texture is partly
    # transparent as well as where the triangle covers the pixel partly.
    source = coverage[:, None] * colour
    return materialise(source + (1.0 - source[:, 3:]) * under)


def _bilinear(texture, u, v):
    """Texture values `(p, 4)` at fractional `(col, row) = (u, v)` positions, clamped at the
    border."""
    h, w = texture.shape[:2]
    flat = texture.reshape(h * w, -1)
    c = jnp.clip(u, 0.0, w - 1.0)
    r = jnp.clip(v, 0.0, h - 1.0)
    c0 = jnp.clip(jnp.floor(c), 0, max(w - 2, 0)).astype(jnp.int32)
    r0 = jnp.clip(jnp.floor(r), 0, max(h - 2, 0)).astype(jnp.int32)
    dc = 1 if w > 1 else 0
    dr = w if h > 1 else 0
    fc, fr = (c - c0)[:, None], (r - r0)[:, None]
    at = r0 * w + c0
    top = flat[at] * (1 - fc) + flat[at + dc] * fc
    bottom = flat[at + dr] * (1 - fc) + flat[at + dr + dc] * fc
    return top * (1 - fr) + bottom * fr


def depth_from_handles(rig: AbstractRig, depths: Any) -> Float[np.ndarray, " n"]:
    """A depth per shape-mesh vertex from a depth per handle, for `Renderer.build(depth=)`:
    each vertex takes the depth of the handle nearest to it along the mesh (a geodesic
    distance, so that an arm's vertices follow the arm's handle, not the body's one
    across a gap).

    A part that holds no handle (a head between two shoulders) is shared among the
    handles nearest to it, and where a limb is posed over it, the limb and the part
    of it sharing the limb's depth would tie: within each handle's depth, the vertices
    nearer the handle are drawn on top (by less than the smallest step between two
    depths given), so that the limb lies whole over what is farther from its handle.

    Args:
        rig: a `Rig`.
        depths: a number per row of the targets (one per point handle, two per bone: its
            start and end; a bone's pinned points take depths between the two). Larger
            depths are drawn on top.
    """
    depth, distance = spread_from_handles(rig, depths, "depths")
    distinct = np.unique(depth)
    step = np.diff(distinct).min() if len(distinct) > 1 else 1.0
    farthest = distance.max()
    return depth - 0.25 * step * distance / farthest if farthest > 0 else depth


def spread_from_handles(rig: AbstractRig, values: Any,
                        name: str = "values") -> tuple[np.ndarray, np.ndarray]:
    """Each shape-mesh vertex's value of the handle nearest to it along the mesh, and
    its distance along the mesh to that handle: `((n,), (n,))`.

    `values` holds a number per row of the targets (a bone's pinned points take values
    between its start's and its end's); rows that pin nothing (spare pins, pins taken
    out) give none.
    """
    values = np.asarray(values, np.float64)
    count = rig.handles.count
    if values.shape != (count,) or not np.all(np.isfinite(values)):
        raise ValueError(f"{name} must be {count} finite numbers, one per row of the targets "
                         f"(a point handle has one, a bone two), got shape {values.shape}.")
    n = rig.shape_mesh.vertices.shape[0]
    graph = _edge_graph(rig.shape_mesh.vertices, rig.shape_mesh.faces)
    pins = np.asarray(rig.handles.row_active())
    pinned = np.asarray(rig.shape_mesh.handles)[pins]
    distance, _, nearest = scipy.sparse.csgraph.dijkstra(
        graph, directed=False, indices=pinned, min_only=True, return_predecessors=True)
    handles = rig.handles
    along = np.asarray(handles.along)[pins]
    row_value = ((1 - along) * values[np.asarray(handles.first)[pins]]
                 + along * values[np.asarray(handles.second)[pins]])
    # A vertex pinned by several rows (bones sharing a joint) keeps the last one's value.
    by_vertex = np.zeros(n)
    by_vertex[pinned] = row_value
    return by_vertex[np.maximum(nearest, 0)], np.where(np.isfinite(distance), distance, 0.0)


def render(mesh: Any, vertices: Any, image: Any = None, **options: Any) -> Float[Array,
                                                                                  "rows cols 4"]:
    """One picture of `mesh` at `vertices`: `Renderer.build(mesh, image, **options)(vertices)`.

    For many pictures of one mesh, build the `Renderer` once and call it, or draw them
    all with `Renderer.frames`: building measures the mesh and prepares the texture.
    """
    return Renderer.build(mesh, image, **options)(jnp.asarray(vertices))


def stack_renderers(renderers: Any, like: Any = None):
    """One renderer whose arrays have a leading axis over `renderers` (padded to the
    largest, or like the stack `like`); `Renderer.stack` documents it."""
    if isinstance(renderers, Renderer) or not isinstance(renderers, Sequence) or not len(
            renderers):
        raise TypeError(f"Renderer.stack takes a list of renderers (at least one), got "
                        f"{type(renderers).__name__}.")
    for i, r in enumerate(renderers):
        if not isinstance(r, Renderer):
            raise TypeError(f"renderers[{i}] is a {type(r).__name__}, not an mvcjax.Renderer "
                            "(a layered character's renderer does not stack).")
        if r.window.ndim != 1:
            raise ValueError(f"renderers[{i}] is a stack already; stack the renderers it was "
                             "made of with the others.")
    if like is not None and (not isinstance(like, Renderer) or like.window.ndim != 2):
        raise TypeError(f"like= takes a stack of renderers (Renderer.stack), got "
                        f"{type(like).__name__}.")
    first, other = (renderers[0], "renderers[0]") if like is None else (like, "like=")
    for i, r in enumerate(renderers):
        for name, what in [("shape", "picture size (rows, cols)"),
                           ("antialias", "antialias="), ("see_through", "alpha="),
                           ]:
            if getattr(r, name) != getattr(first, name):
                raise ValueError(
                    f"renderers[{i}] has {what} {getattr(r, name)}, {other} "
                    f"{getattr(first, name)}: a stack draws every picture alike; build them "
                    f"with the same {what.split(' ')[0]}.")
        if r.texture.dtype != first.texture.dtype:
            raise ValueError(f"renderers[{i}] is {r.texture.dtype.name}, {other} "
                             f"{first.texture.dtype.name}: build them with the same dtype=.")
    sizes = [(r.rest.shape[0], r.faces.shape[0], *r.texture.shape[:2]) for r in renderers]
    if like is None:
        tile, budget = stack_tiling(renderers)
        n, f, h, w = np.max(sizes, axis=0).tolist()
    else:
        tile, budget = like.tile, like.budget
        n, f, h, w = like.rest.shape[1], like.faces.shape[1], *like.texture.shape[1:3]
        names = ["vertices", "triangles", "picture rows", "picture columns"]
        over = [f"renderers[{i}] has {a} {k}, like= {b}" for i, size in enumerate(sizes)
                for k, a, b in zip(names, size, (n, f, h, w)) if a > b]
        if over:
            raise ValueError(too_large("; ".join(over[:3])).replace("rigs", "renderers"))
    padded = []
    for r in renderers:
        dtype = r.texture.dtype
        texture = np.asarray(r.texture)
        # Edge rows and columns repeated: the texture lookup clamps at its edge, and
        # reads the same there.
        texture = np.pad(texture, ((0, h - texture.shape[0]), (0, w - texture.shape[1]),
                                   (0, 0)), mode="edge")
        r = dataclasses.replace(r, tile=tile, budget=budget)
        padded.append(eqx.tree_at(
            lambda r: (r.faces, r.boundary, r.texture_points, r.texture, r.rest, r.level), r,
            (to_device(pad_rows(r.faces, f), np.int32), to_device(pad_rows(r.boundary, f), bool),
             to_device(pad_rows(r.texture_points, n, np.asarray(r.texture_points)[0]), dtype),
             to_device(texture, dtype),
             to_device(pad_rows(r.rest, n, np.asarray(r.rest)[0]), dtype),
             to_device(pad_rows(r.level, f), np.int32))))
    return stacked(padded)
