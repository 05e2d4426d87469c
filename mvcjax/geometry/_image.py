"""Pictures in: an image file or array as straight RGBA, and its foreground mask (alpha
above a threshold, or a background colour keyed out)."""

from __future__ import annotations

import os
import sys
from typing import Any

import equinox as eqx
import numpy as np
from jaxtyping import Bool, Float

from ..core import is_real_number, kind_of, refuse_string, whole_number

_CHANNELS = "(rows, cols) grey, (rows, cols, 3) RGB or (rows, cols, 4) RGBA"


def is_pil_image(image) -> bool:
    # Without importing Pillow: an object can only be a Pillow image if Pillow is loaded.
    pil = sys.modules.get("PIL.Image")
    return pil is not None and isinstance(image, pil.Image)


def _from_pil(image, name: str) -> np.ndarray:
    if image.mode.startswith("I;16"):
        # convert("RGBA") clips 16-bit grey to 8 bits: 1000 out of 65535 came out white.
        return _from_array(np.asarray(image, np.uint16), name)
    if image.mode == "I":
        values = np.asarray(image)
        if values.min() < 0 or values.max() > 65535:
            raise ValueError(f"{name} holds 32-bit integers from {values.min()} to "
                             f"{values.max()}, beyond 16 bits, and mvcjax cannot tell their "
                             "range; load it yourself and pass floats in 0..1.")
        return _from_array(values.astype(np.uint16), name)
    if image.mode == "F":
        return _from_array(np.asarray(image), name)
    return _from_array(np.asarray(image.convert("RGBA")), name)


def _from_file(path, name: str) -> np.ndarray:
    from PIL import Image, UnidentifiedImageError

    if not os.path.exists(path):
        raise FileNotFoundError(f"No image file at {name} (relative paths start at "
                                f"{os.getcwd()}); check the path.")
    if os.path.isdir(path):
        raise IsADirectoryError(f"{name} is a folder, not an image file; give the file's path.")
    try:
        with Image.open(path) as image:
            return _from_pil(image, name)
    except UnidentifiedImageError:
        raise ValueError(f"Pillow cannot read {name} as an image (not a format it knows, or "
                         "not a picture); save it as PNG, or load it yourself and pass the "
                         "array.") from None
    except (FileNotFoundError, PermissionError):
        raise
    except OSError as error:
        raise ValueError(f"Pillow could not read {name}: {error}. The file may be truncated "
                         "or damaged; save it again, e.g. as PNG.") from error


def _from_array(image, name: str) -> np.ndarray:
    try:
        array = np.asarray(image)
    except ValueError:
        raise ValueError(f"{name} must be an array, {_CHANNELS}; got a ragged "
                         "sequence.") from None
    if array.dtype.kind == "b":
        raise TypeError(f"{name} holds booleans, which is a mask, not a picture; pass it to "
                        "Shape.from_image directly, which takes masks (or pass a picture of "
                        "numbers).")
    if array.dtype.kind not in "iuf":
        raise TypeError(f"{name} must hold numbers, got {kind_of(array)}; pass uint8 "
                        "(0..255), uint16 (0..65535) or floats in 0..1.")
    if array.ndim == 3 and array.shape[2] == 1:
        array = array[..., 0]
    if array.ndim not in (2, 3) or (array.ndim == 3 and array.shape[2] not in (3, 4)):
        hint = ""
        if array.ndim == 3 and array.shape[2] == 2:
            hint = " For grey with alpha, stack it as RGBA: np.dstack([g, g, g, alpha])."
        elif array.ndim == 3 and array.shape[0] in (3, 4):
            hint = " Channels first? Move them last: np.moveaxis(image, 0, -1)."
        raise ValueError(f"{name} must be {_CHANNELS}, got an array of shape "
                         f"{array.shape}.{hint}")
    if array.size == 0:
        raise ValueError(f"{name} is empty (shape {array.shape}); give a picture with at least "
                         "one pixel.")
    if array.dtype.kind in "iu":
        if array.dtype not in (np.uint8, np.uint16):
            raise TypeError(f"{name} holds {array.dtype} integers, whose range mvcjax cannot "
                            "tell; pass uint8 (0..255, e.g. image.astype(np.uint8)), uint16 "
                            "(0..65535) or floats in 0..1.")
        # Divided in float32, so the dtype's largest value is exactly 1 (opaque).
        array = array.astype(np.float32) / np.float32(np.iinfo(array.dtype).max)
    else:
        nan = np.isnan(array)
        if nan.any():
            raise ValueError(f"{name} has {int(nan.sum())} NaN values; a picture's channels "
                             "are numbers in 0..1 (replace them, e.g. np.nan_to_num).")
        lo, hi = float(array.min()), float(array.max())
        if lo < 0 or hi > 1:
            raise ValueError(f"{name} holds floats from {lo:g} to {hi:g}, outside 0..1; if "
                             "they are 0..255, divide by 255 (or pass them as uint8).")
        array = array.astype(np.float32)
    if array.ndim == 2:
        array = np.repeat(array[..., None], 3, axis=2)
    if array.shape[2] == 3:
        array = np.concatenate([array, np.ones_like(array[..., :1])], axis=2)
    return np.ascontiguousarray(array)


