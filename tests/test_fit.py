"""Fitting handle targets to a picture: a known pose recovered from rest, textured (in
float32) and from its silhouette only (in float64); the silhouette loss's gradient
against finite differences; no recompilation; and the errors for bad input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mvcjax
from mvcjax import datasets

SIZE = (56, 64)
# The fit's stages: a 3-pixel blur sees the moves (3 to 5 pixels), then sharper.
BLURS = (3.0, 1.5, 0.0)
ALPHA = mvcjax.advanced.AlphaChannel()  # silhouettes only
RGBA = mvcjax.advanced.RGBAChannels()  # colour and alpha


def small_rig(dtype):
    # A coarse horse: about 200 shape-mesh vertices, 5 handles.
    shape = datasets.horse(tolerance=3.0)
    return mvcjax.Rig.build(shape, datasets.horse_handles(), shape_spacing=shape.diagonal / 15,
                            dtype=dtype)


def true_targets(rig):
    # The front hoof lifted forward and the head raised, by 3 to 5 pixels at this size.
    offsets = 0.6 * datasets.horse_drag()
    return rig.handle_positions + jnp.asarray(offsets, rig.handle_positions.dtype)


def scene(rig):
    """A renderer whose window holds the rest and the true pose, and the pixel's size."""
    poses = np.concatenate([np.asarray(rig.shape_mesh.vertices),
                            np.asarray(rig.deform(true_targets(rig)))])
    window = mvcjax.fit_window(poses, SIZE, margin=0.1)
    renderer = mvcjax.Renderer.build(rig, size=SIZE, window=window)
    return renderer, (window[2] - window[0]) / SIZE[1]


@pytest.fixture(scope="module")
def rig64():
    return small_rig(jnp.float64)


@pytest.fixture(scope="module")
def rig32():
    return small_rig(jnp.float32)


def errors_in_pixels(found, truth, pixel):
    return np.linalg.norm(np.asarray(found, np.float64) - np.asarray(truth, np.float64),
                          axis=1) / pixel


def target_picture(rig, renderer, channels):
    """The true pose drawn: the checkerboard in colour, or its silhouette's mask."""
    picture = np.asarray(renderer(rig.deform(true_targets(rig))))
    return picture if channels == RGBA else picture[..., 3]


def check_fit(rig, channels, **options):
    """Recover the true pose from rest; return the renderer and the result."""
    renderer, pixel = scene(rig)
    truth = true_targets(rig)
    picture = target_picture(rig, renderer, channels)
    result = mvcjax.fit_targets(rig, renderer, picture, channels=channels, blurs=BLURS,
                                steps=20, **options)

    assert result.targets.dtype == rig.handle_positions.dtype
    assert bool(result.fit_converged)
    start = errors_in_pixels(rig.handle_positions, truth, pixel)
    found = errors_in_pixels(result.targets, truth, pixel)
    assert start.max() > 3.0  # a move the one-pixel edge alone would not see
    assert found.max() < 0.05, found
    before = mvcjax.image_loss(rig, renderer, rig.handle_positions, picture, channels=channels)
    after = mvcjax.image_loss(rig, renderer, result.targets, picture, channels=channels)
    assert float(before) > 1e3 * float(after)
    # The history starts at the rest pose's loss at the first blur, ends at the loss of
    # the targets found, and never rises (Levenberg-Marquardt keeps only steps that
    # lower it).
    history = np.asarray(result.loss_history)
    np.testing.assert_allclose(
        history[0, 0], mvcjax.image_loss(rig, renderer, rig.handle_positions, picture,
                                         channels=channels, blur=BLURS[0]), rtol=1e-4)
    # The loss reported is the targets' own: near zero (a billionth of the start in
    # float32) two programs computing it round differently, by less than a hundredth of
    # the dtype's epsilon times the starting loss.
    rounding = 1e-2 * float(jnp.finfo(result.targets.dtype).eps) * float(before)
    np.testing.assert_allclose(float(result.loss), float(after), rtol=1e-3, atol=rounding)
    for stage, steps in zip(history, np.asarray(result.steps)):
        assert np.all(np.diff(stage[:steps]) <= 1e-6 * stage[0])
        assert np.all(np.isnan(stage[steps:]))
    return renderer, result


def test_textured_fit_recovers_the_pose_in_float32():  # in conftest.SLOW: a compilation
    rig = small_rig(jnp.float32)
    renderer, _ = check_fit(rig, RGBA, warn=False)
    assert renderer.texture.dtype == jnp.float32


