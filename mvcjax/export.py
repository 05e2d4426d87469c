"""Files out: animations (GIF, animated PNG, WebP, MP4), pictures, outlines as SVG and
meshes as Wavefront OBJ.

Numpy in, files out: every function takes numpy arrays (JAX arrays and nested lists are
converted with `np.asarray`) and needs no JAX. Pictures are `(rows, cols, 4)` RGBA or
`(rows, cols, 3)` RGB, either float in `[0, 1]` with straight (not premultiplied) alpha,
or `uint8`. Animations are written by Pillow, MP4 by imageio's ffmpeg plugin (the
optional `imageio-ffmpeg` package: `pip install 'mvcjax[video]'`).

Shape coordinates are y up, as everywhere in mvcjax: `write_svg` flips them for SVG's
y-down page, and `texture_uv` maps them to texture coordinates of a picture under the
pixel convention of `mvcjax.pixels_to_points`.
"""

from __future__ import annotations

import math
import os
import warnings
from pathlib import Path
from typing import Any
from xml.sax.saxutils import quoteattr

import numpy as np

from .core import as_points, is_real_number, is_whole_number, kind_of, progress_bar
from .geometry import (
    as_matte_rgb,
    boundary_loops,
    byte_values,
    check_channels,
    check_values,
    ring_area,
    to_bytes,
    to_uint8,
)

__all__ = [
    "ANIMATION_SUFFIXES",
    "outline_rings",
    "texture_uv",
    "to_uint8",
    "write_animation",
    "write_image",
    "write_obj",
    "write_svg",
]

_ANIMATION_FORMATS = {".gif": "GIF", ".png": "PNG", ".apng": "PNG", ".webp": "WEBP",
                      ".mp4": "MP4"}
_IMAGE_FORMATS = {".png": "PNG", ".webp": "WEBP", ".jpg": "JPEG", ".jpeg": "JPEG"}
# The suffixes `write_animation` writes (any case).
ANIMATION_SUFFIXES = tuple(_ANIMATION_FORMATS)

# The GIF palette is computed from this many frames spread over the animation, and from
# at most this many of their opaque pixels: enough for the colours of a deforming
# picture, and cheap to compute.
_PALETTE_FRAMES = 8
_PALETTE_PIXELS = 1 << 18

_DEFAULT_QUALITY = {"WEBP": 80, "JPEG": 90}
_DEFAULT_CRF = 23  # libx264's own default


# ---- checks ---------------------------------------------------------------------------


def _format_of(path, formats: dict[str, str], function: str) -> tuple[Path, str]:
    if not isinstance(path, str | os.PathLike):
        raise TypeError(f"path must be a str or a pathlib.Path, got {type(path).__name__}.")
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in formats:
        raise ValueError(
            f"path {str(path)!r} has suffix {suffix or '(none)'!r}, which {function} cannot "
            f"write; give one of {', '.join(formats)}."
        )
    return path, formats[suffix]


def _as_picture(picture, name: str = "picture") -> np.ndarray:
    array = np.asarray(picture)
    if array.ndim != 3:
        raise ValueError(f"{name} must have shape (rows, cols, 3) or (rows, cols, 4), got shape "
                         f"{array.shape}.")
    check_channels(array.shape, name, "(rows, cols, 3 or 4)")
    if array.shape[0] == 0 or array.shape[1] == 0:
        raise ValueError(f"{name} has shape {array.shape}: it must have at least one row and "
                         "one column.")
    check_values(array, name)
    return array


