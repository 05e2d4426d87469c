"""Updates a second of `mvcjax.interact` while a handle is dragged, on matplotlib's Agg
canvas (no screen), mesh only and textured, with the fold overlay drawn and without it.

For each shape mesh (about 6k vertices by default), each way of drawing (the shape
filled with its control mesh over it, and textured by a `Renderer` of `--size` pixels)
and each `show_folds` (the folded triangles drawn red with a hint counting them, or not),
a 6 x 6 inch figure at 100 dpi is made and drawn once (the picture rendered at the axes'
size in pixels, as `interact` does by default), a press lands on the head's handle, and `--moves`
synthesised motion events drag it along a circle, each event going through the canvas as
a backend would send it. An update is the whole handling of one event: the compiled
solve, skin (and render), the fold mask, the artists' new data and the blit. Reported:
the median update and the updates a second it allows, its parts (the compiled pose
program alone; the drawing: the rest), the number of XLA compilations during the drag
(0 expected), the most triangles folded during it (0 expected: the circle folds
nothing), the first pose (compilation included), and a full redraw of the figure
(`canvas.draw()`, the pose not recomputed): the drawing cost blitting avoids, to compare
with the update's drawing. Then a second drag pulls the back's handle down through the
legs in `--moves` steps, which folds them: the median update over the moves where
something is folded (the overlay and the hint drawn) and the median number folded. Then,
back at rest, `--pins` clicks on the shape away from the handles each add a pin and a
right-click on it takes it out again: the median time from the click to the new pose on
the canvas, for adding and for removing (`Posing.pin_seconds`), and the compilations
they caused (0 expected: a pin changes numbers, not shapes). With both
`show_folds` measured (the default), the two sessions take turns event by event, so
that on a shared machine the load falls on both alike. The target, at least 30
updates a second at 6k vertices, is printed and recorded, never asserted.

    python benchmarks/interact.py                     # 6k vertices, 200 moves
    python benchmarks/interact.py --quick --json FILE # 1.5k vertices, 30 moves
    python benchmarks/interact.py --solver paper      # FixedG() instead of the default
"""

from __future__ import annotations

import argparse
import sys
import time

from _timing import median_ms, spacing_for, write_results

TARGET_UPDATES_PER_S = 30.0
PIN_CLICKS = 10
BACK = 3  # the horse's back handle
FOLDING_PULL = (0.0, -150.0)  # pulling the back's handle this far folds the horse's legs
SOLVERS = ("default", "paper", "fold-free")