def load_image(image: Any) -> Float[np.ndarray, "rows cols 4"]:
    """A picture as straight (not premultiplied) RGBA floats in 0..1, `(rows, cols, 4)`.

    Row 0 is the top of the picture; `pixels_to_points` gives the shape coordinates of
    its pixels (`Shape.from_image` uses this convention).

    Args:
        image: a path (`str` or `os.PathLike`) to an image file, read with Pillow (its
            first frame; palette, grey, grey with alpha and RGB files become RGBA, opaque
            where the file has no alpha; 16-bit grey keeps its 16 bits; an EXIF
            orientation tag is not applied, so the grid is the stored one, as
            `np.asarray(PIL.Image.open(path))` gives it); a Pillow image; or an
            array, `(rows, cols)` grey (made opaque grey), `(rows, cols, 3)` RGB (made
            opaque) or `(rows, cols, 4)` RGBA. Arrays of `uint8` (0..255) or `uint16`
            (0..65535) are divided by 255 or 65535; float arrays must lie in 0..1.

    Returns:
        A new `float32` array `(rows, cols, 4)`: red, green, blue, alpha.

    Refused, with an error naming the problem and the fix: a missing file
    (`FileNotFoundError`), a file Pillow cannot read, an array of another shape (such as
    `(rows, cols, 2)`) or empty, booleans (a mask: pass it to `Shape.from_image`),
    integers other than `uint8` and `uint16`, complex numbers or objects, NaN, and floats
    outside 0..1.
    """
    if isinstance(image, (str, os.PathLike)):
        return _from_file(image, repr(os.fspath(image)))
    if is_pil_image(image):
        return _from_pil(image, f"the Pillow image ({image.mode})")
    return _from_array(image, "image")


def _number(value, name: str, below: str) -> float:
    """A finite number in 0 <= value < 1, or an error naming `name`."""
    if not is_real_number(value):
        raise TypeError(f"{name} must be a number from 0 to below 1, got {value!r}.")
    if not 0 <= value < 1:
        why = f": {below}" if value >= 1 else ""
        raise ValueError(f"{name} must be a number from 0 to below 1, got {value}{why}.")
    return float(value)


class CornerColour(eqx.Module):
    """The background colour of a picture is its top-left pixel's (`background=` of
    `image_mask`, `cut_out` and `Shape.from_image`): for a sprite on a plain backdrop
    whose colour is not known."""

    def __call__(self, picture: Float[np.ndarray, "rows cols 4"]) -> Float[np.ndarray, 3]:
        """The RGB colour of `picture`'s top-left pixel."""
        return picture[0, 0, :3]


