import warnings

import numpy as np
import pytest
from PIL import Image

import mvcjax
from mvcjax import image_mask, load_image


def disc(rows=30, cols=40, centre=(12, 22), radius=9):
    r, c = np.mgrid[:rows, :cols]
    return (r - centre[0]) ** 2 + (c - centre[1]) ** 2 <= radius**2


def test_arrays_become_straight_rgba_floats():
    grey = np.array([[0, 128], [255, 64]], np.uint8)
    rgba = load_image(grey)
    assert rgba.dtype == np.float32 and rgba.shape == (2, 2, 4)
    np.testing.assert_array_equal(rgba[..., 0], grey / np.float32(255))
    np.testing.assert_array_equal(rgba[..., 0], rgba[..., 2])
    assert np.all(rgba[..., 3] == 1)  # opaque, exactly
    rgb = np.zeros((3, 4, 3), np.uint16)
    rgb[0, 0] = [65535, 0, 1000]
    loaded = load_image(rgb)
    np.testing.assert_allclose(loaded[0, 0], [1, 0, 1000 / 65535, 1], rtol=1e-6)
    assert np.all(loaded[..., 3] == 1)
    floats = np.random.default_rng(0).uniform(0, 1, (5, 6, 4))
    np.testing.assert_allclose(load_image(floats), floats, rtol=1e-6)
    np.testing.assert_array_equal(load_image(grey[..., None]), rgba)  # (rows, cols, 1)


def test_uint8_and_floats_agree():
    rgba = np.random.default_rng(1).integers(0, 256, (6, 7, 4)).astype(np.uint8)
    np.testing.assert_allclose(load_image(rgba), load_image(rgba / 255.0), atol=1e-7)
    mask = disc()
    picture = np.where(mask[..., None], [200, 40, 10, 255], [0, 0, 0, 0]).astype(np.uint8)
    np.testing.assert_array_equal(image_mask(picture), image_mask(picture / 255.0))
    np.testing.assert_array_equal(image_mask(picture), mask)


def test_files_read_through_pillow(tmp_path):
    mask = disc()
    grey = np.where(mask, 0, 255).astype(np.uint8)
    Image.fromarray(grey).save(tmp_path / "grey.png")
    loaded = load_image(tmp_path / "grey.png")
    np.testing.assert_array_equal(loaded, load_image(grey))
    np.testing.assert_array_equal(image_mask(str(tmp_path / "grey.png"), background="white"),
                                  mask)
    la = np.stack([grey, np.where(mask, 255, 0).astype(np.uint8)], axis=-1)
    Image.fromarray(la, "LA").save(tmp_path / "la.png")
    np.testing.assert_array_equal(image_mask(tmp_path / "la.png"), mask)
    # A 16-bit grey PNG keeps its 16 bits (Pillow's convert("RGBA") clips them to 255).
    deep = (np.arange(12).reshape(3, 4) * 5000).astype(np.uint16)
    Image.fromarray(deep).save(tmp_path / "deep.png")
    np.testing.assert_allclose(load_image(tmp_path / "deep.png")[..., 0], deep / 65535,
                               rtol=1e-6)


def test_palette_files_with_and_without_transparency(tmp_path):
    mask = disc()
    palette = Image.fromarray(mask.astype(np.uint8), "P")
    palette.putpalette([255, 255, 255, 200, 30, 30])  # index 0 white, 1 red
    palette.save(tmp_path / "opaque.png")
    np.testing.assert_array_equal(image_mask(tmp_path / "opaque.png",
                                             background=mvcjax.advanced.CornerColour()),
                                  mask)
    palette.save(tmp_path / "transparent.png", transparency=0)
    picture = load_image(tmp_path / "transparent.png")
    np.testing.assert_array_equal(picture[..., 3], mask.astype(np.float32))
    np.testing.assert_array_equal(image_mask(picture), mask)


def test_pillow_images_are_pictures():
    mask = disc()
    image = Image.fromarray(np.where(mask, 0, 255).astype(np.uint8))
    np.testing.assert_array_equal(image_mask(image, background=(255, 255, 255)), mask)


