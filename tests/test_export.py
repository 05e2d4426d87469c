"""mvcjax.export: animations, pictures, SVG outlines and OBJ meshes read back."""

import sys
import xml.etree.ElementTree as ET

import imageio.v3 as iio
import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image

import mvcjax
from mvcjax import export
from mvcjax.core import _progress
from mvcjax.geometry import ring_area

COUNT, ROWS, COLS = 5, 24, 32


def disc_frames(count=COUNT, rows=ROWS, cols=COLS):
    """RGBA float frames: a textured disc that turns, soft-edged, transparent corners."""
    y, x = np.mgrid[:rows, :cols].astype(np.float64)
    dx, dy = x - (cols - 1) / 2, y - (rows - 1) / 2
    alpha = np.clip(0.45 * min(rows, cols) - np.hypot(dx, dy) + 0.5, 0, 1)
    frames = np.empty((count, rows, cols, 4))
    for i in range(count):
        t = 2 * np.pi * i / count
        u = np.cos(t) * dx - np.sin(t) * dy
        frames[i, ..., 0] = (u > 0) * 0.9
        frames[i, ..., 1] = 0.5 + 0.4 * np.sin(u / 3)
        frames[i, ..., 2] = 0.2 + 0.1 * i / count
        frames[i, ..., 3] = alpha
    return frames


def read_frames(path):
    """Every frame of a Pillow animation as RGBA uint8."""
    with Image.open(path) as image:
        frames = []
        for i in range(image.n_frames):
            image.seek(i)
            frames.append(np.asarray(image.convert("RGBA")))
        return np.stack(frames)


@pytest.mark.parametrize("suffix", [".gif", ".png", ".apng", ".webp"])
def test_pillow_animations_read_back(tmp_path, suffix):
    frames = disc_frames()
    path = tmp_path / f"a{suffix}"
    export.write_animation(path, frames, fps=10)
    back = read_frames(path)
    assert back.shape == (COUNT, ROWS, COLS, 4)
    clear = frames[..., 3] < 0.5
    assert np.all(back[..., 0, 0, 3] == 0)  # a transparent corner
    if suffix == ".gif":
        with Image.open(path) as image:
            assert image.info["transparency"] == 255
            assert image.info["loop"] == 0
            assert image.info["duration"] == 100
        np.testing.assert_array_equal(back[..., 3] == 0, clear)
        opaque = export.to_uint8(frames, matte="white")[~clear]
        assert np.abs(back[..., :3][~clear].astype(int) - opaque).mean() < 3
    else:
        # Alpha is exact in both; WebP's colour is lossy.
        np.testing.assert_array_equal(back[..., 3], export.to_uint8(frames)[..., 3])
        if suffix != ".webp":
            np.testing.assert_array_equal(back, export.to_uint8(frames))


def test_mp4_reads_back_with_odd_size_padded(tmp_path):
    frames = disc_frames(COUNT, 23, 31)
    path = tmp_path / "a.mp4"
    export.write_animation(path, frames, fps=12)
    back = iio.imread(path, plugin="FFMPEG")
    assert back.shape == (COUNT, 24, 32, 3)
    assert iio.immeta(path, plugin="FFMPEG")["fps"] == 12
    # The padding is the matte, the corners composited onto it: white.
    assert back[:, -1].mean() > 245 and back[:, :, -1].mean() > 245
    want = export.to_uint8(frames, matte="white").astype(int)
    assert np.abs(back[:, :23, :31].astype(int) - want).mean() < 12


def test_mp4_without_imageio_ffmpeg(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)
    with pytest.raises(ImportError, match=r"pip install 'mvcjax\[video\]'"):
        export.write_animation(tmp_path / "a.mp4", disc_frames())


@pytest.mark.parametrize("suffix", [".gif", ".png", ".webp", ".mp4"])
def test_float_and_uint8_frames_agree(tmp_path, suffix):
    frames = disc_frames(3)
    export.write_animation(tmp_path / f"f{suffix}", frames)
    export.write_animation(tmp_path / f"u{suffix}", list(export.to_uint8(frames)))
    export.write_animation(tmp_path / f"j{suffix}", jnp.asarray(frames, jnp.float32))
    f, u, j = ((tmp_path / f"{k}{suffix}").read_bytes() for k in "fuj")
    assert f == u == j


