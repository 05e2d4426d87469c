"""`mvcjax.interact` dragged with a real mouse: in JupyterLab in Chromium, and in a Tk
window on a virtual X display.

- **browser**: a JupyterLab server on localhost, a notebook that runs
  `%matplotlib widget` (ipympl) and `mvcjax.interact(rig)` (filled, or textured: the
  checkerboard drawn by a `Renderer`), opened in the system's Chromium by Playwright (no
  browser download). The mouse presses on the front hoof's dot, moves in `--moves` steps
  `--step` seconds apart, and releases. The kernel reports the targets and its updates;
  the page counts the pictures the widget drew (calls of the canvas' `drawImage`,
  wrapped before the page loads), so the updates a second the browser received are
  measured where the user sees them.
- **window**: Xvfb, a script showing `mvcjax.interact` with the TkAgg backend, and
  `xdotool` pressing, moving and releasing the X pointer over the same dot.

After the drag, a click on the horse's body adds a pin there and a right-click on its
dot removes it: the time from each click to its pose is reported (`Posing.pin_seconds`).

Both report the drag's time, the updates the kernel (or script) made and their median
time, the pictures the browser drew a second, and whether the dragged target moved by
the drag. Needs `playwright`, `jupyterlab` and `ipympl` (pip) and Chromium, Xvfb and
xdotool (Debian: `apt-get install chromium xvfb xdotool`); a part whose tools are
missing is skipped with a line saying which.

    python benchmarks/live.py                      # 6k vertices, 60 moves
    python benchmarks/live.py --quick --json FILE  # the default horse rig, 20 moves
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import json
import os
import secrets
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _timing import spacing_for, write_results

HOOF = 0  # the horse's front hoof: the dot dragged
DRAG = (60.0, 40.0)  # screen pixels: right and up
BODY = (200.0, 180.0)  # a spot on the horse's body, away from its handles: a pin goes there
CHROMIUM = "/usr/bin/chromium"

# The rig and the session, as a user's notebook or script has them.
SETUP = """\
import json, time
import numpy as np
import mvcjax
from mvcjax import datasets
shape = datasets.horse()
rig = mvcjax.Rig.build(shape, datasets.horse_handles(), shape_spacing={spacing})
posing = mvcjax.interact(rig{texture})
"""
# Where the dots are, in the figure's pixels (y up), and how big the figure is.
PINS = """\
posing.figure.canvas.draw()
print("PINS " + json.dumps({"pins": posing.axes.transData.transform(posing.targets).tolist(),
                             "body": posing.axes.transData.transform([{body}]).tolist()[0],
                             "size": list(posing.figure.canvas.get_width_height())}))
"""
DRAGGED = """\
print("DRAGGED " + json.dumps({"updates": posing.updates}))
"""
RESULT = """\
print("RESULT " + json.dumps({"targets": posing.targets.tolist(),
                               "rest": np.asarray(rig.handle_positions).tolist(),
                               "updates": posing.updates,
                               "update_seconds": posing.update_seconds,
                               "pin_seconds": posing.pin_seconds,
                               "rows": posing.rig.handles.count,
                               "vertices": int(rig.shape_mesh.vertices.shape[0])}))