class _Compilations:
    def __init__(self):
        self.count = 0

    def __call__(self, event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            self.count += 1


def _mouse(posing, kind: str, point, button: int = 1) -> None:
    from matplotlib.backend_bases import MouseEvent

    x, y = posing.axes.transData.transform(point)
    MouseEvent(f"{kind}_event", posing.figure.canvas, x, y, button=button)._process()


def _pin_spots(rig, count: int):
    """`count` shape-mesh vertices off the outline, a tenth of the shape's size or more
    from every handle: where the clicks add pins."""
    import numpy as np

    from mvcjax.geometry._topology import boundary_loops

    vertices = np.asarray(rig.shape_mesh.vertices, np.float64)
    handles = np.asarray(rig.handle_positions, np.float64)
    far = np.min(np.linalg.norm(vertices[:, None] - handles[None], axis=2), axis=1)
    outline = np.concatenate(boundary_loops(np.asarray(rig.shape_mesh.faces)))
    inner = np.setdiff1d(np.flatnonzero(far > 0.1 * np.ptp(vertices, axis=0).max()), outline)
    return vertices[np.random.default_rng(0).choice(inner, count, replace=False)]


def _pins(sessions, spots) -> tuple[list[list[float]], list[list[float]]]:
    """For each session, the click-to-pose seconds of each pin added at `spots` and of
    its removal, the sessions taking turns."""
    added, removed = [[] for _ in sessions], [[] for _ in sessions]
    for spot in spots:
        for k, posing in enumerate(sessions):
            _mouse(posing, "button_press", spot)
            _mouse(posing, "button_release", spot)
            added[k].append(posing.pin_seconds[-1])
            _mouse(posing, "button_press", posing.targets[-1], button=3)
            removed[k].append(posing.pin_seconds[-1])
    return added, removed


def _solver(name: str):
    import mvcjax
    from mvcjax.solvers import DEFAULT_SOLVER

    return {"default": DEFAULT_SOLVER, "paper": mvcjax.FixedG(),
            "fold-free": mvcjax.FoldFree()}[name]


def _drag(sessions, handle: int, path) -> tuple[list[list[float]], list[list[int]]]:
    """A drag of `handle` along `path` in each session, the sessions taking turns event
    by event (so that a shared machine's load falls on all alike): for each session, the
    time of each motion event and the folds after it."""
    for posing in sessions:
        _mouse(posing, "button_press", posing.targets[handle])
    times, folds = [[] for _ in sessions], [[] for _ in sessions]
    for point in path:
        for k, posing in enumerate(sessions):
            t0 = time.perf_counter()
            _mouse(posing, "motion_notify", point)
            times[k].append(time.perf_counter() - t0)
            folds[k].append(posing.folds)
    for posing in sessions:
        _mouse(posing, "button_release", path[-1])
    return times, folds


def run(rig, mode: str, size: int, moves: int, solver: str, shows: list[bool],
        pins: int) -> list[dict]:
    """One row per `show_folds` in `shows`, their sessions dragged side by side."""
    import jax
    import jax.numpy as jnp
    import matplotlib.pyplot as plt
    import numpy as np

    import mvcjax

    options = {"solver": _solver(solver)}
    if mode == "textured":
        options.update({"size": (size, size)} if size
                       else {"fill": mvcjax.advanced.Checkerboard()})
    sessions, first_ms, redraw_ms = [], [], []
    for show in shows:
        t0 = time.perf_counter()
        posing = mvcjax.interact(rig, show_folds=show, **options)
        first_ms.append((time.perf_counter() - t0) * 1e3)
        canvas = posing.figure.canvas
        canvas.draw()
        redraw = []
        for _ in range(5):
            t0 = time.perf_counter()
            canvas.draw()
            redraw.append(time.perf_counter() - t0)
        redraw_ms.append(float(np.median(redraw) * 1e3))
        sessions.append(posing)
    head = sessions[0].targets[-1].copy()
    radius = 0.1 * float(np.ptp(np.asarray(rig.shape_mesh.vertices), axis=0).max())
    angles = np.linspace(0, 2 * np.pi, moves)
    path = head + radius * np.stack([np.cos(angles) - 1, np.sin(angles)], axis=1)
    compilations = _Compilations()
    jax.monitoring.register_event_duration_secs_listener(compilations)
    circle_times, circle_folds = _drag(sessions, len(sessions[0].targets) - 1, path)
    targets = sessions[0]._all.copy()  # every row of the session's rig
    for posing in sessions:
        posing.reset()
    back = sessions[0].targets[BACK].copy()
    pull = back + np.linspace(0, 1, moves + 1)[1:, None] * np.asarray(FOLDING_PULL)
    pull_times, pull_folds = _drag(sessions, BACK, pull)
    dragging = compilations.count
    for posing in sessions:
        posing.reset()
    added, removed = _pins(sessions, _pin_spots(rig, pins))
    jax.monitoring.unregister_event_duration_listener(compilations)
    targets = jnp.asarray(targets, rig.energy.rest.dtype)
    rows = []
    for k, posing in enumerate(sessions):
        pose_ms = median_ms(posing._pose, [(posing._rig, targets)], repeats=50)
        times = np.asarray(circle_times[k])
        folds = np.asarray(pull_folds[k])
        folded = folds > 0
        update_ms = float(np.median(times) * 1e3)
        plt.close(posing.figure)
        row = {
            "mode": mode,
            "solver": solver,
            "show_folds": shows[k],
            "shape_vertices": int(rig.shape_mesh.vertices.shape[0]),
            "size": ("{}x{}".format(*posing.renderer.shape) if posing.renderer is not None
                     else None),
            "moves": moves,
            "updates": len(times),
            "update_ms": update_ms,
            "update_p90_ms": float(np.percentile(times, 90) * 1e3),
            "updates_per_s": 1e3 / update_ms,
            "pose_ms": pose_ms,
            "drawing_ms": update_ms - pose_ms,
            "compilations_while_dragging": dragging,
            "pin_clicks": pins,
            "pin_add_ms": float(np.median(added[k]) * 1e3),
            "pin_remove_ms": float(np.median(removed[k]) * 1e3),
            "compilations_while_pinning": compilations.count - dragging,
            "folds_max_circle": int(max(circle_folds[k])),
            "folded_moves": int(folded.sum()),
            "folded_update_ms": (float(np.median(np.asarray(pull_times[k])[folded]) * 1e3)
                                 if folded.any() else None),
            "folds_median": int(np.median(folds[folded])) if folded.any() else 0,
            "first_pose_ms": first_ms[k],
            "full_redraw_ms": redraw_ms[k],
            "target_updates_per_s": TARGET_UPDATES_PER_S,
            "target_met": 1e3 / update_ms >= TARGET_UPDATES_PER_S,
        }
        row["full_redraw_over_drawing"] = row["full_redraw_ms"] / row["drawing_ms"]
        rows.append(row)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a small mesh, few moves (CI)")
    parser.add_argument("--json", help="write the rows to this JSON file")
    parser.add_argument("--vertices", type=int, nargs="*", help="shape-mesh sizes")
    parser.add_argument("--size", type=int,
                        help="textured picture's side (default: the axes' size in pixels)")
    parser.add_argument("--moves", type=int, help="motion events per drag")
    parser.add_argument("--pins", type=int, default=PIN_CLICKS,
                        help="pins added and removed by clicks")
    parser.add_argument("--solver", choices=SOLVERS, default="default",
                        help="the solver of every update: rig.deform's default, the "
                             "paper's FixedG(), or FoldFree()")
    parser.add_argument("--show-folds", choices=("on", "off", "both"), default="both",
                        help="draw the fold overlay, not, or measure both")
    args = parser.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import mvcjax
    from mvcjax import datasets

    sizes = args.vertices or ([1500] if args.quick else [6000])
    moves = args.moves or (30 if args.quick else 200)
    shape, handles = datasets.horse(), datasets.horse_handles()
    shows = {"on": [True], "off": [False], "both": [True, False]}[args.show_folds]
    rows = []
    for vertices in sizes:
        rig = mvcjax.Rig.build(shape, handles, shape_spacing=spacing_for(shape, vertices))
        for mode in ("mesh", "textured"):
            for row in run(rig, mode, args.size, moves, args.solver, shows, args.pins):
                rows.append(row)
                show = row["show_folds"]
                folded = (f"{row['folded_update_ms']:.1f} ms with {row['folds_median']} "
                          f"folded ({row['folded_moves']} moves)"
                          if row["folded_update_ms"] is not None else "nothing folded")
                print(f"{row['shape_vertices']:>6} {mode:>8} {row['size'] or '':>8} folds "
                      f"{'shown' if show else 'off  '}: update {row['update_ms']:.1f} ms "
                      f"({row['updates_per_s']:.0f}/s; pose {row['pose_ms']:.1f} ms, "
                      f"drawing {row['drawing_ms']:.1f} ms), "
                      f"{row['compilations_while_dragging']} compilations while dragging, "
                      f"{row['folds_max_circle']} folded; pulled through the legs: "
                      f"{folded}; full redraw {row['full_redraw_ms']:.1f} ms; a pin added "
                      f"{row['pin_add_ms']:.1f} ms, removed {row['pin_remove_ms']:.1f} ms "
                      f"click to pose ({row['compilations_while_pinning']} compilations); "
                      "target >= "
                      f"{TARGET_UPDATES_PER_S:.0f}/s {'met' if row['target_met'] else 'MISSED'}",
                      flush=True)
    if args.json:
        write_results(args.json, rows, benchmark="interact", canvas="Agg",
                      solver=args.solver)
    return 0


if __name__ == "__main__":
    sys.exit(main())
