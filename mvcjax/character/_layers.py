"""Layered pictures in: a character's parts as RGBA layers of one canvas, from a list of
pictures or a layered file (Photoshop's PSD through psd-tools, OpenRaster through pyora),
bottom layer first."""

from __future__ import annotations

import os
import warnings
from typing import Any, NamedTuple

import numpy as np
from jaxtyping import Float

from ..geometry import load_image

# Layered file formats by suffix.
_FORMATS = {".psd": "psd", ".psb": "psd", ".ora": "ora"}


class Layer(NamedTuple):
    """One part of a layered character.

    Attributes:
        name: the layer's name (a file's layer name, or `"layer 0"`, `"layer 1"`, ...).
        picture: `(rows, cols, 4)` straight RGBA floats in 0..1, the size of the canvas;
            the part is where alpha is above the threshold.
    """

    name: str
    picture: Float[np.ndarray, "rows cols 4"]


def _canvas_layer(name: str, image, offset, canvas: tuple[int, int],
                  opacity: float = 1.0) -> Layer:
    """A layer's pixels (a Pillow image placed at `offset = (left, top)`) on the canvas,
    its alpha times `opacity`."""
    rows, cols = canvas
    picture = np.zeros((rows, cols, 4), np.float32)
    pixels = load_image(image)
    pixels[..., 3] *= opacity
    left, top = int(offset[0]), int(offset[1])
    # The part of the layer that lies on the canvas (a layer may reach past its edges).
    r0, c0 = max(top, 0), max(left, 0)
    r1, c1 = min(top + pixels.shape[0], rows), min(left + pixels.shape[1], cols)
    if r1 > r0 and c1 > c0:
        picture[r0:r1, c0:c1] = pixels[r0 - top:r1 - top, c0 - left:c1 - left]
    return Layer(name, picture)


def _opacity(layer, scale: float) -> float:
    """A layer's opacity times its groups' (each as a fraction of `scale`)."""
    opacity = 1.0
    while layer is not None and hasattr(layer, "opacity") and hasattr(layer, "parent"):
        opacity *= float(layer.opacity) / scale
        layer = layer.parent
    return opacity


def _warn_blend_modes(path: str, modes: dict[str, str]) -> None:
    if modes:
        listed = ", ".join(f"{name!r} ({mode})" for name, mode in modes.items())
        warnings.warn(f"{path!r}: layers {listed} blend by other modes than Normal; mvcjax "
                      "lays every part over those beneath (Normal), so their colours will "
                      "differ from the file's. Merge such effects into the layer's pixels to "
                      "keep them.", UserWarning, stacklevel=4)


def _read_psd(path: str) -> list[Layer]:
    from psd_tools import PSDImage
    from psd_tools.constants import BlendMode

    psd = PSDImage.open(path)
    layers, modes = [], {}
    for layer in psd.descendants():  # bottom to top, groups opened
        if layer.is_group() or not layer.is_visible():
            continue
        image = layer.topil()
        if image is None:  # an adjustment or an empty layer: nothing to draw
            continue
        if layer.blend_mode not in (BlendMode.NORMAL, BlendMode.PASS_THROUGH):
            modes[layer.name] = layer.blend_mode.name.lower().replace("_", " ")
        layers.append(_canvas_layer(layer.name, image, layer.offset, (psd.height, psd.width),
                                    _opacity(layer, 255.0)))
    _warn_blend_modes(path, modes)
    return layers


def _read_ora(path: str) -> list[Layer]:
    from pyora import Project

    project = Project.load(path)
    cols, rows = project.dimensions
    # pyora lists the layers bottom first (the file's stack lists them top first).
    visible = [layer for layer in project.iter_layers if layer.visible]
    _warn_blend_modes(path, {layer.name: layer.composite_op.split(":")[-1] for layer in visible
                             if layer.composite_op not in ("svg:src-over", None)})
    return [_canvas_layer(layer.name, layer.get_image_data(), layer.offsets, (rows, cols),
                          _opacity(layer, 1.0))
            for layer in visible]


def _read_layered_file(path) -> list[Layer]:
    name = repr(os.fspath(path))
    kind = _FORMATS.get(os.path.splitext(os.fspath(path))[1].lower())
    if kind is None:
        raise ValueError(f"{name} is not a layered file mvcjax reads (.psd, .psb or .ora); "
                         "give a list of pictures, one per part, bottom first, instead.")
    if not os.path.isfile(path):
        raise FileNotFoundError(f"No layered file at {name} (relative paths start at "
                                f"{os.getcwd()}); check the path.")
    try:
        layers = (_read_psd if kind == "psd" else _read_ora)(os.fspath(path))
    except Exception as error:  # the readers raise many kinds for a damaged file
        raise ValueError(f"{name} could not be read as {kind.upper()} ({error}); "
                         "it may be damaged or of another format: save it again, or give a "
                         "list of pictures instead.") from error
    if not layers:
        raise ValueError(f"{name} holds no visible pixel layer; a character needs at least "
                         "one.")
    return layers


def load_layers(layers: Any) -> list[Layer]:
    """A layered character's parts as `Layer`s, bottom first.

    Args:
        layers: a path to a layered file (`.psd`/`.psb` read by psd-tools, `.ora`
            OpenRaster read by pyora: visible pixel layers, groups opened, each placed
            on the canvas, its alpha times its opacity and its groups'; a layer that
            blends by another mode than Normal is drawn as Normal, with a warning), or a
            list of parts in draw order, bottom first: pictures
            (arrays, Pillow images or paths, read by `load_image`), `Layer`s or
            `(name, picture)` pairs, all the same size.

    Returns:
        A list of `Layer(name, picture)`, pictures `(rows, cols, 4)` straight RGBA floats.

    Refused with an error naming the layer: pictures of different sizes, and a layer
    with no opaque pixel (nothing to rig).
    """
    if isinstance(layers, (str, os.PathLike)):
        parts = _read_layered_file(layers)
    else:
        if not isinstance(layers, (list, tuple)) or not layers:
            raise TypeError(f"layers must be a layered file's path or a non-empty list of "
                            f"pictures (bottom first), got {type(layers).__name__}.")
        parts = []
        for i, item in enumerate(layers):
            if isinstance(item, tuple) and len(item) == 2 and isinstance(item[0], str):
                name, picture = item
            else:
                name, picture = f"layer {i}", item
            parts.append(Layer(str(name), load_image(picture)))
    size = parts[0].picture.shape[:2]
    for layer in parts:
        if layer.picture.shape[:2] != size:
            raise ValueError(
                f"layer {layer.name!r} is {layer.picture.shape[0]}x{layer.picture.shape[1]} "
                f"pixels, the first layer ({parts[0].name!r}) {size[0]}x{size[1]}: the "
                "layers of a character share one canvas; pad or place them on it.")
        if not np.any(layer.picture[..., 3] > 0):
            raise ValueError(f"layer {layer.name!r} is empty (fully transparent); drop it, "
                             "or draw the part on it.")
    return parts
