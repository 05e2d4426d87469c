"""Posing with the mouse, without a screen: synthesised press, motion and release events on
an Agg canvas move a handle's target, redraw the shape by blitting, and never recompile."""

import jax
import matplotlib
import numpy as np
import pytest

import mvcjax

matplotlib.use("Agg")

import matplotlib.pyplot as plt
from matplotlib.backend_bases import MouseEvent

HEAD = 4  # the horse's head handle

# ipympl's toolbar, built outside a kernel, passes traitlets an argument it deprecates.
pytestmark = [pytest.mark.filterwarnings(
    "ignore:Passing unrecognized arguments:DeprecationWarning"),
    # Agg, as everywhere here: the warning is tested once, below.
    pytest.mark.filterwarnings("ignore:matplotlib's backend")]


# A pose as shown against the pose computed again, and targets set by the mouse against
# where it was, on the horse (about 500 units across), in float32: a few roundings.
POSE = dict(rtol=0, atol=1e-3)
TARGET = dict(rtol=0, atol=1e-4)


@pytest.fixture(autouse=True)
def close_figures():
    yield
    plt.close("all")


def mouse(posing, kind, point, button=1):
    """A mouse event at a point of the plane, through the canvas as a backend sends it."""
    x, y = posing.axes.transData.transform(np.asarray(point, np.float64))
    MouseEvent(f"{kind}_event", posing.figure.canvas, x, y, button=button)._process()


def drag(posing, handle, path):
    mouse(posing, "button_press", posing.targets[handle])
    for point in path:
        mouse(posing, "motion_notify", point)
    mouse(posing, "button_release", path[-1])


