import subprocess
import sys

import matplotlib.image
import PIL.Image
import PIL.ImageSequence


def test_demo_writes_a_figure_an_animation_and_reports(tmp_path):
    out, animation = tmp_path / "demo.png", tmp_path / "demo.gif"
    layers = tmp_path / "layers.gif"
    result = subprocess.run([sys.executable, "-m", "mvcjax", "demo", "--out", str(out),
                             "--animation", str(animation), "--frames", "12", "--size", "96",
                             "--layers", str(layers)],
                            capture_output=True, text=True, check=True)
    for word in ["building its rig ...", "compiling", "drawing", "shape mesh", "control",
                 "preprocess", "per frame", "animation", "drawn in layers", "4 parts"]:
        assert word in result.stdout
    with PIL.Image.open(layers) as gif:
        assert gif.n_frames >= 10 and gif.size == (240, 260)
    with PIL.Image.open(animation) as gif:
        assert gif.size == (96, 96)
        images, held = gif.n_frames, sum(frame.info["duration"] for frame in
                                         PIL.ImageSequence.Iterator(gif))
    # What the report says is what the file holds: 12 frames' time, in as many images as
    # differ from the one before (a repeat is held longer).
    assert round(held / (1000 / 24)) == 12
    said = "12 frames" + ("" if images == 12 else f" in {images} images")
    assert f"({said}" in result.stdout
    image = matplotlib.image.imread(out)
    assert image.shape[0] > 300 and image.shape[1] > 600
    assert image[..., :3].std() > 0.05  # not a blank canvas


def test_the_demo_frames_the_arm_poses_and_the_rest_outline_under_them():
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    import mvcjax
    from mvcjax.__main__ import _plot_arm_poses

    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    rig = mvcjax.Rig.build(mvcjax.Shape.from_polygon(square), [[0.5, 0.5]])
    rest = np.asarray(rig.shape_mesh.vertices)
    moved = rest + np.array([3.0, 2.0])
    poses = {"default": (moved, None, 0), "FoldFree": (moved, None, 0)}
    fig, axes = plt.subplots(1, 2)
    _plot_arm_poses(axes, {"rig": rig, "targets": moved[:1], "poses": poses}, 90.0)
    for ax in axes:
        (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
        for points in (rest, moved):
            assert x0 < points[:, 0].min() and points[:, 0].max() < x1
            assert y0 < points[:, 1].min() and points[:, 1].max() < y1
    plt.close(fig)


def test_every_commands_help_names_each_default_once_and_helps_every_option(capsys):
    import argparse
    import re

    import pytest

    from mvcjax.__main__ import _parser, main

    commands = next(a for a in _parser()._actions if isinstance(a, argparse._SubParsersAction))
    for command, parser in commands.choices.items():
        with pytest.raises(SystemExit):
            main([command, "--help"])
        text = " ".join(capsys.readouterr().out.split())
        assert "(default: None)" not in text
        # "(default: X) (default: Y)": argparse's default after the help's own
        assert not re.search(r"\(default:[^()]*\) \(default:", text), text
        assert all(action.help for action in parser._actions), command


def test_a_second_run_loads_what_the_first_compiled(tmp_path):
    # The command line keeps its programs in JAX's persistent compilation cache: the
    # second run of a command finds every program there and writes nothing new.
    import os

    import numpy as np

    cache = tmp_path / "cache"
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}

    def run(out):
        subprocess.run([sys.executable, "-m", "mvcjax", "dataset", "glyphs", str(out),
                        "--glyphs", "L", "--glyph-size", "40", "--poses", "2", "--batch",
                        "2", "--size", "40", "--progress", "off", "--compile-cache",
                        str(cache)], env=env, capture_output=True, text=True, check=True)
        return {p.name: p.stat().st_mtime_ns for p in cache.iterdir()}

    first = run(tmp_path / "first")
    assert len(first) > 10
    assert run(tmp_path / "second") == first
    pictures = [np.load(next((tmp_path / name).rglob("*.npz"))) for name in ("first",
                                                                                "second")]
    assert all(np.array_equal(pictures[0][k], pictures[1][k]) for k in pictures[0].files)