def _background_colour(background, picture: np.ndarray) -> np.ndarray:
    """The background's RGB in 0..1 (float32, like the picture)."""
    if isinstance(background, CornerColour):
        return background(picture)
    refuse_string("background", background, {"corner": "mvcjax.advanced.CornerColour()"})
    if isinstance(background, str):
        from PIL import ImageColor

        try:
            rgb = ImageColor.getrgb(background)
        except ValueError:
            raise ValueError(f"background={background!r} is not a colour: give a colour "
                             'name or "#rrggbb", RGB numbers, (255, 255, 255) or (1.0, 1.0, '
                             "1.0) for white, or mvcjax.advanced.CornerColour() (the colour "
                             "of the top-left pixel).") from None
        if len(rgb) != 3:
            raise ValueError(f"background={background!r} has an alpha; give its colour only "
                             "(alpha is judged by alpha_threshold).")
        return np.asarray(rgb, np.float32) / np.float32(255)
    try:
        colour = np.asarray(background)
    except ValueError:
        colour = np.asarray(None)
    if colour.dtype.kind not in "iuf" or colour.shape != (3,):
        raise TypeError(f"background must be an RGB colour, 3 numbers (0..255 integers or "
                        f"0..1 floats), a colour name or mvcjax.advanced.CornerColour(), got "
                        f"{background!r}.")
    if colour.dtype.kind in "iu":
        if colour.min() < 0 or colour.max() > 255:
            raise ValueError(f"background={background!r} is outside 0..255; integers are "
                             "0..255, floats 0..1.")
        # (1, 1, 1) is white to someone thinking in 0..1 and almost black in 0..255.
        if colour.max() == 1:
            floats = tuple(float(c) for c in colour)
            raise ValueError(f"background={background!r} is ambiguous: integer colours are "
                             f"0..255, which makes it almost black; for the 0..1 colour pass "
                             f"floats, {floats}, or 0..255 integers such as (255, 255, 255).")
        return colour.astype(np.float32) / np.float32(255)
    if not np.all(np.isfinite(colour)) or colour.min() < 0 or colour.max() > 1:
        raise ValueError(f"background={background!r} is outside 0..1; floats are 0..1, for "
                         "0..255 pass integers such as (255, 255, 255).")
    return colour.astype(np.float32)


def image_mask(
    image: Any,
    *,
    alpha_threshold: Any = 0.5,
    background: Any = None,
    key_tolerance: Any = 0.1,
) -> Bool[np.ndarray, "rows cols"]:
    """The foreground of a picture: where it is opaque enough and not the background.

    A pixel is foreground where its alpha is above `alpha_threshold` and, if
    `background` is given, its colour differs from the background's by more than
    `key_tolerance` in some channel. A picture that is opaque everywhere (RGB, or alpha 1
    everywhere) needs `background`.

    Args:
        image: a picture, anything `load_image` takes (a path, a Pillow image, a grey,
            RGB or RGBA array).
        alpha_threshold: alpha above which a pixel is foreground, from 0 to below 1.
        background: the colour to key out: RGB as 0..255 integers or 0..1 floats,
            a colour name or `"#rrggbb"`, or `mvcjax.advanced.CornerColour()` for the
            colour of the top-left pixel. Required for an opaque picture.
        key_tolerance: largest difference, in 0..1 units and any of red, green or
            blue, at which a pixel's colour still counts as the background, from 0 to
            below 1. Anti-aliased edges lie between the two colours: the default, 0.1,
            keys out only what is close to the background.

    Returns:
        A boolean array `(rows, cols)`, true on the foreground; `Shape.from_image` traces
        it.

    Refused with a `ValueError` naming the fix: an opaque picture without
    `background`, a foreground that is empty (alpha at or below the threshold, or every
    pixel the background's colour) or everywhere.
    """
    picture = load_image(image)
    threshold = _number(alpha_threshold, "alpha_threshold", "alpha is at most 1")
    tolerance = _number(key_tolerance, "key_tolerance",
                        "no colour differs from another by more than 1")
    alpha = picture[..., 3]
    opaque = bool(np.all(alpha == 1))
    if opaque and background is None:
        raise ValueError(
            "The picture is opaque (RGB, or alpha 1 everywhere), so alpha cannot tell the "
            "shape from its background: pass background= its colour (e.g. background=(255, "
            "255, 255) for white, or background=mvcjax.advanced.CornerColour() for the "
            "colour of the top-left pixel), or give a picture with alpha."
        )
    mask = alpha > threshold
    if not mask.any():
        raise ValueError(f"alpha is at or below {threshold:g} everywhere (its largest value is "
                         f"{alpha.max():.3g}): the picture is transparent; lower "
                         "alpha_threshold or check the picture.")
    if background is not None:
        colour = _background_colour(background, picture)
        keyed = np.max(np.abs(picture[..., :3] - colour), axis=-1) > tolerance
        if not (mask & keyed).any():
            shown = tuple(round(float(c), 3) for c in colour)
            raise ValueError(f"Every {'opaque ' if not opaque else ''}pixel is within "
                             f"key_tolerance={tolerance:g} of the background colour {shown} "
                             "(0..1 RGB): nothing is left as foreground; check background= "
                             "or lower key_tolerance.")
        mask &= keyed
    if mask.all():
        fix = ("pass background= to key out a colour as well" if background is None else
               "check background= or raise key_tolerance")
        raise ValueError(f"The foreground is everywhere (alpha above {threshold:g}"
                         f"{'' if background is None else ', no pixel the background colour'})"
                         f", so it has no outline; {fix}.")
    return mask


