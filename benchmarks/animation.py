"""An animation posed frame after frame: `mvcjax.deform_frames` with every frame solved
from its turned start (`chunk` frames at a time, vmapped), against `warm_start=True`
(each frame from the pose before it, one after another), with the default solver and
with `FoldFree`; and what the check of traced targets costs a jitted frame.

The animation: the built-in character with a bone per arm, its right arm turned from
rest to 150 degrees about the shoulder over `frames` frames. For each solver and start:
the first call's time (compiling included), the median time a frame over several calls,
the flipped shape triangles summed over the frames, and the largest handle miss, in
percent of the rest bounding-box diagonal. The check row times `jax.jit(rig.deform)` of
the default horse with targets checked for NaN when run (`eqx.error_if`, as mvcjax does)
and without, interleaved.

    python benchmarks/animation.py [--quick] [--json benchmarks/results/animation-cpu-2core.json]
"""

from __future__ import annotations

import sys
import time

from _timing import compile_ms, interleaved_median_ms, quick_and_json, write_results

DEGREES = 150.0


def arm_sweep(frames: int):
    """The character's rig and its targets `(frames, h, 2)`: the right arm turned from
    rest to `DEGREES`."""
    import numpy as np

    import mvcjax
    from mvcjax import datasets

    rig = mvcjax.Rig.build(datasets.character(), datasets.character_bones("arms"))
    rest = np.asarray(rig.handle_positions)
    targets = np.repeat(rest[None], frames, axis=0)
    for k, angle in enumerate(np.linspace(0.0, DEGREES, frames)):
        # Rows 4 and 5: the right arm's bone, from the shoulder to the wrist.
        targets[k, 5] = datasets._rotate(rest[5], rest[4], float(angle))
    return rig, targets


def measure_starts(frames: int, repeats: int) -> list[dict]:
    import jax
    import numpy as np

    import mvcjax

    rig, targets = arm_sweep(frames)
    mesh = rig.shape_mesh
    diagonal = float(np.linalg.norm(np.ptp(np.asarray(mesh.vertices), axis=0)))
    rows = []
    for name, solver in (("default", None), ("FoldFree", mvcjax.FoldFree())):
        for warm in (False, True):
            args = () if solver is None else (solver,)

            def run(warm=warm, args=args):
                return mvcjax.deform_frames(rig, targets, *args, warm_start=warm)

            first = compile_ms(run)
            times = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                posed = jax.block_until_ready(run())
                times.append(time.perf_counter() - t0)
            posed = np.asarray(posed)
            flipped = sum(int(mvcjax.flipped_triangles(mesh.vertices, p, mesh.faces))
                          for p in posed)
            pinned = posed[:, np.asarray(mesh.handles)]
            wanted = np.stack([np.asarray(rig.handles.pinned_targets(
                rig.frame.to_local(t))) for t in targets])
            miss = np.linalg.norm(pinned - np.asarray(rig.frame.to_world(wanted)), axis=-1)
            rows.append({"solver": name, "warm_start": warm, "frames": frames,
                         "first_s": first / 1e3,
                         "frame_ms": float(np.median(times)) * 1e3 / frames,
                         "flipped": flipped,
                         "max_miss_pct": float(miss.max()) / diagonal * 100})
            print(rows[-1], flush=True)
    return rows


def measure_check(repeats: int) -> dict:
    import jax
    import numpy as np

    import mvcjax
    from mvcjax import datasets
    from mvcjax.core import _checks

    rig = mvcjax.Rig.build(datasets.horse(), datasets.horse_handles())
    targets = np.asarray(rig.handle_positions + datasets.horse_drag())
    checked = jax.jit(lambda t: rig.deform(t))
    real = _checks.finite_when_traced
    _checks.finite_when_traced = lambda array, message: array
    try:
        unchecked = jax.jit(lambda t: rig.deform(t))
        jax.block_until_ready(unchecked(targets))
    finally:
        _checks.finite_when_traced = real
    jax.block_until_ready(checked(targets))
    times = interleaved_median_ms({"checked": (checked, [(targets,)]),
                                   "unchecked": (unchecked, [(targets,)])}, repeats)
    row = {"shape_vertices": int(rig.shape_mesh.vertices.shape[0]),
           "checked_ms": times["checked"], "unchecked_ms": times["unchecked"]}
    print(row, flush=True)
    return row


def format_table(data: dict) -> str:
    lines = ["| solver | start | first call (s) | per frame (ms) | flipped (all frames) "
             "| largest handle miss (% of diagonal) |", "|---|---|---|---|---|---|"]
    for r in data["rows"]:
        start = "each from the pose before (`warm_start=True`)" if r["warm_start"] else (
            "each from its turned start")
        lines.append(f"| {r['solver']} | {start} | {r['first_s']:.1f} | {r['frame_ms']:.2g} "
                     f"| {r['flipped']} | {r['max_miss_pct']:.2g} |")
    check = data["meta"]["check"]
    lines += ["", f"The check of traced targets, on a jitted frame of the default horse "
              f"({check['shape_vertices']} shape vertices): {check['checked_ms']:.3f} ms "
              f"checked, {check['unchecked_ms']:.3f} ms without."]
    return "\n".join(lines)


def main(argv=None) -> int:
    args = quick_and_json(__doc__, "fewer frames and repeats", argv)
    frames, repeats = (12, 2) if args.quick else (30, 5)
    rows = measure_starts(frames, repeats)
    check = measure_check(200 if args.quick else 2000)
    if args.json:
        write_results(args.json, rows, quick=args.quick, check=check, degrees=DEGREES)
    return 0


if __name__ == "__main__":
    sys.exit(main())