def _as_frames(frames) -> list[np.ndarray]:
    """The frames as a list of `(rows, cols, c)` arrays, all checked, none copied."""
    if isinstance(frames, str | bytes):
        raise TypeError("frames must be an array (n, rows, cols, 3 or 4) or a sequence of "
                        f"pictures, got a {type(frames).__name__}.")
    if hasattr(frames, "shape") and hasattr(frames, "dtype"):  # numpy, JAX, ...
        array = np.asarray(frames)
        if array.ndim != 4:
            hint = (" For a single picture use write_image, or pass frames[None]."
                    if array.ndim == 3 else "")
            raise ValueError(f"frames must have shape (n, rows, cols, 3 or 4), got shape "
                             f"{array.shape}.{hint}")
        items = list(array)
    else:
        try:
            items = [np.asarray(frame) for frame in frames]
        except TypeError:
            raise TypeError("frames must be an array (n, rows, cols, 3 or 4) or a sequence of "
                            f"pictures, got {type(frames).__name__}.") from None
        except ValueError as error:  # a ragged picture
            raise ValueError(f"frames holds a picture that is not a rectangular array: "
                             f"{error}") from None
    if not items:
        raise ValueError("frames is empty: give at least one picture.")
    first = None
    for i, frame in enumerate(items):
        _as_picture(frame, f"frames[{i}]")
        if first is None:
            first = frame.shape
        elif frame.shape != first:
            raise ValueError(f"frames[{i}] has shape {frame.shape} but frames[0] has shape "
                             f"{first}: every frame must have the same size and channels "
                             "(pad or crop them to one size).")
    return items


def _check_quality(quality) -> None:
    if quality is None:
        return
    if not is_real_number(quality) or not 0 <= quality <= 100:
        raise ValueError(f"quality must be a number from 0 to 100 (or None for the format's "
                         f"default), got {quality!r}.")


def _quality(kind: str, quality) -> int:
    return round(_DEFAULT_QUALITY[kind] if quality is None else quality)


# ---- pictures -------------------------------------------------------------------------


def write_image(path: Any, picture: Any, *, matte: Any = "white", quality: Any = None) -> None:
    """Write one picture as PNG, WebP or JPEG (from the path's suffix).

    PNG (lossless) and WebP keep the alpha channel; JPEG has none, so RGBA pictures are
    composited onto `matte`.

    Args:
        path: where to write; the suffix picks the format: `.png`, `.webp`, `.jpg`,
            `.jpeg` (any case).
        picture: `(rows, cols, 4)` RGBA or `(rows, cols, 3)` RGB, float in `[0, 1]`
            (straight alpha) or `uint8`.
        matte: the background colour of JPEG (a name, `"#rrggbb"` or three floats in
            `[0, 1]`); unused by PNG and WebP.
        quality: 0 to 100 for the lossy formats, or `None` for their defaults (WebP 80,
            JPEG 90); PNG ignores it.

    Raises:
        ValueError: an unknown suffix, a wrong shape, NaN or floats outside `[0, 1]`,
            a `quality` outside `[0, 100]` or an invalid `matte`.
    """
    from PIL import Image

    path, kind = _format_of(path, _IMAGE_FORMATS, "write_image")
    array = _as_picture(picture)
    _check_quality(quality)
    matte_rgb = as_matte_rgb(matte) if kind == "JPEG" else None
    image = Image.fromarray(np.ascontiguousarray(to_bytes(array, matte_rgb)))
    options = {} if kind == "PNG" else {"quality": _quality(kind, quality)}
    image.save(path, format=kind, **options)


# ---- animations -----------------------------------------------------------------------