class Compilations:
    """Counts XLA compilations while active."""

    def __init__(self):
        self.count = 0

    def __call__(self, event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            self.count += 1

    def __enter__(self):
        jax.monitoring.register_event_duration_secs_listener(self)
        return self

    def __exit__(self, *exc):
        jax.monitoring.unregister_event_duration_listener(self)


def started(posing):
    posing.figure.canvas.draw()  # as a backend does when the figure is first shown
    return posing


def canvas_pixels(posing):
    return np.asarray(posing.figure.canvas.buffer_rgba()).astype(np.int16)


@pytest.mark.parametrize("textured", [False, True], ids=["filled", "textured"])
def test_a_drag_moves_the_target_and_the_drawn_shape_without_recompiling(horse_rig32, textured):
    options = {"size": (64, 64)} if textured else {}
    posing = started(mvcjax.interact(horse_rig32, **options))
    rest = posing.targets.copy()
    before = canvas_pixels(posing)
    start = rest[HEAD]
    path = [start + step * np.array([4.0, 2.5]) for step in range(1, 6)]
    with Compilations() as compiled:
        drag(posing, HEAD, path)
    assert compiled.count == 0
    assert posing.updates == len(path)
    np.testing.assert_allclose(posing.targets[HEAD], path[-1], atol=1e-6 * np.abs(start).max())
    np.testing.assert_array_equal(np.delete(posing.targets, HEAD, 0), np.delete(rest, HEAD, 0))
    expected = horse_rig32.deform(posing.targets)
    np.testing.assert_allclose(posing.shape_vertices, expected, **POSE)
    if textured:
        picture = posing.renderer(expected)
        np.testing.assert_allclose(posing.picture, np.round(np.asarray(picture) * 255), atol=1)
        np.testing.assert_array_equal(posing._image.get_array(), posing.picture)
    else:
        outline = posing._patch.get_path().vertices
        at_rest = np.asarray(horse_rig32.shape_mesh.vertices)[posing._outline_index]
        np.testing.assert_allclose(outline, np.asarray(expected)[posing._outline_index],
                                   **POSE)
        assert np.abs(outline - at_rest).max() > 1.0
    # What was blitted is what a full redraw draws: no artist left behind or stale.
    blitted = canvas_pixels(posing)
    assert np.abs(blitted - before).max() > 100
    posing.figure.canvas.draw()
    assert np.abs(canvas_pixels(posing) - blitted).max() <= 2


def test_moves_after_release_or_away_from_handles_change_nothing(horse_rig32):
    posing = started(mvcjax.interact(horse_rig32))
    rest = posing.targets.copy()
    drag(posing, HEAD, [rest[HEAD] + 10.0])
    moved = posing.targets.copy()
    mouse(posing, "motion_notify", rest[HEAD] + 30.0)  # released: not dragging any more
    far = 0.5 * (rest[0] + rest[3])  # between two handles, far from both
    mouse(posing, "button_press", far)
    mouse(posing, "motion_notify", far + 20.0)
    mouse(posing, "button_release", far + 20.0)
    np.testing.assert_array_equal(posing.targets, moved)
    assert posing.updates == 1


def shape_point_away_from_handles(rig, seed=0):
    """A shape-mesh vertex inside the horse, far from every handle and the outline."""
    v = np.asarray(rig.shape_mesh.vertices, np.float64)
    loops = mvcjax.geometry.boundary_loops(np.asarray(rig.shape_mesh.faces))
    handles = np.asarray(rig.handle_positions)
    far = np.min(np.linalg.norm(v[:, None] - handles[None], axis=2), axis=1)
    ok = np.setdiff1d(np.flatnonzero(far > 60.0), np.concatenate(loops))
    return int(np.random.default_rng(seed).choice(ok))


def test_a_click_adds_a_pin_and_a_right_click_removes_one_without_compiling(horse_rig32):
    posing = started(mvcjax.interact(horse_rig32))
    rest = posing.targets.copy()
    drag(posing, HEAD, [rest[HEAD] + 5.0])  # compiled by now
    vertex = shape_point_away_from_handles(horse_rig32)
    point = np.asarray(horse_rig32.shape_mesh.vertices)[vertex].astype(np.float64)
    before = posing.shape_vertices.copy()
    seen = []  # what the figure showed after each mouse event: checked afterwards

    def shown():  # the session's own rig: its spare rows are all there
        seen.append((posing._all.copy(), posing.shape_vertices.copy(), posing._rig))
        assert posing.folds == 0  # every pose shown here unfolded

    with Compilations() as compiled:
        mouse(posing, "button_press", point)  # a pin there, and dragged at once
        shown()
        mouse(posing, "motion_notify", point + [25.0, 10.0])
        mouse(posing, "button_release", point + [25.0, 10.0])
        shown()
        mouse(posing, "button_press", posing.targets[HEAD], button=3)  # the head's pin out
        shown()
        mouse(posing, "button_press", rest[0] + [300.0, 300.0])  # beside the shape: nothing
        shown()
    assert compiled.count == 0
    (_, pinned, _), (_, moved, _), (_, freed, rig_freed), last = seen
    assert len(posing.targets) == 6 and posing.rig.handles.count == 6
    # Pinned where it is: the pose stays the energy's minimum (test_pins); the default
    # solver's 100 steps take another path to it, ending a little apart.
    np.testing.assert_allclose(pinned, before, rtol=0, atol=0.2)
    for targets, vertices, rig in seen[1:]:
        np.testing.assert_allclose(vertices, rig.deform(targets), **POSE)
    np.testing.assert_allclose(posing.targets[5], point + [25.0, 10.0], **TARGET)
    assert np.linalg.norm(moved[vertex] - (point + [25.0, 10.0])) < 2.0
    assert rig_freed.active[:6].tolist() == [True] * 4 + [False, True]
    assert posing.rig.active.tolist() == [True] * 4 + [False, True]
    np.testing.assert_allclose(freed, posing.rig.deform(posing.targets), **POSE)
    assert not np.allclose(freed, moved, atol=1.0)
    np.testing.assert_array_equal(last[1], freed)
    assert len(posing.pin_seconds) == 2
    assert posing._pose._cache_size() == 1
    # Undo keeps the pins as a few small arrays, not rigs (each with a factor of its own).
    assert not any(isinstance(pins, mvcjax.Rig) for _, pins in posing._history)
    key(posing, "u")  # the head's pin is back
    assert posing.rig.active.all()
    key(posing, "u")  # the new pin back where it was placed (its spot of the control
    np.testing.assert_allclose(posing.targets[5], point, rtol=0, atol=0.01)  # mesh)
    key(posing, "u")  # and gone
    assert len(posing.targets) == 5 and posing.rig is horse_rig32
    for row in range(4):
        mouse(posing, "button_press", posing.targets[row], button=3)
    mouse(posing, "button_press", posing.targets[HEAD], button=3)
    assert "last pin" in posing._status.get_text()
    assert posing.rig.active.tolist() == [False] * 4 + [True]


def test_pins_fill_the_spare_rows_then_say_so(horse_rig32):
    posing = started(mvcjax.interact(horse_rig32, spare_pins=2))
    points = [np.asarray(horse_rig32.shape_mesh.vertices)[
        shape_point_away_from_handles(horse_rig32, seed)] for seed in range(3)]
    for point in points:
        mouse(posing, "button_press", point)
        mouse(posing, "button_release", point)
    assert len(posing.targets) == 7
    assert "all 2 spare pins are placed" in posing._status.get_text()
    posing.record()
    drag(posing, 5, [points[0] + 10.0])
    mouse(posing, "button_press", posing.targets[6], button=3)
    drag(posing, 5, [points[0] + 20.0])
    frames = np.asarray(posing.frames())
    assert frames.shape[0] == 4
    np.testing.assert_allclose(frames[-1], posing.shape_vertices, **POSE)
    assert posing.recorded().shape == (4, 6, 2)
    plain = started(mvcjax.interact(horse_rig32, spare_pins=0))
    mouse(plain, "button_press", points[0])
    assert "spare_pins" in plain._status.get_text() and len(plain.targets) == 5


@pytest.mark.parametrize("stretch", [False, True])
def test_bones_are_dragged_by_their_ends(horse, stretch):
    # A rigid bone turns about the end not dragged, which stays on its dot, even with
    # the mouse beyond the bone's reach; a stretchy bone's end follows the mouse.
    rig = mvcjax.Rig.build(horse, [mvcjax.Bone((150.0, 170.0), (250.0, 170.0), stretch=stretch),
                                   (280.0, 20.0), (62.0, 20.0)])
    posing = started(mvcjax.interact(rig))
    start, end = posing.targets[0].copy(), posing.targets[1].copy()
    mouse_at = end + np.array([60.0, 100.0])
    drag(posing, 1, [end + np.array([0.0, 20.0]), mouse_at])
    np.testing.assert_allclose(posing.targets[0], start, **TARGET)
    if stretch:
        np.testing.assert_allclose(posing.targets[1], mouse_at, **TARGET)
    else:
        towards = (mouse_at - start) / np.linalg.norm(mouse_at - start)
        np.testing.assert_allclose(posing.targets[1], start + 100.0 * towards, **TARGET)
        # The bone's pinned points: its start exactly on the start's dot.
        pinned = np.asarray(rig.pinned_targets(posing.targets))
        assert np.min(np.linalg.norm(pinned - start, axis=1)) < 1e-6
    x, y = posing._bone_line.get_data()
    np.testing.assert_allclose([x[1], y[1]], posing.targets[1])
    np.testing.assert_allclose(posing.shape_vertices, rig.deform(posing.targets), **POSE)


def test_a_recorded_drag_gives_frames_and_an_animation(horse_rig32, tmp_path):
    posing = started(mvcjax.interact(horse_rig32, record=True))
    start = posing.targets[HEAD].copy()
    path = [start + np.array([3.0 * i, 0.0]) for i in range(1, 8)]
    drag(posing, HEAD, path)
    recorded = posing.recorded()
    assert recorded.shape == (len(path) + 1, 5, 2)  # the rest pose, then each move
    np.testing.assert_allclose(recorded[-1, HEAD], path[-1], **TARGET)
    np.testing.assert_allclose(recorded[0], horse_rig32.handle_positions)
    # Resampled in time: the first and last poses kept, linear in between.
    sampled = posing.recorded(fps=1000)
    np.testing.assert_allclose(sampled[0], recorded[0])
    assert np.all(np.diff(sampled[:, HEAD, 0]) >= -1e-9)
    frames = posing.frames()
    assert frames.shape == (len(recorded), horse_rig32.shape_mesh.vertices.shape[0], 2)
    np.testing.assert_allclose(frames[-1], horse_rig32.deform(recorded[-1]), **POSE)
    path_gif = tmp_path / "drag.gif"
    posing.write_animation(path_gif, fps=10,
                           renderer=mvcjax.Renderer.build(horse_rig32, size=(32, 32)))
    assert path_gif.stat().st_size > 1000
    posing.record(False)
    drag(posing, HEAD, [start])
    assert len(posing.recorded()) == len(recorded)


def test_set_targets_and_reset(horse_rig32):
    posing = mvcjax.interact(horse_rig32)
    targets = np.asarray(horse_rig32.handle_positions) + 5.0
    posing.set_targets(targets)
    np.testing.assert_allclose(posing.shape_vertices, horse_rig32.deform(targets), **POSE)
    posing.reset()
    np.testing.assert_allclose(posing.targets, horse_rig32.handle_positions)
    with pytest.raises(ValueError, match=r"targets must be \(5, 2\)"):
        posing.set_targets(np.zeros((4, 2)))


@pytest.mark.float64
def test_it_draws_in_given_axes_at_any_placement_and_scale(horse):
    shape = mvcjax.Shape.from_polygon(1e-3 * horse.outer + 1e3, [1e-3 * h + 1e3
                                                                   for h in horse.holes])
    handles = [1e-3 * np.asarray(h) + 1e3 for h in mvcjax.datasets.horse_handles()]
    rig = mvcjax.Rig.build(shape, handles)
    _, axes = plt.subplots(1, 2)
    posing = started(mvcjax.interact(rig, ax=axes[1]))
    assert posing.axes is axes[1]
    start = posing.targets[HEAD].copy()
    drag(posing, HEAD, [start + 0.01])
    np.testing.assert_allclose(posing.targets[HEAD], start + 0.01, **TARGET)
    np.testing.assert_allclose(posing.shape_vertices, rig.deform(posing.targets), **POSE)


def test_bad_input_says_what_to_do(horse_rig32, horse):
    with pytest.raises(TypeError, match="rig must be an mvcjax.Rig"):
        mvcjax.interact(horse)
    with pytest.raises(ValueError, match="no handle of the rig lies in the window"):
        mvcjax.interact(horse_rig32, window=(1e4, 1e4, 1e4 + 10, 1e4 + 10))
    other = mvcjax.Renderer.build(mvcjax.Rig.build(horse, mvcjax.datasets.horse_handles(),
                                                   shape_spacing=20.0), size=(16, 16))
    with pytest.raises(ValueError, match="renderer was built for a mesh of"):
        mvcjax.interact(horse_rig32, renderer=other)
    moved = (np.asarray(horse_rig32.shape_mesh.vertices) + 50.0, horse_rig32.shape_mesh.faces)
    with pytest.raises(ValueError, match="another mesh of the same size"):
        mvcjax.interact(horse_rig32, renderer=mvcjax.Renderer.build(moved, size=(16, 16)))
    with pytest.raises(ValueError, match="pick_radius"):
        mvcjax.interact(horse_rig32, pick_radius=0)
    with pytest.raises(ValueError, match="margin must be a number"):
        mvcjax.interact(horse_rig32, margin="wide")
    with pytest.raises(ValueError, match=r"window must be \(xmin, ymin, xmax, ymax\)"):
        mvcjax.interact(horse_rig32, window=(0, 0, -1, 1))
    with pytest.raises(TypeError, match="ax must be matplotlib axes"):
        mvcjax.interact(horse_rig32, ax="left")
    posing = mvcjax.interact(horse_rig32)
    with pytest.raises(ValueError, match="nothing was recorded"):
        posing.recorded()


def test_jupyter_widget_canvases_are_blitted(horse_rig32):
    # ipympl's canvas (`%matplotlib widget`) reports supports_blit = False; it can blit,
    # and a blit there sends the changed pixels to the browser.
    from matplotlib.figure import Figure

    try:
        from ipympl.backend_nbagg import _Backend_ipympl
    finally:
        plt.switch_backend("Agg")  # importing ipympl makes it pyplot's backend

    figure = Figure()
    _Backend_ipympl.new_figure_manager_given_figure(1, figure)
    posing = started(mvcjax.interact(horse_rig32, ax=figure.add_subplot()))
    canvas = posing.figure.canvas
    blits, draws = [], []
    canvas.blit = lambda bbox=None: blits.append(bbox)
    canvas.draw_idle = lambda: draws.append(1)
    drag(posing, HEAD, [posing.targets[HEAD] + 5.0, posing.targets[HEAD] + 9.0])
    assert len(blits) == posing.updates == 2 and not draws


def test_a_picture_made_for_the_axes_is_drawn_where_matplotlib_would_draw_it(horse_rig32):
    from matplotlib.image import AxesImage

    _, ax = plt.subplots(figsize=(2.5, 2.5))
    posing = started(mvcjax.interact(horse_rig32, ax=ax, fill=mvcjax.advanced.Checkerboard()))
    box = ax.bbox
    assert posing.renderer.shape == (round(box.height), round(box.width))  # the default size
    drag(posing, HEAD, [posing.targets[HEAD] + 12.0])
    canvas = posing.figure.canvas
    canvas.restore_region(posing._background)
    ax.draw_artist(posing._image)  # pixel for pixel
    direct = canvas_pixels(posing)
    canvas.restore_region(posing._background)
    AxesImage.draw(posing._image, canvas.get_renderer())  # matplotlib's resampling
    resampled = canvas_pixels(posing)
    difference = np.abs(direct - resampled).max(axis=-1)
    assert np.abs(direct - canvas_pixels(started(posing))).max() > 0  # handles drawn on top
    # They differ at edges only, by the box's sub-pixel place; a shift by one pixel, or a
    # flip, would differ at three times as many pixels or more.
    assert np.mean(difference > 8) < 0.04 and difference.mean() < 3


BACK = 3  # the horse's back handle: pulled down through the legs, the legs fold
FOLDING = np.array([0.0, -150.0])  # a pull of the back handle that folds the legs


def red_pixels(posing):
    """How many canvas pixels are the fold overlay's red over the filled shape."""
    pixels = canvas_pixels(posing)
    r, g, b = pixels[..., 0], pixels[..., 1], pixels[..., 2]
    return int(np.sum((r > 190) & (g < 110) & (b < 90)))


def folded_corners(rest, pose, faces):
    """The corners of the triangles flipped between rest and pose, sorted, for comparing
    sets of triangles."""
    def signed(v):
        (ax, ay), (bx, by), (cx, cy) = (v[faces[:, i]].T for i in range(3))
        return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)

    flipped = np.sign(signed(rest)) != np.sign(signed(pose))
    corners = pose[faces[flipped]].reshape(-1, 6)
    return corners[np.lexsort(corners.T[::-1])]


