"""Pictures out: float pictures in [0, 1] (or uint8) checked and turned into bytes."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..core import kind_of


def check_values(picture: np.ndarray, name: str) -> None:
    """Refuse dtypes other than float and uint8, and floats that are NaN or outside [0, 1]."""
    if picture.dtype == np.uint8:
        return
    if picture.dtype.kind != "f":
        hint = (" If the values are 0-255, convert with .astype(np.uint8)."
                if picture.dtype.kind in "iub" else "")
        raise TypeError(f"{name} must be float in [0, 1] or uint8, got {kind_of(picture)} "
                        f"({picture.dtype}).{hint}")
    if picture.size == 0:
        return
    # min and max propagate NaN: two passes cover NaN, infinities and the range.
    lo, hi = float(np.min(picture)), float(np.max(picture))
    if math.isnan(lo) or math.isnan(hi):
        raise ValueError(f"{name} contains NaN values; give finite values in [0, 1] "
                         "(e.g. np.nan_to_num(x, nan=0.0)).")
    if lo < 0.0 or hi > 1.0:
        raise ValueError(f"{name} has values in [{lo:g}, {hi:g}], outside [0, 1]: float "
                         "pictures must lie in [0, 1] (np.clip(x, 0, 1)), or pass uint8.")


def check_channels(shape: tuple[int, ...], name: str, expected: str) -> None:
    if shape[-1] not in (3, 4):
        raise ValueError(f"{name} has shape {shape}: expected {expected}, the last axis 3 "
                         "(RGB) or 4 (RGBA) channels.")


def as_matte_rgb(matte) -> np.ndarray:
    """A colour name, '#rrggbb' or 3 floats in [0, 1], as float32 RGB in [0, 1]."""
    if isinstance(matte, str):
        from PIL import ImageColor

        try:
            rgb = ImageColor.getrgb(matte)[:3]
        except ValueError:
            raise ValueError(f"matte {matte!r} is not a colour: give a name such as 'white', "
                             "'#rrggbb' or three floats in [0, 1].") from None
        return np.asarray(rgb, np.float32) / 255
    try:
        rgb = np.asarray(matte, np.float64)
    except (TypeError, ValueError):
        rgb = None
    if rgb is None or rgb.shape != (3,) or not np.all((rgb >= 0) & (rgb <= 1)):
        raise ValueError(f"matte must be a colour name, '#rrggbb' or three floats (r, g, b) in "
                         f"[0, 1], got {matte!r}.")
    return rgb.astype(np.float32)


def byte_values(values: np.ndarray) -> np.ndarray:
    # Round to nearest: the values are in [0, 1], so the +0.5 never passes 255.5.
    return (values * 255 + 0.5).astype(np.uint8)


def to_bytes(picture: np.ndarray, matte_rgb: np.ndarray | None) -> np.ndarray:
    if picture.dtype != np.uint8:
        picture = byte_values(picture)
    if matte_rgb is None or picture.shape[-1] == 3:
        return picture
    # Composited from the rounded bytes, so that float pictures and their to_uint8 give
    # the same files, at the cost of at most one level: `colour * alpha + matte * (1 -
    # alpha)`, rounded, looked up in a table of every (alpha, colour) pair per channel.
    alpha = (np.arange(256, dtype=np.float32) * np.float32(1 / 255))[:, None]
    colour = np.arange(256, dtype=np.float32)[None, :]
    out = np.empty((*picture.shape[:-1], 3), np.uint8)
    index = picture[..., 3].astype(np.int32) << 8
    for c in range(3):
        table = (colour * alpha + (255 * matte_rgb[c]) * (1 - alpha) + 0.5).astype(np.uint8)
        np.take(table.ravel(), index | picture[..., c], out=out[..., c])
    return out


def to_uint8(pictures: Any, *, matte: Any = None) -> np.ndarray:
    """Pictures as `uint8`, optionally composited onto an opaque colour.

    Args:
        pictures: one picture `(rows, cols, 3 or 4)` or a stack `(n, rows, cols, 3 or 4)`,
            float in `[0, 1]` (straight alpha) or `uint8` (returned as is without `matte`).
        matte: `None` to keep the channels; or a colour (a name such as `"white"`,
            `"#rrggbb"` or three floats in `[0, 1]`) to lay RGBA pictures over, which
            gives RGB: `colour * alpha + matte * (1 - alpha)`.

    Returns:
        `uint8` array of the same shape (the last axis 3 where an RGBA picture was
        composited), each float `v` rounded to the nearest of `v * 255`.

    Raises:
        ValueError: a shape other than the above, NaN, or floats outside `[0, 1]`.
        TypeError: a dtype other than float or `uint8`.
    """
    array = np.asarray(pictures)
    if array.ndim not in (3, 4):
        raise ValueError(f"pictures must have shape (rows, cols, 3 or 4) or (n, rows, cols, 3 "
                         f"or 4), got shape {array.shape}.")
    check_channels(array.shape, "pictures", "(..., rows, cols, 3 or 4)")
    check_values(array, "pictures")
    return to_bytes(array, None if matte is None else as_matte_rgb(matte))