def write_animation(
    path: Any,
    frames: Any,
    *,
    fps: Any = 24,
    loop: Any = 0,
    progress: Any = None,
    quality: Any = None,
    matte: Any = "white",
) -> None:
    """Write pictures as an animation: GIF, animated PNG, WebP or MP4.

    The format comes from the path's suffix:

    - `.png` or `.apng`: animated PNG, lossless, full alpha. Compressed with zlib's
      fastest level, which keeps writing fast (lossless animations are large anyway).
    - `.webp`: lossy WebP (`quality`) with lossless alpha.
    - `.gif`: 256 colours, 1-bit transparency. One palette of up to 255 colours serves
      every frame: Pillow's fast octree on the opaque pixels of a few frames spread over
      the animation (Pillow's default, a median cut of every frame, is slow on long
      animations), each frame mapped to it without dithering (dithering
      noise crawls from frame to frame and makes the file larger); one more entry is the
      transparent one.
      Pixels with alpha below 1/2 become transparent; the others are composited onto
      `matte`, so that soft edges blend into a page of that colour (set `matte` to
      the page's background) instead of showing a hard, jagged rim. GIF delays are
      whole hundredths of a second, alternated so that the average rate is `fps`;
      browsers slow down delays under 2/100 s, so above 50 fps a GIF plays slower.
    - `.mp4`: H.264 (libx264's `veryfast` preset, `yuv420p` for browsers, `+faststart`
      so that they play before the end has loaded) through imageio's ffmpeg plugin;
      needs `pip install 'mvcjax[video]'` (the `imageio-ffmpeg` package, which ships an
      ffmpeg binary). MP4 has no alpha: RGBA frames are composited onto
      `matte`. H.264's 4:2:0 colour needs an even width and height: an odd one is
      padded with a row or column of `matte` at the bottom or right, so the video is
      then one pixel taller or wider than the frames.

    GIF, animated PNG and WebP merge a frame identical to the one before it into a
    longer frame, so that they may hold fewer frames than given, the timing kept.

    Args:
        path: where to write; the suffix (any case) picks the format: `.gif`, `.png`,
            `.apng`, `.webp`, `.mp4`.
        frames: `(n, rows, cols, 4)` RGBA or `(n, rows, cols, 3)` RGB pictures, an array
            or a sequence of `(rows, cols, c)` arrays of one size, float in `[0, 1]`
            (straight alpha) or `uint8`.
        fps: frames per second, positive.
        loop: how many times the animation plays, 0 for ever (MP4 ignores it).
        progress: `None` shows a tqdm bar on stderr when writing more than 10 frames to
            a terminal; `True` always, `False` never. The bar counts frames as they are
            prepared and handed to the encoder; the Pillow formats then encode.
        quality: 0 to 100 for the lossy formats, or `None` for their defaults: WebP's
            quality (default 80); MP4's constant rate factor `round(51 * (1 - quality /
            100))` (default CRF 23, libx264's). GIF and animated PNG are lossless and
            ignore it.
        matte: the background colour (a name such as `"white"`, `"#rrggbb"` or three
            floats in `[0, 1]`) of MP4, and of GIF's semi-transparent pixels; animated
            PNG and WebP keep the alpha and ignore it. To flatten those too, pass
            `to_uint8(frames, matte=...)`.

    Raises:
        ValueError: an unknown suffix; no frames; frames of a wrong shape, of different
            sizes, with NaN or with floats outside `[0, 1]`; `fps` not positive; `loop`
            negative; `quality` outside `[0, 100]`; an invalid `matte`.
        TypeError: frames of a dtype other than float or `uint8`.
        ImportError: MP4 without the `imageio-ffmpeg` package.
    """
    path, kind = _format_of(path, _ANIMATION_FORMATS, "write_animation")
    items = _as_frames(frames)
    _check_timing(fps, loop, progress)
    _check_quality(quality)
    matte_rgb = as_matte_rgb(matte)
    if kind == "MP4":
        _write_mp4(path, items, float(fps), quality, matte_rgb, progress)
    elif kind == "GIF":
        _write_gif(path, items, float(fps), int(loop), matte_rgb, progress)
    else:
        _write_pillow(path, kind, items, float(fps), int(loop), quality, progress)


def _check_timing(fps, loop, progress) -> None:
    """`write_animation`'s `fps`, `loop` and `progress`, or an error naming the one."""
    if not is_real_number(fps) or not 0 < fps < math.inf:
        raise ValueError(f"fps must be a positive number of frames per second, got {fps!r}.")
    if not is_whole_number(loop) or loop < 0:
        raise ValueError(f"loop must be how many times to play, an integer >= 0 (0 for ever), "
                         f"got {loop!r}.")
    if progress is not None and not isinstance(progress, bool):
        raise TypeError(f"progress must be None, True or False, got {progress!r}.")


def _write_pillow(path, kind, items, fps, loop, quality, progress) -> None:
    from PIL import Image

    with progress_bar(len(items), progress, path.name) as bar:
        images = []
        for frame in items:
            images.append(Image.fromarray(np.ascontiguousarray(to_bytes(frame, None))))
            bar.update()
        bar.set_postfix_str("encoding")
        if kind == "PNG":
            # zlib level 1: much faster than the default level, for somewhat larger
            # files.
            options: dict[str, Any] = {"compress_level": 1, "default_image": False}
        else:
            options = {"quality": _quality(kind, quality)}
        images[0].save(path, format=kind, save_all=True, append_images=images[1:],
                       duration=1000 / fps, loop=loop, **options)