@pytest.fixture(scope="module")
def folding_rig(horse_rig32):
    """The horse with the paper's energy, whose drag of the back folds it (the default
    energy folds far less)."""
    return horse_rig32.with_weights(mvcjax.Weights.paper())


def test_a_drag_that_folds_draws_the_folded_triangles_red_without_recompiling(folding_rig):
    horse_rig32 = folding_rig
    solver = mvcjax.FixedG(iterations=15)
    posing = started(mvcjax.interact(horse_rig32, solver=solver))
    rest_vertices = np.asarray(horse_rig32.shape_mesh.vertices)
    faces = np.asarray(horse_rig32.shape_mesh.faces)
    assert posing.folds == 0 and not posing._fold_patch.get_visible() and posing.hint == ""
    unfolded_red = red_pixels(posing)
    start = posing.targets[BACK].copy()
    path = [start + FOLDING * step / 5 for step in range(1, 6)]
    counts = []
    with Compilations() as compiled:
        mouse(posing, "button_press", start)
        for point in path:
            mouse(posing, "motion_notify", point)
            counts.append(posing.folds)
            expected = mvcjax.flipped_triangles(rest_vertices, posing.shape_vertices, faces)
            assert posing.folds == expected
        mouse(posing, "button_release", path[-1])
    assert compiled.count == 0
    assert len(set(counts)) > 1 and counts[-1] > 100  # the count followed the drag
    np.testing.assert_allclose(posing.shape_vertices, horse_rig32.deform(posing.targets, solver),
                               **POSE)
    # The overlay holds the flipped triangles, each once, at their posed corners.
    drawn = posing._fold_patch.get_path().vertices.reshape(-1, 4, 2)[:, :3].reshape(-1, 6)
    assert posing._fold_patch.get_visible() and len(drawn) == posing.folds
    np.testing.assert_array_equal(drawn[np.lexsort(drawn.T[::-1])],
                                  folded_corners(rest_vertices, posing.shape_vertices, faces))
    assert red_pixels(posing) > unfolded_red + 200
    assert posing.hint == f"{posing.folds} triangles folded: try solver=mvcjax.FoldFree()"
    assert posing._fold_hint.get_visible() and len(posing._fold_hint.get_path().vertices)
    # What was blitted is what a full redraw draws, overlay and hint included.
    blitted = canvas_pixels(posing)
    posing.figure.canvas.draw()
    assert np.abs(canvas_pixels(posing) - blitted).max() <= 2
    # Back at rest: nothing folded, nothing red, no hint.
    key(posing, "u")
    assert posing.folds == 0 and posing.hint == ""
    assert not posing._fold_patch.get_visible() and not posing._fold_hint.get_visible()
    assert red_pixels(posing) == unfolded_red


