"""Shape: an outer polygon and its holes, from vertex lists or from a silhouette image."""

from __future__ import annotations

import os
import re
from typing import Any

import numpy as np
import shapely
import shapely.ops
from jaxtyping import Float

from ..core import as_array, as_points, is_real_number, is_whole_number, kind_of
from ._coordinates import ring_area
from ._image import image_mask, is_pil_image


def _as_ring(points, name: str) -> np.ndarray:
    """`(n, 2)` float64 vertices without repeats, or an error naming `name`."""
    ring = as_points(points, name, allow_empty=True)
    # A vertex equal to the next one, cyclically, is dropped: this removes a closing
    # vertex repeated at the end (a common convention) and doubled vertices, which
    # the mesher refuses. Only exact repeats: a near one is a real vertex (a tolerance
    # relative to the coordinates dropped one of a small star near 1e5).
    keep = np.any(ring != np.roll(ring, -1, axis=0), axis=1)
    ring = ring[keep] if keep.any() else ring[:1]
    if len(ring) < 3:
        raise ValueError(f"{name} needs at least 3 distinct vertices, got {len(ring)}.")
    return ring


def _where(point, rings, normalised, centre, size) -> list[float]:
    """A point of the normalised frame in the caller's coordinates: the given vertex
    where it is one, since mapping back shows rounding noise (60.00000000000001)."""
    point = np.asarray(point, np.float64)
    for ring, norm in zip(rings, normalised):
        distance = np.hypot(*(norm - point).T)
        if distance.min() <= 1e-12:
            return ring[distance.argmin()].tolist()
    return [float(f"{c:.12g}") for c in point * size + centre]


def _check_rings_apart(rings, normalised, centre, size) -> None:
    """Refuse rings that touch each other or themselves, which a valid polygon allows
    (holes may meet at a point) but the mesher does not (Triangle crashed on two holes
    sharing a corner). Judged on the `normalised` rings."""
    names = ["outer"] + [f"holes[{i}]" for i in range(len(rings) - 1)]
    lines = [shapely.LinearRing(r) for r in normalised]
    for name, line in zip(names, lines):
        if not line.is_simple:
            raise ValueError(f"{name} touches itself (it is not simple); separate its parts or "
                             "drop the vertex where they meet.")
    tree = shapely.STRtree(lines)
    for i, j in tree.query(lines, predicate="intersects").T:
        if i < j:
            where = shapely.intersection(lines[i], lines[j]).representative_point()
            point = _where(where.coords[0], rings, normalised, centre, size)
            raise ValueError(
                f"{names[i]} and {names[j]} touch at {point}: the mesher needs rings apart. "
                "Separate them by a gap, merge them into one ring (shapely's union), or "
                "fill one."
            )


def _check_component(component, count: int, what: str) -> None:
    if component is None:
        return
    if not is_whole_number(component):
        raise TypeError(f"component must be a whole number (0 for the largest {what}), got "
                        f"{component!r}.")
    if not 0 <= component < count:
        raise ValueError(f"component={component} but there {'is' if count == 1 else 'are'} "
                         f"only {count} {what}{'' if count == 1 else 's'}; use 0 to "
                         f"{count - 1}.")


def _one_polygon(geometry, component) -> shapely.Polygon:
    """The polygon of a shapely `Polygon`, or one part of a `MultiPolygon`."""
    if isinstance(geometry, (shapely.Polygon, shapely.MultiPolygon)) and geometry.is_empty:
        raise ValueError(f"outer is an empty shapely {geometry.geom_type}; give one with area.")
    if isinstance(geometry, shapely.Polygon):
        _check_component(component, 1, "part")
        return geometry
    if isinstance(geometry, shapely.MultiPolygon):
        parts = sorted(geometry.geoms, key=lambda g: -g.area)
        if component is None:
            if len(parts) == 1:
                return parts[0]
            raise ValueError(
                f"outer is a MultiPolygon of {len(parts)} parts (areas "
                f"{[round(p.area, 6) for p in parts[:5]]}, largest first); pick one with "
                "component=0 for the largest, component=1 for the next, and so on."
            )
        _check_component(component, len(parts), "part")
        return parts[component]
    raise TypeError(f"outer must be vertices, a shapely Polygon or MultiPolygon, got a "
                    f"shapely {geometry.geom_type}.")