def test_rgb_frames_and_gif_loop_count(tmp_path):
    frames = disc_frames()[..., :3]
    export.write_animation(tmp_path / "once.gif", frames, loop=1)
    export.write_animation(tmp_path / "thrice.gif", frames, loop=3, fps=24)
    with Image.open(tmp_path / "once.gif") as image:
        assert image.n_frames == COUNT and "loop" not in image.info
        assert "transparency" not in image.info
    with Image.open(tmp_path / "thrice.gif") as image:
        assert image.info["loop"] == 2  # repeats after the first play
        durations = []
        for i in range(image.n_frames):
            image.seek(i)
            durations.append(image.info["duration"])
        # Whole hundredths, alternated so that frame i ends at round(100 i / 24).
        assert durations == [40, 40, 40, 50, 40]


def test_to_uint8_and_matte():
    picture = np.array([[[1.0, 0.0, 0.0, 0.6], [0.0, 0.0, 1.0, 0.0]]])
    np.testing.assert_array_equal(export.to_uint8(picture), [[[255, 0, 0, 153], [0, 0, 255, 0]]])
    np.testing.assert_array_equal(export.to_uint8(picture, matte="white"),
                                  [[[255, 102, 102], [255, 255, 255]]])
    np.testing.assert_array_equal(export.to_uint8(picture, matte=(0, 0, 0)),
                                  [[[153, 0, 0], [0, 0, 0]]])
    as_bytes = export.to_uint8(picture)
    assert export.to_uint8(as_bytes) is as_bytes
    np.testing.assert_array_equal(export.to_uint8(as_bytes, matte="#000000"),
                                  [[[153, 0, 0], [0, 0, 0]]])


@pytest.mark.parametrize("suffix", [".png", ".webp", ".jpg"])
def test_write_image(tmp_path, suffix):
    picture = disc_frames(1)[0]
    export.write_image(tmp_path / f"p{suffix}", picture, quality=95)
    with Image.open(tmp_path / f"p{suffix}") as image:
        assert image.size == (COLS, ROWS)
        back = np.asarray(image)
    if suffix == ".jpg":
        assert back.shape == (ROWS, COLS, 3) and back[0, 0].min() > 240  # on white
    else:
        assert back.shape == (ROWS, COLS, 4) and back[0, 0, 3] == 0
    if suffix == ".png":
        np.testing.assert_array_equal(back, export.to_uint8(picture))


def test_progress_is_silent_unless_asked(tmp_path, capfd):
    frames = disc_frames(12, 8, 8)
    for suffix in (".gif", ".mp4"):
        export.write_animation(tmp_path / f"a{suffix}", frames)
    assert capfd.readouterr().err == ""
    export.write_animation(tmp_path / "b.gif", frames, progress=True)
    assert "12/12" in capfd.readouterr().err


def test_progress_by_default_on_a_terminal_for_many_frames(tmp_path, capfd, monkeypatch):
    monkeypatch.setattr(_progress, "stderr_is_terminal", lambda: True)
    export.write_animation(tmp_path / "few.gif", disc_frames(10, 8, 8))
    assert capfd.readouterr().err == ""
    export.write_animation(tmp_path / "many.gif", disc_frames(11, 8, 8))
    assert "11/11" in capfd.readouterr().err