def test_a_pose_without_folds_draws_no_overlay(horse_rig32):
    posing = started(mvcjax.interact(horse_rig32))
    drag(posing, HEAD, [posing.targets[HEAD] + np.array([10.0, 5.0])])
    faces = np.asarray(horse_rig32.shape_mesh.faces)
    assert mvcjax.flipped_triangles(horse_rig32.shape_mesh.vertices, posing.shape_vertices,
                                    faces) == 0
    assert posing.folds == 0 and posing.hint == ""
    assert not posing._fold_patch.get_visible() and not posing._fold_hint.get_visible()


def test_show_folds_false_draws_no_overlay_and_still_counts(folding_rig):
    horse_rig32 = folding_rig
    targets = np.asarray(horse_rig32.handle_positions).copy()
    targets[BACK] += FOLDING
    shown, hidden = (started(mvcjax.interact(horse_rig32, show_folds=show))
                     for show in (True, False))
    for posing in (shown, hidden):
        posing.set_targets(targets)
    faces = np.asarray(horse_rig32.shape_mesh.faces)
    folds = mvcjax.flipped_triangles(horse_rig32.shape_mesh.vertices, hidden.shape_vertices,
                                     faces)
    assert folds > 0 and hidden.folds == shown.folds == folds
    assert hidden._fold_patch is None and hidden._fold_hint is None and hidden.hint == ""
    assert red_pixels(shown) > red_pixels(hidden) + 200
    # What was blitted is what a full redraw draws: nothing red left behind.
    blitted = canvas_pixels(hidden)
    hidden.figure.canvas.draw()
    assert np.abs(canvas_pixels(hidden) - blitted).max() <= 2