@pytest.mark.float64
def test_fit_recovers_the_pose_in_colour_and_from_the_silhouette_in_float64(rig64,
                                                                          monkeypatch):
    renderer, _ = check_fit(rig64, RGBA)
    assert renderer.texture.dtype == jnp.float64
    # The silhouette's fit, another picture, start and tolerances run the same compiled
    # program: the residuals are not traced again.
    traced = []
    residuals = mvcjax._fit._residuals
    def counted(*args):
        if isinstance(args[4], jax.core.Tracer):  # traced for a compilation
            traced.append(1)
        return residuals(*args)

    monkeypatch.setattr(mvcjax._fit, "_residuals", counted)
    check_fit(rig64, ALPHA)
    assert not traced

    # Tolerances no step can meet: each stage runs out of steps, and the fit says so.
    mask = target_picture(rig64, renderer, ALPHA)
    with pytest.warns(RuntimeWarning, match="did not converge in 20 steps"):
        stuck = mvcjax.fit_targets(rig64, renderer, mask, channels=ALPHA, blurs=BLURS,
                                   steps=20, rtol=0.0, atol=0.0)
    assert not traced
    assert not np.any(np.asarray(stuck.converged))
    np.testing.assert_array_equal(np.asarray(stuck.steps), 20)


@pytest.mark.float64
def test_silhouette_loss_gradient_matches_finite_differences(rig64):
    renderer = mvcjax.Renderer.build(rig64, size=SIZE, window=scene(rig64)[0].window)
    truth = true_targets(rig64)
    mask = renderer(rig64.deform(truth))[..., 3]
    # Halfway between rest and the truth, where many edge pixels are partly covered.
    at = 0.5 * (rig64.handle_positions + truth)
    direction = jax.random.normal(jax.random.key(0), at.shape, at.dtype)

    @jax.jit
    @jax.value_and_grad
    def loss(targets, picture, blur):
        return mvcjax.image_loss(rig64, renderer, targets, picture, channels=ALPHA,
                                 blur=blur)

    for blur in (0.0, 2.0):
        exact = float(jnp.sum(loss(at, mask, blur)[1] * direction))
        # Plane units, about 1e-7 pixels: a step too small to change which triangle a
        # pixel shows (where that changes the picture jumps: a step of 1e-4 met a jump).
        h = 1e-6
        approx = float((loss(at + h * direction, mask, blur)[0]
                        - loss(at - h * direction, mask, blur)[0]) / (2 * h))
        assert abs(exact) > 1e-5
        assert abs(exact - approx) < 1e-5 * abs(approx), (blur, exact, approx)
    # Blur and picture are numbers of the program: one compilation for all of them.
    loss(at, 0.5 * mask, 0.5)
    assert loss._cache_size() == 1


def test_blur_spreads_a_pixel_into_a_gaussian_and_keeps_its_sum():
    from mvcjax._fit import _blurred

    picture = jnp.zeros((40, 30)).at[20, 15].set(1.0)
    blurred = np.asarray(_blurred(picture, 2.0))
    # A Gaussian of standard deviation 2 along each axis, centred on the pixel.
    rows, cols = np.mgrid[:40, :30]
    np.testing.assert_allclose(blurred.sum(), 1.0, rtol=1e-6)
    np.testing.assert_allclose(np.sum(blurred * (rows - 20.0) ** 2), 4.0, rtol=1e-3)
    np.testing.assert_allclose(np.sum(blurred * (cols - 15.0) ** 2), 4.0, rtol=1e-3)
    np.testing.assert_allclose(np.asarray(_blurred(picture, 0.0)), np.asarray(picture))


# ---- errors ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def renderer32(rig32):
    return scene(rig32)[0]


def test_picture_of_another_size(rig32, renderer32):
    with pytest.raises(ValueError, match=r"picture is 40 x 64 pixels.*56 x 64.*size="):
        mvcjax.fit_targets(rig32, renderer32, np.zeros((40, 64, 4)))
    with pytest.raises(ValueError, match=r"picture is 56 x 50 pixels"):
        mvcjax.image_loss(rig32, renderer32, rig32.handle_positions, np.zeros((56, 50)),
                          channels=ALPHA)


def test_picture_with_wrong_channels(rig32, renderer32):
    targets = rig32.handle_positions
    with pytest.raises(ValueError, match="picture is RGB, which has no alpha.*mask"):
        mvcjax.image_loss(rig32, renderer32, targets, np.zeros((56, 64, 3)), channels=ALPHA)
    with pytest.raises(ValueError, match="^picture: "):
        mvcjax.image_loss(rig32, renderer32, targets, np.zeros((56, 64, 5)))
    with pytest.raises(ValueError, match=r"picture \(a mask\) must hold values in \[0, 1\]"):
        mvcjax.image_loss(rig32, renderer32, targets, np.full((56, 64), 2.0), channels=ALPHA)
    with pytest.raises(TypeError, match=r"channels must be mvcjax.advanced.RGBAChannels\(\)"):
        mvcjax.image_loss(rig32, renderer32, targets, np.zeros((56, 64, 4)), channels="rgb")


