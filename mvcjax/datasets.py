"""Built-in shapes."""

from __future__ import annotations

import numpy as np

from ._shape import Shape


def horse(tolerance: float = 1.0) -> Shape:
    """The silhouette of `skimage.data.horse()` (400 x 328 pixels, y up), as a `Shape`.

    The outline is simplified to within `tolerance` pixels; noise holes under 10 square
    pixels are filled. The two front legs are separated by a slot about one pixel wide
    over much of their length: a test for any control mesh.
    """
    from skimage import data

    return Shape.from_image(~data.horse(), tolerance=tolerance, min_hole_area=10.0)


def horse_handles() -> np.ndarray:
    """Default handles on the horse, `(5, 2)`: the right front hoof, the two hind
    hooves, the middle of the back and the head. The left front hoof is left free.
    """
    return np.array([[280.0, 20.0], [62.0, 20.0], [125.0, 27.0], [200.0, 230.0], [372.0, 238.0]])


def horse_drag() -> np.ndarray:
    """The demo's drag: offsets `(5, 2)` for `horse_handles()`, the front hoof lifted
    forward, the head raised, the other handles kept."""
    return np.array([[45.0, 40.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [10.0, 25.0]])