def test_a_fold_free_drag_starts_each_step_from_the_pose_before(horse_rig32):
    posing = mvcjax.interact(horse_rig32, solver=mvcjax.FoldFree())
    rest = np.asarray(horse_rig32.handle_positions)
    previous = np.asarray(posing.control_vertices)
    for step in (1, 2, 3):
        targets = rest.copy()
        targets[BACK] += 0.15 * step * FOLDING
        posing.set_targets(targets)
        expected = horse_rig32.solve(targets, mvcjax.FoldFree(), init=previous)
        # Both stop at FoldFree's float32 tolerance, compiled apart.
        np.testing.assert_allclose(posing.control_vertices, expected, rtol=0,
                                   atol=2e-4 * float(horse_rig32.frame.scale))
        assert mvcjax.flipped_triangles(horse_rig32.control_mesh.vertices,
                                        posing.control_vertices,
                                        horse_rig32.control_mesh.faces) == 0
        previous = np.asarray(posing.control_vertices)


def test_the_fold_free_solver_poses_without_a_suggestion(horse_rig32):
    targets = np.asarray(horse_rig32.handle_positions).copy()
    targets[BACK] += 0.4 * FOLDING  # the default solver folds the control mesh here
    control = horse_rig32.control_mesh
    posing = mvcjax.interact(horse_rig32, solver=mvcjax.FoldFree())
    posing.set_targets(targets)
    assert mvcjax.flipped_triangles(control.vertices, posing.control_vertices,
                                    control.faces) == 0
    np.testing.assert_allclose(posing.shape_vertices, horse_rig32.skin(posing.control_vertices),
                               **POSE)
    faces = np.asarray(horse_rig32.shape_mesh.faces)
    assert posing.folds == mvcjax.flipped_triangles(horse_rig32.shape_mesh.vertices,
                                                    posing.shape_vertices, faces)
    folds = posing.folds
    assert posing.hint == (f"{folds} triangle{'s' * (folds != 1)} folded" if folds else "")
    # Its suggestion is for the other solvers.
    assert mvcjax._interact._fold_words(3, mvcjax.FoldFree()) == "3 triangles folded"