def _is_default(value, default) -> bool:
    if value is default:
        return True
    # A number equal to the default (0.5 given as 0.5, 1/2 or np.float32(0.5)) is the default.
    return (default is not None and not isinstance(value, bool)
            and isinstance(value, (int, float, np.integer, np.floating)) and value == default)


def pixels_to_points(pixels: Any, rows: int) -> Float[np.ndarray, "*n 2"]:
    """Image positions `(..., 2)` of `(row, col)` (an array or nested lists, integer or
    fractional) to shape coordinates `(x, y)`, y up: the centre of
    pixel `(row, col)` of an image with `rows` rows is `(col, rows - 1 - row)`.

    This is the convention of `Shape.from_image` (row 0 is the top of the picture, as
    `load_image` returns it); fractional positions map linearly.
    """
    pixels = np.asarray(pixels, np.float64)
    return np.stack([pixels[..., 1], rows - 1 - pixels[..., 0]], axis=-1)


def points_to_pixels(points: Any, rows: int) -> Float[np.ndarray, "*n 2"]:
    """Shape coordinates `(..., 2)` of `(x, y)` (an array or nested lists) to image
    positions `(row, col)`, the inverse of `pixels_to_points`."""
    points = np.asarray(points, np.float64)
    return np.stack([rows - 1 - points[..., 1], points[..., 0]], axis=-1)


def _picture_or_mask(image, alpha_threshold, background, key_tolerance):
    """The mask `Shape.from_image` traces: `image` itself, or a picture's `image_mask`;
    the picture-only options are refused with a mask unless left at their defaults."""
    picture = isinstance(image, (str, os.PathLike)) or is_pil_image(image)
    if not picture:
        image = as_array(image, "image", "a 2D mask or a picture (rows, cols[, channels])")
        picture = image.ndim == 3 and image.dtype.kind != "b"
        if image.ndim == 3 and image.dtype.kind == "b":
            raise ValueError(f"mask must be a 2D image, got booleans of shape {image.shape}; "
                             "a picture holds numbers, (rows, cols, 3) RGB or (rows, cols, "
                             "4) RGBA.")
    if picture:
        return image_mask(image, alpha_threshold=alpha_threshold, background=background,
                          key_tolerance=key_tolerance)
    given = [f"{name}={value!r}" for name, value, default in [
        ("alpha_threshold", alpha_threshold, 0.5), ("background", background, None),
        ("key_tolerance", key_tolerance, 0.1)] if not _is_default(value, default)]
    if given:
        them, apply = ("them", "apply") if len(given) > 1 else ("it", "applies")
        raise ValueError(f"{', '.join(given)} only {apply} to a picture (RGB or RGBA), "
                         "but image is a 2D mask, foreground where true; drop "
                         f"{them}, or pass the picture itself.")
    return image


def _check_mask(mask: np.ndarray) -> None:
    """Refuse a mask that is not 2D, not boolean or numeric, or has NaN or infinite pixels."""
    if mask.ndim != 2:
        raise ValueError(f"mask must be a 2D image, or a picture (rows, cols, 3) RGB or "
                         f"(rows, cols, 4) RGBA, got an array of shape {mask.shape}.")
    if mask.dtype.kind not in "biuf":
        raise TypeError(f"mask must be a boolean or numeric image, got {kind_of(mask)}; "
                        "pass e.g. image > threshold.")
    if mask.dtype.kind == "f" and not np.all(np.isfinite(mask)):
        bad = int(np.sum(~np.isfinite(mask)))
        raise ValueError(f"mask has {bad} NaN or infinite pixels, which are neither "
                         "foreground nor background; replace them first (np.nan_to_num, "
                         "or a threshold such as np.nan_to_num(mask) > 0.5).")


def _check_tolerances(tolerance, min_hole_area) -> None:
    """Refuse a `tolerance` or `min_hole_area` that is not a finite number >= 0."""
    for name, value in [("tolerance", tolerance), ("min_hole_area", min_hole_area)]:
        if not is_real_number(value):
            raise TypeError(f"{name} must be a number >= 0, got {value!r}.")
        if not np.isfinite(value) or value < 0:
            raise ValueError(f"{name} must be a finite number >= 0, got {value}.")


