"""Progress bars for long work (many frames drawn or written): tqdm, shown on a terminal
only, so that tests, CI logs and notebooks' stored outputs stay clean."""

from __future__ import annotations

import sys

# A bar for a handful of frames only flickers: `progress=None` shows one above this.
MIN_FRAMES = 10


def stderr_is_terminal() -> bool:
    try:
        return sys.stderr is not None and sys.stderr.isatty()
    except (AttributeError, ValueError):  # replaced or closed streams
        return False


def progress_bar(total: int, progress, description: str):
    """A tqdm bar over `total` frames: `progress` True shows it, False hides it, None
    shows it for more than `MIN_FRAMES` frames on a terminal."""
    from tqdm import tqdm

    if progress is None:
        progress = total > MIN_FRAMES and stderr_is_terminal()
    return tqdm(total=total, disable=not progress, desc=description, unit="frame", leave=False)