def test_the_hint_is_drawn_from_cached_glyphs_as_the_whole_text_would_be():
    from matplotlib.font_manager import FontProperties
    from matplotlib.textpath import TextPath

    from mvcjax._interact import _text_path

    for text in ("1 triangle folded", "1203 triangles folded: try solver=mvcjax.FoldFree()"):
        whole = TextPath((0, 0), text, prop=FontProperties(size=8.0))
        pieced = _text_path(text, 8.0)
        np.testing.assert_array_equal(pieced.codes, whole.codes)
        np.testing.assert_allclose(pieced.vertices, whole.vertices, **POSE)


def test_the_default_solver_is_that_of_rig_deform(horse_rig32):
    from mvcjax.solvers import DEFAULT_SOLVER

    posing = mvcjax.interact(horse_rig32)
    assert posing.solver is DEFAULT_SOLVER
    targets = np.asarray(horse_rig32.handle_positions) + np.array([0.0, 12.0])
    posing.set_targets(targets)
    np.testing.assert_allclose(posing.shape_vertices, horse_rig32.deform(targets), **POSE)


def test_folds_are_drawn_over_a_textured_picture(horse_rig32):
    posing = started(mvcjax.interact(horse_rig32, size=(48, 48)))
    targets = np.asarray(horse_rig32.handle_positions).copy()
    targets[BACK] += FOLDING
    posing.set_targets(targets)
    folds = mvcjax.flipped_triangles(horse_rig32.shape_mesh.vertices, posing.shape_vertices,
                                     horse_rig32.shape_mesh.faces)
    assert folds > 0 and posing.folds == folds
    assert len(posing._fold_patch.get_path().vertices) == 4 * folds
    artists = posing._artists()
    assert artists.index(posing._image) < artists.index(posing._fold_patch)  # on top
    blitted = canvas_pixels(posing)
    posing.figure.canvas.draw()
    assert np.abs(canvas_pixels(posing) - blitted).max() <= 2


