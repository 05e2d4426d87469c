import re

import numpy as np
import pytest
import shapely

import mvcjax
from mvcjax import Shape

SQUARE = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])


def signed_area(ring):
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)


def test_orientation_is_normalised():
    hole = SQUARE[::-1] * 0.4 + 3.0  # clockwise input hole given counter-clockwise below
    shape = Shape.from_polygon(SQUARE[::-1], [hole[::-1]])
    assert signed_area(shape.outer) > 0
    assert signed_area(shape.holes[0]) < 0
    assert shape.area == pytest.approx(100 - 16)


def test_closing_vertex_and_duplicates_are_dropped():
    shape = Shape.from_polygon(np.vstack([SQUARE, SQUARE[:1]]))
    assert len(shape.outer) == 4


@pytest.mark.parametrize(
    "outer, message",
    [
        (np.array([[0, 0], [1, 1], [1, 0], [0, 1.0]]), "not simple"),
        (np.array([[0, 0], [1, 1.0]]), "at least 3"),
        (np.array([[0, 0], [1, np.nan], [1, 0]]), "NaN"),
        (np.zeros((4, 3)), r"shape \(n, 2\)"),
    ],
)
def test_bad_polygons_are_explained(outer, message):
    with pytest.raises(ValueError, match=message):
        Shape.from_polygon(outer)


def test_hole_outside_is_an_error():
    with pytest.raises(ValueError, match="not simple"):
        Shape.from_polygon(SQUARE, [SQUARE + 20])


def test_from_image_converts_rows_to_y_up():
    mask = np.zeros((20, 30), bool)
    mask[2:6, 10:25] = True  # a bar near the top of the image
    shape = Shape.from_image(mask, tolerance=0)
    xmin, ymin, xmax, ymax = shape.bounds
    assert (xmin, xmax) == (9.5, 24.5)
    assert (ymin, ymax) == (20 - 6 - 0.5, 20 - 2 - 0.5)  # high in the image means large y
    assert shape.area == pytest.approx(4 * 15 - 4 * 0.125)  # marching squares cuts corners


def test_from_image_touching_the_border_is_closed():
    mask = np.zeros((20, 20), bool)
    mask[:, :8] = True  # touches three sides
    exact = Shape.from_image(mask, tolerance=0)
    assert exact.polygon.is_valid
    assert exact.area == pytest.approx(20 * 8 - 4 * 0.125)
    assert exact.bounds == (-0.5, -0.5, 7.5, 19.5)
    simplified = Shape.from_image(mask, tolerance=0.5)
    assert len(simplified.outer) < len(exact.outer)
    assert simplified.polygon.hausdorff_distance(exact.polygon) <= 0.5 + 1e-9


def test_from_image_keeps_holes():
    mask = np.zeros((40, 40), bool)
    mask[5:35, 5:35] = True
    mask[15:25, 15:25] = False
    shape = Shape.from_image(mask)
    assert len(shape.holes) == 1
    assert shapely.Polygon(shape.holes[0]).area == pytest.approx(100, rel=0.1)


def test_from_image_errors():
    with pytest.raises(ValueError, match="no foreground"):
        Shape.from_image(np.zeros((5, 5), bool))
    with pytest.raises(ValueError, match="foreground everywhere.*~mask"):
        Shape.from_image(np.ones((5, 5), bool))
    with pytest.raises(ValueError, match="2D image"):
        Shape.from_image(np.ones((5, 5, 3), bool))
    mask = np.zeros((20, 20), bool)
    mask[2:6, 2:6] = True
    mask[10:18, 10:18] = True
    mask[2:4, 14:16] = True
    with pytest.raises(ValueError, match="3 separate foreground components.*component=0"):
        Shape.from_image(mask)
    largest = Shape.from_image(mask, component=0, tolerance=0)
    assert largest.bounds[0] == pytest.approx(9.5)
    with pytest.raises(ValueError, match="only 3 components"):
        Shape.from_image(mask, component=3)


