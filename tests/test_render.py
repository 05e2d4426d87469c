"""The renderer: pictures back at rest, exact shifts and rotations, affine warps against
scikit-image, gradients against finite differences, folds, draw order, bad input."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from skimage import data, draw, measure, morphology, transform

import mvcjax
from mvcjax import datasets

from conftest import host_callbacks

GROWN = mvcjax.advanced.GrownWindow()  # the renderer's window, grown to hold the pose


@pytest.fixture(scope="module")
def picture():
    """A character picture: scikit-image's horse silhouette as alpha, its astronaut photo
    as paint (a texture with fine detail), at a third of the size."""
    mask = transform.rescale((~data.horse()).astype(float), 0.35, order=0) > 0.5
    paint = transform.resize(data.astronaut(), mask.shape, anti_aliasing=True)
    return np.dstack([paint, mask]).astype(np.float64)


@pytest.fixture(scope="module")
def rig(picture):
    shape = mvcjax.Shape.from_image(picture)
    handles = [shape.closest_point(p) for p in [(20, 25), (110, 25), (115, 95), (30, 80)]]
    return mvcjax.Rig.build(shape, handles)


@pytest.fixture(scope="module")
def rig64(picture):
    """The same rig in float64, for finite differences."""
    shape = mvcjax.Shape.from_image(picture)
    handles = [shape.closest_point(p) for p in [(20, 25), (110, 25), (115, 95), (30, 80)]]
    return mvcjax.Rig.build(shape, handles, dtype=jnp.float64)


# Pixel values (in [0, 1]) that should agree exactly do, to float32 rounding: the
# programs that draw them (batched or not, a window grown or given) round pixel
# coordinates of a few hundred pixels differently, by float32's epsilon times that (about
# 5e-5 of a pixel), and a value changes by up to its colour's slope (about 1 a pixel)
# times that. Far below an 8-bit picture's step, 1/255.
ROUNDING = 5e-5


@pytest.fixture(scope="module")
def renderer(rig, picture):
    return mvcjax.Renderer.build(rig, picture)


def premultiplied(p):
    p = np.asarray(p)
    return np.concatenate([p[..., :3] * p[..., 3:], p[..., 3:]], axis=-1)


def inside(picture, margin=2):
    """Pixels at least `margin` pixels inside the silhouette."""
    return morphology.erosion(picture[..., 3] > 0.5, morphology.disk(margin))


def test_rest_pose_draws_the_picture_back(renderer, rig, picture):
    out = np.asarray(renderer(rig.shape_mesh.vertices))
    assert out.shape == picture.shape and np.all(np.isfinite(out))
    # Away from the outline the picture comes back to rounding (bilinear lookups at pixel
    # centres); along it, alpha is the mesh's antialiased coverage of the pixel.
    assert np.abs(out - picture)[inside(picture)].max() < ROUNDING
    alpha_error = np.abs(out[..., 3] - picture[..., 3])
    assert alpha_error.mean() < 0.01
    assert alpha_error[~morphology.dilation(picture[..., 3] > 0.5, morphology.disk(2))].max() == 0


def test_the_default_draw_order_is_decided_at_rest(renderer, rig):
    # The core's depth: fixed per triangle, whatever the pose, so that no pose (nor a
    # pose at rest to rounding) can reorder the triangles.
    vertices = np.asarray(rig.shape_mesh.vertices)
    faces = np.asarray(rig.shape_mesh.faces)
    depth = mvcjax.advanced.core_depth(vertices, faces)
    # Deepest inside the outline is the core, at depth 0; the farthest are the limbs' ends.
    assert depth.min() == 0 and depth.max() > 0.5 * np.ptp(vertices, axis=0).max()
    # The renderer keeps the triangles deepest last, in bands of depth.
    drawn = np.asarray(renderer.faces)
    assert sorted(map(tuple, drawn)) == sorted(map(tuple, faces))
    assert np.all(np.diff(depth[drawn].mean(axis=1)) >= 0)
    level = np.asarray(renderer.level)
    assert np.all(np.diff(level) >= 0) and level.max() == 15
    noise = np.random.default_rng(0).normal(scale=1e-5, size=vertices.shape)
    rest = premultiplied(renderer(vertices))
    for pose in [vertices + noise, rig.deform(rig.handle_positions)]:
        np.testing.assert_allclose(premultiplied(renderer(pose)), rest, atol=10 * ROUNDING)


def test_the_outline_is_one_edge_across_the_draw_levels(rig, picture):
    # Neighbours along the outline in different bands of depth draw one antialiased edge:
    # the picture equals the one drawn with every triangle on one level, in any pose.
    flat = np.zeros(rig.shape_mesh.vertices.shape[0])
    one_level = mvcjax.Renderer.build(rig, picture, depth=flat)
    banded = mvcjax.Renderer.build(rig, picture)
    assert len(np.unique(np.asarray(banded.level))) == 16
    dragged = rig.handle_positions.at[0].add(jnp.array([6.0, -4.0]))
    for pose in [rig.shape_mesh.vertices, rig.deform(dragged)]:
        np.testing.assert_allclose(premultiplied(banded(pose)), premultiplied(one_level(pose)),
                                   atol=0.5 / 2**6)  # ties of quantised coverage


def test_core_depth_is_the_same_at_any_place_and_scale(rig):
    vertices = np.asarray(rig.shape_mesh.vertices, np.float64)
    faces = np.asarray(rig.shape_mesh.faces)
    depth = mvcjax.advanced.core_depth(vertices, faces)
    np.testing.assert_allclose(mvcjax.advanced.core_depth(vertices * 1e-3 + 500.0, faces) * 1e3,
                               depth, rtol=1e-6, atol=1e-6 * depth.max())
    # Two pieces each have their own core.
    two = mvcjax.advanced.core_depth(np.concatenate([vertices, vertices + 1e4]),
                            np.concatenate([faces, faces + len(vertices)]))
    np.testing.assert_allclose(two, np.concatenate([depth, depth]))


def test_an_arm_swung_across_its_own_body_stays_in_front_in_every_frame():
    # One silhouette: the sprite's arm turned across its chest and back. Wherever the arm
    # alone would cover a pixel wholly, in this frame and the last, the arm shows in
    # both: no part of the body flickers over it, and no patch stays over the armpit.
    shape, picture = datasets.sprite(), datasets.sprite_picture()
    rig = mvcjax.Rig.build(shape, datasets.sprite_handles())
    rest = np.asarray(rig.handle_positions, np.float64)
    frames = 16
    targets = np.repeat(rest[None], frames, 0)
    for k, turn in enumerate(np.radians(-110) * np.sin(np.linspace(0, np.pi, frames))):
        c, s = np.cos(turn), np.sin(turn)
        targets[k, 4] = rest[3] + np.array([[c, -s], [s, c]]) @ (rest[4] - rest[3])
    poses = np.asarray(mvcjax.deform_frames(rig, targets))
    vertices = np.asarray(rig.shape_mesh.vertices, np.float64)
    faces = np.asarray(rig.shape_mesh.faces)
    # The arm: triangles along the shoulder-to-hand bone beyond its first third. The
    # picture is painted blue, the arm red, so that the picture says which part shows.
    start, end = rest[3], rest[4]
    centre = vertices[faces].mean(axis=1)
    along = np.clip((centre - start) @ (end - start) / np.sum((end - start) ** 2), 0, 1)
    arm = (np.linalg.norm(start + along[:, None] * (end - start) - centre, axis=1) < 12) \
        & (along > 0.3)
    rows, cols = picture.shape[:2]
    painted = np.zeros((rows, cols, 4))
    painted[..., 2] = 1.0
    painted[..., 3] = np.asarray(picture)[..., 3] / 255.0
    for triangle in vertices[faces[arm]]:
        rr, cc = draw.polygon(rows - 1 - triangle[:, 1], triangle[:, 0], (rows, cols))
        painted[rr, cc, :3] = (1.0, 0.0, 0.0)
    window = (-0.5, -0.5, cols - 0.5, rows - 0.5)
    arm_alone = mvcjax.Renderer.build((vertices, faces[arm]), fill=(1.0, 0.0, 0.0),
                                      window=window, size=(rows, cols))
    covered = np.stack([np.asarray(arm_alone(p))[..., 3] > 0.99 for p in poses])
    shown = mvcjax.Renderer.build(rig, painted).frames(poses)
    red = shown[..., 0].astype(int) > shown[..., 2]
    assert covered.sum() > 1000  # the arm crosses the body
    both = covered[1:] & covered[:-1]
    switched = both & (red[1:] != red[:-1])
    # A handful of pixels where the arm's first third (painted blue) meets the rest.
    assert switched.sum() <= 8, switched.sum()
    assert np.sum(covered & ~red) <= 8


def test_whole_pixel_translation_shifts_the_picture_exactly(renderer, rig):
    rest = premultiplied(renderer(rig.shape_mesh.vertices))
    moved = premultiplied(renderer(rig.shape_mesh.vertices + jnp.array([3.0, -2.0])))
    # Three pixels right, two down (y is up); a pixel's shading sees the same numbers.
    assert np.abs(moved[2:, 3:] - rest[:-2, :-3]).max() < ROUNDING
    assert np.abs(moved[:2]).max() == 0 and np.abs(moved[:, :3]).max() == 0


def test_quarter_turn_rotates_the_picture(rig, picture):
    rows, cols = picture.shape[:2]
    square = max(rows, cols)
    window = (-0.5, -0.5, square - 0.5, square - 0.5)
    vertices = rig.shape_mesh.vertices
    r = mvcjax.Renderer.build(rig, picture, window=window, size=(square, square))
    centre = (square - 1) / 2
    # (x, y) -> (centre - (y - centre), x): a quarter turn counter-clockwise.
    turned = jnp.stack([2 * centre - vertices[:, 1], vertices[:, 0]], axis=1)
    rest, out = premultiplied(r(vertices)), premultiplied(r(turned))
    # A counter-clockwise turn in the plane (y up) is np.rot90 of the pixel grid.
    assert np.abs(out - np.rot90(rest)).max() < ROUNDING


def test_affine_drag_matches_scikit_image_affine_warp(rig, picture):
    matrix = np.array([[0.9, 0.25], [-0.15, 1.05]])
    shift = np.array([12.0, -6.0])
    vertices = np.asarray(rig.shape_mesh.vertices) @ matrix.T + shift
    r = mvcjax.Renderer.build(rig, picture)
    out = premultiplied(r(vertices))
    # scikit-image warps in (col, row) pixel coordinates, rows down: conjugate the map.
    rows = picture.shape[0]
    flip = np.array([[1, 0, 0], [0, -1, rows - 1], [0, 0, 1]])
    plane = np.eye(3)
    plane[:2, :2], plane[:2, 2] = matrix, shift
    forward = transform.AffineTransform(flip @ plane @ flip)
    expected = transform.warp(premultiplied(picture), forward.inverse, order=1)
    target = inside(np.asarray(r(vertices)), margin=3)
    assert target.sum() > 2000
    assert np.abs(out - expected)[target].max() < ROUNDING


def test_vmap_and_jit_agree_with_single_frames_without_recompiling(renderer, rig):
    frames = jnp.stack([rig.shape_mesh.vertices + jnp.array([s, 0.5 * s]) for s in range(3)])
    batched = jax.vmap(renderer)(frames)
    for frame, picture in zip(frames, batched):
        # Premultiplied: straight colours are ill-conditioned where alpha is tiny.
        np.testing.assert_allclose(premultiplied(renderer(frame)), premultiplied(picture),
                                   atol=ROUNDING)
    jitted = jax.jit(lambda v: renderer(v))
    jitted(frames[0])
    before = jitted._cache_size()
    jitted(frames[1]), jitted(frames[2])
    assert jitted._cache_size() == before


def test_vmap_draws_frames_in_turn_as_the_plain_vmap_would_with_gradients(renderer, rig):
    # jax.vmap(renderer) takes a batching rule (one frame after another, lax.map): the
    # same pictures as JAX's batching of the single frame's drawing, per-frame windows
    # ("grow") too, and the gradients of single frames; a batch of renderers is batched
    # by JAX.
    from mvcjax.rendering._render import _draw

    frames = jnp.stack([rig.shape_mesh.vertices * (1.0 + 0.1 * s) + jnp.array([s, -s])
                        for s in range(3)])
    fast = jax.jit(jax.vmap(renderer))(frames)
    plain = jax.jit(jax.vmap(lambda v: _draw(renderer, v, renderer.window)))(frames)
    np.testing.assert_allclose(premultiplied(fast), premultiplied(plain), atol=ROUNDING)
    grown = jax.vmap(lambda v: renderer(v, window=GROWN))(frames)
    for k in range(3):
        np.testing.assert_allclose(premultiplied(grown[k]),
                                   premultiplied(renderer(frames[k], window=GROWN)),
                                   atol=ROUNDING)

    def loss(v):
        return jnp.sum(jax.vmap(renderer)(v)[..., :3] ** 2)

    grad = jax.grad(loss)(frames)
    single = jnp.stack([jax.grad(lambda v: jnp.sum(renderer(v)[..., :3] ** 2))(frames[k])
                        for k in range(3)])
    assert float(jnp.abs(single).max()) > 0
    np.testing.assert_allclose(grad, single, atol=1e-4 * float(jnp.abs(single).max()))
    both = jax.tree.map(lambda *x: jnp.stack(x), renderer, renderer)
    pair = jax.vmap(lambda r, v: r(v))(both, frames[:2])
    np.testing.assert_allclose(premultiplied(pair), premultiplied(fast[:2]), atol=ROUNDING)


@pytest.fixture(scope="module")
def renderer256(rig, picture):
    return mvcjax.Renderer.build(rig, picture, size=(256, 256))


@pytest.mark.parametrize("share", [0.0, 1e-4, 0.1, 0.2, 0.6, 0.95])
@pytest.mark.parametrize("size", [(256, 256), (45, 61)])
def test_shading_only_the_drawn_pixels_equals_shading_every_pixel(renderer256, rig, picture,
                                                                   share, size):
    # The shading lists the drawn pixels' runs and takes a loop of one of a few lengths
    # (at 256 x 256 none, 1, 4 or 8 chunks: these shares take each), which must all
    # give what shading every pixel and keeping the drawn ones gives; at 45 x 61 the
    # last run is padded.
    from mvcjax.rendering._render import (
        _face_table,
        _shade,
        _shade_steps,
        _shade_where,
        _straight,
        key_layout,
        to_pixels,
    )

    renderer = renderer256 if size == (256, 256) else mvcjax.Renderer.build(rig, picture,
                                                                           size=size)
    rows, cols = renderer.shape
    if size == (256, 256):
        assert _shade_steps(rows * cols) == (0, 1, 4, 8)
    faces = renderer.faces
    tri = to_pixels(rig.shape_mesh.vertices, renderer.window, rows, cols)[faces]
    table = _face_table(tri, renderer.texture_points[faces], renderer.boundary)
    face_bits, _ = key_layout(faces.shape[0])
    rng = np.random.default_rng(0)
    layer = np.where(rng.random(rows * cols) < share,
                     rng.integers(0, faces.shape[0], rows * cols), -1).astype(np.int32)
    # What lies under a drawn pixel varies; elsewhere it is the picture's fill, as in a
    # frame, where only drawn pixels have anything but the background under them.
    fill = jnp.asarray([0.2, 0.3, 0.4, 0.5], table.dtype)
    under = jnp.where(jnp.asarray(layer >= 0)[:, None],
                      jnp.asarray(rng.random((rows * cols, 4)), table.dtype), fill)
    pixel = np.arange(rows * cols)

    def every_pixel(below):
        return np.asarray(_shade(renderer, table[np.maximum(layer, 0)].T,
                                 jnp.asarray(layer >= 0), jnp.asarray(pixel % cols, table.dtype),
                                 jnp.asarray(pixel // cols, table.dtype), below))

    for below, finish in [(under, None), (fill, None), (under, _straight)]:
        picture_fill = fill if finish is None else finish(fill)
        listed = jax.jit(lambda keys, c, finish=finish, picture_fill=picture_fill: _shade_where(
            renderer, table, keys, face_bits, cols, c, picture_fill, finish=finish))(
            jnp.asarray(layer), below)
        expected = np.where((layer >= 0)[:, None], every_pixel(below), np.asarray(fill))
        if finish is not None:
            expected = np.asarray(finish(expected))
        assert listed.shape == (rows * cols, 4)
        np.testing.assert_allclose(np.asarray(listed), expected, atol=ROUNDING)


@pytest.mark.float64
def test_gradients_match_finite_differences_inside_and_across_the_edge(rig64, picture):
    rig = rig64
    r = mvcjax.Renderer.build(rig, picture)
    vertices = rig.shape_mesh.vertices + 0.3
    rest = np.asarray(r(vertices))
    alpha = rest[..., 3]
    interior = inside(rest, margin=3) & (np.arange(alpha.size).reshape(alpha.shape) % 7 == 0)
    edge = (alpha > 0.1) & (alpha < 0.9)
    assert edge.sum() > 50
    direction = jax.random.normal(jax.random.key(0), vertices.shape, vertices.dtype)
    for where in (interior, edge):
        weights = jnp.asarray(where[..., None] * np.linspace(1, 2, 4))

        def loss(v, weights=weights):
            return jnp.sum(premultiplied_jax(r(v)) * weights)

        exact = jnp.sum(jax.grad(loss)(vertices) * direction)
        h = 1e-6
        approx = (loss(vertices + h * direction) - loss(vertices - h * direction)) / (2 * h)
        assert abs(float(exact)) > 1e-3
        assert float(exact) == pytest.approx(float(approx), rel=1e-4)


def premultiplied_jax(p):
    return jnp.concatenate([p[..., :3] * p[..., 3:], p[..., 3:]], axis=-1)


@pytest.mark.float64
def test_gradient_with_respect_to_the_picture(rig64, picture):
    rig = rig64
    def loss(texture):
        r = mvcjax.Renderer.build(rig, picture)
        r = eqx_replace_texture(r, texture)
        return jnp.sum(premultiplied_jax(r(rig.shape_mesh.vertices * 0.97 + 2.0)) ** 2)

    texture = mvcjax.Renderer.build(rig, picture).texture
    # Colours only: where alpha is 1 the output's clip to [0, 1] has a kink.
    exact, approx = directional(loss, texture, mask=np.arange(4) < 3)
    assert abs(exact) > 1e-3
    assert exact == pytest.approx(approx, rel=1e-6)


def eqx_replace_texture(renderer, texture):
    return eqx.tree_at(lambda r: r.texture, renderer, texture)


def directional(f, x, h=1e-6, mask=True):
    d = jax.random.normal(jax.random.key(1), x.shape, x.dtype) * mask
    exact = float(jnp.sum(jax.grad(f)(x) * d))
    return exact, float((f(x + h * d) - f(x - h * d)) / (2 * h))


def test_folded_and_degenerate_meshes_give_finite_pictures_and_gradients(renderer, rig):
    vertices = np.asarray(rig.shape_mesh.vertices).copy()
    rng = np.random.default_rng(0)
    folded = vertices + rng.normal(scale=1.5, size=vertices.shape)  # many flipped triangles
    collapsed = np.zeros_like(vertices) + 40.0  # every triangle a point
    line = np.stack([vertices[:, 0], np.full(len(vertices), 30.0)], axis=1)  # zero area
    for v in (folded, collapsed, line):
        out = renderer(jnp.asarray(v))
        assert np.all(np.isfinite(out))
        grad = jax.grad(lambda v: jnp.sum(renderer(v)))(jnp.asarray(v))
        assert np.all(np.isfinite(grad))
    assert np.asarray(renderer(jnp.asarray(collapsed)))[..., 3].max() == 0


def two_squares(depth=None):
    """Two unit squares side by side (one mesh, 8 vertices), the right one's vertices
    movable over the left one."""
    square = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], float)
    vertices = np.concatenate([square, square + [20, 0]])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    r = mvcjax.Renderer.build((vertices, faces), fill=(1.0, 0.0, 0.0), depth=depth,
                              window=(-5, -5, 35, 15), size=(20, 40))
    return r, vertices


def test_draw_order_by_depth_and_by_default_the_dragged_part_on_top():
    red, blue = np.array([1.0, 0, 0, 1]), np.array([0, 0, 1.0, 1])
    for depth, moved_on_top in [(None, True), ([0, 0, 0, 0, 1, 1, 1, 1], True),
                                ([1, 1, 1, 1, 0, 0, 0, 0], False)]:
        r, vertices = two_squares(depth)
        # Paint: left square red, right blue, through a two-texel texture.
        texture = jnp.asarray(np.stack([red, blue])[None], r.texture.dtype)
        points = jnp.asarray([[0.0, 0.0]] * 4 + [[1.0, 0.0]] * 4, r.texture.dtype)
        r = eqx.tree_at(lambda q: (q.texture, q.texture_points), r, (texture, points))
        moved = vertices.copy()
        moved[4:] -= [15, 0]  # the right square half over the left one
        out = np.asarray(r(jnp.asarray(moved)))
        overlap = out[10, 12]  # pixel centre (x, y) = (7.5, 4.5), inside both squares
        expected = blue if moved_on_top else red
        np.testing.assert_allclose(overlap, expected, atol=1e-12)


def test_frames_take_a_draw_order_per_frame():
    red, blue = np.array([1.0, 0, 0, 1]), np.array([0, 0, 1.0, 1])
    r, vertices = two_squares(None)
    texture = jnp.asarray(np.stack([red, blue])[None], r.texture.dtype)
    points = jnp.asarray([[0.0, 0.0]] * 4 + [[1.0, 0.0]] * 4, r.texture.dtype)
    r = eqx.tree_at(lambda q: (q.texture, q.texture_points), r, (texture, points))
    moved = vertices.copy()
    moved[4:] -= [15, 0]
    right = np.asarray(r.faces).min(axis=1) >= 4  # the right square's triangles
    levels = np.stack([np.where(right, 2, 0), np.where(right, 0, 2), np.where(right, 2, 0)])
    out = r.frames(np.repeat(moved[None], 3, 0), levels=levels, progress=False, chunk=2)
    on_top = [blue, red, blue]
    for picture, colour in zip(out, on_top):
        np.testing.assert_array_equal(picture[10, 12], (colour * 255).astype(np.uint8))
    for bad in (levels[:2], levels.astype(float), levels + r.max_level):
        with pytest.raises(ValueError, match="levels must be"):
            r.frames(np.repeat(moved[None], 3, 0), levels=bad, progress=False)


def test_filled_shapes_without_a_picture(rig):
    board = mvcjax.Renderer.build(rig, size=(96, 128))
    out = np.asarray(board(rig.shape_mesh.vertices))
    assert out.shape == (96, 128, 4)
    solid = out[..., 3] == 1
    colours = np.unique(np.round(out[solid][:, :3], 3), axis=0)
    assert solid.sum() > 1000 and len(colours) >= 2  # both squares of the checkerboard
    flat = mvcjax.Renderer.build(rig, size=(96, 128), fill=(0.2, 0.4, 0.6))
    out = np.asarray(flat(rig.shape_mesh.vertices))
    drawn = out[..., 3] > 0
    np.testing.assert_allclose(out[drawn][:, :3], np.broadcast_to([0.2, 0.4, 0.6],
                                                                  (drawn.sum(), 3)), atol=ROUNDING)
    white = mvcjax.Renderer.build(rig, size=(96, 128), fill=(0.2, 0.4, 0.6),
                                  background=(1, 1, 1))
    out = np.asarray(white(rig.shape_mesh.vertices))
    np.testing.assert_allclose(out[0, 0], [1, 1, 1, 1])
    assert np.all(out[..., 3] == 1)


def test_window_can_change_without_recompiling(renderer, rig):
    vertices = rig.shape_mesh.vertices
    wide = renderer(vertices, window=(-40.0, -40.0, 200.0 - 40, 164.0 * 1.2 - 40))
    assert np.asarray(wide)[..., 3].sum() < np.asarray(renderer(vertices))[..., 3].sum()


def test_fit_window_holds_all_frames_with_square_pixels(rig):
    frames = np.stack([np.asarray(rig.shape_mesh.vertices) + [s * 30.0, 0] for s in range(4)])
    xmin, ymin, xmax, ymax = mvcjax.fit_window(frames, (100, 300), margin=0.0)
    assert xmin <= frames[..., 0].min() and xmax >= frames[..., 0].max()
    assert ymin <= frames[..., 1].min() and ymax >= frames[..., 1].max()
    assert (xmax - xmin) / 300 == pytest.approx((ymax - ymin) / 100)


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"image": np.zeros((10, 10, 2))}, ValueError, "image"),
        ({"size": (0, 10)}, ValueError, "size must be"),
        ({"window": (0, 0, -1, 1)}, ValueError, "window must be"),
        ({"fill": "stripes"}, ValueError, "fill must be"),
        ({"background": (2, 0, 0)}, ValueError, "background must be"),
        ({"depth": [1.0, 2.0]}, ValueError, "depth must be"),
        ({"image_window": (0, 0, 1, 1)}, ValueError, "image_window places a picture"),
        ({"budget": 0}, ValueError, "budget must be"),
    ],
)
def test_bad_arguments_are_refused_with_a_reason(rig, kwargs, error, match):
    with pytest.raises(error, match=match):
        mvcjax.Renderer.build(rig, **kwargs)


def test_bad_vertices_and_meshes_are_refused(renderer, rig):
    with pytest.raises(ValueError, match=r"vertices must be \(\d+, 2\)"):
        renderer(rig.shape_mesh.vertices[:-1])
    with pytest.raises(TypeError, match="mesh must be a Rig"):
        mvcjax.Renderer.build("horse")
    with pytest.raises(ValueError, match="faces must index"):
        mvcjax.Renderer.build((np.zeros((3, 2)), np.array([[0, 1, 5]])))


def test_a_pose_beyond_the_budget_raises(rig):
    small = mvcjax.Renderer.build(rig, size=(64, 64), budget=4)
    with pytest.raises(Exception, match="budget"):
        jax.block_until_ready(small(rig.shape_mesh.vertices))


def test_frames_past_the_budget_are_refused_before_any_is_drawn(rig):
    # `frames` counts each pose's pixel tiles on the host first and names the first past
    # the budget; its drawing program then holds no check of its own (a host callback,
    # which JAX's persistent compilation cache would not keep: each process would compile
    # the renderer again).
    from mvcjax.core import checked_on_entry
    from mvcjax.rendering._render import _draw_batch, _tiles_needed

    rest = np.asarray(rig.shape_mesh.vertices, np.float32)
    centre = rest.mean(axis=0)
    frames = np.stack([rest, rest, centre + 3.0 * (rest - centre)])
    needed = np.asarray(_tiles_needed(mvcjax.Renderer.build(rig, size=(64, 64)), frames))
    assert needed[0] == needed[1] < needed[2]
    small = mvcjax.Renderer.build(rig, size=(64, 64), budget=int(needed[0]))
    assert small.frames(frames[:2]).shape == (2, 64, 64, 4)
    with pytest.raises(ValueError, match="frame 2 needs more pixel tiles than the renderer's"):
        small.frames(frames, chunk=2)

    def jaxpr():  # of a function of its own each time: a jaxpr traced anew
        return jax.make_jaxpr(lambda f: _draw_batch(small, f, None))(frames).jaxpr

    with checked_on_entry():
        assert host_callbacks(jaxpr(), "_draw_batch") == (0, 0)
    assert host_callbacks(jaxpr(), "_draw_batch")[1] > 0  # elsewhere, still checked


def test_depth_from_handles_follows_the_mesh_to_the_nearest_handle(rig):
    depths = np.arange(rig.handles.count, dtype=float)
    depth = mvcjax.depth_from_handles(rig, depths)
    assert depth.shape == (rig.shape_mesh.vertices.shape[0],)
    # Each handle's own vertex has its depth; every other vertex its nearest handle's,
    # lowered by under a quarter of the step between two depths the farther it lies.
    np.testing.assert_array_equal(depth[np.asarray(rig.shape_mesh.handles)], depths)
    owner = np.floor(depth + 0.5)
    assert set(np.unique(owner)) == set(depths)
    assert np.all(depth <= owner) and np.all(depth >= owner - 0.25)
    with pytest.raises(ValueError, match="one per row of the targets"):
        mvcjax.depth_from_handles(rig, [1.0])


def test_depth_from_handles_puts_a_bone_on_top(rig, picture):
    """A leg (its handle deepest) swung over the body is drawn over it, and under it
    with the depths reversed."""
    targets = np.asarray(rig.handle_positions).copy()
    base = np.asarray(rig.deform(jnp.asarray(targets)))
    front = mvcjax.Renderer.build(rig, picture, depth=mvcjax.depth_from_handles(
        rig, [1.0, 0.0, 0.0, 0.0]))
    back = mvcjax.Renderer.build(rig, picture, depth=mvcjax.depth_from_handles(
        rig, [-1.0, 0.0, 0.0, 0.0]))
    # Handle 0's part moved over the middle of the shape by translating its vertices.
    depth = mvcjax.depth_from_handles(rig, [1.0, 0.0, 0.0, 0.0])
    moved = base.copy()
    moved[depth > 0.5] += [35.0, 20.0]
    a, b = np.asarray(front(jnp.asarray(moved))), np.asarray(back(jnp.asarray(moved)))
    differs = np.abs(a - b).max(axis=-1) > 0.05
    assert differs.sum() > 20  # where the parts overlap, the order shows


def test_a_limb_over_a_part_without_a_handle_is_drawn_whole(capfd):
    """The sprite's right arm (drawn on top) raised across its head, which holds no
    handle: the head's half nearest the arm shares the arm's depth, and the arm must lie
    whole over it, not in specks of sleeve showing through the face."""
    rig = mvcjax.Rig.build(datasets.sprite(), datasets.sprite_handles())
    targets = np.array(rig.handle_positions)
    shoulder, wrist = targets[3], targets[4]  # the right arm's bone
    up = np.radians(120.0)
    targets[4] = shoulder + np.linalg.norm(wrist - shoulder) * np.array([np.cos(up),
                                                                         np.sin(up)])
    depths = np.zeros(rig.handles.count)
    depths[3:5] = 1.0
    renderer = mvcjax.Renderer.build(rig, datasets.sprite_picture(), size=(390, 360),
                                     depth=mvcjax.depth_from_handles(rig, depths))
    posed = rig.deform(targets)
    # The default solver folds the shoulder here (counted), away from the head.
    folded = int(np.sum(mvcjax.flipped_triangles(rig.shape_mesh.vertices, posed,
                                                 rig.shape_mesh.faces)))
    picture = np.asarray(renderer(posed, window=GROWN))
    shirt = np.array([52, 101, 164]) / 255  # the arm's sleeve is the shirt's blue
    blue = (np.abs(picture[..., :3] - shirt).max(axis=-1) < 0.08) & (picture[..., 3] > 0.99)
    sizes = np.bincount(measure.label(blue).ravel())[1:]
    assert len(sizes) == 1, (f"{len(sizes) - 1} specks of sleeve apart from the shirt "
                             f"(sizes {sorted(sizes)[:-1]}); {folded} folded triangles")


def test_frames_draws_batches_as_bytes_with_silent_progress(renderer, rig, capfd):
    frames = np.stack([np.asarray(rig.shape_mesh.vertices) + [s, 0.0] for s in range(5)])
    pictures = renderer.frames(frames, chunk=2)
    assert pictures.shape == (5, *renderer.shape, 4) and pictures.dtype == np.uint8
    for frame, picture in zip(frames, pictures):
        expected = np.round(np.asarray(renderer(jnp.asarray(frame))) * 255)
        # Where alpha is (almost) nil the straight colour is any colour.
        seen = expected[..., 3] >= 5
        assert np.abs(picture.astype(float) - expected)[seen].max() <= 1
    assert capfd.readouterr().err == ""
    renderer.frames(frames[:2], progress=True)
    assert "2/2" in capfd.readouterr().err
    with pytest.raises(ValueError, match=r"vertices must be \(frames"):
        renderer.frames(frames[0])
    # On a list of devices (here the one there is) the chunks go to each in turn.
    np.testing.assert_array_equal(renderer.frames(frames, chunk=2,
                                                  devices=jax.local_devices()), pictures)
    with pytest.raises(ValueError, match="devices must be a non-empty list of JAX devices"):
        renderer.frames(frames, devices=[])


@pytest.mark.parametrize(("alpha", "expected"),
                         [(mvcjax.advanced.PictureAlpha(), [0.5, 0.0, 0.5, 1.0]),
                          (mvcjax.advanced.MeshAlpha(), [1.0, 0.0, 0.0, 1.0])],
                         ids=["picture", "mesh"])
def test_a_partly_transparent_picture_lies_over_the_background(alpha, expected):
    square = np.array([[0, 0], [9, 0], [9, 9], [0, 9]], float)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    half_red = np.broadcast_to([1.0, 0.0, 0.0, 0.5], (10, 10, 4))
    out = mvcjax.render((square, faces), jnp.asarray(square), half_red,
                        background=(0.0, 0.0, 1.0, 1.0), alpha=alpha)
    np.testing.assert_allclose(out[5, 5], expected, atol=1e-12)
    assert np.all(np.asarray(out)[..., 3] == 1)  # an opaque background stays opaque


def test_a_grown_window_holds_a_pose_that_leaves_the_frame(renderer, rig):
    away = rig.shape_mesh.vertices + jnp.array([60.0, 0.0])
    with pytest.warns(UserWarning, match="1 pose drawn reaches outside"):
        cut = np.asarray(renderer(away))
    grown = np.asarray(renderer(away, window=GROWN))
    # Cut off at the frame's right edge, the pose is whole in a grown window: nothing is
    # drawn along its border, and the drawn area is the rest picture's, scaled down.
    assert cut[:, -1, 3].max() > 0.5
    for edge in (grown[0], grown[-1], grown[:, 0], grown[:, -1]):
        assert edge[..., 3].max() == 0
    rest = np.asarray(renderer(rig.shape_mesh.vertices))[..., 3].sum()
    assert 0.2 * rest < grown[..., 3].sum() < rest  # the grown window's pixels are larger
    with pytest.raises(TypeError, match=r"None or mvcjax.advanced.GrownWindow\(\), got 'fit'"):
        renderer(away, window="fit")


def test_a_picture_that_is_not_the_shapes_is_refused(rig, picture):
    # The same sprite flipped upside down: its alpha has little to do with the rig's
    # shape, which a renderer would paint with the wrong pixels.
    with pytest.raises(ValueError, match="of the mesh's area lies on the picture's visible"):
        mvcjax.Renderer.build(rig, picture[::-1, ::-1])
    # Shifted by 60 pixels it is refused too; placed back with image_window it is drawn.
    shifted = np.zeros_like(picture)
    shifted[:, 60:] = picture[:, :-60]
    with pytest.raises(ValueError, match="image_window"):
        mvcjax.Renderer.build(rig, shifted)
    rows, cols = picture.shape[:2]
    mvcjax.Renderer.build(rig, shifted, image_window=(-60.5, -0.5, cols - 60.5, rows - 0.5))
    # Opaque pictures have no outline to compare with: drawn as given.
    mvcjax.Renderer.build(rig, picture[::-1, ::-1, :3])


def test_frames_say_once_that_an_animation_leaves_the_window(renderer, rig, picture):
    import warnings

    rest = np.asarray(rig.shape_mesh.vertices)
    inside = np.stack([rest + [s, 0.0] for s in (0.0, 1.0)])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        renderer.frames(inside)  # within the picture's frame: nothing said
    width = float(renderer.window[2] - renderer.window[0])
    leaving = np.stack([rest + [s * width, 0.0] for s in (0.0, 0.5, 1.0)])
    np.testing.assert_array_equal(renderer.leaves_window(leaving), [False, True, True])
    assert not renderer.leaves_window(inside).any()
    said_what = r"2 of 3 frames \(the first: frame 1\).*fit_window"
    with pytest.warns(UserWarning, match=said_what) as said:
        renderer.frames(leaving)
    assert len(said) == 1
    # The fix it names keeps every frame whole.
    whole = mvcjax.Renderer.build(rig, picture,
                                  window=mvcjax.fit_window(leaving, renderer.shape))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        whole.frames(leaving)


_DRAWS = {
    "plain": lambda r, poses: [r(v) for v in poses],
    "jit": lambda r, poses: [jax.jit(lambda r, v: r(v))(r, v) for v in poses],
    "vmap": lambda r, poses: jax.vmap(r)(poses),
    "jit_vmap": lambda r, poses: jax.jit(jax.vmap(lambda v: r(v)))(poses),
    "stack": lambda r, poses: jax.vmap(lambda s, v: s(v))(
        mvcjax.Renderer.stack([r] * len(poses)), poses),
}


@pytest.mark.parametrize("draw", list(_DRAWS), ids=list(_DRAWS))
def test_every_way_of_drawing_says_when_a_pose_is_cut_off(renderer, rig, draw):
    import warnings

    rest = rig.shape_mesh.vertices
    width = float(renderer.window[2] - renderer.window[0])
    poses = jnp.stack([rest, rest + jnp.array([0.5 * width, 0.0])])
    with pytest.warns(UserWarning, match="reaches outside the renderer's window") as said:
        jax.block_until_ready(_DRAWS[draw](renderer, poses))
    assert len(said) == 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # inside, or in a window given: nothing said
        jax.block_until_ready(_DRAWS[draw](renderer, poses[:1]))
        jax.block_until_ready(renderer(poses[1], renderer.window))


def _sprite_arm_across_the_chest():
    from mvcjax import datasets
    from mvcjax.rig import parse_handles

    rig = mvcjax.Rig.build(datasets.sprite(), datasets.sprite_handles())
    targets, _, _ = parse_handles(datasets.sprite_handles())
    shoulder, turn = targets[3], np.radians(-100.0)  # the right arm, across the chest
    rotation = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    targets[4] = shoulder + rotation @ (targets[4] - shoulder)
    return rig, rig.deform(targets), datasets.sprite_picture()


def test_a_part_over_its_own_shape_draws_no_see_through_seam():
    # Where the swung arm's edge crosses the chest, the pixels it covers partly show the
    # chest beneath, not the background: no pixel inside the silhouette is partly
    # transparent (one whose eight neighbours are all opaque).
    rig, posed, picture = _sprite_arm_across_the_chest()
    alpha = np.asarray(mvcjax.Renderer.build(rig, picture)(posed))[..., 3]
    padded = np.pad(alpha, 1)
    neighbours = np.min([np.roll(np.roll(padded, dy, 0), dx, 1)[1:-1, 1:-1]
                         for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0)],
                        axis=0)
    seam = (alpha < 0.98) & (neighbours >= 0.98)
    assert int(seam.sum()) == 0
