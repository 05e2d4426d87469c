"""Checks of the user's arrays at mvcjax's edges, with errors that name the argument,
what was wrong and the fix."""

from __future__ import annotations

import numpy as np

_KINDS = {"c": "complex numbers", "b": "booleans", "U": "strings", "S": "bytes",
          "O": "Python objects", "M": "dates", "m": "time spans", "V": "records"}


def kind_of(array: np.ndarray) -> str:
    """What an array holds, in words."""
    return _KINDS.get(array.dtype.kind, array.dtype.name)


def as_points(points, name: str, rows: str = "n", *, allow_empty: bool = False) -> np.ndarray:
    """`(rows, 2)` real, finite float64 points, or a `TypeError`/`ValueError` naming `name`."""
    try:
        array = np.asarray(points)
    except ValueError:
        raise ValueError(f"{name} must be an array of shape ({rows}, 2) of (x, y) points; got a "
                         "ragged sequence.") from None
    if array.dtype.kind == "c":
        raise TypeError(f"{name} has complex coordinates: pass real (x, y) pairs, e.g. "
                        "np.stack([z.real, z.imag], axis=1).")
    if array.dtype.kind not in "iuf":
        raise TypeError(f"{name} must hold real (x, y) numbers, got {kind_of(array)}; pass a "
                        f"float array of shape ({rows}, 2).")
    array = array.astype(np.float64)
    if array.ndim != 2 or array.shape[1] != 2 or (len(array) == 0 and not allow_empty):
        raise ValueError(f"{name} must be an array of shape ({rows}, 2) with at least one (x, y) "
                         f"point, got shape {array.shape}.")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} contains NaN or infinite coordinates; give finite (x, y) "
                         "points.")
    return array