def test_thin_slot_survives_simplification(horse):
    # The horse's front legs are a pixel apart: the outline must stay simple and open there.
    assert horse.polygon.is_valid
    assert not horse.polygon.covers(shapely.Point(260.5, 50.0))
    assert horse.polygon.covers(shapely.Point(255.0, 50.0))
    assert horse.polygon.covers(shapely.Point(266.0, 50.0))


def star(points=12, inner=0.35):
    k = np.arange(points)
    r = np.where(k % 2 == 0, 1.0, inner)
    a = k * 2 * np.pi / points
    return np.stack([r * np.cos(a), r * np.sin(a)], axis=1)


def test_a_near_closing_vertex_far_out_is_a_real_vertex():
    # The last vertex of this star is 0.7 from its first: np.allclose's tolerance near
    # 1e5 would take it for a repeated closing vertex and drop it.
    shape = Shape.from_polygon(star() + 1e5)
    assert len(shape.outer) == 12
    assert shape.area == pytest.approx(Shape.from_polygon(star()).area, rel=1e-6)
    assert len(Shape.from_polygon(np.vstack([star(), star()[:1]])).outer) == 12


@pytest.mark.parametrize("scale, offset", [(1e-20, 0.0), (1e20, 0.0), (1.0, 1e8), (1e-3, 1e3)])
def test_any_scale_and_placement(scale, offset):
    base = Shape.from_polygon(star())
    shape = Shape.from_polygon(star() * scale + offset)
    assert len(shape.outer) == 12
    assert shape.area == pytest.approx(base.area * scale**2, rel=1e-6)
    np.testing.assert_array_equal(shape.outer, star() * scale + offset)  # given ones, kept


@pytest.mark.parametrize("holes, message", [
    ([[[40, 40], [60, 40], [60, 60], [40, 60]], [[60, 60], [80, 60], [80, 80], [60, 80]]],
     r"holes\[0\] and holes\[1\] touch at \[60.0, 60.0\]"),
    ([[[0, 40], [20, 30], [20, 50]]], r"outer and holes\[0\] touch"),
])
def test_rings_that_touch_are_refused(holes, message):
    # Triangle crashed the interpreter (exit 139) on two holes sharing a corner.
    outer = np.array([[0, 0], [100, 0], [100, 100], [0, 100.0]])
    with pytest.raises(ValueError, match=message):
        Shape.from_polygon(outer, np.asarray(holes, float))


def test_a_ring_that_touches_itself_is_refused():
    bowtie_ish = np.array([[0, 0], [2, 0], [2, 2], [1, 0], [0, 2.0]])
    with pytest.raises(ValueError, match="touches itself|not simple"):
        Shape.from_polygon(bowtie_ish)


@pytest.mark.parametrize("outer, error, message", [
    (np.array([[0, 0], [1, 0], [0, 1j]]), TypeError, "complex"),
    (np.array([[True, False], [False, True], [True, True]]), TypeError, "booleans"),
    ("square", TypeError, "real"),
    ([[0, 0], [1, 0, 3], [0, 1]], ValueError, "ragged"),
])
def test_bad_coordinates_are_explained(outer, error, message):
    with pytest.raises(error, match=message):
        Shape.from_polygon(outer)


def test_shapely_polygons_are_accepted():
    polygon = shapely.Polygon(SQUARE, [SQUARE[::-1] * 0.4 + 3.0])
    shape = Shape.from_polygon(polygon)
    assert shape.area == pytest.approx(polygon.area)
    assert len(shape.holes) == 1
    two = shapely.MultiPolygon([shapely.Polygon(SQUARE), shapely.Polygon(SQUARE * 0.5 + 20)])
    with pytest.raises(ValueError, match="2 parts .*component=0"):
        Shape.from_polygon(two)
    assert Shape.from_polygon(two, component=1).area == pytest.approx(25.0)
    with pytest.raises(TypeError, match="LineString"):
        Shape.from_polygon(shapely.LineString(SQUARE))
    with pytest.raises(ValueError, match="holes must be empty"):
        Shape.from_polygon(polygon, [SQUARE * 0.1 + 1])


