"""The renderer's options as objects: what fills a shape drawn without a picture, where
a drawn shape's edge comes from, and a window grown to hold the pose."""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..core import is_real_number, whole_number


class Checkerboard(eqx.Module):
    """A checkerboard fill (`Renderer.build(fill=...)`, the default): shows every stretch
    and shear of a deformation.

    Attributes:
        cells: squares along the picture's longer side.
        colours: the two RGB colours in [0, 1].
    """

    cells: int = 8
    colours: tuple = ((0.95, 0.62, 0.22), (0.36, 0.2, 0.09))

    def __check_init__(self):
        whole_number(self.cells, "Checkerboard(cells=)")
        colours = np.asarray(self.colours, dtype=object)
        if colours.shape != (2, 3) or not all(
                is_real_number(c) and 0 <= c <= 1 for c in colours.ravel()):
            raise ValueError(f"Checkerboard(colours=) takes two RGB colours in [0, 1], got "
                             f"{self.colours!r}.")

    def picture(self, rows: int = 256, cols: int = 256) -> Float[np.ndarray, "rows cols 4"]:
        """The opaque `(rows, cols, 4)` checkerboard as a picture."""
        side = max(rows, cols) / self.cells
        r, c = np.mgrid[:rows, :cols]
        odd = ((r // side + c // side) % 2).astype(bool)
        colours = np.asarray(self.colours, np.float32)
        rgb = np.where(odd[..., None], colours[1], colours[0])
        return np.concatenate([rgb, np.ones((rows, cols, 1), np.float32)], axis=-1)


class AbstractAlpha(eqx.Module):
    """Where a drawn shape's edge comes from (`Renderer.build(alpha=...)`): `MeshAlpha()`
    or `PictureAlpha()`.

    Attributes:
        see_through: whether the picture's own alpha shows (the texture is kept
            partly transparent).
    """

    see_through: ClassVar[bool]


class MeshAlpha(AbstractAlpha):
    """The mesh is the silhouette (as `Shape.from_image` traced it), antialiased by its
    coverage of each pixel; the picture is drawn opaque, its colours carried past its own
    soft edge so that no dark rim comes in. The default."""

    see_through: ClassVar[bool] = False


class PictureAlpha(AbstractAlpha):
    """The picture's alpha multiplies the mesh's coverage: for pictures that are partly
    transparent inside."""

    see_through: ClassVar[bool] = True


class GrownWindow(eqx.Module):
    """A window for one call of a renderer (`renderer(vertices, window=GrownWindow())`):
    the renderer's own, grown to hold the pose with a margin, then to the picture's
    aspect ratio about its centre (square pixels), for a pose that leaves the picture's
    frame. Pure JAX: a pose's numbers, no recompilation.

    Attributes:
        margin: room round the pose, a fraction of its extent.
    """

    margin: float = 0.05

    def __check_init__(self):
        if not is_real_number(self.margin) or not 0 <= self.margin < np.inf:
            raise ValueError(f"GrownWindow(margin=) takes a finite number >= 0, got "
                             f"{self.margin!r}.")

    def __call__(self, window: Float[Array, 4], vertices: Float[Array, "n 2"],
                 shape: tuple[int, int]) -> Float[Array, 4]:
        """`window` grown to hold `vertices` in a picture of `shape` `(rows, cols)`."""
        points = jax.lax.stop_gradient(vertices)
        lo, hi = points.min(axis=0), points.max(axis=0)
        margin = self.margin * (hi - lo)
        lo = jnp.minimum(window[:2], lo - margin)
        hi = jnp.maximum(window[2:], hi + margin)
        rows, cols = shape
        centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        pixel = jnp.maximum(half[0] / cols, half[1] / rows)
        half = pixel * jnp.array([cols, rows], window.dtype)
        return jnp.concatenate([centre - half, centre + half])