def test_without_a_window_it_says_nothing_can_be_dragged(horse_rig32):
    import warnings

    with pytest.warns(UserWarning, match="shows no window.*%matplotlib widget"):
        mvcjax.interact(horse_rig32)
    # On a canvas that takes the mouse (an ipympl widget's), nothing is said.
    from matplotlib.figure import Figure

    try:
        from ipympl.backend_nbagg import _Backend_ipympl
    finally:
        plt.switch_backend("Agg")  # importing ipympl makes it pyplot's backend
    figure = Figure()
    _Backend_ipympl.new_figure_manager_given_figure(1, figure)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        mvcjax.interact(horse_rig32, ax=figure.add_subplot())


def key(posing, name):
    from matplotlib.backend_bases import KeyEvent

    KeyEvent("key_press_event", posing.figure.canvas, name)._process()


def test_keys_undo_reset_toggle_the_mesh_and_record(horse_rig32):
    posing = started(mvcjax.interact(horse_rig32))
    rest = posing.targets.copy()
    head = rest[HEAD]
    drag(posing, HEAD, [head + [10.0, 0.0]])
    after_one = posing.targets.copy()
    drag(posing, 0, [rest[0] + [0.0, 15.0]])
    mouse(posing, "button_press", posing.targets[1])  # a click that moves nothing
    mouse(posing, "button_release", posing.targets[1])
    key(posing, "u")  # takes back the second drag, not the click
    np.testing.assert_array_equal(posing.targets, after_one)
    np.testing.assert_allclose(posing.shape_vertices, horse_rig32.deform(after_one), **POSE)
    key(posing, "r")
    np.testing.assert_array_equal(posing.targets, rest)
    key(posing, "u")  # a reset is undone too
    np.testing.assert_array_equal(posing.targets, after_one)
    key(posing, "u")
    np.testing.assert_array_equal(posing.targets, rest)
    key(posing, "u")
    assert "nothing to undo" in posing._status.get_text()
    assert posing._control.get_visible()
    key(posing, "m")
    assert not posing._control.get_visible()
    key(posing, "m")
    assert posing._control.get_visible()
    assert not posing.recording
    key(posing, " ")
    assert posing.recording
    drag(posing, HEAD, [head + [5.0, 0.0], head + [9.0, 0.0]])
    key(posing, " ")
    assert not posing.recording and "3 poses" in posing._status.get_text()
    assert len(posing.recorded()) == 3
    assert "u undo" in posing.axes.get_title()