def test_bad_masks_and_options_are_explained():
    mask = np.zeros((20, 20))
    mask[5:15, 5:15] = 1.0
    with_nan = mask.copy()
    with_nan[0, 0] = np.nan
    with pytest.raises(ValueError, match="1 NaN"):
        Shape.from_image(with_nan)
    with pytest.raises(TypeError, match="boolean or numeric"):
        Shape.from_image(mask.astype(complex))
    with pytest.raises(TypeError, match="boolean or numeric"):
        Shape.from_image(mask.astype(str))
    for name in ("tolerance", "min_hole_area"):
        for bad in (np.nan, -1.0):
            with pytest.raises(ValueError, match=name):
                Shape.from_image(mask, **{name: bad})
    with pytest.raises(TypeError, match="component must be a whole number"):
        Shape.from_image(mask, component=1.5)
    with pytest.raises(ValueError, match="only 1 component"):
        Shape.from_image(mask, component=1)


@pytest.mark.parametrize("axis", [0, 1])
def test_a_one_pixel_line_keeps_its_area(axis):
    # It became a triangle of half its area (horizontal), then the rig hung.
    mask = np.zeros((20, 40), bool)
    mask[10, 5:35] = True
    shape = Shape.from_image(mask if axis == 0 else mask.T)
    assert shape.area > 0.9 * (30 - 1)


def test_repeats_at_the_end_and_near_vertices_far_out():
    # Doubled closing vertices are dropped cyclically (a second one was kept, and the
    # mesher refuses a repeated vertex); an extra vertex 0.3 from the first near 1e5 stays.
    assert len(Shape.from_polygon(np.vstack([SQUARE, SQUARE[:1], SQUARE[:1]])).outer) == 4
    assert len(Shape.from_polygon(np.vstack([SQUARE[:1], SQUARE])).outer) == 4
    near = np.vstack([star(), [[1.0, -0.3]]])
    shape = Shape.from_polygon(near + 1e5)
    assert len(shape.outer) == 13
    assert shape.area == pytest.approx(Shape.from_polygon(near).area, rel=1e-6)


@pytest.mark.parametrize("holes, error, message", [
    (None, TypeError, r"pass \(\) for none"),
    (SQUARE * 0.2 + 1, ValueError, r"single array of shape \(4, 2\); pass \[hole\]"),
])
def test_holes_given_as_one_array_or_none_are_explained(holes, error, message):
    with pytest.raises(error, match=message):
        Shape.from_polygon(SQUARE, holes)


@pytest.mark.parametrize("scale", [1e-200, 1e200])
def test_scales_beyond_float_areas_are_refused(scale):
    # The area overflowed to inf (or underflowed to 0) silently.
    with pytest.raises(ValueError, match="diagonal of .* outside 1e-100 to 1e100.*rescale"):
        Shape.from_polygon(SQUARE * scale)


def test_where_rings_meet_is_told_in_the_given_coordinates():
    # GEOS judges the normalised copy; its location must not leak into the message.
    a = np.array([[4, 4], [6, 4], [6, 6], [4, 6.0]])
    where = r"not simple: .* at \[10000000[46]\.0, 10000000[46]\.0\]"
    with pytest.raises(ValueError, match=where):
        Shape.from_polygon(SQUARE + 1e8, [a + 1e8, a + [2, 0] + 1e8])  # a shared side
    tiny = 1e-20
    with pytest.raises(ValueError, match=re.escape(f"touch at {[6 * tiny, 6 * tiny]}")):
        Shape.from_polygon(SQUARE * tiny, [a * tiny, (a + 2) * tiny])  # a shared corner