@pytest.mark.parametrize(
    ("path", "frames", "options", "error", "match"),
    [
        ("a.avi", disc_frames(2), {}, ValueError, r"suffix '\.avi'.*\.gif, \.png, \.apng"),
        ("a", disc_frames(2), {}, ValueError, r"suffix '\(none\)'"),
        ("a.gif", [], {}, ValueError, "frames is empty"),
        ("a.gif", disc_frames(2)[0], {}, ValueError, r"shape \(n, rows, cols.*write_image"),
        ("a.gif", disc_frames(2)[..., :2], {}, ValueError, r"frames\[0\].*3 \(RGB\) or 4"),
        ("a.gif", [np.zeros((4, 4, 3)), np.zeros((4, 5, 3))], {}, ValueError,
         r"frames\[1\] has shape \(4, 5, 3\) but frames\[0\]"),
        ("a.gif", [np.zeros((4, 4, 3)), np.full((4, 4, 3), np.nan)], {}, ValueError,
         r"frames\[1\] contains NaN"),
        ("a.gif", disc_frames(2) * 2, {}, ValueError, r"outside \[0, 1\].*np\.clip"),
        ("a.gif", np.zeros((2, 4, 4, 3), np.int64), {}, TypeError, r"\.astype\(np\.uint8\)"),
        ("a.gif", disc_frames(2), {"fps": 0}, ValueError, "fps must be a positive"),
        ("a.gif", disc_frames(2), {"fps": -24.0}, ValueError, "fps must be a positive"),
        ("a.gif", disc_frames(2), {"loop": -1}, ValueError, "loop must be"),
        ("a.webp", disc_frames(2), {"quality": 101}, ValueError, "quality must be"),
        ("a.mp4", disc_frames(2), {"matte": "nocolour"}, ValueError, "matte 'nocolour'"),
        ("a.mp4", disc_frames(2), {"matte": (0, 0, 2)}, ValueError, r"three floats"),
    ],
)
def test_animation_errors(tmp_path, path, frames, options, error, match):
    with pytest.raises(error, match=match):
        export.write_animation(tmp_path / path, frames, **options)
    assert not (tmp_path / path).exists()


def test_image_and_to_uint8_errors(tmp_path):
    with pytest.raises(ValueError, match=r"\.png, \.webp, \.jpg, \.jpeg"):
        export.write_image(tmp_path / "a.gif", np.zeros((4, 4, 3)))
    with pytest.raises(ValueError, match=r"picture must have shape \(rows, cols, 3\)"):
        export.write_image(tmp_path / "a.png", np.zeros((2, 4, 4, 3)))
    with pytest.raises(ValueError, match="pictures contains NaN"):
        export.to_uint8(np.full((2, 2, 4), np.nan))


def svg_rings(path):
    """The rings of the single path of an SVG written by write_svg, and the root."""
    root = ET.parse(path).getroot()
    paths = root.findall("{http://www.w3.org/2000/svg}path")
    assert len(paths) == 1 and paths[0].get("fill-rule") == "evenodd"
    rings = []
    for command in paths[0].get("d").split("Z")[:-1]:
        points = command.replace("M", " ").replace("L", " ").split()
        rings.append(np.array([[float(v) for v in p.split(",")] for p in points]))
    return rings, root, paths[0]


def test_svg_of_a_shape(tmp_path, ring_shape):
    export.write_svg(tmp_path / "s.svg", ring_shape, stroke="black")
    rings, root, path = svg_rings(tmp_path / "s.svg")
    assert [len(r) for r in rings] == [len(r) for r in ring_shape.rings]
    for ring, want in zip(rings, ring_shape.rings):
        np.testing.assert_allclose(ring, want * [1, -1], atol=1e-4)  # y flipped
    x, y, w, h = map(float, root.get("viewBox").split())
    assert x < -50 < 50 < x + w and y < -50 < 50 < y + h
    assert path.get("stroke") == "black"


def test_svg_of_a_deformed_mesh(tmp_path):
    shape = mvcjax.Shape.from_polygon([[0, 0], [40, 0], [40, 10], [0, 10]],
                                      [[[10, 3], [10, 7], [30, 7], [30, 3]]])
    rig = mvcjax.Rig.build(shape, [[2.0, 5.0], [38.0, 5.0]])
    deformed = rig.deform(rig.handle_positions + np.array([[0.0, 0.0], [0.0, 10.0]]))
    rings = export.outline_rings(deformed, rig.shape_mesh.faces)
    assert len(rings) == 2
    assert ring_area(rings[0]) > 0 > ring_area(rings[1])
    export.write_svg(tmp_path / "d.svg", rings, fill=None, stroke="#ff0000", width=400)
    back, root, path = svg_rings(tmp_path / "d.svg")
    for ring, want in zip(back, rings):
        np.testing.assert_allclose(ring, want * [1, -1], rtol=1e-6, atol=1e-5)
    assert root.get("width") == "400" and path.get("fill") == "none"


