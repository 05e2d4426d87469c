"""Interact: drag a rig's handles with the mouse, and the shape (or its picture) follows.

A `Posing` owns one matplotlib axes. Its solve, skin and (with a picture) render are one
compiled program, called with new targets on every mouse move; shapes never change, so
it compiles once. The figure is updated by blitting: the static parts (axes, rest
outline) are drawn once and kept as a bitmap, and each move restores that bitmap, draws
only the moving artists and copies the axes' box to the screen. A full redraw draws
every artist of the figure; a blit, only the moving ones.

Folds are shown as they happen: the program also marks the shape triangles whose
orientation left their rest orientation, and those are drawn red over the shape, with a
hint that counts them. The hint is drawn as a path (glyph outlines, kept per digit):
matplotlib's text draws each glyph anew on every draw, a cost that a blit would pay on
every update.

Any interactive matplotlib backend works: a desktop window (`QtAgg`, `TkAgg`, `MacOSX`)
or Jupyter through ipympl (`%matplotlib widget`). Canvases that cannot blit (vector
backends) fall back to `draw_idle`, which is slower but correct; the inline backend
draws a still picture only, so nothing can be dragged there.
"""

from __future__ import annotations

import functools
import re
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._animation import deform_frames
from .core import is_real_number, is_whole_number
from .export import write_animation
from .geometry import barycentric_coordinates, boundary_loops, edges, locate_points, signed_areas
from .rendering import Renderer, check_drawn_mesh, check_window, fit_window, in_window
from .rig import AbstractRig, Init, TurnedStart, pin_state, pinned_row, with_pin_state, with_rows
from .solvers import DEFAULT_SOLVER, AbstractSolver, FoldFree, check_solver

_HANDLE_STYLE = {"marker": "o", "markersize": 9, "color": "tab:red", "markeredgecolor": "white",
                 "markeredgewidth": 1.2, "linestyle": "none"}
# The figure's help line: the mouse and the keys (`Posing._on_key`), with pins by click
# or without.
_KEYS = "keys: u undo, r reset, m mesh, space record"
_HELP = "drag a red dot · click the shape: add a pin · right-click a dot: remove it\n" + _KEYS
_DRAG_HELP = "drag a red dot\n" + _KEYS
_NO_PINS_HINT = ("no spare pins: interact(rig, spare_pins=8) adds pins by click; a\n"
                 "character's pins are its handles (a new one: mvcjax.Character.build)")
_FOLD_STYLE = {"facecolor": (0.85, 0.05, 0.05, 0.55), "edgecolor": (0.85, 0.05, 0.05, 0.9),
               "linewidth": 0.6}
_HINT_COLOR = "#b01010"
_HINT_FONT_POINTS = 8.0


def _pose(rig: AbstractRig, renderer: Renderer | None, solver: AbstractSolver,
          rest_sign: np.ndarray, targets: Float[Array, "h 2"], init: Init = TurnedStart()):
    """The control and shape meshes for these targets, solved from `init`; with a
    renderer, the picture as `uint8` RGBA (a quarter of the bytes to hand to matplotlib,
    which draws those fastest); which shape triangles are flipped (their signed area's
    sign is not `rest_sign`, as `flipped_triangles` counts them), and how many."""
    control = rig.solve(targets, solver, init=init)
    control, shape = rig.joined(control), rig.joined(rig.skin(control))  # drawn as one mesh
    flipped = jnp.sign(signed_areas(shape, rig.shape_mesh.faces)) != rest_sign
    folds = jnp.sum(flipped, dtype=jnp.int32)
    if renderer is None:
        return control, shape, None, flipped, folds
    picture = renderer(shape, renderer.window)  # the view: what leaves it is seen to
    picture = jnp.round(jnp.clip(picture, 0, 1) * 255).astype(jnp.uint8)
    return control, shape, picture, flipped, folds


def _outline_codes(loops: list[np.ndarray]) -> np.ndarray:
    """Path codes of the shape's boundary loops as one compound path (holes cut out)."""
    from matplotlib.path import Path

    codes = []
    for loop in loops:
        part = np.full(len(loop) + 1, Path.LINETO, np.uint8)
        part[0], part[-1] = Path.MOVETO, Path.CLOSEPOLY
        codes.append(part)
    return np.concatenate(codes)