def _gif_delays(count: int, fps: float) -> list[int]:
    """Delays in milliseconds, whole hundredths of a second, whose running sum follows
    `i / fps` as closely as those allow, each at least 2/100 s."""
    ticks = np.round(np.arange(count + 1) * (100 / fps))
    return [10 * max(int(d), 2) for d in np.diff(ticks)]


def _write_gif(path, items, fps, loop, matte_rgb, progress) -> None:
    from PIL import Image

    has_alpha = items[0].shape[-1] == 4
    matte_bytes = byte_values(matte_rgb)

    def opaque_colours(frame):
        frame = to_bytes(frame, None)
        rgb = to_bytes(frame, matte_rgb)
        return (rgb, frame[..., 3] < 128) if has_alpha else (rgb, None)  # alpha < 1/2

    picks = np.unique(np.linspace(0, len(items) - 1, _PALETTE_FRAMES).round().astype(int))
    samples = []
    for i in picks:
        rgb, clear = opaque_colours(items[i])
        samples.append(rgb.reshape(-1, 3) if clear is None else rgb[~clear])
    sample = np.concatenate(samples)
    if len(sample) > _PALETTE_PIXELS:
        sample = sample[:: -(-len(sample) // _PALETTE_PIXELS)]
    if len(sample) == 0:  # every sampled pixel transparent
        sample = matte_bytes[None]
    colours = 255 if has_alpha else 256
    palette_image = Image.fromarray(np.ascontiguousarray(sample[None])).quantize(
        colours, method=Image.Quantize.FASTOCTREE
    )
    palette = palette_image.getpalette()[: 3 * colours]
    clear_index = len(palette) // 3
    if has_alpha:
        palette = palette + matte_bytes.tolist()  # what viewers without transparency show

    with progress_bar(len(items), progress, path.name) as bar:
        images = []
        for frame in items:
            rgb, clear = opaque_colours(frame)
            image = Image.fromarray(np.ascontiguousarray(rgb)).quantize(
                palette=palette_image, dither=Image.Dither.NONE
            )
            if clear is not None:
                image.paste(clear_index, mask=Image.fromarray(clear))
            image.putpalette(palette)
            images.append(image)
            bar.update()
        bar.set_postfix_str("encoding")
        options: dict[str, Any] = {}
        if has_alpha:
            # Disposal 2 clears each frame to transparent before the next, which is
            # drawn on an empty page instead of over the previous frame.
            options.update(transparency=clear_index, disposal=2)
        # GIF's loop count is how many times to repeat after the first play, and no
        # count at all plays once.
        if loop != 1:
            options["loop"] = 0 if loop == 0 else loop - 1
        # optimize=False: Pillow's palette optimisation would renumber the shared
        # palette frame by frame, and costs time.
        images[0].save(path, format="GIF", save_all=True, append_images=images[1:],
                       duration=_gif_delays(len(images), fps), optimize=False, **options)


def _write_mp4(path, items, fps, quality, matte_rgb, progress) -> None:
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError:
        raise ImportError(
            "writing .mp4 needs the imageio-ffmpeg package, which ships an ffmpeg binary: "
            "pip install 'mvcjax[video]' (or pip install imageio-ffmpeg)."
        ) from None
    import imageio.v3 as iio

    rows, cols = items[0].shape[:2]
    even_rows, even_cols = rows + rows % 2, cols + cols % 2
    matte_bytes = byte_values(matte_rgb)
    crf = _DEFAULT_CRF if quality is None else round(51 * (1 - quality / 100))

    def rgb_frames(bar):
        for frame in items:
            rgb = to_bytes(frame, matte_rgb)
            if (even_rows, even_cols) != (rows, cols):
                padded = np.empty((even_rows, even_cols, 3), np.uint8)
                padded[...] = matte_bytes
                padded[:rows, :cols] = rgb
                rgb = padded
            yield rgb
            bar.update()

    with progress_bar(len(items), progress, path.name) as bar, warnings.catch_warnings():
        # JAX warns at every os.fork once it is imported, but the fork that starts ffmpeg
        # execs at once: no JAX thread is needed in the child.
        warnings.filterwarnings("ignore", r"os\.fork\(\) was called", RuntimeWarning)
        # libx264's veryfast preset: faster than its default (medium), for files about
        # as large and colours slightly less faithful.
        # A generator streams the frames to ffmpeg one at a time; macro_block_size=1
        # stops imageio from resizing to multiples of 16, the padding above is enough.
        iio.imwrite(path, rgb_frames(bar), is_batch=True, plugin="FFMPEG", extension=".mp4",
                    fps=fps, codec="libx264", quality=None, pixelformat="yuv420p",
                    macro_block_size=1, ffmpeg_log_level="error",
                    output_params=["-crf", str(crf), "-preset", "veryfast",
                                   "-movflags", "+faststart"])


# ---- outlines -------------------------------------------------------------------------


def _as_faces(faces, vertex_count: int) -> np.ndarray:
    array = np.asarray(faces)
    if array.dtype.kind not in "iu":
        raise TypeError(f"faces must be integer vertex indices, got {kind_of(array)} "
                        f"({array.dtype}).")
    if array.ndim != 2 or array.shape[1] != 3:
        raise ValueError(f"faces must have shape (f, 3), a row of vertex indices per triangle, "
                         f"got shape {array.shape}.")
    if array.size and (array.min() < 0 or array.max() >= vertex_count):
        raise ValueError(f"faces holds vertex indices from {array.min()} to {array.max()}, but "
                         f"there are {vertex_count} vertices: indices are 0-based, in "
                         f"[0, {vertex_count - 1}].")
    return array.astype(np.int64)


def outline_rings(vertices: Any, faces: Any) -> list[np.ndarray]:
    """The boundary loops of a triangle mesh, as rings of points for `write_svg`.

    With a rig's deformed vertices, `write_svg(path, outline_rings(deformed,
    rig.shape_mesh.faces))` writes the deformed outline.

    Args:
        vertices: `(n, 2)` vertex positions, rest or deformed.
        faces: `(f, 3)` triangles, 0-based vertex indices, counter-clockwise at rest.

    Returns:
        A list of `(k, 2)` float64 arrays, one per boundary loop, oriented as the faces
        (outer loops counter-clockwise, holes clockwise): counter-clockwise loops first,
        the largest first, then the holes.

    Raises:
        ValueError: vertices or faces of a wrong shape, indices out of range, or a
            boundary passing twice through a vertex.
    """
    points = as_points(vertices, "vertices")
    loops = boundary_loops(_as_faces(faces, len(points)))
    rings = [points[loop] for loop in loops]
    return sorted(rings, key=ring_area, reverse=True)


def _as_rings(outline) -> list[np.ndarray]:
    rings = getattr(outline, "rings", None)  # an mvcjax.Shape
    if rings is None:
        rings = outline
        if isinstance(rings, np.ndarray) or hasattr(rings, "shape"):
            # One array: a single ring (k, 2), or rings of one length (m, k, 2).
            array = np.asarray(rings)
            rings = [array] if array.ndim == 2 else list(array)
    try:
        rings = list(rings)
    except TypeError:
        raise TypeError("outline_or_rings must be an mvcjax.Shape or a list of (k, 2) rings, "
                        f"got {type(outline).__name__}.") from None
    if not rings:
        raise ValueError("outline_or_rings has no rings: give at least one (k, 2) ring.")
    checked = []
    for i, ring in enumerate(rings):
        ring = as_points(ring, f"rings[{i}]", "k")
        if len(ring) > 1 and np.array_equal(ring[0], ring[-1]):
            ring = ring[:-1]  # closed by the path's Z
        if len(ring) < 3:
            raise ValueError(f"rings[{i}] has {len(ring)} distinct vertices; a ring needs at "
                             "least 3.")
        checked.append(ring)
    return checked


def _numbers(values: np.ndarray) -> list[str]:
    # Seven significant digits: well under a thousandth of a pixel on pictures of
    # thousands of pixels, and short files.
    return [f"{v:.7g}" for v in values.tolist()]


def write_svg(
    path: Any,
    outline_or_rings: Any,
    *,
    fill: Any = "#4c72b0",
    stroke: Any = None,
    stroke_width: Any = 1.0,
    margin: Any = None,
    width: Any = None,
) -> None:
    """Write an outline as an SVG path, y flipped so that it looks right in a browser.

    The rings (outer boundaries and holes, in any order and orientation) become one
    `<path>` with `fill-rule="evenodd"`, so that holes stay empty. Shape coordinates are
    y up and SVG's are y down: a point `(x, y)` is drawn at `(x, -y)`. The view box fits
    the rings with a margin.

    Args:
        path: where to write the `.svg` file.
        outline_or_rings: an `mvcjax.Shape` (its `rings`), a list of `(k, 2)` rings in
            shape coordinates (`outline_rings(vertices, faces)` gives a deformed mesh's),
            or one `(k, 2)` ring. A ring may repeat its first vertex at the end.
        fill: the fill colour (any SVG colour: a name, `"#rrggbb"`), or `None` for none.
        stroke: the outline's colour, or `None` for no outline.
        stroke_width: the outline's width in screen pixels, whatever the zoom.
        margin: space around the rings, in shape units; `None` gives 2% of the larger
            side of their bounding box.
        width: the drawing's width in CSS pixels (its height follows); `None` makes one
            shape unit one pixel, right for shapes from pictures.

    Raises:
        ValueError: no rings, a ring with fewer than 3 vertices or non-finite
            coordinates, or a negative `margin`, `width` or `stroke_width`.
    """
    rings = _as_rings(outline_or_rings)
    for name, value in (("margin", margin), ("width", width), ("stroke_width", stroke_width)):
        if value is not None and (not is_real_number(value)
                                  or not 0 <= value < math.inf):
            raise ValueError(f"{name} must be a finite number >= 0, got {value!r}.")
    for name, value in (("fill", fill), ("stroke", stroke)):
        if value is not None and not isinstance(value, str):
            raise TypeError(f"{name} must be an SVG colour string such as 'black' or "
                            f"'#4c72b0', or None, got {value!r}.")
    points = np.concatenate(rings)
    lo = np.array([points[:, 0].min(), -points[:, 1].max()])
    hi = np.array([points[:, 0].max(), -points[:, 1].min()])
    extent = float(np.max(hi - lo))
    if margin is None:
        margin = 0.02 * extent if extent > 0 else 1.0
    lo, size = lo - margin, hi - lo + 2 * margin
    if width is None:
        pixels = size
    else:
        pixels = size * (width / size[0]) if size[0] > 0 else np.array([width, width])

    commands = []
    for ring in rings:
        xs, ys = _numbers(ring[:, 0]), _numbers(-ring[:, 1])
        coordinates = [f"{x},{y}" for x, y in zip(xs, ys)]
        commands.append(f"M{coordinates[0]} L{' '.join(coordinates[1:])} Z")
    view = " ".join(_numbers(np.concatenate([lo, size])))
    w, h = _numbers(pixels)
    style = [f"fill={quoteattr(fill or 'none')}", 'fill-rule="evenodd"']
    if stroke is not None:
        style += [f"stroke={quoteattr(stroke)}", f'stroke-width="{float(stroke_width):g}"',
                  'stroke-linejoin="round"', 'vector-effect="non-scaling-stroke"']
    text = (
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        f'<svg xmlns="http://www.w3.org/2000/svg" viewBox="{view}" width="{w}" '
        f'height="{h}">\n'
        f'  <path {" ".join(style)}\n'
        f'        d="{" ".join(commands)}"/>\n'
        "</svg>\n"
    )
    Path(path).write_text(text, encoding="utf-8")


# ---- meshes ---------------------------------------------------------------------------


def texture_uv(points: Any, rows: Any, cols: Any) -> np.ndarray:
    """Texture coordinates `(u, v)` of shape points on a picture of `rows x cols` pixels.

    Under mvcjax's pixel convention (`mvcjax.pixels_to_points`: the centre of pixel
    `(row, col)` is `(x, y) = (col, rows - 1 - row)`), `u = (x + 0.5) / cols` and
    `v = (y + 0.5) / rows`: `(0, 0)` is the picture's bottom-left corner and `(1, 1)` its
    top-right one, as OBJ and OpenGL expect. Use the rest vertices, so that the texture
    follows the deformation: `write_obj(path, deformed, faces,
    texture_coordinates=texture_uv(rig.shape_mesh.vertices, rows, cols))`.

    Args:
        points: `(n, 2)` points `(x, y)` in shape coordinates (y up).
        rows: the picture's height in pixels.
        cols: the picture's width in pixels.

    Returns:
        `(n, 2)` float64 `(u, v)`, in `[0, 1]` for points on the picture.
    """
    for name, value in (("rows", rows), ("cols", cols)):
        if not is_whole_number(value) or value < 1:
            raise ValueError(f"{name} must be a positive whole number of pixels, got {value!r}.")
    xy = as_points(points, "points")
    return np.stack([(xy[:, 0] + 0.5) / cols, (xy[:, 1] + 0.5) / rows], axis=1)


def _as_real(values, name: str, columns: tuple[int, ...], rows: str) -> np.ndarray:
    array = np.asarray(values)
    if array.dtype.kind not in "iuf":
        raise TypeError(f"{name} must be real numbers, got {kind_of(array)} ({array.dtype}).")
    if array.ndim != 2 or array.shape[1] not in columns:
        wanted = " or ".join(f"({rows}, {c})" for c in columns)
        raise ValueError(f"{name} must have shape {wanted}, got shape {array.shape}.")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} contains NaN or infinite values; give finite numbers.")
    # Floats keep their dtype, so that float32 prints as short as float32 allows.
    return array if array.dtype.kind == "f" else array.astype(np.float64)


def write_obj(path: Any, vertices: Any, faces: Any, *, texture_coordinates: Any = None) -> None:
    """Write a triangle mesh as a Wavefront OBJ file.

    Lines `v x y 0` (or `v x y z`), then `vt u v` when texture coordinates are given,
    then `f a b c` (or `f a/a b/b c/c`, a texture coordinate per vertex), 1-based.
    Numbers are written in the shortest form that reads back to the same value.

    To texture the mesh with the picture it was made from, give
    `texture_coordinates=texture_uv(rest_vertices, rows, cols)` and a material
    (`.mtl`, `map_Kd picture.png`) in the viewer.

    Args:
        path: where to write the `.obj` file.
        vertices: `(n, 2)` vertex positions (z = 0 is written) or `(n, 3)`.
        faces: `(f, 3)` triangles, 0-based vertex indices.
        texture_coordinates: `(n, 2)` `(u, v)` per vertex, usually in `[0, 1]`, or
            `None`.

    Raises:
        ValueError: arrays of a wrong shape, non-finite values, or indices out of range.
    """
    # meshio or trimesh could write this, but OBJ is a few kinds of text line: not worth
    # a dependency.
    points = _as_real(vertices, "vertices", (2, 3), "n")
    triangles = _as_faces(faces, len(points))
    uv = None
    if texture_coordinates is not None:
        uv = _as_real(texture_coordinates, "texture_coordinates", (2,), "n")
        if len(uv) != len(points):
            raise ValueError(f"texture_coordinates has {len(uv)} rows but there are "
                             f"{len(points)} vertices: give one (u, v) per vertex.")
    # astype(str) writes each float in the shortest form that round-trips in its dtype.
    text = points.astype(str)
    lines = ["# written by mvcjax"]
    if points.shape[1] == 2:
        lines += [f"v {x} {y} 0" for x, y in text.tolist()]
    else:
        lines += [f"v {x} {y} {z}" for x, y, z in text.tolist()]
    one_based = (triangles + 1).astype(str).tolist()
    if uv is not None:
        lines += [f"vt {u} {v}" for u, v in uv.astype(str).tolist()]
        lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in one_based]
    else:
        lines += [f"f {a} {b} {c}" for a, b, c in one_based]
    Path(path).write_text("\n".join(lines) + "\n", encoding="ascii")