def test_backgrounds_in_every_spelling():
    mask = disc()
    picture = np.where(mask[..., None], [10, 120, 250], [0, 255, 0]).astype(np.uint8)
    for background in [(0, 255, 0), (0.0, 1.0, 0.0), np.array([0, 255, 0]), "lime", "#00ff00",
                       mvcjax.advanced.CornerColour()]:
        np.testing.assert_array_equal(image_mask(picture, background=background), mask)
    # Anti-aliasing: a pixel between the colours counts as background within key_tolerance.
    picture[0, 0] = [0, 235, 0]
    assert not image_mask(picture, background=(0, 255, 0))[0, 0]
    assert image_mask(picture, background=(0, 255, 0), key_tolerance=0.05)[0, 0]


def test_alpha_and_a_keyed_colour_together():
    mask = disc()
    picture = np.zeros(mask.shape + (4,))
    picture[..., 3] = 1.0
    picture[:, :5, 3] = 0.2  # a transparent margin on the left
    picture[mask, :3] = [0.9, 0.2, 0.1]
    assert not image_mask(picture, background=(0.0, 0.0, 0.0))[:, :5].any()
    np.testing.assert_array_equal(image_mask(picture, background=(0.0, 0.0, 0.0)), mask)
    np.testing.assert_array_equal(image_mask(picture, alpha_threshold=0.1,
                                             background=(0.0, 0.0, 0.0)), mask)