def test_svg_errors(tmp_path):
    with pytest.raises(ValueError, match="no rings"):
        export.write_svg(tmp_path / "a.svg", [])
    with pytest.raises(ValueError, match=r"rings\[0\] has 2 distinct vertices"):
        export.write_svg(tmp_path / "a.svg", [[[0, 0], [1, 0], [0, 0]]])
    with pytest.raises(ValueError, match=r"rings\[1\] contains NaN"):
        export.write_svg(tmp_path / "a.svg", [np.eye(3)[:, :2], np.full((3, 2), np.nan)])


def read_obj(path):
    vertices, uvs, faces = [], [], []
    for line in path.read_text().splitlines():
        kind, *values = line.split()
        if kind == "v":
            vertices.append([float(v) for v in values])
        elif kind == "vt":
            uvs.append([float(v) for v in values])
        elif kind == "f":
            corners = [v.split("/") for v in values]
            assert all(len(set(c)) == 1 for c in corners)  # a/a: one index per corner
            faces.append([int(c[0]) - 1 for c in corners])
    return np.array(vertices), np.array(uvs), np.array(faces)


def test_obj_reads_back(tmp_path):
    picture = np.zeros((20, 30), bool)
    picture[4:16, 5:25] = True
    shape = mvcjax.Shape.from_image(picture)
    rig = mvcjax.Rig.build(shape, [[7.0, 10.0], [22.0, 10.0]])
    rest, faces = np.asarray(rig.shape_mesh.vertices), np.asarray(rig.shape_mesh.faces)
    uv = export.texture_uv(rest, 20, 30)
    assert uv.min() >= 0 and uv.max() <= 1
    export.write_obj(tmp_path / "m.obj", rest, faces, texture_coordinates=uv)
    vertices, uvs, back_faces = read_obj(tmp_path / "m.obj")
    # Written in the shortest form that round-trips in their own dtype (float32 here).
    np.testing.assert_array_equal(vertices[:, :2].astype(rest.dtype), rest)
    assert not vertices[:, 2].any()
    np.testing.assert_array_equal(uvs.astype(uv.dtype), uv)
    np.testing.assert_array_equal(back_faces, faces)
    export.write_obj(tmp_path / "plain.obj", rest.astype(np.float32), faces)
    vertices, uvs, back_faces = read_obj(tmp_path / "plain.obj")
    assert len(uvs) == 0 and "/" not in (tmp_path / "plain.obj").read_text()
    np.testing.assert_array_equal(vertices[:, :2].astype(np.float32), rest.astype(np.float32))


def test_texture_uv_matches_the_pixel_convention():
    rows, cols = 4, 6
    corners = mvcjax.pixels_to_points([[0, 0], [rows - 1, cols - 1]], rows)
    np.testing.assert_allclose(export.texture_uv(corners, rows, cols),
                               [[0.5 / cols, 1 - 0.5 / rows], [1 - 0.5 / cols, 0.5 / rows]])


def test_obj_errors(tmp_path):
    vertices, faces = np.eye(3)[:, :2], np.array([[0, 1, 2]])
    with pytest.raises(ValueError, match=r"indices from 1 to 3.*\[0, 2\]"):
        export.write_obj(tmp_path / "a.obj", vertices, faces + 1)
    with pytest.raises(TypeError, match="faces must be integer"):
        export.write_obj(tmp_path / "a.obj", vertices, faces.astype(float))
    with pytest.raises(ValueError, match="one \\(u, v\\) per vertex"):
        export.write_obj(tmp_path / "a.obj", vertices, faces, texture_coordinates=vertices[:2])