def _foreground(mask: np.ndarray) -> np.ndarray:
    """The mask as booleans, refused when it is all background or all foreground (no
    outline either way)."""
    mask = mask.astype(bool)
    if not mask.any():
        raise ValueError("mask has no foreground pixel; pass a mask that is true on the shape.")
    if mask.all():
        raise ValueError(
            "mask is foreground everywhere, so it has no outline; if the shape is dark "
            "on a light background, pass the inverted mask (~mask)."
        )
    return mask


def _one_component(mask: np.ndarray, component) -> np.ndarray:
    """The mask of one 4-connected foreground component, counted from the largest;
    `component` is required when there are several."""
    from skimage import measure

    labels, count = measure.label(mask, connectivity=1, return_num=True)
    _check_component(component, count, "component")
    if count > 1:
        sizes = np.bincount(labels.ravel())[1:]
        order = np.argsort(-sizes, kind="stable")
        if component is None:
            raise ValueError(
                f"mask has {count} separate foreground components (sizes "
                f"{sorted(sizes.tolist(), reverse=True)[:5]} pixels, largest first); "
                "pick one with component=0 for the largest, component=1 for the next, "
                "or clean the mask (e.g. skimage.morphology.remove_small_objects)."
            )
        mask = labels == order[component] + 1
    return mask


def _pixel_outline(mask: np.ndarray, min_hole_area) -> tuple[np.ndarray, list, float]:
    """The mask's outline along the pixel boundaries, in shape coordinates: the outer
    ring, the holes of at least `min_hole_area`, and the area they enclose."""
    from skimage import measure

    rows = mask.shape[0]
    padded = np.pad(mask, 1).astype(np.float64)
    contours = measure.find_contours(padded, 0.5)
    rings = [pixels_to_points(c - 1.0, rows) for c in contours]  # unpadded
    areas = [abs(shapely.Polygon(r).area) for r in rings]
    order = np.argsort(areas)[::-1]
    outer = rings[order[0]]
    holes = [rings[i] for i in order[1:] if areas[i] > min_hole_area]
    return outer, holes, areas[order[0]] - sum(shapely.Polygon(h).area for h in holes)