def test_shapely_edge_cases():
    with pytest.raises(ValueError, match="empty shapely Polygon"):
        Shape.from_polygon(shapely.Polygon())
    with pytest.raises(ValueError, match="empty shapely MultiPolygon"):
        Shape.from_polygon(shapely.MultiPolygon())
    with pytest.raises(TypeError, match="Point"):
        Shape.from_polygon(shapely.Point(0, 0))
    with pytest.raises(TypeError, match="GeometryCollection"):
        Shape.from_polygon(shapely.GeometryCollection([shapely.Polygon(SQUARE)]))
    with pytest.raises(ValueError, match="component= picks a part"):
        Shape.from_polygon(SQUARE, component=0)
    one = shapely.MultiPolygon([shapely.Polygon(SQUARE)])
    assert Shape.from_polygon(one).area == pytest.approx(100.0)
    with_z = shapely.Polygon(np.c_[SQUARE, np.ones(4)])  # z is dropped
    np.testing.assert_array_equal(Shape.from_polygon(with_z).outer, SQUARE)


def test_more_bad_masks_and_options():
    mask = np.zeros((30, 30), bool)
    mask[10:20, 10:20] = True
    with pytest.raises(TypeError, match="Python objects"):
        Shape.from_image(mask.astype(object))
    with pytest.raises(ValueError, match="100 NaN or infinite"):
        Shape.from_image(np.where(mask, np.inf, 0.0))
    with pytest.raises(TypeError, match="component must be a whole number"):
        Shape.from_image(mask, component=True)
    with pytest.raises(TypeError, match="tolerance must be a number"):
        Shape.from_image(mask, tolerance="1")
    with pytest.raises(ValueError, match="min_hole_area"):
        Shape.from_image(mask, min_hole_area=np.inf)
    assert Shape.from_image(mask.astype(np.uint8), component=np.int64(0)).area == \
        pytest.approx(100 - 0.5)
    # A huge tolerance ends (halved from the image's size, not from 1e300) and keeps the area.
    assert Shape.from_image(mask, tolerance=1e300).area == pytest.approx(100 - 0.5, rel=0.02)


def test_a_one_pixel_line_matches_its_pixel_contour():
    from skimage import measure

    mask = np.zeros((20, 40), bool)
    mask[10, 5:35] = True
    (contour,) = measure.find_contours(np.pad(mask, 1).astype(float), 0.5)
    raw = shapely.Polygon(contour).area  # about 30 - 0.5
    for m in (mask, mask.T):
        assert Shape.from_image(m).area == pytest.approx(raw, rel=0.05)


def test_the_pixel_convention_is_code():
    # One foreground pixel at (row 2, col 5) of a 7-row image: its square of outline is
    # centred on the pixel's centre, and the two maps invert each other.
    mask = np.zeros((7, 9), bool)
    mask[2, 5] = True
    shape = mvcjax.Shape.from_image(mask, tolerance=0)
    np.testing.assert_allclose(shape.outer.mean(axis=0), mvcjax.pixels_to_points([2, 5], 7))
    np.testing.assert_allclose(mvcjax.pixels_to_points([2, 5], 7), [5.0, 4.0])
    rng = np.random.default_rng(0)
    pixels = rng.uniform(-3, 10, (50, 2))
    np.testing.assert_allclose(mvcjax.points_to_pixels(mvcjax.pixels_to_points(pixels, 7), 7),
                               pixels)


def drawn_disc(rows=40, cols=50, centre=(18, 22), radius=12):
    r, c = np.mgrid[:rows, :cols]
    return (r - centre[0]) ** 2 + (c - centre[1]) ** 2 <= radius**2


def test_from_image_takes_rgba_on_the_pixel_grid():
    mask = drawn_disc()
    rows = mask.shape[0]
    rgba = np.zeros(mask.shape + (4,), np.uint8)
    rgba[mask] = [200, 60, 20, 255]
    shape = Shape.from_image(rgba, tolerance=0)
    # Every pixel centre is inside the outline exactly where the pixel is foreground.
    r, c = np.mgrid[:rows, : mask.shape[1]]
    centres = mvcjax.pixels_to_points(np.stack([r, c], axis=-1), rows)
    inside = shapely.contains_xy(shape.polygon, centres[..., 0], centres[..., 1])
    np.testing.assert_array_equal(inside, mask)
    # Marching squares cuts an eighth of a pixel at each corner of the pixel outline.
    assert abs(shape.area - mask.sum()) <= 0.25 * shape.polygon.length
    rs, cs = np.nonzero(mask)
    lo = mvcjax.pixels_to_points([rs.max(), cs.min()], rows) - 0.5
    hi = mvcjax.pixels_to_points([rs.min(), cs.max()], rows) + 0.5
    assert shape.bounds == (*lo, *hi)
    simplified = Shape.from_image(rgba)
    assert simplified.area == pytest.approx(mask.sum(), rel=0.02)


