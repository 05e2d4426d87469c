import subprocess
import sys

import matplotlib.image


def test_demo_writes_a_figure_and_reports(tmp_path):
    out = tmp_path / "demo.png"
    result = subprocess.run([sys.executable, "-m", "mvcjax", "demo", "--out", str(out)],
                            capture_output=True, text=True, check=True)
    for word in ["shape mesh", "control", "preprocess", "per frame"]:
        assert word in result.stdout
    image = matplotlib.image.imread(out)
    assert image.shape[0] > 300 and image.shape[1] > 600
    assert image[..., :3].std() > 0.05  # not a blank canvas
