import subprocess
import sys

import matplotlib.image
import PIL.Image


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
        assert gif.n_frames == 12 and gif.size == (96, 96)
    image = matplotlib.image.imread(out)
    assert image.shape[0] > 300 and image.shape[1] > 600
    assert image[..., :3].std() > 0.05  # not a blank canvas
