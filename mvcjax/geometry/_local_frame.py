"""Where a shape sits and how large it is: the frame every rig is built and solved in.

A rig works in coordinates centred on the shape's bounding box and scaled to its unit
diagonal, and maps back to the user's coordinates at its edges. Nothing inside then
depends on where the shape sits or how large it is: squared lengths neither overflow at
1e20 nor underflow at 1e-20, and float32 keeps its digits for the shape instead of
spending them on an offset.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ..core import to_device

# The finest detail a rig must resolve, relative to the shape's diagonal: the user's
# coordinates of a shape far from the origin must still hold it in the rig's dtype.
RESOLUTION = 1e-5


class Frame(eqx.Module):
    """The map between the user's coordinates and a rig's own: `local = (world - centre)
    / scale`.

    Attributes:
        centre: `(2,)` the centre of the shape's bounding box, in the user's coordinates.
        scale: the length of the bounding box's diagonal.
    """

    centre: Float[Array, " 2"]
    scale: Float[Array, ""]

    def to_local(self, points: Float[ArrayLike, "*n 2"]) -> Float[Array, "*n 2"]:
        """User coordinates to the rig's (centred, unit diagonal)."""
        return (points - self.centre) / self.scale

    def to_world(self, points: Float[ArrayLike, "*n 2"]) -> Float[Array, "*n 2"]:
        """The rig's coordinates back to the user's."""
        return points * self.scale + self.centre


def bounding_frame(points: Float[np.ndarray, "n 2"]) -> tuple[np.ndarray, float]:
    """`(centre, diagonal)` of the points' bounding box, in float64."""
    points = np.asarray(points, np.float64)
    lo, hi = points.min(axis=0), points.max(axis=0)
    return 0.5 * (lo + hi), float(np.hypot(*(hi - lo)))


def check_representable(centre: np.ndarray, scale: float, dtype) -> None:
    """Refuse a shape whose position its dtype cannot resolve to `RESOLUTION` of its
    size: a rig returns the user's coordinates, and float32 holds 7 digits of them."""
    eps = float(jnp.finfo(dtype).eps)
    if not np.isfinite(scale) or scale <= 0:
        raise ValueError(f"The shape's bounding-box diagonal is {scale}; it must be a positive, "
                         "finite length.")
    extent = float(np.max(np.abs(centre))) + scale
    if extent * eps > RESOLUTION * scale:
        raise ValueError(
            f"The shape is {scale:.3g} across but sits {float(np.max(np.abs(centre))):.3g} from "
            f"the origin: {jnp.dtype(dtype).name} resolves only {extent * eps / scale:.1e} of "
            f"its size there (mvcjax needs {RESOLUTION:g}). Build the rig with "
            "dtype=jnp.float64 (after jax.config.update('jax_enable_x64', True)), or move the "
            "shape near the origin and add the offset back to the results."
        )


def points_to_local(points, frame: tuple[np.ndarray, float]) -> np.ndarray:
    """`Frame.to_local` on the host, in float64, for build time: `frame` is the
    `(centre, scale)` of `bounding_frame`."""
    centre, scale = frame
    return (np.asarray(points, np.float64) - centre) / scale


def frame_array(centre: np.ndarray, scale: float, dtype) -> Frame:
    return Frame(to_device(centre, dtype), to_device(scale, dtype))
