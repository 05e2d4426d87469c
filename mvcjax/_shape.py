"""Shape: an outer polygon and its holes, from vertex lists or from a silhouette image."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import shapely
import shapely.ops
from jaxtyping import Bool, Float


def _as_ring(points, name: str) -> np.ndarray:
    ring = np.asarray(points, dtype=np.float64)
    if ring.ndim != 2 or ring.shape[1] != 2:
        raise ValueError(
            f"{name} must be an array of shape (n, 2) holding (x, y) vertices, "
            f"got shape {ring.shape}."
        )
    if not np.all(np.isfinite(ring)):
        raise ValueError(f"{name} contains NaN or infinite coordinates; remove them.")
    if len(ring) > 1 and np.allclose(ring[0], ring[-1]):
        ring = ring[:-1]  # a closing vertex repeated at the end is a common convention
    keep = np.ones(len(ring), bool)
    keep[1:] = np.any(ring[1:] != ring[:-1], axis=1)
    ring = ring[keep]
    if len(ring) < 3:
        raise ValueError(f"{name} needs at least 3 distinct vertices, got {len(ring)}.")
    return ring


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

    def __init__(self, outer, holes: Sequence = ()):
        outer = _as_ring(outer, "outer")
        holes = tuple(_as_ring(h, f"holes[{i}]") for i, h in enumerate(holes))
        polygon = shapely.Polygon(outer, holes)
        if not polygon.is_valid:
            reason = shapely.is_valid_reason(polygon)
            raise ValueError(
                f"The polygon is not simple: {reason}. The outer ring and holes must not "
                "cross or touch themselves or each other, and every hole must lie inside "
                "the outer ring; fix the vertices (shapely.make_valid can help) or "
                "simplify the outline less aggressively."
            )
        if polygon.area <= 0:
            raise ValueError("The polygon has zero area; give at least 3 non-collinear vertices.")
        polygon = shapely.geometry.polygon.orient(polygon, sign=1.0)
        self.outer = np.asarray(polygon.exterior.coords, dtype=np.float64)[:-1]
        self.holes = tuple(
            np.asarray(r.coords, dtype=np.float64)[:-1] for r in polygon.interiors
        )

    @classmethod
    def from_polygon(cls, outer, holes: Sequence = ()) -> Shape:
        """A shape from its outer boundary and optional holes.

        Args:
            outer: `(n, 2)` `(x, y)` vertices of the outer boundary, in either orientation.
            holes: sequence of `(m, 2)` vertex arrays, one per hole, in either orientation.
        """
        return cls(outer, holes)

    @classmethod
    def from_image(
        cls,
        mask: Bool[np.ndarray, "rows cols"],
        *,
        tolerance: float = 0.5,
        component: int | None = None,
        min_hole_area: float = 0.0,
    ) -> Shape:
        """The silhouette of a binary image as a shape, in pixel units with y up.

        Pixel `(row, col)` has its centre at `(x, y) = (col, rows - 1 - row)`. The
        outline runs through the half-pixel boundary between foreground and
        background (scikit-image's marching squares), so a silhouette touching the
        image border is closed along the border.

        Args:
            mask: 2D array, foreground where true (or non-zero).
            tolerance: maximal distance, in pixels, between the simplified outline and
                the pixel contour (Douglas-Peucker, `skimage.measure.approximate_polygon`).
                It is lowered automatically where simplification would make the outline
                cross itself. 0 keeps every contour vertex.
            component: which 4-connected foreground component to use when there are
                several, counted from the largest (0 is the largest). Required then.
            min_hole_area: holes of smaller area, in square pixels, are filled.
        """
        from skimage import measure

        mask = np.asarray(mask)
        if mask.ndim != 2:
            raise ValueError(f"mask must be a 2D image, got an array of shape {mask.shape}.")
        mask = mask.astype(bool)
        if not mask.any():
            raise ValueError("mask has no foreground pixel; pass a mask that is true on the shape.")
        if mask.all():
            raise ValueError(
                "mask is foreground everywhere, so it has no outline; if the shape is dark "
                "on a light background, pass the inverted mask (~mask)."
            )
        labels, count = measure.label(mask, connectivity=1, return_num=True)
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
            if not 0 <= component < count:
                raise ValueError(f"component={component} but mask has only {count} components.")
            mask = labels == order[component] + 1
        elif component not in (None, 0):
            raise ValueError(f"component={component} but mask has a single component; use 0.")

        rows = mask.shape[0]
        padded = np.pad(mask, 1).astype(np.float64)
        contours = measure.find_contours(padded, 0.5)
        # (row, col) in the padded image -> (x, y) with y up.
        rings = [np.stack([c[:, 1] - 1.0, rows - c[:, 0]], axis=1) for c in contours]
        areas = [abs(shapely.Polygon(r).area) for r in rings]
        order = np.argsort(areas)[::-1]
        outer_raw = rings[order[0]]
        holes_raw = [rings[i] for i in order[1:] if areas[i] > max(min_hole_area, 0.0)]
        tol = float(tolerance)
        while True:
            simplify = (lambda r: measure.approximate_polygon(r, tol)) if tol > 0 else (lambda r: r)
            try:
                return cls(simplify(outer_raw), [simplify(h) for h in holes_raw])
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
