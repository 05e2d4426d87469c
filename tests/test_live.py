"""`mvcjax.interact` dragged with a real mouse, and pins added and removed by clicks:
in JupyterLab in Chromium (Playwright, ipympl) and in a Tk window on a virtual X display
(Xvfb, xdotool), as `benchmarks/live.py` measures it. Skipped, saying what to install,
where Chromium or Xvfb is missing."""

import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import live


def check_dragged(row: dict, moves: int) -> None:
    # The mouse went right and up on the screen: the hoof's target went right and up in
    # the shape's coordinates (y up), by about the drag's length, one update a move or
    # fewer (a backend may merge moves).
    moved = np.asarray(row["moved"])
    assert moved[0] > 20 and moved[1] > 10, moved
    assert abs(moved[1] / moved[0] - live.DRAG[1] / live.DRAG[0]) < 0.2
    assert moves // 4 <= row["updates"] <= moves + 1
    # A click on the body added a pin, a right-click on its dot took it out again.
    assert len(row["pin_ms"]) == 2 and row["rows_after_pins"] == 5


MOVES = 12


def dragged(tmp_path, missing, drag) -> dict:
    """The drag's row, checked, or a skip naming what to install."""
    if missing:
        pytest.skip(f"no live drag: {missing}")
    row = drag(tmp_path, moves=MOVES, step_s=0.05)
    check_dragged(row, MOVES)
    return row


def test_interact_in_jupyterlab_in_chromium(tmp_path):
    row = dragged(tmp_path, live.missing_for_browser(), live.browser_drag)
    # The widget's picture changed where the leg went, and only around the shape.
    before = np.asarray(Image.open(tmp_path / "before.png").convert("RGB"), np.int32)
    after = np.asarray(Image.open(tmp_path / "after.png").convert("RGB"), np.int32)
    changed = np.abs(after - before).max(axis=-1) > 40
    rows, cols = np.indices(changed.shape)
    x, y = row["pressed_at"]
    near = np.hypot(cols - x, rows - y) < 100
    assert (changed & near).sum() > 300
    assert changed.mean() < 0.25
    # The browser drew the drag's poses as they came.
    assert row["browser_pictures"] >= MOVES // 4
    # The pin's red dot showed where the body was clicked, and went with the right-click.
    pinned, unpinned = (np.asarray(Image.open(tmp_path / f"{name}.png").convert("RGB"),
                                   np.int32) for name in ("pinned", "unpinned"))
    x, y = row["clicked_at"]
    dot = np.hypot(cols - x, rows - y) < 6

    def red(picture):
        return (picture[..., 0] > 180) & (picture[..., 1] < 90) & (picture[..., 2] < 90)

    assert red(pinned)[dot].sum() > 20 and red(unpinned)[dot].sum() < 5


def test_interact_in_a_tk_window_on_a_virtual_display(tmp_path):
    dragged(tmp_path, live.missing_for_window(), live.window_drag)