def test_pictures_give_the_shape_of_their_mask(tmp_path):
    from PIL import Image

    mask = drawn_disc()
    mask[15:20, 20:24] = False  # a hole
    expected = Shape.from_image(mask)
    white = np.where(mask[..., None], [30, 30, 160], [255, 255, 255]).astype(np.uint8)
    rgba = np.dstack([white, np.where(mask, 255, 0).astype(np.uint8)])
    Image.fromarray(rgba).save(tmp_path / "shape.png")
    Image.fromarray(np.where(mask, 0, 255).astype(np.uint8)).save(tmp_path / "grey.png")
    Image.fromarray(white).convert("P", palette=Image.Palette.ADAPTIVE, colors=2).save(
        tmp_path / "palette.png")
    for shape in [
        Shape.from_image(white, background=(255, 255, 255)),
        Shape.from_image(white / 255.0, background=(1.0, 1.0, 1.0)),
        Shape.from_image(white, background=mvcjax.advanced.CornerColour()),
        Shape.from_image(rgba),
        Shape.from_image(rgba / 255.0),
        Shape.from_image(tmp_path / "shape.png"),
        Shape.from_image(str(tmp_path / "grey.png"), background="white"),
        Shape.from_image(tmp_path / "palette.png", background=mvcjax.advanced.CornerColour()),
        Shape.from_image(Image.fromarray(rgba)),
        Shape.from_image(mvcjax.load_image(np.where(mask, 0, 255).astype(np.uint8)),
                         background="white"),
    ]:
        for ring, ring_expected in zip(shape.rings, expected.rings, strict=True):
            np.testing.assert_array_equal(ring, ring_expected)


def test_a_sample_silhouette_as_a_keyed_picture():
    # scikit-image's horse, dark on white, as an RGB picture: the same shape as the mask.
    from skimage import data

    from mvcjax import datasets

    horse = data.horse()
    picture = np.where(horse[..., None], 255, 0).astype(np.uint8).repeat(3, axis=2)
    shape = Shape.from_image(picture, background=(255, 255, 255), tolerance=1.0,
                             min_hole_area=10.0)
    for ring, expected in zip(shape.rings, datasets.horse().rings, strict=True):
        np.testing.assert_array_equal(ring, expected)


def test_picture_options_with_a_mask_are_refused():
    mask = drawn_disc()
    for options in [{"background": "white"}, {"alpha_threshold": 0.2}, {"key_tolerance": 0.3}]:
        with pytest.raises(ValueError, match=f"{next(iter(options))}=.*only applies to a "
                                             "picture.*2D mask"):
            Shape.from_image(mask, **options)
    # At their defaults they are harmless.
    assert Shape.from_image(mask, alpha_threshold=0.5, key_tolerance=0.1).area == \
        Shape.from_image(mask).area
    with pytest.raises(ValueError, match=r"2D image.*\(4, 5, 6, 3\)"):
        Shape.from_image(np.zeros((4, 5, 6, 3)))
    with pytest.raises(ValueError, match="opaque.*pass background="):
        Shape.from_image(np.zeros((4, 5, 3), np.uint8))
    with pytest.raises(ValueError, match="2D image.*booleans"):
        Shape.from_image(np.zeros((4, 5, 4), bool))
    with pytest.raises(FileNotFoundError, match="missing.png"):
        Shape.from_image("missing.png")