def cut_out(
    image: Any,
    *,
    background: Any = CornerColour(),
    key_tolerance: Any = 0.1,
    edge: Any = 2,
) -> Float[np.ndarray, "rows cols 4"]:
    """A picture on a plain background (a JPEG sprite on white) as RGBA, its background
    keyed out and its edge colours freed of it: what to rig and render instead of the
    opaque picture, which would draw a rim of the background's colour round the shape.

    The foreground is `image_mask`'s. Pixels more than `edge` pixels inside it keep their
    colour, with alpha 1. Along the outline (within `edge` pixels of it, on both sides) a
    pixel is a mix of the background's colour `B` and the nearest clean foreground
    colour `F`: its alpha is how far along from `B` to `F` its colour lies, and its
    colour is `F` (the background's share removed, as matting tools do). Elsewhere alpha
    is 0. Where `F` is too close to `B` to tell a mix, the mask decides.

    Args:
        image: a picture, anything `load_image` takes.
        background: the colour to key out, as `image_mask` takes it (default
            `CornerColour()`: the top-left pixel's).
        key_tolerance: as `image_mask`'s.
        edge: the width in pixels of the band along the outline whose colours are
            mixed with the background (JPEG blurs over about two).

    Returns:
        A new `float32` array `(rows, cols, 4)`: straight RGBA, for `Shape.from_image`
        and `Renderer.build`.
    """
    import scipy.ndimage

    picture = load_image(image)
    width = whole_number(edge, "edge", minimum=0)
    mask = image_mask(picture, background=background, key_tolerance=key_tolerance)
    key = _background_colour(background, picture).astype(np.float64)
    rgb = picture[..., :3].astype(np.float64)
    clean = scipy.ndimage.binary_erosion(mask, iterations=width) if width else mask
    if not clean.any():
        clean = mask  # a part thinner than the band: its own colours are all there is
    _, (row, col) = scipy.ndimage.distance_transform_edt(~clean, return_indices=True)
    nearest = rgb[row, col]
    towards = nearest - key
    reach = np.sum(towards * towards, axis=-1)
    mixed = np.clip(np.sum((rgb - key) * towards, axis=-1) / np.maximum(reach, 1e-12), 0, 1)
    band = (scipy.ndimage.binary_dilation(mask, iterations=width) if width else mask) & ~clean
    # A foreground colour within the key's tolerance of the background: no mix to measure.
    telling = np.sqrt(reach) > float(key_tolerance)
    alpha = np.where(clean, 1.0, np.where(band, np.where(telling, mixed, mask), 0.0))
    colour = np.where(band[..., None], nearest, rgb)
    out = np.concatenate([colour, (alpha * picture[..., 3])[..., None]], axis=-1)
    return out.astype(np.float32)