def test_bad_pictures_are_explained(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere.png"):
        load_image(tmp_path / "nowhere.png")
    (tmp_path / "notes.txt").write_text("not a picture")
    with pytest.raises(ValueError, match="Pillow cannot read.*notes.txt"):
        load_image(tmp_path / "notes.txt")
    Image.fromarray(np.zeros((50, 50, 3), np.uint8)).save(tmp_path / "whole.png")
    (tmp_path / "cut.png").write_bytes((tmp_path / "whole.png").read_bytes()[:60])
    with pytest.raises(ValueError, match="could not read.*cut.png.*truncated"):
        load_image(str(tmp_path / "cut.png"))
    with pytest.raises(IsADirectoryError, match="folder"):
        load_image(tmp_path)
    with pytest.raises(ValueError, match=r"shape \(5, 5, 2\).*np.dstack"):
        load_image(np.zeros((5, 5, 2)))
    with pytest.raises(ValueError, match="Channels first.*moveaxis"):
        load_image(np.zeros((3, 5, 6)))
    with pytest.raises(ValueError, match=r"shape \(2, 5, 5, 4\)"):
        load_image(np.zeros((2, 5, 5, 4)))
    with pytest.raises(ValueError, match="ragged"):
        load_image([[0.0, 1.0], [0.5]])
    with pytest.raises(ValueError, match="empty"):
        load_image(np.zeros((0, 5, 3), np.uint8))
    with_nan = np.zeros((4, 4, 3))
    with_nan[1, 1, 0] = np.nan
    with pytest.raises(ValueError, match="1 NaN"):
        load_image(with_nan)
    with pytest.raises(ValueError, match="0 to 255.*divide by 255"):
        load_image(np.full((4, 4, 3), 255.0) * np.eye(4)[..., None])
    with pytest.raises(ValueError, match="outside 0..1"):
        load_image(np.full((4, 4), -0.5))
    with pytest.raises(TypeError, match="mask, not a picture.*Shape.from_image"):
        load_image(np.zeros((4, 4, 3), bool))
    with pytest.raises(TypeError, match="complex"):
        load_image(np.zeros((4, 4, 3), complex))
    with pytest.raises(TypeError, match="Python objects"):
        load_image(np.zeros((4, 4, 3), object))
    with pytest.raises(TypeError, match="int64 integers.*uint8"):
        load_image(np.zeros((4, 4, 3), np.int64))


def test_bad_masks_from_pictures_are_explained():
    mask = disc()
    rgb = np.where(mask[..., None], 0, 255).astype(np.uint8).repeat(3, axis=2)
    rgba = np.dstack([rgb, np.where(mask, 255, 0).astype(np.uint8)])
    with pytest.raises(ValueError, match="opaque.*pass background="):
        image_mask(rgb)
    with pytest.raises(ValueError, match="opaque.*pass background="):
        image_mask(np.dstack([rgb, np.full(mask.shape, 255, np.uint8)]))
    with pytest.raises(ValueError, match=r"alpha is at or below 0.5 everywhere \(its largest "
                                         r"value is 0.3\)"):
        image_mask(np.dstack([rgb / 255, np.full(mask.shape, 0.3)]))
    with pytest.raises(ValueError, match="foreground is everywhere.*pass background="):
        image_mask(np.dstack([rgb / 255, np.full(mask.shape, 0.9)]))
    with pytest.raises(ValueError, match="foreground is everywhere.*raise key_tolerance"):
        image_mask(rgb, background=(128, 0, 0))
    with pytest.raises(ValueError, match="Every pixel is within key_tolerance=0.1"):
        image_mask(np.full((5, 5, 3), 250, np.uint8), background="white")
    with pytest.raises(ValueError, match="Every opaque pixel is within"):
        image_mask(np.where(mask[..., None], 255, 0).astype(np.uint8).repeat(4, axis=2),
                   background="white")
    for background, error, message in [
        ((1, 1, 1), ValueError, r"ambiguous.*\(1.0, 1.0, 1.0\).*\(255, 255, 255\)"),
        ((300, 0, 0), ValueError, "outside 0..255"),
        ((1.5, 0.0, 0.0), ValueError, "outside 0..1.*integers"),
        ((np.nan, 0.0, 0.0), ValueError, "outside 0..1"),
        ((255, 255, 255, 255), TypeError, "RGB colour, 3 numbers"),
        ((True, False, True), TypeError, "RGB colour"),
        ("blanc", ValueError, "'blanc' is not a colour.*CornerColour"),
        ("#ffffff80", ValueError, "has an alpha"),
        (object(), TypeError, "RGB colour"),
    ]:
        with pytest.raises(error, match=message):
            image_mask(rgba, background=background)
    for name in ("alpha_threshold", "key_tolerance"):
        for bad in (1.0, -0.1, np.nan):
            with pytest.raises(ValueError, match=f"{name} must be a number from 0 to below 1"):
                image_mask(rgba, **{name: bad})
        for bad in ("0.5", True, None):
            with pytest.raises(TypeError, match=name):
                image_mask(rgba, **{name: bad})
    with pytest.raises(TypeError, match="mask, not a picture"):
        image_mask(mask)


def test_a_sample_picture_keys_out():
    # A photograph neither made nor cleaned here: keyed on its corner colour, many parts.
    from skimage import data

    coffee = data.coffee()
    mask = image_mask(coffee, background=mvcjax.advanced.CornerColour())
    assert mask.shape == coffee.shape[:2] and 0 < mask.mean() < 1
    shape = mvcjax.Shape.from_image(coffee, background=mvcjax.advanced.CornerColour(), component=0,
                                    min_hole_area=50.0, tolerance=1.0)
    assert 0.5 * mask.size < shape.area < mask.size


def _sprite_png_and_jpeg():
    """A drawn sprite (a brown body, a pale head, a red scarf), antialiased: as RGBA with
    alpha (a PNG's content) and composited on white and saved as a JPEG."""
    import io

    from PIL import ImageDraw

    big = 4
    size = (96 * big, 128 * big)
    coverage = Image.new("L", size[::-1], 0)
    paint = Image.new("RGB", size[::-1], (117, 92, 79))
    for draw, fill in ((ImageDraw.Draw(coverage), 255), (ImageDraw.Draw(paint), None)):
        draw.ellipse([30 * big, 40 * big, 98 * big, 88 * big], fill=fill or (117, 92, 79))
        draw.ellipse([50 * big, 10 * big, 78 * big, 40 * big], fill=fill or (235, 200, 170))
        draw.rectangle([44 * big, 36 * big, 84 * big, 46 * big], fill=fill or (200, 30, 40))
    cover = np.asarray(coverage, np.float64)[..., None] / 255

    def shrink(a):  # the mean of each big x big block
        return a.reshape(96, big, 128, big, -1).mean(axis=(1, 3))

    # Straight colours: each pixel's paint averaged over the part of it the sprite covers.
    alpha = shrink(cover)[..., 0]
    painted = shrink(np.asarray(paint, np.float64) / 255 * cover)
    colour = painted / np.maximum(alpha, 1e-9)[..., None]
    colour[alpha == 0] = (117 / 255, 92 / 255, 79 / 255)
    png = np.dstack([colour, alpha])
    on_white = colour * alpha[..., None] + (1 - alpha[..., None])
    buffer = io.BytesIO()
    Image.fromarray(np.round(on_white * 255).astype(np.uint8)).save(buffer, "JPEG", quality=90)
    return png, load_image(Image.open(io.BytesIO(buffer.getvalue())))


@pytest.mark.filterwarnings("ignore:image is opaque")
def test_a_keyed_jpeg_renders_without_a_halo():
    # The same sprite from a PNG with alpha and from a JPEG on white: cut out of the white,
    # its edge pixels render in the sprite's colours, not the background's.
    png, jpeg = _sprite_png_and_jpeg()
    shape = mvcjax.Shape.from_image(png)
    rig = mvcjax.Rig.build(shape, [shape.closest_point(p) for p in [(40, 30), (90, 30), (64, 80)]])
    rest = rig.shape_mesh.vertices

    def edge_colour(picture):
        out = np.asarray(mvcjax.Renderer.build(rig, picture)(rest))
        reference = np.asarray(mvcjax.Renderer.build(rig, png)(rest))
        edge = (reference[..., 3] > 0.05) & (reference[..., 3] < 0.95)
        assert edge.sum() > 100
        return out[edge, :3].mean(axis=0)

    want = edge_colour(png)
    cut = mvcjax.cut_out(jpeg, background=mvcjax.advanced.CornerColour())
    assert np.abs(edge_colour(cut) - want).max() < 0.05
    assert np.abs(edge_colour(jpeg) - want).max() > 0.1  # the opaque JPEG: a light rim
    # Cut out, it makes the same shape as the PNG's alpha, to a pixel along the outline.
    np.testing.assert_allclose(mvcjax.Shape.from_image(cut).area, shape.area, rtol=0.03)


def test_an_opaque_picture_on_a_backdrop_warns_and_names_cut_out():
    png, jpeg = _sprite_png_and_jpeg()
    shape = mvcjax.Shape.from_image(png)
    rig = mvcjax.Rig.build(shape, [shape.closest_point((64, 80))])
    with pytest.warns(UserWarning, match=r"rim.*mvcjax\.cut_out\(image\)"):
        mvcjax.Renderer.build(rig, jpeg)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        board = mvcjax.advanced.Checkerboard().picture(128, 128)
        for picture in (png, mvcjax.cut_out(jpeg), board):
            mvcjax.Renderer.build(rig, picture)


def test_cut_out_keeps_the_inside_and_drops_the_background():
    picture = np.ones((30, 40, 3))
    picture[disc()] = (0.2, 0.4, 0.6)
    cut = mvcjax.cut_out(picture, background=(1.0, 1.0, 1.0))
    assert cut.shape == (30, 40, 4) and cut.dtype == np.float32
    inside = disc(radius=6)
    want = np.broadcast_to([0.2, 0.4, 0.6, 1.0], (inside.sum(), 4))
    np.testing.assert_allclose(cut[inside], want, atol=1e-6)
    assert np.all(cut[~disc(radius=12), 3] == 0)
    # The outline's pixels take the foreground's colour, whatever their alpha.
    band = disc(radius=10) & ~disc(radius=7)
    np.testing.assert_allclose(cut[band, :3], np.broadcast_to([0.2, 0.4, 0.6], (band.sum(), 3)),
                               atol=1e-6)
    with pytest.raises(ValueError, match="edge"):
        mvcjax.cut_out(picture, background=(1.0, 1.0, 1.0), edge=-1)