def _segments(points: np.ndarray, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x and y of the segments between `points[pairs]`, NaN-separated: one Line2D draws
    them all, and new data costs one array (a LineCollection builds a path per segment)."""
    if len(pairs) == 0:
        return np.empty(0), np.empty(0)
    segments = np.full((len(pairs), 3, 2), np.nan)
    segments[:, :2] = points[pairs]
    return segments[..., 0].ravel(), segments[..., 1].ravel()


def _triangle_codes(count: int) -> np.ndarray:
    """Path codes of `count` closed triangles, four vertices each."""
    from matplotlib.path import Path

    one = np.array([Path.MOVETO, Path.LINETO, Path.LINETO, Path.CLOSEPOLY], Path.code_type)
    return np.tile(one, count)


@functools.cache
def _glyphs(text: str, points: float):
    """`text` as a path in points (baseline at y = 0) and its advance width."""
    from matplotlib.font_manager import FontProperties
    from matplotlib.textpath import TextPath, text_to_path

    font = FontProperties(size=points)
    width = text_to_path.get_text_width_height_descent(text, font, ismath=False)[0]
    return TextPath((0, 0), text, prop=font), width


def _text_path(text: str, points: float):
    """`text` as one path in points, put together from cached pieces (each digit, and
    each run of other characters), so that a count that changes costs no font work."""
    from matplotlib.path import Path

    pieces, x = [], 0.0
    for piece in re.findall(r"\d|\D+", text):
        path, width = _glyphs(piece, points)
        if len(path.vertices):
            pieces.append(Path(path.vertices + (x, 0.0), path.codes))
        x += width
    return Path.make_compound_path(*pieces) if pieces else Path(np.empty((0, 2)))


def _fold_words(folds: int, solver: AbstractSolver) -> str:
    words = f"{folds} triangle{'s' if folds != 1 else ''} folded"
    if isinstance(solver, FoldFree):
        return words
    return words + ": try solver=mvcjax.FoldFree()"


def _check_posing_options(rig, solver, pick_radius, margin, ax, spare_pins) -> None:
    """`Posing`'s arguments checked, with errors naming the one to fix."""
    if not isinstance(rig, AbstractRig):
        raise TypeError(f"rig must be an mvcjax.Rig (mvcjax.Rig.build(shape, handles)) "
                        f"or an mvcjax.Character, got {type(rig).__name__}.")
    check_solver(solver)
    if not (is_real_number(pick_radius) and pick_radius > 0):
        raise ValueError(f"pick_radius must be a positive number of screen pixels, got "
                         f"{pick_radius!r}.")
    if not (is_real_number(margin) and margin >= 0):
        raise ValueError(f"margin must be a number >= 0 (a fraction of the shape's size), "
                         f"got {margin!r}.")
    if ax is not None and not hasattr(ax, "transData"):
        raise TypeError(f"ax must be matplotlib axes (e.g. plt.subplots()[1]), got "
                        f"{type(ax).__name__}.")
    if not (is_whole_number(spare_pins) and spare_pins >= 0):
        raise ValueError(f"spare_pins must be a whole number >= 0 (how many pins a click "
                         f"can add), got {spare_pins!r}.")


class Posing:
    """A live session posing a rig with the mouse; make one with `mvcjax.interact`.

    Press on a red dot (a handle's target) and drag it: the shape follows while the mouse
    moves. Click the shape away from the dots to add a pin there (and drag it at once),
    right-click a dot to remove its pin. The session keeps what a user wants
    to keep: the current `targets`, the pose (`shape_vertices`), and, while recording,
    every pose of a drag (`recorded`, `frames`, `write_animation`). Shape triangles turned
    inside out (a fold) are drawn red while they are, and counted in `folds`.

    Pins come and go without a pause: the session poses the rig with `spare_pins`
    spare rows (`Rig.with_spare_pins`), and a click places one (`Rig.with_pin`) or
    takes one out (`Rig.without_pin`), which changes numbers only, never the compiled
    program.

    Attributes:
        rig: the rig with the pins as they are now: the rig given, plus a point handle
            for each pin added (rows after the rig's own), a handle taken out staying
            as an inactive row (`Rig.active`). `rig.deform(targets)` gives the pose.
        targets: `(h, 2)` the current targets of `rig` (numpy; a copy is kept by the
            session).
        renderer: draws the textured picture, or None to draw the shape filled.
        solver: the solver of every update.
        figure, axes: the matplotlib figure and axes it draws in.
        folds: how many shape triangles the current pose turned inside out (their
            orientation is not their rest orientation; `mvcjax.flipped_triangles` of
            the rest and current shape meshes). Counted with or without `show_folds`.
        show_folds: whether folded triangles are drawn, and counted in a hint.
        hint: the fold hint drawn in the axes' top left corner ("" while nothing is
            folded, or without `show_folds`).
        updates: how many poses were drawn.
        update_seconds: the wall time of each update, from the mouse event to the blit.
        pin_seconds: the wall time of each pin added or removed, from the click to the
            blit of the new pose.
    """

    def __init__(self, rig: Any, image: Any = None, *, ax: Any = None,
                 solver: Any = DEFAULT_SOLVER, size: Any = None, window: Any = None,
                 margin: Any = 0.3, control_mesh: Any = True, record: Any = False,
                 pick_radius: Any = 12.0, renderer: Any = None, show_folds: Any = True,
                 spare_pins: Any = 8, **render_options: Any):
        _check_posing_options(rig, solver, pick_radius, margin, ax, spare_pins)
        self._given, self.solver = rig, solver
        # A character's parts are rigs of their own: it keeps the handles it was built with.
        self._own_rows = rig.handles.count
        spare = rig.with_spare_pins(int(spare_pins)) if spare_pins else rig
        self._pinning = spare is not rig
        self._rig = spare
        self._kept: tuple[Any, AbstractRig] | None = None
        self._control_mesh_wanted = bool(control_mesh)
        self.show_folds = bool(show_folds)
        rest = np.asarray(rig.shape_mesh.vertices, np.float64)
        self._faces = np.asarray(rig.shape_mesh.faces, np.int64)
        rest_sign = np.sign(signed_areas(rest, self._faces)).astype(np.int8)
        renderer = self._set_view(rig, rest, ax, window, size, margin, renderer, image,
                                  render_options)
        # The renderer and solver are constants of the session's one program; the rig is
        # an argument, so that a pin placed or taken out (new numbers, the same shapes)
        # runs the same program.
        self._pose = jax.jit(lambda r, t, *init: _pose(r, renderer, solver, rest_sign, t,
                                                      *init))
        # `FoldFree` starts each drag step from the pose before it (the rest mesh at
        # first): a start without folds near the answer, where the turned start of a
        # pose that folds would send it back to the rigid one.
        self._warm = isinstance(solver, FoldFree)
        self._dtype = np.dtype(rig.handles.rest.dtype)
        self._pick_radius = float(pick_radius)
        self._bones = np.asarray(rig.handles.bones, np.int64).reshape(-1, 2)
        self._pivot = _rigid_bone_pivots(rig)
        self._loops = boundary_loops(np.asarray(rig.shape_mesh.faces))
        self._outline_index = np.concatenate([np.append(loop, loop[0]) for loop in self._loops])
        self._control_edges = edges(np.asarray(rig.control_mesh.faces))

        self._all = np.asarray(self._rig.handle_positions, np.float64).copy()
        self._control_vertices = None
        self.updates, self.update_seconds, self.pin_seconds = 0, [], []
        self._dragged: int | None = None
        # The targets and the rig before each move, for undo.
        self._history: list[tuple[np.ndarray, Any]] = []
        self._background = None
        self._recording, self._recorded, self._times = bool(record), [], []
        self._recorded_pins: list[Any] = []

        self._draw_static(rest)
        self._solve()
        self._draw_pose()
        canvas = self.figure.canvas
        self._connections = [
            canvas.mpl_connect("draw_event", self._on_draw),
            canvas.mpl_connect("button_press_event", self._on_press),
            canvas.mpl_connect("motion_notify_event", self._on_motion),
            canvas.mpl_connect("button_release_event", self._on_release),
            canvas.mpl_connect("key_press_event", self._on_key),
        ]
        if self._recording:
            self._record()

    def _set_view(self, rig, rest, ax, window, size, margin, renderer, image,
                  render_options):
        """The session's window, axes, figure and renderer; the mesh the renderer draws
        (a character's parts as one mesh, in the layers' order)."""
        import matplotlib.pyplot as plt  # lazily: matplotlib only for interactive sessions

        given_rest = np.asarray(rig.handle_positions, np.float64)
        if window is None:
            window = (renderer.window if renderer is not None
                      else fit_window(np.concatenate([rest, given_rest]),
                                      size, margin=margin))
        self.window = tuple(float(w) for w in check_window(window, "window"))
        self._check_in_view(given_rest)
        if ax is None:
            _, ax = plt.subplots(figsize=(6, 6))
        self.axes, self.figure = ax, ax.figure
        _warn_if_no_window(self.figure)
        _show_window(ax, self.window)
        if renderer is None and (image is not None or render_options or size is not None):
            renderer = Renderer.build(rig, image, window=self.window,
                                      size=size if size is not None else _pixels(ax),
                                      **render_options)
        elif renderer is not None and (image is not None or render_options):
            raise ValueError("pass either renderer= or image= (and render options), not both.")
        self.renderer = renderer
        renderer = renderer.mesh if renderer is not None else None
        if renderer is not None:
            check_drawn_mesh(renderer, rig.shape_mesh.vertices, rig.shape_mesh.faces)
        return renderer

    # ---- what the user keeps -----------------------------------------------------------

    @property
    def _rig(self) -> AbstractRig:
        return self._session_rig

    @_rig.setter
    def _rig(self, rig: AbstractRig) -> None:
        # The rows that pin, on the host: read at every update. The pins' state is what
        # undo and recordings keep (a few small arrays; a rig has its own factor).
        self._session_rig, self._active = rig, np.asarray(rig.handles.active)
        self._pins = pin_state(rig) if self._pinning else None

    def _with_pins(self, pins) -> AbstractRig:
        """The session's rig with the pins of `pins` (a `pin_state`)."""
        return self._rig if pins is self._pins else with_pin_state(self._rig, pins)

    def _rows(self) -> np.ndarray:
        """The session's target rows that `rig` and `targets` hold: the given rig's,
        then each spare pin placed."""
        active = self._active
        return np.concatenate([np.arange(self._own_rows),
                               self._own_rows + np.flatnonzero(active[self._own_rows:])])

    @property
    def rig(self) -> AbstractRig:
        if self._rig is self._given:
            return self._given
        if self._kept is None or self._kept[0] is not self._rig:
            rows = self._rows()
            if len(rows) == self._own_rows and self._active[:self._own_rows].all():
                kept = self._given  # nothing added, nothing taken out
            else:
                kept = with_rows(self._rig, rows)
            self._kept = (self._rig, kept)
        return self._kept[1]

    @property
    def targets(self) -> np.ndarray:
        return self._all[self._rows()]

    @property
    def shape_vertices(self) -> np.ndarray:
        """`(n, 2)` the deformed shape mesh of the current targets."""
        return np.asarray(self._shape)

    @property
    def control_vertices(self) -> np.ndarray:
        """`(c, 2)` the solved control mesh of the current targets."""
        return np.asarray(self._control_vertices)

    @property
    def picture(self) -> np.ndarray | None:
        """`(rows, cols, 4)` uint8 RGBA of the current pose, or None without a renderer."""
        return None if self._picture is None else np.asarray(self._picture)

    @property
    def recording(self) -> bool:
        """Whether every new pose is recorded (`record(True)` starts, `record(False)` stops)."""
        return self._recording

    def record(self, on: Any = True) -> None:
        """Start (or stop) recording poses: each update appends the targets and the time."""
        self._recording = bool(on)
        if on and not self._recorded:
            self._record()

    def _recorded_all(self, fps: Any) -> tuple[np.ndarray, list]:
        """The recorded targets of every session row (a pin's rows hold its rest
        position while it pinned nothing) and the pins of each (`pin_state`), sampled at `fps`."""
        if not self._recorded:
            raise ValueError("nothing was recorded: call posing.record() (or interact(..., "
                             "record=True)) before dragging.")
        rest = np.asarray(self._rig.handle_positions, np.float64)
        active = [self._active if pins is None else pins[1] for pins in self._recorded_pins]
        targets = np.stack([np.where(a[:, None], t, rest)
                            for t, a in zip(self._recorded, active)])
        if fps is None:
            return targets, list(self._recorded_pins)
        if not (is_real_number(fps) and fps > 0):
            raise ValueError(f"fps must be a positive number of frames per second, got {fps!r}.")
        times = np.asarray(self._times) - self._times[0]
        count = max(1, int(np.floor(times[-1] * fps)) + 1)
        at = np.arange(count) / fps
        flat = targets.reshape(len(targets), -1)
        sampled = np.stack([np.interp(at, times, column) for column in flat.T], axis=1)
        # Each frame posed with the pins of the last update at or before it.
        last = np.searchsorted(times, at, side="right") - 1
        return (sampled.reshape(count, *targets.shape[1:]),
                [self._recorded_pins[k] for k in last])

    def recorded(self, fps: Any = None) -> np.ndarray:
        """`(frames, h, 2)` the recorded targets of `rig` (the pins as they are now): one
        per update, or, with `fps`, sampled at that rate from the recording's times
        (linear in between), so that an animation replays the drag at the speed it was
        made. A pin added during the recording holds its rest position before it."""
        return self._recorded_all(fps)[0][:, self._rows()]

    def frames(self, fps: Any = None) -> Float[Array, "frames n 2"]:
        """`(frames, n, 2)` the recorded poses of the shape mesh, each with the pins it
        was made with (`deform_frames` of the recorded targets), ready for
        `Renderer.frames` and `mvcjax.export`."""
        targets, pins = self._recorded_all(fps)
        runs, start = [], 0
        for end in range(1, len(pins) + 1):
            if end == len(pins) or pins[end] is not pins[start]:
                rig = self._with_pins(pins[start])
                runs.append(rig.joined(deform_frames(
                    rig, targets[start:end].astype(self._dtype), self.solver)))
                start = end
        return jnp.concatenate(runs)

    def write_animation(self, path: Any, *, fps: Any = 30, renderer: Any = None,
                        **options: Any) -> None:
        """Write the recorded drag as an animation file (GIF, PNG, WebP or MP4: see
        `mvcjax.export.write_animation`, which gets `options`), replayed at `fps`.

        Drawn by `renderer`, or the session's, or, without one, the shape filled with a
        checkerboard in the session's window, 512 pixels along its longer side."""
        renderer = renderer if renderer is not None else self.renderer
        if renderer is None:
            mesh = self._given.shape_mesh
            renderer = Renderer.build((mesh.vertices, mesh.faces), window=self.window)
        write_animation(path, renderer.mesh.frames(self.frames(fps)), fps=fps, **options)

    def set_targets(self, targets: Any) -> None:
        """Move every target of `rig` at once (e.g. from code, or to replay a pose) and
        redraw."""
        targets = np.asarray(targets, np.float64)
        rows = self._rows()
        if targets.shape != (len(rows), 2) or not np.all(np.isfinite(targets)):
            raise ValueError(f"targets must be {(len(rows), 2)}, finite (x, y) per handle, "
                             f"got shape {targets.shape}.")
        self._all[rows] = targets
        self._update()

    def _remember(self) -> None:
        self._history.append((self._all.copy(), self._pins))

    def reset(self) -> None:
        """Every target back at rest, the pins where they are (undone by `undo`)."""
        self._remember()
        self._all = np.asarray(self._rig.handle_positions, np.float64).copy()
        self._update()

    def undo(self) -> bool:
        """Take back the last move (a drag, a pin added or removed, a reset): the
        targets and pins as they were before it. False if there is nothing to take
        back."""
        if not self._history:
            return False
        self._all, pins = self._history.pop()
        self._rig = self._with_pins(pins)
        self._update()
        return True

    def add_pin(self, point: Any) -> int:
        """Pin the shape where it is at `point` in the current pose (what a click on the
        shape does), and return the pin's row in the session (`rig` and `targets` hold
        it last). The pose stays as it is; the pin holds that spot of the shape."""
        point = np.asarray(point, np.float64)
        at_rest = self._at_rest(point)
        if at_rest is None:
            raise ValueError(f"point {point.tolist()} is not on the shape as it is posed; "
                             "click on the shape to add a pin.")
        return self._pin(at_rest)

    def _pin(self, at_rest: np.ndarray) -> int:
        """`add_pin` of the spot at rest point `at_rest`."""
        if not self._pinning:
            raise ValueError("this session has no spare pins: interact(rig, spare_pins=8) "
                             "with an mvcjax.Rig adds pins by click (a Character's pins "
                             "are the handles it was built with).")
        free = np.flatnonzero(~self._active[self._own_rows:])
        if not len(free):
            raise ValueError(f"all {self._rig.handles.count - self._own_rows} spare pins are "
                             "placed: remove one (right-click it), or interact(..., "
                             "spare_pins=more).")
        row = self._own_rows + int(free[0])
        rig = self._rig.with_pin(row, at_rest)
        self._remember()
        self._rig = rig
        # Its target: where the pin's spot of the control mesh is now, which the pose
        # already meets (the pose stays the minimum), a hair from the click.
        pinned = pinned_row(rig, row)
        index = np.asarray(rig.energy.handles)[pinned]
        coef = np.asarray(rig.energy.handle_coef, np.float64)[pinned]
        self._all[row] = coef @ np.asarray(self._control_vertices, np.float64)[index]
        self._update()
        return row

    def remove_pin(self, row: Any) -> None:
        """Take out the pin of session row `row` (for a bone's end, the bone): what a
        right-click on its dot does."""
        rig = self._rig.without_pin(row)
        self._remember()
        self._rig = rig
        self._update()

    def toggle_mesh(self) -> None:
        """Show or hide the control mesh drawn over a filled shape."""
        if self._control is None:
            self._status.set_text("the control mesh is drawn over a filled shape only "
                                  "(interact without a picture, control_mesh=True)")
        else:
            self._control.set_visible(not self._control.get_visible())
            self._status.set_text("")
        self._blit()

    def disconnect(self) -> None:
        """Stop listening to the mouse (the figure stays as it is)."""
        for cid in self._connections:
            self.figure.canvas.mpl_disconnect(cid)
        self._connections = []

    # ---- drawing -------------------------------------------------------------------------

    def _check_in_view(self, rest: np.ndarray) -> None:
        if not in_window(rest, self.window).any():
            raise ValueError(f"no handle of the rig lies in the window {self.window}, so none "
                             "can be dragged; leave window= out (it then holds the shape and "
                             "its handles) or pass one that holds them, e.g. "
                             "mvcjax.fit_window(rig.handle_positions).")

    def _draw_static(self, rest: np.ndarray) -> None:
        ax = self.axes
        xmin, ymin, xmax, ymax = self.window
        outline = rest[self._outline_index]
        breaks = np.cumsum([len(loop) + 1 for loop in self._loops])[:-1]
        for part in np.split(outline, breaks):
            ax.plot(part[:, 0], part[:, 1], color="0.75", linewidth=0.8, zorder=1)
        ax.set_title(_HELP if self._pinning else _DRAG_HELP, fontsize=8)
        animated = {"animated": True}
        if self.renderer is not None:
            self._image = _picture_class()(ax, extent=(xmin, xmax, ymin, ymax), origin="upper",
                                   interpolation="bilinear", zorder=2, **animated)
            self._image.set_data(np.zeros((*self.renderer.shape, 4), np.uint8))
            ax.add_image(self._image)
            self._patch = None
        else:
            from matplotlib.patches import PathPatch
            from matplotlib.path import Path

            self._image = None
            self._codes = _outline_codes(self._loops)
            self._patch = PathPatch(Path(outline, self._codes), facecolor="#f2b36b",
                                    edgecolor="#7a4a1c", linewidth=1.0, zorder=2, **animated)
            ax.add_patch(self._patch)
        self._control = None
        if self.renderer is None and len(self._control_edges) and self._control_mesh_wanted:
            (self._control,) = ax.plot([], [], "-", color="tab:blue", linewidth=0.5,
                                       alpha=0.6, zorder=3, **animated)
        (self._bone_line,) = ax.plot([], [], "-", color="tab:red", linewidth=2.5, zorder=4,
                                     **animated)
        (self._handles,) = ax.plot([], [], zorder=5, **_HANDLE_STYLE, **animated)
        # Hints only: a text that changes on every update (a rate, say) draws its glyphs
        # anew each time.
        self._status = ax.text(0.01, 0.01, "", transform=ax.transAxes, fontsize=8,
                               color="0.3", zorder=6, **animated)
        self._fold_patch = self._fold_hint = None
        if self.show_folds:
            from matplotlib.patches import PathPatch
            from matplotlib.path import Path
            from matplotlib.transforms import Affine2D, ScaledTranslation

            # Over the shape or picture, under the control mesh and the handles.
            self._fold_patch = PathPatch(Path(np.empty((0, 2))), zorder=2.5, visible=False,
                                         **_FOLD_STYLE, **animated)
            ax.add_patch(self._fold_patch)
            self._fold_codes = _triangle_codes(len(self._faces))
            # Glyph outlines in points, placed a little in from the axes' top left corner.
            points = (Affine2D().translate(4.0, -4.0 - _HINT_FONT_POINTS).scale(1 / 72)
                      + self.figure.dpi_scale_trans
                      + ScaledTranslation(0.0, 1.0, ax.transAxes))
            self._fold_hint = PathPatch(Path(np.empty((0, 2))), facecolor=_HINT_COLOR,
                                        edgecolor="none", transform=points, zorder=6,
                                        visible=False, **animated)
            ax.add_artist(self._fold_hint)
        self._hinted_folds, self.hint = 0, ""

    def _start(self) -> tuple:
        """The solve's start, as `_pose`'s trailing arguments: none for the turned
        start, or the control vertices of the pose before (at first, the rest)."""
        if not self._warm:
            return ()
        last = self._control_vertices
        return (self._rig.control_mesh.vertices if last is None else last,)

    def _solve(self) -> None:
        pose = jax.block_until_ready(
            self._pose(self._rig, jnp.asarray(self._all.astype(self._dtype)),
                       *self._start()))
        self._control_vertices, self._shape, self._picture, self._flipped, folds = pose
        self.folds = int(folds)

    def _draw_folds(self) -> None:
        from matplotlib.path import Path

        folds = self.folds
        if folds:
            # The mask is fetched only when something is folded, and the path holds the
            # folded triangles alone: a pose without folds costs the count, nothing more.
            shape = np.asarray(self._shape)
            corners = shape[self._faces[np.asarray(self._flipped)]]
            vertices = np.concatenate([corners, corners[:, :1]], axis=1).reshape(-1, 2)
            self._fold_patch.set_path(Path(vertices, self._fold_codes[:len(vertices)]))
        if self._fold_patch.get_visible() != bool(folds):
            self._fold_patch.set_visible(bool(folds))
        if folds != self._hinted_folds:
            # Rebuilt only when the count changes: a blit redraws the path, never the font.
            self._hinted_folds = folds
            self.hint = _fold_words(folds, self.solver) if folds else ""
            if folds:
                self._fold_hint.set_path(_text_path(self.hint, _HINT_FONT_POINTS))
            self._fold_hint.set_visible(bool(folds))

    def _draw_pose(self) -> None:
        if self._image is not None:
            self._image.set_data(np.asarray(self._picture))
        else:
            from matplotlib.path import Path

            outline = np.asarray(self._shape)[self._outline_index]
            self._patch.set_path(Path(outline, self._codes))
        if self._control is not None:
            self._control.set_data(*_segments(np.asarray(self._control_vertices),
                                              self._control_edges))
        active = self._active
        self._handles.set_data(self._all[active, 0], self._all[active, 1])
        self._bone_line.set_data(*_segments(self._all, self._bones[active[self._bones[:, 0]]]))
        if self.show_folds:
            self._draw_folds()

    def _artists(self):
        return [a for a in (self._image, self._patch, self._fold_patch, self._control,
                            self._bone_line, self._handles, self._status, self._fold_hint)
                if a is not None]

    def _blit(self) -> None:
        canvas = self.figure.canvas
        if self._background is None or not _can_blit(canvas):
            canvas.draw_idle()
            return
        canvas.restore_region(self._background)
        for artist in self._artists():
            self.axes.draw_artist(artist)
        canvas.blit(self.axes.bbox)

    def _update(self) -> None:
        start = time.perf_counter()
        self._solve()
        self._draw_pose()
        self._blit()
        self.update_seconds.append(time.perf_counter() - start)
        self.updates += 1
        if self._recording:
            self._record()

    def _record(self) -> None:
        self._recorded.append(self._all.copy())
        self._recorded_pins.append(self._pins)
        self._times.append(time.perf_counter())

    # ---- mouse -----------------------------------------------------------------------------

    def _on_draw(self, event) -> None:
        # A full draw (first show, resize, zoom) renews the bitmap of the static parts.
        canvas = self.figure.canvas
        if _can_blit(canvas):
            self._background = canvas.copy_from_bbox(self.axes.bbox)
            for artist in self._artists():
                self.axes.draw_artist(artist)

    def _nearest(self, event) -> int | None:
        """The session row of the dot under the mouse (within `pick_radius` screen
        pixels), or None."""
        rows = np.flatnonzero(self._active)
        screen = self.axes.transData.transform(self._all[rows])
        distance = np.hypot(screen[:, 0] - event.x, screen[:, 1] - event.y)
        best = int(np.argmin(distance))
        return int(rows[best]) if distance[best] <= self._pick_radius else None

    def _on_press(self, event) -> None:
        if event.inaxes is not self.axes or self._toolbar_busy():
            return
        picked = self._nearest(event)
        start = time.perf_counter()
        if event.button == 3 and picked is not None:
            try:
                self.remove_pin(picked)
            except ValueError as error:  # the last pin
                self._say(str(error).split(";")[0] + ": add another pin first")
                return
            self.pin_seconds.append(time.perf_counter() - start)
        elif event.button == 1 and picked is not None:
            self._remember()
            self._dragged = picked
            self._status.set_text("")  # a hint goes with the drag's first update
        elif event.button == 1 and event.xdata is not None:
            self._add_pin_at(np.array([event.xdata, event.ydata]), start)
        elif event.button == 3:
            self._say(_HELP if self._pinning else _NO_PINS_HINT)

    def _add_pin_at(self, point: np.ndarray, start: float) -> None:
        if not self._pinning:
            self._say(_NO_PINS_HINT)
            return
        at_rest = self._at_rest(point)
        if at_rest is None:
            return  # a click beside the shape
        try:
            row = self._pin(at_rest)
        except ValueError as error:  # every spare pin placed
            self._say(str(error))
            return
        self.pin_seconds.append(time.perf_counter() - start)
        self._dragged = row  # press, then drag: the new pin follows at once
        self._remember()

    def _at_rest(self, point: np.ndarray) -> np.ndarray | None:
        """Where the spot of the posed shape at `point` lies at rest, or None off the
        shape."""
        posed = np.asarray(self._shape, np.float64)
        face, depth = locate_points(point[None], posed, self._faces)
        if depth[0] < 0:
            return None
        corners = self._faces[face[0]]
        bary = barycentric_coordinates(point[None], posed[corners][None])[0]
        return bary @ np.asarray(self._given.shape_mesh.vertices, np.float64)[corners]

    def _say(self, text: str) -> None:
        self._status.set_text(text)
        self._blit()

    def _on_motion(self, event) -> None:
        if self._dragged is None or event.inaxes is not self.axes or event.xdata is None:
            return
        self._all[self._dragged] = self._dragged_to(self._dragged,
                                                    np.array([event.xdata, event.ydata]))
        self._update()

    def _dragged_to(self, row: int, mouse: np.ndarray) -> np.ndarray:
        """Where target `row` goes for the mouse at `mouse`: there, or for an end of a
        rigid bone, the bone turned about its other end (which stays on its dot) to
        point at the mouse, at its rest length."""
        other, length = self._pivot.get(row, (None, 0.0))
        if other is None:
            return mouse
        offset = mouse - self._all[other]
        distance = float(np.hypot(*offset))
        if distance == 0:
            return self._all[row]
        return self._all[other] + offset * (length / distance)

    def _on_release(self, event) -> None:
        if self._dragged is not None and np.array_equal(self._history[-1][0], self._all):
            self._history.pop()  # a click that moved nothing is no move to undo
        self._dragged = None

    def _on_key(self, event) -> None:
        key = (event.key or "").lower()
        if key in ("u", "ctrl+z", "cmd+z"):
            if not self.undo():
                self._say("nothing to undo")
        elif key == "r":
            self.reset()
        elif key == "m":
            self.toggle_mesh()
        elif key == " ":
            self.record(not self._recording)
            self._status.set_text(f"recording ({len(self._recorded)} poses so far)"
                                  if self._recording else
                                  f"recording stopped: {len(self._recorded)} poses; "
                                  "posing.write_animation(path) writes them")
            self._blit()

    def _toolbar_busy(self) -> bool:
        # While the toolbar pans or zooms, presses belong to it.
        toolbar = getattr(self.figure.canvas, "toolbar", None)
        return bool(getattr(toolbar, "mode", ""))


# matplotlib's canvases that draw to memory or to files only.
_NO_WINDOW = frozenset({"agg", "pdf", "svg", "ps", "cairo", "template", "pgf"})


def _warn_if_no_window(figure) -> None:
    """Say that nothing can be dragged where the figure's canvas shows no window and
    takes no mouse (matplotlib's Agg, its inline backend in Jupyter, file backends)."""
    import matplotlib

    backend = matplotlib.get_backend()
    module = type(figure.canvas).__module__
    kind = module.rsplit("backend_", 1)[-1] if module.startswith("matplotlib.backends.") else ""
    if "inline" in backend.lower() or kind in _NO_WINDOW:
        import warnings

        warnings.warn(
            f"matplotlib's backend {backend!r} shows no window and takes no mouse: the "
            "figure can be drawn and saved, but nothing can be dragged. In Jupyter, run "
            "%matplotlib widget first (pip install 'mvcjax[widget]'); in a script, use a "
            "desktop backend (it needs a display) and call plt.show().",
            stacklevel=3)


def _rigid_bone_pivots(rig: AbstractRig) -> dict[int, tuple[int, float]]:
    """For each target row that ends a rigid bone: the row of its other end, and the
    bone's rest length."""
    pivots = {}
    for start, end, length in rig.handles.rigid_bones(rig.handle_positions):
        pivots[start], pivots[end] = (end, length), (start, length)
    return pivots


def _show_window(ax, window) -> None:
    xmin, ymin, xmax, ymax = window
    ax.set_xlim(xmin, xmax)
    ax.set_ylim(ymin, ymax)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.apply_aspect()


def _pixels(ax) -> tuple[int, int]:
    """`(rows, cols)`: the axes' box on the canvas, in pixels."""
    box = ax.get_window_extent()
    return max(1, round(box.height)), max(1, round(box.width))


@functools.cache
def _picture_class():
    # Made on first use: importing matplotlib's image module would slow `import mvcjax`
    # for sessions that never draw.
    from matplotlib.image import AxesImage

    class Picture(AxesImage):
        """A picture drawn pixel for pixel when it was rendered for the axes as they are
        (their size in pixels, their view): matplotlib's resampling of an image costs
        more than rendering it. Resampled as any image otherwise (after a resize, a zoom
        or a save at another dpi)."""

        def draw(self, renderer, *args, **kwargs):
            picture = self.get_array()
            box = self.axes.bbox
            extent = self.get_extent()
            view = self.axes.viewLim
            as_made = (picture.shape[:2] == (round(box.height), round(box.width))
                       and np.allclose([view.x0, view.x1, view.y0, view.y1], extent,
                                       rtol=0, atol=1e-9 * max(1.0, np.abs(extent).max())))
            if not (as_made and self.get_visible()):
                return super().draw(renderer, *args, **kwargs)
            gc = renderer.new_gc()
            gc.set_clip_rectangle(box)
            # Agg puts an array's first row at the bottom; the picture's is its top.
            renderer.draw_image(gc, round(box.x0), round(box.y0), np.asarray(picture)[::-1])
            gc.restore()
            self.stale = False

    return Picture


def _can_blit(canvas) -> bool:
    # Agg-based canvases can. ipympl's (webagg's) reports supports_blit = False, because
    # matplotlib's own widgets met problems there, yet it has the Agg
    # buffer's copy and restore, and its blit sends the changed pixels to the browser.
    return hasattr(canvas, "copy_from_bbox") and hasattr(canvas, "restore_region")


def interact(rig: Any, image: Any = None, *, ax: Any = None, solver: Any = DEFAULT_SOLVER,
             size: Any = None, window: Any = None, margin: Any = 0.3,
             control_mesh: Any = True, record: Any = False, pick_radius: Any = 12.0,
             renderer: Any = None, show_folds: Any = True, spare_pins: Any = 8,
             **render_options: Any) -> Posing:
    """Pose `rig` with the mouse: a figure in which dragging a handle moves the shape.

    Press on a red dot (a handle's target) and drag; the shape, or its picture, follows
    while the mouse moves. Keys: `u` undo, `r` reset, `m` show or hide the control mesh,
    space start or stop recording. Dragging one end of a rigid bone turns the bone about its
    other end, which stays on its dot (the dragged end follows the mouse's direction at
    the bone's length); a stretchy bone's ends move independently. Click the shape away
    from the dots to add a pin there (keep the button down to drag it at once);
    right-click a dot to remove its pin (a bone's end: the bone). Pins come and go
    without rebuilding the meshes or compiling anything (`Rig.with_pin`), up to
    `spare_pins` added pins at a time; `posing.rig` is the rig with the pins as they
    are. Where the pose
    folds the shape (triangles turned inside out), those triangles are drawn red and a
    hint counts them, while they are folded.

    Needs an interactive matplotlib backend: in Jupyter, `pip install 'mvcjax[widget]'`
    (ipympl) and run `%matplotlib widget` first; in a script, a desktop backend (the
    default one where a display is available), then `plt.show()`.

    Args:
        rig: the rig to pose.
        image: draw the shape textured by this picture (as `Renderer.build` takes it:
            an array or a file path); None draws it filled, or, with `size` or other
            render options, with a checkerboard.
        ax: the matplotlib axes to draw in (default: a new 6 x 6 inch figure).
        solver: the solver of every update, any mvcjax solver. Default: the one
            `rig.deform` uses when given none, so that a pose here is the pose
            `rig.deform(posing.targets)` gives. `mvcjax.FoldFree()` never folds the
            control mesh: the choice where folds must not happen.
        size: `(rows, cols)` of the drawn picture, when there is one. Default: the axes'
            size in pixels, which draws fastest (the picture is copied pixel for pixel).
        window: the rectangle `(xmin, ymin, xmax, ymax)` shown; default the rest shape
            and its handles with `margin` of their size around them, room to drag in.
        margin: see `window`.
        control_mesh: draw the control mesh's edges over a filled shape.
        record: record from the start (see `Posing.record`).
        pick_radius: how near (in screen pixels) a press must be to a dot to grab it.
        renderer: a `Renderer` built for this rig, instead of `image` and its options.
        show_folds: draw the folded shape triangles red over the shape, with a hint that
            counts them; False draws neither (`Posing.folds` still counts them).
        spare_pins: how many pins a click can add (`Rig.with_spare_pins`); 0 for
            none. A `Character` keeps the handles it was built with.
        **render_options: more options of `Renderer.build` (`fill`, `alpha`, `depth`...).

    Returns:
        The `Posing`: keep it (it holds the figure's callbacks), read `targets`,
        `shape_vertices` and `folds`, and `frames()` / `write_animation()` a recorded drag.
    """
    return Posing(rig, image, ax=ax, solver=solver, size=size, window=window, margin=margin,
                  control_mesh=control_mesh, record=record, pick_radius=pick_radius,
                  renderer=renderer, show_folds=show_folds, spare_pins=spare_pins,
                  **render_options)