"""
# Counts the pictures drawn on each canvas of the page, with their times.
COUNT_DRAWS = """
window.__draws = [];
const ids = new WeakMap();
let canvases = 0;
const original = CanvasRenderingContext2D.prototype.drawImage;
CanvasRenderingContext2D.prototype.drawImage = function (...args) {
    if (!ids.has(this.canvas)) ids.set(this.canvas, canvases++);
    window.__draws.push([performance.now(), ids.get(this.canvas)]);
    return original.apply(this, args);
};
"""


def missing_for_browser() -> str | None:
    """Why the browser drag cannot run here, or None."""
    for module, install in [("playwright", "pip install playwright"),
                            ("jupyterlab", "pip install jupyterlab"),
                            ("ipympl", "pip install ipympl")]:
        if importlib.util.find_spec(module) is None:
            return f"{module} is not installed ({install})"
    if not os.path.exists(CHROMIUM):
        return f"no Chromium at {CHROMIUM} (Debian: apt-get install chromium)"
    return None


def missing_for_window() -> str | None:
    """Why the window drag cannot run here, or None."""
    for tool in ("Xvfb", "xdotool"):
        if shutil.which(tool) is None:
            return f"{tool} is not installed (Debian: apt-get install xvfb xdotool)"
    if importlib.util.find_spec("tkinter") is None:
        return "this Python has no tkinter"
    return None


def _setup(spacing: float | None, textured: bool) -> str:
    texture = ', fill=mvcjax.advanced.Checkerboard()' if textured else ""
    return SETUP.format(spacing=repr(spacing), texture=texture)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for_port(port: int, process: subprocess.Popen, log: Path, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"the server exited:\n{log.read_text()[-2000:]}")
        with contextlib.suppress(OSError):
            socket.create_connection(("127.0.0.1", port), 0.5).close()
            return
        time.sleep(0.2)
    raise TimeoutError(f"nothing listened on port {port} after {timeout:.0f} s")


def _summary(result: dict, drag_s: float) -> dict:
    import numpy as np

    moved = np.subtract(result["targets"][HOOF], result["rest"][HOOF])
    # The drag's updates: those before the pins were clicked.
    dragged = result.get("dragged", result["updates"] - len(result["pin_seconds"]))
    seconds = result["update_seconds"][:dragged]
    return {
        "shape_vertices": result["vertices"],
        "moved": moved.tolist(),
        "updates": dragged,
        "update_ms": float(np.median(seconds) * 1e3) if seconds else None,
        "drag_s": drag_s,
        "updates_per_s": dragged / drag_s,
        "pin_ms": [1e3 * s for s in result["pin_seconds"]],
        "rows_after_pins": result["rows"],
    }


def browser_drag(workdir: Path, *, spacing: float | None = None, textured: bool = False,
                 moves: int = 20, step_s: float = 0.01) -> dict:
    """Drag the hoof's dot in JupyterLab in Chromium; the kernel's and the page's counts,
    and the widget's screenshots before and after (`before.png`, `after.png`)."""
    import nbformat
    from playwright.sync_api import sync_playwright

    workdir = Path(workdir)
    notebook = nbformat.v4.new_notebook(cells=[
        nbformat.v4.new_code_cell("%matplotlib widget\n" + _setup(spacing, textured)),
        nbformat.v4.new_code_cell(PINS.replace("{body}", repr(list(BODY)))),
        nbformat.v4.new_code_cell(DRAGGED), nbformat.v4.new_code_cell(RESULT)])
    notebook.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3",
                                       "language": "python"}
    nbformat.write(notebook, workdir / "pose.ipynb")
    port, token, log = _free_port(), secrets.token_hex(16), workdir / "server.log"
    started = time.monotonic()
    with open(log, "w") as out:
        server = subprocess.Popen(
            [sys.executable, "-m", "jupyter", "lab", "--no-browser", "--allow-root",
             f"--port={port}", "--ip=127.0.0.1", f"--IdentityProvider.token={token}",
             f"--ServerApp.root_dir={workdir}", "--LabApp.news_url="],
            stdout=out, stderr=subprocess.STDOUT)
    try:
        _wait_for_port(port, server, log, 60)
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=CHROMIUM,
                                                 args=["--no-sandbox"])
            page = browser.new_page(viewport={"width": 1400, "height": 1000})
            page.add_init_script(COUNT_DRAWS)
            page.goto(f"http://127.0.0.1:{port}/lab/tree/pose.ipynb?token={token}")
            page.get_by_text("| Idle").wait_for(timeout=90_000)
            row = {"lab_s": time.monotonic() - started}

            def run_cell(index: int, prefix: str | None = None) -> dict | None:
                page.locator(".jp-Notebook .jp-Cell").nth(index).click()
                page.keyboard.press("Shift+Enter")
                if prefix is None:
                    return None
                output = page.locator(".jp-OutputArea-output", has_text=prefix + " ")
                output.wait_for(timeout=180_000)
                return json.loads(output.inner_text().split(prefix + " ", 1)[1].strip())

            shown = time.monotonic()
            run_cell(0)
            canvas = page.locator(".jupyter-matplotlib-figure canvas").last
            canvas.wait_for(timeout=180_000)
            pins = run_cell(1, "PINS")
            row["first_picture_s"] = time.monotonic() - shown
            canvas.scroll_into_view_if_needed()
            page.wait_for_timeout(500)
            box = canvas.bounding_box()
            width, height = pins["size"]

            def on_page(point):  # figure pixels (y up) -> the page's
                return (box["x"] + point[0] * box["width"] / width,
                        box["y"] + (height - point[1]) * box["height"] / height)

            x, y = on_page(pins["pins"][HOOF])
            canvas.screenshot(path=str(workdir / "before.png"))
            row["pressed_at"] = [x - box["x"], y - box["y"]]  # in the screenshots
            page.evaluate("window.__draws = []")
            page.mouse.move(x, y)
            page.mouse.down()
            begin = time.monotonic()
            for k in range(1, moves + 1):
                page.mouse.move(x + DRAG[0] * k / moves, y - DRAG[1] * k / moves)
                page.wait_for_timeout(step_s * 1e3)
            page.mouse.up()
            # The kernel runs a cell after every mouse message before it.
            dragged = run_cell(2, "DRAGGED")["updates"]
            drag_s = time.monotonic() - begin
            page.wait_for_timeout(1000)
            canvas.screenshot(path=str(workdir / "after.png"))
            draws = page.evaluate("window.__draws")  # the drag's pictures
            # A click on the body adds a pin there; a right-click on its dot removes it.
            body = on_page(pins["body"])
            row["clicked_at"] = [body[0] - box["x"], body[1] - box["y"]]
            page.mouse.click(*body)
            page.wait_for_timeout(1000)
            canvas.screenshot(path=str(workdir / "pinned.png"))
            page.mouse.click(*body, button="right")
            page.wait_for_timeout(1000)
            canvas.screenshot(path=str(workdir / "unpinned.png"))
            result = run_cell(3, "RESULT")
            result["dragged"] = dragged
            browser.close()
    finally:
        server.terminate()
        server.wait(30)
    row.update(_summary(result, drag_s))
    # Each canvas of the widget counts its pictures; the one drawn most is the figure's.
    counts: dict = {}
    for when, canvas_id in draws:
        counts.setdefault(canvas_id, []).append(when)
    times = max(counts.values(), key=len) if counts else []
    row["browser_pictures"] = len(times)
    row["browser_pictures_per_s"] = (
        (len(times) - 1) / ((times[-1] - times[0]) / 1e3) if len(times) > 1 else 0.0)
    return row