def test_handles_out_of_the_window(rig32):
    away = mvcjax.Renderer.build(rig32, size=SIZE, window=(1000.0, 1000.0, 1064.0, 1056.0))
    with pytest.raises(ValueError, match=r"no handle of the rig lies in the renderer's "
                                         r"window.*fit_window"):
        mvcjax.fit_targets(rig32, away, np.zeros((*SIZE, 4)))
    # Some handles outside: a warning naming them (then the picture's error, before any
    # compilation).
    window = mvcjax.fit_window(rig32.shape_mesh.vertices, SIZE)
    half = (window[0], window[1], 0.5 * (window[0] + window[2]), window[3])
    part = mvcjax.Renderer.build(rig32, size=SIZE, window=half)
    with pytest.warns(UserWarning, match=r"handles \[0, 4\] lie outside.*fit_window"), \
            pytest.raises(ValueError, match="picture is 1 x 1"):
        mvcjax.fit_targets(rig32, part, np.zeros((1, 1)), channels=ALPHA)


def test_renderer_for_another_mesh(rig32):
    triangle = (np.array([[0.0, 0.0], [400.0, 0.0], [0.0, 300.0]]), np.array([[0, 1, 2]]))
    renderer = mvcjax.Renderer.build(triangle, size=SIZE)
    with pytest.raises(ValueError, match=r"renderer was built for a mesh of \d+ vertices, "
                                         r"but the rig's shape mesh has \d+.*Renderer.build"):
        mvcjax.fit_targets(rig32, renderer, np.zeros((*SIZE, 4)))
    moved = (rig32.shape_mesh.vertices + 1.0, rig32.shape_mesh.faces)
    with pytest.raises(ValueError, match="another mesh of the same size"):
        mvcjax.image_loss(rig32, mvcjax.Renderer.build(moved, size=SIZE),
                          rig32.handle_positions, np.zeros((*SIZE, 4)))


def test_bad_options(rig32, renderer32):
    picture = np.zeros((*SIZE, 4))
    with pytest.raises(ValueError, match="blurs must be one or more numbers >= 0"):
        mvcjax.fit_targets(rig32, renderer32, picture, blurs=(2.0, -1.0))
    with pytest.raises(ValueError, match="steps must be a whole number .*>= 1"):
        mvcjax.fit_targets(rig32, renderer32, picture, steps=0)
    with pytest.raises(TypeError, match="method must be an optimistix Gauss-Newton"):
        mvcjax.fit_targets(rig32, renderer32, picture, method="lm")


@pytest.mark.float64
def test_a_rigid_bone_is_fitted_by_pivot_and_angle():
    # A bone's pose fixes only its centre and direction; fitted by its pivot and angle,
    # its targets come back as the true ones, exactly its length apart.
    shape = datasets.horse(tolerance=3.0)
    knee, hoof = np.array([268.5, 72.0]), np.array([272.0, 26.0])
    points = [tuple(p) for p in datasets.horse_handles()[1:]]
    rig = mvcjax.Rig.build(shape, [*points, mvcjax.Bone(knee, hoof)],
                           shape_spacing=shape.diagonal / 15, dtype=jnp.float64)
    rest = np.asarray(rig.handle_positions)
    truth = rest.copy()
    truth[4] = knee + [12.0, 6.0]
    truth[5] = truth[4] + datasets._rotate(hoof, knee, 35.0) - knee
    truth[3] += [0.0, 20.0]  # the head raised
    truth = jnp.asarray(truth)
    poses = np.concatenate([np.asarray(rig.shape_mesh.vertices), np.asarray(rig.deform(truth))])
    window = mvcjax.fit_window(poses, SIZE, margin=0.1)
    renderer = mvcjax.Renderer.build(rig, size=SIZE, window=window)
    pixel = (window[2] - window[0]) / SIZE[1]
    result = mvcjax.fit_targets(rig, renderer, np.asarray(renderer(rig.deform(truth))),
                                blurs=BLURS, steps=20)
    assert errors_in_pixels(rest, truth, pixel).max() > 3.0
    found = np.asarray(result.targets)
    assert errors_in_pixels(found, truth, pixel).max() < 0.05
    assert np.linalg.norm(found[5] - found[4]) == pytest.approx(np.linalg.norm(hoof - knee),
                                                                rel=1e-12)