class Shape:
    """A 2D shape: one simple outer polygon and zero or more holes, y up.

    The outer ring is counter-clockwise and every hole clockwise, whatever order the
    input used. Build one with `Shape.from_polygon` or `Shape.from_image`.

    Attributes:
        outer: `(n, 2)` float64 vertices of the outer boundary, counter-clockwise,
            not repeating the first vertex at the end.
        holes: tuple of `(m, 2)` arrays, each a hole's boundary, clockwise.
    """

    outer: Float[np.ndarray, "n 2"]
    holes: tuple[Float[np.ndarray, "m 2"], ...]

    def __init__(self, outer: Any, holes: Any = ()):
        """A shape from its outer ring and holes (see `Shape.from_polygon`).

        Args:
            outer: `(n, 2)` real `(x, y)` vertices, either orientation, the first vertex
                repeated at the end or not.
            holes: sequence of such arrays, one per hole.

        Refused with an error naming the ring: non-numeric, complex, boolean, ragged or
        non-finite coordinates, fewer than 3 distinct vertices, rings that cross or touch
        themselves or each other (even at one point), holes outside the outer ring, no
        area, and a bounding-box diagonal outside 1e-100 to 1e100.
        """
        if holes is None:
            raise TypeError("holes must be a sequence of (m, 2) vertex arrays, one per hole; "
                            "pass () for none.")
        if isinstance(holes, np.ndarray) and holes.ndim == 2:
            raise ValueError(f"holes must be a sequence of (m, 2) vertex arrays, one per hole, "
                             f"got a single array of shape {holes.shape}; pass [hole].")
        outer = _as_ring(outer, "outer")
        holes = tuple(_as_ring(h, f"holes[{i}]") for i, h in enumerate(holes))
        # Judged in the shape's own frame: GEOS's tolerances are absolute, and a shape at
        # 1e-20 or far from the origin would be misjudged.
        lo, hi = outer.min(axis=0), outer.max(axis=0)
        centre, size = 0.5 * (lo + hi), float(np.hypot(*(hi - lo)))
        # Areas (and the mesher's squared distances) overflow or underflow beyond these.
        if not 1e-100 <= size <= 1e100:
            raise ValueError(f"outer has a bounding-box diagonal of {size:.3g}, outside 1e-100 "
                             "to 1e100 where areas fit in float64; rescale the coordinates.")
        normalised = [(r - centre) / size for r in (outer, *holes)]
        polygon = shapely.Polygon(normalised[0], normalised[1:])
        if not polygon.is_valid:
            reason = shapely.is_valid_reason(polygon)
            # GEOS reports where, in the normalised frame: shown in the given coordinates.
            found = re.fullmatch(r"(.*)\[(\S+) (\S+)\]", reason)
            if found:
                point = _where([float(found[2]), float(found[3])],
                               [outer, *holes], normalised, centre, size)
                reason = f"{found[1]} at {point}"
            raise ValueError(
                f"The polygon is not simple: {reason}. The outer ring and holes must not "
                "cross or touch themselves or each other, and every hole must lie inside "
                "the outer ring; fix the vertices (shapely.make_valid can help) or "
                "simplify the outline less aggressively."
            )
        # In the normalised frame the area is a fraction of the diagonal squared: below
        # 1e-14 the shape is a line as far as float64 (and any mesh) can tell.
        if not polygon.area > 1e-14:
            raise ValueError(f"The polygon has (almost) zero area ({polygon.area:.2g} of its "
                             "bounding-box diagonal squared); give at least 3 non-collinear "
                             "vertices.")
        _check_rings_apart([outer, *holes], normalised, centre, size)
        # Orientation from the signed areas, so that the stored rings are the given
        # coordinates themselves (not mapped there and back).
        self.outer = outer if ring_area(normalised[0]) > 0 else outer[::-1].copy()
        self.holes = tuple(h if ring_area(n) < 0 else h[::-1].copy()
                           for h, n in zip(holes, normalised[1:]))

    @classmethod
    def from_polygon(cls, outer: Any, holes: Any = (), *, component: Any = None) -> Shape:
        """A shape from its outer boundary and optional holes, or from shapely.

        Args:
            outer: `(n, 2)` `(x, y)` vertices of the outer boundary, in either orientation;
                or a `shapely.Polygon` (its holes included), or a `shapely.MultiPolygon`
                with `component` saying which part. Other geometries (lines, points,
                collections) are refused with a `TypeError`, empty ones with a
                `ValueError`.
            holes: sequence of `(m, 2)` vertex arrays, one per hole, in either orientation
                (empty when `outer` is a shapely geometry).
            component: which part of a `MultiPolygon`, counted from the largest by area
                (0 is the largest). Required when it has several; refused with vertices.

        The rings are checked as in `Shape` (invalid or touching rings are refused).
        """
        if isinstance(outer, shapely.Geometry):
            if len(holes):
                raise ValueError("holes must be empty when outer is a shapely geometry: its "
                                 "holes are its interiors.")
            polygon = _one_polygon(outer, component)
            # get_coordinates drops z, which a shape has no use for.
            return cls(shapely.get_coordinates(polygon.exterior)[:-1],
                       [shapely.get_coordinates(r)[:-1] for r in polygon.interiors])
        if component is not None:
            raise ValueError("component= picks a part of a shapely MultiPolygon; outer is an "
                             "array of vertices, a single polygon.")
        return cls(outer, holes)

    @classmethod
    def from_image(
        cls,
        image: Any,
        *,
        tolerance: Any = 0.5,
        component: Any = None,
        min_hole_area: Any = 0.0,
        alpha_threshold: Any = 0.5,
        background: Any = None,
        key_tolerance: Any = 0.1,
    ) -> Shape:
        """The silhouette of a mask or a picture as a shape, in pixel units with y up.

        The picture's pixel grid and the shape's coordinates agree exactly: the centre of
        pixel `(row, col)` of an image with `rows` rows is at `(x, y) = (col, rows - 1 -
        row)`, so one pixel is one unit, and the outline runs along the half-pixel
        boundary between foreground and background pixels (scikit-image's marching
        squares, which cuts each corner across its diagonal). `pixels_to_points` and
        `points_to_pixels` map positions in the picture and on the shape onto each other.
        A silhouette touching the image border is closed along the border.

        Args:
            image: a 2D mask, foreground where true (or non-zero): an array of booleans,
                integers or floats; other dtypes (complex, strings, objects) are refused
                with a `TypeError`, NaN or infinite pixels with a `ValueError`. Or a
                picture: a `(rows, cols, 3)` RGB or `(rows, cols, 4)` RGBA array, a path
                to an image file or a Pillow image, read by `load_image` and made a mask
                by `image_mask` (foreground where alpha is above `alpha_threshold`, and,
                with `background`, where the colour is not the background's). A 2D array
                is always a mask: for a grey picture, pass `load_image(grey)`.
            tolerance: maximal distance, in pixels, between the simplified outline and
                the pixel contour (Douglas-Peucker, `skimage.measure.approximate_polygon`).
                It is lowered automatically where simplification would make the outline
                cross itself or change its area by more than 2% (a one-pixel line would
                collapse). 0 keeps every contour vertex. Must be a finite number >= 0.
            component: which 4-connected foreground component to use when there are
                several, counted from the largest (0 is the largest). Required then; an
                `int`, not a bool or float.
            min_hole_area: holes of smaller area, in square pixels, are filled. Must be a
                finite number >= 0.
            alpha_threshold: pictures only: alpha above which a pixel is foreground, from
                0 to below 1.
            background: pictures only: the colour to key out, RGB as 0..255 integers or
                0..1 floats, a colour name or `"#rrggbb"`, or
                `mvcjax.advanced.CornerColour()` for the colour of the top-left pixel.
                Required for an opaque picture (RGB, or alpha 1
                everywhere).
            key_tolerance: pictures only: largest difference, in 0..1 units and any of
                red, green or blue, at which a colour still counts as the background.

        The picture-only options are refused with a mask, unless left at their defaults.
        """
        mask = _picture_or_mask(image, alpha_threshold, background, key_tolerance)
        _check_mask(mask)
        _check_tolerances(tolerance, min_hole_area)
        mask = _one_component(_foreground(mask), component)
        outer, holes, area = _pixel_outline(mask, min_hole_area)
        # Beyond the image's size a tolerance simplifies no further, only halves longer.
        tol = min(float(tolerance), float(np.hypot(*mask.shape)))
        return cls._simplified(outer, holes, area, tol)

    @classmethod
    def _simplified(cls, outer, holes, area: float, tol: float) -> Shape:
        """The shape of the pixel outline simplified by Douglas-Peucker at `tol`, halving
        `tol` until the outline stays simple and keeps its area `area` within 2%."""
        from skimage import measure

        while True:
            simple = [measure.approximate_polygon(r, tol) if tol > 0 else r
                      for r in (outer, *holes)]
            try:
                shape = cls(simple[0], simple[1:])
                # A shape one pixel thin collapses under simplification (a one-pixel
                # line became a triangle of half its area).
                if tol <= 0 or abs(shape.area - area) <= 0.02 * area:
                    return shape
            except ValueError:
                if tol <= 0:
                    raise
                # Thin gaps (one background pixel) can make the simplified sides cross.
            tol = tol / 2 if tol > 1e-3 else 0.0

    # ---- geometry helpers -------------------------------------------------------------

    @property
    def polygon(self) -> shapely.Polygon:
        """The shape as a shapely polygon."""
        return shapely.Polygon(self.outer, self.holes)

    @property
    def rings(self) -> tuple[np.ndarray, ...]:
        """The outer ring followed by the holes."""
        return (self.outer, *self.holes)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """`(xmin, ymin, xmax, ymax)`."""
        lo, hi = self.outer.min(0), self.outer.max(0)
        return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])

    @property
    def diagonal(self) -> float:
        """Length of the bounding-box diagonal: the scale used by tolerances."""
        xmin, ymin, xmax, ymax = self.bounds
        return float(np.hypot(xmax - xmin, ymax - ymin))

    @property
    def area(self) -> float:
        return float(self.polygon.area)

    def closest_point(self, point) -> np.ndarray:
        """The point of the shape (interior or boundary) nearest to `point`."""
        p = shapely.Point(np.asarray(point, dtype=np.float64))
        poly = self.polygon
        if poly.covers(p):
            return np.asarray(p.coords[0])
        return np.asarray(shapely.ops.nearest_points(poly, p)[0].coords[0])

    def __repr__(self) -> str:
        return (
            f"Shape({len(self.outer)} outer vertices, {len(self.holes)} holes, "
            f"area {self.area:.4g}, diagonal {self.diagonal:.4g})"
        )