# The window's script: shows the session, writes where the dots are, and when told to
# stop (a file appears), writes the result.
WINDOW_SCRIPT = """\
import json, os, sys, time
import matplotlib
matplotlib.use("TkAgg")
import matplotlib.pyplot as plt
{setup}
plt.show(block=False)
plt.pause(1.0)
posing.figure.canvas.draw()
plt.pause(0.2)
widget = posing.figure.canvas.get_tk_widget()
out = sys.argv[1]
with open(out + ".tmp", "w") as f:
    json.dump({{"pins": posing.axes.transData.transform(posing.targets).tolist(),
               "body": posing.axes.transData.transform([{body}]).tolist()[0],
               "origin": [widget.winfo_rootx(), widget.winfo_rooty()],
               "height": widget.winfo_height()}}, f)
os.replace(out + ".tmp", out + ".pins")
deadline = time.monotonic() + 300
while not os.path.exists(out + ".stop") and time.monotonic() < deadline:
    plt.pause(0.01)
{result}
"""


def window_drag(workdir: Path, *, spacing: float | None = None, textured: bool = False,
                moves: int = 20, step_s: float = 0.01) -> dict:
    """Drag the hoof's dot in a Tk window on a virtual display with `xdotool`."""
    workdir = Path(workdir)
    script = workdir / "window.py"
    script.write_text(WINDOW_SCRIPT.format(
        setup=_setup(spacing, textured), body=list(BODY),
        result=RESULT.replace("print(", "open(out + '.result', 'w').write(", 1)))
    display = f":{90 + os.getpid() % 400}"
    xvfb = subprocess.Popen(["Xvfb", display, "-screen", "0", "1280x1024x24", "-nolisten",
                             "tcp"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    env = dict(os.environ, DISPLAY=display, MPLBACKEND="TkAgg")
    out = workdir / "window"
    started = time.monotonic()
    child = subprocess.Popen([sys.executable, str(script), str(out)], env=env,
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)

    def xdotool(*args) -> None:
        subprocess.run(["xdotool", *map(str, args)], env=env, check=True)

    try:
        pins_file = out.with_suffix(".pins")
        while not pins_file.exists():
            if child.poll() is not None:
                raise RuntimeError(f"the window's script exited:\n{child.stdout.read()}")
            if time.monotonic() - started > 180:
                raise TimeoutError("the window did not show in 180 s")
            time.sleep(0.1)
        row = {"window_s": time.monotonic() - started}
        pins = json.loads(pins_file.read_text())
        def on_screen(point):  # figure pixels (y up) -> the screen's (y down)
            return (round(pins["origin"][0] + point[0]),
                    round(pins["origin"][1] + pins["height"] - point[1]))

        x, y = on_screen(pins["pins"][HOOF])
        xdotool("mousemove", round(x), round(y))
        time.sleep(0.2)
        xdotool("mousedown", 1)
        begin = time.monotonic()
        for k in range(1, moves + 1):
            xdotool("mousemove", round(x + DRAG[0] * k / moves), round(y - DRAG[1] * k / moves))
            time.sleep(step_s)
        xdotool("mouseup", 1)
        drag_s = time.monotonic() - begin
        time.sleep(1.0)
        # A click on the body adds a pin there; a right-click on its dot removes it.
        xdotool("mousemove", *on_screen(pins["body"]))
        xdotool("click", 1)
        time.sleep(1.0)
        xdotool("click", 3)
        time.sleep(1.0)
        out.with_suffix(".stop").touch()
        child.wait(60)
        result = json.loads(out.with_suffix(".result").read_text().split("RESULT ", 1)[1])
    finally:
        child.kill()
        xvfb.terminate()
        xvfb.wait(10)
    row.update(_summary(result, drag_s))
    return row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="the default horse rig, 20 moves (CI)")
    parser.add_argument("--json", help="write the rows to this JSON file")
    parser.add_argument("--vertices", type=int, default=6000, help="shape-mesh vertices")
    parser.add_argument("--moves", type=int, help="mouse moves per drag")
    parser.add_argument("--step", type=float, default=0.01,
                        help="seconds between mouse moves (faster than the updates, so that "
                             "they are what limits the rate)")
    args = parser.parse_args(argv)
    from mvcjax import datasets

    spacing = None if args.quick else spacing_for(datasets.horse(), args.vertices)
    moves = args.moves or (20 if args.quick else 60)
    rows = []
    for where, drag, missing in [("browser", browser_drag, missing_for_browser()),
                                 ("window", window_drag, missing_for_window())]:
        if missing:
            print(f"{where}: skipped, {missing}", flush=True)
            continue
        for textured in (False, True):
            with tempfile.TemporaryDirectory() as workdir:
                row = {"where": where, "textured": textured, "moves": moves,
                       "step_s": args.step, **drag(Path(workdir), spacing=spacing,
                                                   textured=textured, moves=moves,
                                                   step_s=args.step)}
            rows.append(row)
            seen = (f", the browser drew {row['browser_pictures']} pictures "
                    f"({row['browser_pictures_per_s']:.1f}/s)" if where == "browser" else "")
            print(f"{where:>7} {'textured' if textured else 'filled':>8} "
                  f"{row['shape_vertices']:>6} vertices: {row['updates']} updates in "
                  f"{row['drag_s']:.2f} s ({row['updates_per_s']:.1f}/s, median update "
                  f"{row['update_ms']:.1f} ms){seen}; the dot moved "
                  f"({row['moved'][0]:.1f}, {row['moved'][1]:.1f}); a pin added and removed "
                  f"by clicks, click to pose {', '.join(f'{t:.0f}' for t in row['pin_ms'])} ms",
                  flush=True)
    if args.json:
        write_results(args.json, rows, benchmark="live")
    return 0


if __name__ == "__main__":
    sys.exit(main())
